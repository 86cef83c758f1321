"""A grid method's training render with every shape fixed before the step (vmgrid's ``sample_budget``).

The same four stages as the packed renderer (``volume.marching``: march the occupied cells, keep what
is visible after a gradient-free pass, weight it with grad, colour what can matter), with each
compaction into a buffer whose size ``SampleBudget`` chose on the host (``volume.padded``). Nothing in
it reads the device: on a GPU the step can be queued whole (and captured as a graph), on the CPU it
makes no data-dependent shape.
"""
from __future__ import annotations

from typing import Callable, Dict, Optional

import torch

from nerf_core.methods.sample_budget import SampleBudget
from nerf_core.utils import profiling
from nerf_core.volume import grad_scaling, marching, padded, sampling, volrend
from nerf_core.volume.occupancy import OccupancyGrid

Tensor = torch.Tensor

T_MIN = 1e-4  # transmittance below which a sample is hidden (``marching.visible_after_one_pass``)
CLEAR_RAYS = 0.05  # rays still this transparent get colour everywhere (``marching.colour_where_it_matters``)


def render_fixed(rays_o: Tensor, rays_d: Tensor, near: Tensor, far: Tensor, background: Tensor,
                 budget: SampleBudget, step_size: float, n_steps: int, occupancy: OccupancyGrid,
                 density_fn: Callable[[Tensor], Tensor], colour_fn: Callable[[Tensor, Tensor], Tensor],
                 colour_weight: float,
                 grad_scale_fn: Optional[Callable[[Tensor], Optional[Tensor]]] = None) -> Dict[str, Tensor]:
    """Render a training batch through buffers of ``budget``'s sizes.

    Args:
        rays_o, rays_d: (n_rays, 3), unit directions; near, far: (n_rays,); background: (n_rays, 3).
        step_size, n_steps: the marching step and the steps per ray (``padded.steps_for_box``).
        occupancy: the grid the samples are kept in.
        density_fn: points (m, 3) -> densities (m,) (with grad when grad is enabled).
        colour_fn: points (m, 3), unit directions (m, 3) -> colours (m, 3).
        colour_weight: a sample's colour is evaluated where its weight exceeds this.
        grad_scale_fn: sample distances (m,) -> per-sample gradient factors (m,) or None.

    Returns:
        ``marching.composite``'s dict, plus ``fits`` (n_rays,) bool (the rays rendered whole),
        ``weights``, ``t_starts``, ``t_ends``, ``ray_indices`` (k,) (for the method's regularisers)
        and ``n_samples`` (int: the sample buffer's size).
    """
    n_rays = rays_o.shape[0]
    with profiling.stage("sampling"):
        s = padded.occupied_samples_padded(rays_o, rays_d, near, far, step_size, n_steps, occupancy.query,
                                           budget.samples, jitter=True, near_fn=occupancy.query_near,
                                           near_reach=occupancy.near_reach(), run_size=budget.runs)
    pts = sampling.ray_points(rays_o, rays_d, s.ray_indices, 0.5 * (s.t_starts + s.t_ends))
    with torch.no_grad():
        sigma = density_fn(pts)
        with profiling.stage("rendering"):
            trans, _ = volrend.render_transmittance_from_density_packed(s.t_starts, s.t_ends, sigma, s.ray_indices,
                                                                        n_rays)
    pos, t0, t1, ridx, pad, fits_v, n_visible = padded.keep_padded((trans > T_MIN) & ~s.padding, budget.visible,
                                                                   s.t_starts, s.t_ends, s.ray_indices, n_rays)
    pts = pts.index_select(0, pos)
    sigma = density_fn(pts)
    gscale = grad_scale_fn(0.5 * (t0 + t1)) if grad_scale_fn is not None else None
    if gscale is not None:
        sigma = grad_scaling.scale_gradient(sigma, gscale)
    with profiling.stage("rendering"):
        weights, _, _ = volrend.render_weight_from_density_packed(t0, t1, sigma, ridx, n_rays)
        acc = volrend.accumulate_along_rays_packed(weights, ridx, n_rays)
    wants_colour = ((weights.detach() > colour_weight) | (acc.detach().index_select(0, ridx) < CLEAR_RAYS)) & ~pad
    cpos, cpad, n_coloured = padded.compact(wants_colour, budget.coloured)
    per_ray = torch.zeros(n_rays, dtype=torch.long, device=rays_o.device).index_add_(0, ridx, wants_colour.long())
    with profiling.stage("field"):
        rgb = colour_fn(pts.index_select(0, cpos), rays_d.index_select(0, ridx.index_select(0, cpos)))
    if gscale is not None:
        rgb = grad_scaling.scale_gradient(rgb, gscale.index_select(0, cpos))
    out = marching.composite(weights, ridx, t0, t1, n_rays, background, rgb, coloured=cpos, acc=acc,
                             coloured_pad=cpad)
    budget.observe(n_rays, s.count, s.runs, n_visible, n_coloured)
    out.update(fits=s.fits & fits_v & padded.fitting_rays(per_ray, budget.coloured), weights=weights,
               t_starts=t0, t_ends=t1, ray_indices=ridx, n_samples=budget.samples)
    return out
