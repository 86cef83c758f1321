"""The occupancy-marched, early-terminated renderer as flat functions over packed samples (nerfacc's
style): the one home of "keep what is still visible, weight it, colour what can matter, add it up".

A method marches its rays (``sampling.occupied_samples``) into packed samples (``volrend``'s layout:
t_starts, t_ends, ray_indices, each (k,), sorted by ray then distance), then:

1. ``visible_after_one_pass`` or ``visible_front_to_back``: without grad, the samples whose
   transmittance is still above ``t_min``, so that nothing behind an opaque surface is evaluated again;
2. ``volrend.render_weight_from_density_packed`` on the survivors' density (with grad);
3. ``colour_where_it_matters`` (optional): the samples whose colour can change the picture;
4. ``composite``: colour, expected depth and opacity per ray, on the background.

``vmgrid``, ``nerf`` and the mesh export's surface level (``export.level``, dense samples through
``volrend``) all render through these; none reads another's state.
"""
from __future__ import annotations

from typing import Callable, Dict, Optional

import torch

from nerf_core.utils import profiling
from nerf_core.volume import ray_termination, volrend

Tensor = torch.Tensor


def chunked(fn: Callable[[Tensor], Tensor], x: Tensor, chunk: int) -> Tensor:
    """``fn`` over ``x`` (m, ...) in pieces of ``chunk`` rows, concatenated: bounds the memory of a
    field's no-grad evaluation. ``fn`` is called once even for m = 0 (it gives the empty result's shape)."""
    return torch.cat([fn(x[i:i + chunk]) for i in range(0, max(1, x.shape[0]), chunk)])


@torch.no_grad()
def visible_after_one_pass(t_starts: Tensor, t_ends: Tensor, ray_indices: Tensor, n_rays: int, sigmas: Tensor,
                           t_min: float = 1e-4) -> Tensor:
    """Positions (n,) long, in packed order, of the samples whose transmittance is above ``t_min``,
    from every sample's density ``sigmas`` (k,) (the cheapest way when most samples survive, as in
    training once the occupancy grid is tight). The caller weights the survivors again, with grad.

    Args:
        t_starts, t_ends: (k,) each sample's interval along its ray.
        ray_indices: (k,) long, the ray of each sample, sorted by ray then distance.
        n_rays: rays in the batch.
    """
    with profiling.stage("rendering"):
        trans, _ = volrend.render_transmittance_from_density_packed(t_starts, t_ends, sigmas, ray_indices, n_rays)
    return (trans > t_min).nonzero().squeeze(-1)


@torch.no_grad()
def visible_front_to_back(t_starts: Tensor, t_ends: Tensor, ray_indices: Tensor, n_rays: int,
                          density_fn: Callable[[Tensor], Tensor], t_min: float = 1e-4,
                          round_size: int = 32) -> tuple[Tensor, Tensor]:
    """The same kept samples, with density evaluated front to back in rounds of ``round_size``
    samples per ray and no further once a ray is opaque (``ray_termination.visible_samples``;
    rendering, and an MLP's training). ``density_fn``: sample positions (j,) long -> densities (j,).

    Returns (kept positions (n,) long in packed order, their weights (n,) float32)."""
    keep, weights = ray_termination.visible_samples(t_starts, t_ends, ray_indices, n_rays, density_fn,
                                                    t_min=t_min, round_size=round_size)
    return keep.nonzero().squeeze(-1), weights


def colour_where_it_matters(weights: Tensor, acc: Tensor, ray_indices: Tensor, min_weight: float,
                            clear_rays: float = 0.05) -> Tensor:
    """Positions (j,) long of the samples whose colour is evaluated: weight above ``min_weight``, or on
    a ray whose opacity ``acc`` (n_rays,) is still below ``clear_rays``.

    Most surviving samples are transparent space before a surface, so colour is wasted there. Rays
    that are still almost transparent (all of them at initialisation) get colour at every sample:
    treating unevaluated samples as black would teach the density only to darken rays, and a field
    on a random background would then never become opaque."""
    vis = (weights.detach() > min_weight) | (acc.detach().index_select(0, ray_indices) < clear_rays)
    return vis.nonzero().squeeze(-1)


def composite(weights: Tensor, ray_indices: Tensor, t_starts: Tensor, t_ends: Tensor, n_rays: int,
              background: Tensor, rgb: Tensor, coloured: Optional[Tensor] = None,
              acc: Optional[Tensor] = None, coloured_pad: Optional[Tensor] = None) -> Dict[str, Tensor]:
    """Add up a ray batch's packed samples.

    Args:
        weights: (k,) compositing weights T_i alpha_i.
        ray_indices: (k,) long, the ray of each sample.
        t_starts, t_ends: (k,) the samples' intervals (the depth is their weighted midpoint).
        n_rays: rays in the batch.
        background: (n_rays, 3) or (3,) colour behind each ray.
        rgb: (k, 3) colour of every sample, or (j, 3) of the samples at ``coloured`` only.
        coloured: (j,) long positions that ``rgb`` colours (``colour_where_it_matters``), or None.
        acc: (n_rays,) the rays' opacity when the caller already summed it, else None.
        coloured_pad: (j,) bool, the entries of ``coloured`` that are a fixed-size buffer's padding
            (``padded.compact``): they repeat a sample, so their weight is left out of the colour.

    Returns:
        {"rgb": (n_rays, 3) on the background, "depth": (n_rays,) expected distance (normalised by the
        opacity), "acc": (n_rays,) opacity}.
    """
    with profiling.stage("rendering"):
        if acc is None:
            acc = volrend.accumulate_along_rays_packed(weights, ray_indices, n_rays)
        if coloured is None:
            colour = volrend.accumulate_along_rays_packed(weights, ray_indices, n_rays, rgb)
        else:
            w = weights.index_select(0, coloured)
            if coloured_pad is not None:
                w = w.masked_fill(coloured_pad, 0.0)
            colour = volrend.accumulate_along_rays_packed(w, ray_indices.index_select(0, coloured), n_rays, rgb)
        mids = (0.5 * (t_starts + t_ends)).unsqueeze(-1)
        depth = volrend.accumulate_along_rays_packed(weights, ray_indices, n_rays, mids).squeeze(-1)
        depth = depth / acc.clamp_min(1e-6)
        colour = volrend.composite_background(colour, acc, background.to(colour.dtype))
    return {"rgb": colour, "depth": depth, "acc": acc}
