"""Early ray termination evaluated front to back, for rendering without gradients.

A grid method's samples come packed (``volrend``'s layout: sorted by ray, then by distance). The
training path evaluates the density of *every* sample, then keeps those whose transmittance is still
above ``t_min``. Behind an opaque surface every sample is dropped, but its density was paid for: on a
trained ``vmgrid`` about half the samples of the first pass lie behind the first surface (inside the
object and out through the back of the box).

``visible_samples`` gets the same kept samples and weights while evaluating the density in rounds of
``round_size`` samples per ray, front to back, and stops asking for a ray's samples once the ray is
opaque. Transmittance only falls along a ray, so a ray whose transmittance after a round is below
``t_min`` has no later sample above it: the samples skipped are exactly those the full pass drops.
The prefix sums are float64 like ``volrend.render_transmittance_from_density_packed``, so the kept set
and weights equal the full pass's up to float64 rounding (tested against it).
"""
from __future__ import annotations

from typing import Callable

import torch

from nerf_core.volume.volrend import packed_info_from_ray_indices

Tensor = torch.Tensor


def visible_samples(
    t_starts: Tensor,
    t_ends: Tensor,
    ray_indices: Tensor,
    n_rays: int,
    density_fn: Callable[[Tensor], Tensor],
    t_min: float = 1e-4,
    round_size: int = 32,
) -> tuple[Tensor, Tensor]:
    """Samples still visible (transmittance > ``t_min``) and their compositing weights.

    Args:
        t_starts: (k,) start of each packed sample's interval.
        t_ends: (k,) end of each interval.
        ray_indices: (k,) long, the ray of each sample, sorted by ray then distance.
        n_rays: number of rays.
        density_fn: sample positions in the packed arrays (j,) long -> densities (j,); called once
            per round with the samples of the rays not yet opaque.
        t_min: a sample is kept when the transmittance in front of it is above this.
        round_size: samples per ray evaluated per round (smaller: less wasted behind surfaces, more
            calls).

    Returns:
        keep (k,) bool: the kept samples; weights (n_kept,) float32: T_i * alpha_i of the kept samples,
        in packed order.
    """
    k = int(t_starts.shape[0])
    dev = t_starts.device
    keep = torch.zeros(k, dtype=torch.bool, device=dev)
    if k == 0:
        return keep, torch.zeros(0, dtype=torch.float32, device=dev)
    starts, counts = packed_info_from_ray_indices(ray_indices, n_rays)
    rank = torch.arange(k, device=dev) - starts[ray_indices]  # position of each sample along its ray
    depth = torch.zeros(n_rays, dtype=torch.float64, device=dev)  # optical depth in front of the round
    alive = torch.ones(n_rays, dtype=torch.bool, device=dev)
    log_t_min = -torch.log(torch.tensor(t_min, dtype=torch.float64)).item()
    weights = torch.zeros(k, dtype=torch.float32, device=dev)
    n_rounds = (int(counts.max()) + round_size - 1) // round_size
    for r in range(n_rounds):
        lo = r * round_size
        sel = ((rank >= lo) & (rank < lo + round_size) & alive[ray_indices]).nonzero().squeeze(-1)
        if sel.numel() == 0:
            break
        ridx = ray_indices[sel]
        sigma_delta = density_fn(sel).float() * (t_ends[sel].float() - t_starts[sel].float())
        alphas = 1.0 - torch.exp(-sigma_delta)
        sd = sigma_delta.double()
        excl = torch.cumsum(sd, 0) - sd
        first = packed_info_from_ray_indices(ridx, n_rays)[0]
        excl = excl - excl[first.clamp_max(excl.numel() - 1)][ridx] + depth[ridx]
        trans = torch.exp(-excl).float()
        visible = trans > t_min
        keep[sel[visible]] = True
        weights[sel] = trans * alphas
        depth = depth.index_add(0, ridx, sd)
        # Transmittance only falls along a ray: past this depth no later sample can be visible. The
        # margin covers float64 rounding of the prefix sums and the float32 cast of ``trans``.
        alive &= depth < log_t_min + 1e-6
    return keep, weights[keep]
