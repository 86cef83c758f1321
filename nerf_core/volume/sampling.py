"""Where to put samples along rays: box clipping, stratified, importance and occupancy-guided sampling.

All functions work on whatever device their inputs are on.
"""
from __future__ import annotations

from typing import Optional, Tuple

import torch

from nerf_core.utils import arguments

Tensor = torch.Tensor


def ray_aabb_intersect(rays_o: Tensor, rays_d: Tensor, aabb: Tensor,
                       eps: float = 1e-9) -> Tuple[Tensor, Tensor, Tensor]:
    """Slab-method intersection of rays with an axis-aligned box.

    Args:
        rays_o: (n_rays, 3) ray origins.
        rays_d: (n_rays, 3) directions; need not be unit (distances are then in units of |d|).
        aabb: (2, 3) = [min corner, max corner] (moved to ``rays_o``'s device and dtype).
        eps: direction components smaller than this in magnitude count as parallel to the slab.

    Returns:
        t_near (n_rays,), t_far (n_rays,) in ``rays_o``'s dtype, hit (n_rays,) bool. ``t_near`` is
        clamped at 0 so that a ray starting inside the box begins at its origin. Where ``hit`` is False
        the values are meaningless (``t_near == t_far``). A ray parallel to a slab hits only if its
        origin lies between the planes.
    """
    aabb = aabb.to(rays_o)
    d = rays_d
    # Replace exact zeros by a tiny signed value: the slab then spans (-inf, inf) when the origin is
    # between its planes and is empty otherwise, which is the right answer for a parallel ray.
    d = torch.where(d.abs() < eps, torch.full_like(d, eps), d)
    inv = 1.0 / d
    t0 = (aabb[0] - rays_o) * inv
    t1 = (aabb[1] - rays_o) * inv
    t_near = torch.minimum(t0, t1).amax(dim=-1).clamp_min(0.0)
    t_far = torch.maximum(t0, t1).amin(dim=-1)
    hit = t_far > t_near
    t_far = torch.where(hit, t_far, t_near)
    return t_near, t_far, hit


def stratified_samples(near: Tensor, far: Tensor, n_samples: int, jitter: bool,
                       generator: Optional[torch.Generator] = None) -> Tensor:
    """Interval edges for ``n_samples`` stratified samples between near and far.

    Args:
        near: (n_rays,) start of each ray's interval.
        far: (n_rays,) end of each ray's interval.
        n_samples: number of intervals per ray.
        jitter: if True each interior edge moves uniformly inside its stratum (training); else uniform.
        generator: the random generator for the jitter, or None for torch's global one.

    Returns:
        edges (n_rays, n_samples + 1) in ``near``'s dtype, from ``near`` to ``far``: interval i is
        [edges[:, i], edges[:, i+1]].
    """
    n_samples = arguments.integer("stratified_samples", "n_samples", n_samples, low=1)
    near = arguments.tensor("stratified_samples", "near", near, ndim=1)
    far = arguments.tensor("stratified_samples", "far", far, ndim=1)
    arguments.same_shape("stratified_samples", "near", near, "far", far)
    if bool((far < near).any()):
        raise ValueError("stratified_samples: far must be >= near on every ray")
    arguments.instance("stratified_samples", "jitter", jitter, bool, "True or False")
    if generator is not None:
        arguments.instance("stratified_samples", "generator", generator, torch.Generator, "a torch.Generator or None")
    u = torch.linspace(0.0, 1.0, n_samples + 1, device=near.device, dtype=near.dtype).expand(near.shape[0], -1)
    if jitter:
        # Jitter the midpoints between bin edges so that intervals stay ordered and still tile [near, far].
        noise = torch.rand(near.shape[0], n_samples + 1, device=near.device, dtype=near.dtype, generator=generator)
        step = 1.0 / n_samples
        u = u + (noise - 0.5) * step
        u = torch.cat([torch.zeros_like(u[:, :1]), u[:, 1:-1].clamp(0, 1), torch.ones_like(u[:, :1])], dim=-1)
    return near.unsqueeze(-1) + (far - near).unsqueeze(-1) * u


def importance_samples(edges: Tensor, weights: Tensor, n_samples: int, deterministic: bool,
                       generator: Optional[torch.Generator] = None, eps: float = 1e-5) -> Tensor:
    """Inverse-CDF sampling of new distances from a piecewise-constant pdf (hierarchical sampling).

    Args:
        edges: (n_rays, n_bins + 1) sorted bin edges along each ray.
        weights: (n_rays, n_bins) non-negative bin weights (e.g. a coarse pass's compositing weights).
        n_samples: how many distances to draw per ray.
        deterministic: use evenly spaced quantiles instead of random ones (evaluation).
        generator: the random generator for the quantiles, or None for torch's global one.
        eps: added to every weight, so that a ray whose weights are all zero samples uniformly.

    Returns:
        (n_rays, n_samples) sorted distances in ``edges``' dtype, detached (no gradient flows through
        sample placement).
    """
    edges = edges.detach()
    weights = weights.detach().float() + eps  # eps keeps a pdf on rays whose weights are all zero
    pdf = weights / weights.sum(dim=-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)], dim=-1).clamp_max(1.0)
    n_rays = edges.shape[0]
    if deterministic:
        u = (torch.arange(n_samples, device=edges.device, dtype=cdf.dtype) + 0.5) / n_samples
        u = u.expand(n_rays, n_samples).contiguous()
    else:
        u = torch.rand(n_rays, n_samples, device=edges.device, dtype=cdf.dtype, generator=generator).sort(dim=-1).values
    idx = torch.searchsorted(cdf, u, right=True).clamp(1, cdf.shape[-1] - 1)
    cdf_lo, cdf_hi = cdf.gather(-1, idx - 1), cdf.gather(-1, idx)
    e = edges.to(cdf.dtype)
    e_lo, e_hi = e.gather(-1, idx - 1), e.gather(-1, idx)
    frac = ((u - cdf_lo) / (cdf_hi - cdf_lo).clamp_min(1e-12)).clamp(0, 1)
    return (e_lo + frac * (e_hi - e_lo)).to(edges.dtype)


def merge_edges(edges: Tensor, new_t: Tensor) -> Tensor:
    """Sorted union of existing interval edges (n_rays, a) and new distances (n_rays, b) -> (n_rays, a + b)."""
    return torch.sort(torch.cat([edges, new_t], dim=-1), dim=-1).values


def ray_points(rays_o: Tensor, rays_d: Tensor, ray_idx: Tensor, t: Tensor) -> Tensor:
    """(k, 3) points at distances ``t`` (k,) along rays ``ray_idx`` (k,) of ``rays_o``, ``rays_d`` (n_rays, 3).
    ``index_select`` gathers rows about 3x faster than ``rays_o[ray_idx]`` on the CPU (470k rows: 1.2 ms
    against 3.5 ms), and every candidate sample of every ray passes through here."""
    return torch.addcmul(rays_o.index_select(0, ray_idx), rays_d.index_select(0, ray_idx), t.unsqueeze(-1))


def occupied_samples(rays_o: Tensor, rays_d: Tensor, near: Tensor, far: Tensor, step_size: float,
                     occupied_fn, jitter: bool, max_samples: int = 1024,
                     generator: Optional[torch.Generator] = None, near_fn=None,
                     near_reach: float = 0.0) -> Tuple[Tensor, Tensor, Tensor]:
    """March every ray at a fixed step and keep only samples whose midpoint is in an occupied cell.

    Args:
        rays_o, rays_d: (n_rays, 3); near, far: (n_rays,) interval (rays with far <= near get nothing).
        step_size: distance between samples in scene units.
        occupied_fn: maps points (m, 3) -> (m,) bool, e.g. ``OccupancyGrid.query``.
        jitter: shift each ray's samples by a random fraction of a step (training).
        max_samples: cap on the number of steps per ray.
        near_fn, near_reach: optional, to skip empty stretches without testing each step there:
            ``near_fn`` maps points (m, 3) -> (m,) bool and must be True wherever ``occupied_fn`` could
            be True within distance ``near_reach`` (``OccupancyGrid.query_near`` and its
            ``near_reach()``). Each ray is then probed once per run of steps that fits within that
            reach of the probe, and only runs whose probe says yes are tested step by step. The
            result is the same as without them; only the number of points tested drops (on a trained
            demo scene the step-by-step test took a fifth of the render time).

    Returns:
        packed ``t_starts`` (k,), ``t_ends`` (k,), ``ray_indices`` (k,) long, sorted by ray then distance.
    """
    n_rays = rays_o.shape[0]
    span = (far - near).clamp_min(0)
    # Both numbers the host needs (the step count, the longest direction) in one read: each read waits
    # for the device on a GPU.
    want_d = near_fn is not None
    if n_rays:
        first = torch.ceil(span.max() / step_size)
        got = (torch.stack([first, rays_d.norm(dim=-1).max()]) if want_d else first.reshape(1)).tolist()
    else:
        got = [1.0, 0.0]
    n_steps = int(min(max_samples, max(1, int(got[0]))))
    if jitter:
        shift = torch.rand(n_rays, 1, device=rays_o.device, dtype=rays_o.dtype, generator=generator)
    else:
        shift = torch.full((n_rays, 1), 0.5, device=rays_o.device, dtype=rays_o.dtype)
    # A run of `run` steps has its probe half-way between its first and last step, (run - 1) / 2 steps
    # from either end; rays_d need not be unit, so the reach is measured with the longest direction.
    d_max = float(got[1]) if n_rays and want_d else 0.0
    run = int(2 * near_reach / (step_size * d_max)) + 1 if d_max > 0 else 1
    if run >= 3 and n_steps > run:
        ray_idx, step_idx, ok = _steps_near_occupancy(near, far, shift, step_size, n_steps, run, rays_o, rays_d,
                                                      near_fn)
        shift_s = shift[:, 0].index_select(0, ray_idx)
        t = near.index_select(0, ray_idx) + (step_idx.to(rays_o.dtype) + shift_s) * step_size
        # One mask, one compaction: in range, before the far end, and in an occupied cell (testing the
        # few steps past the end costs less than compacting twice).
        keep = ok & (t < far.index_select(0, ray_idx)) & occupied_fn(ray_points(rays_o, rays_d, ray_idx, t))
    else:
        offs = torch.arange(n_steps, device=rays_o.device, dtype=rays_o.dtype)
        t_mid = near.unsqueeze(-1) + (offs + shift) * step_size  # (n_rays, n_steps)
        inside = t_mid < far.unsqueeze(-1)
        ray_idx, step_idx = inside.nonzero(as_tuple=True)
        t = t_mid[ray_idx, step_idx]
        keep = occupied_fn(ray_points(rays_o, rays_d, ray_idx, t))
    sel = keep.nonzero().squeeze(-1)
    ray_idx, t = ray_idx.index_select(0, sel), t.index_select(0, sel)
    half = 0.5 * step_size
    t0 = (t - half).clamp_min(near.index_select(0, ray_idx))
    return t0, (t + half).clamp_max(far.index_select(0, ray_idx)), ray_idx


def _steps_near_occupancy(near, far, shift, step_size, n_steps, run, rays_o, rays_d, near_fn):
    """(ray, step) index pairs (k,), (k,) of every step in a run of ``run`` steps whose probe ``near_fn``
    accepts, sorted by ray then step, and (k,) bool: the step is within ``n_steps`` (``occupied_samples``
    folds it into its own mask, to compact once)."""
    dev, dt = rays_o.device, rays_o.dtype
    n_runs = (n_steps + run - 1) // run
    first = torch.arange(n_runs, device=dev, dtype=dt) * run  # each run's first step
    started = near.unsqueeze(-1) + (first + shift) * step_size < far.unsqueeze(-1)  # (n_rays, n_runs)
    r_idx, run_idx = started.nonzero(as_tuple=True)
    t_probe = near.index_select(0, r_idx) + (run_idx.to(dt) * run + 0.5 * (run - 1)
                                             + shift[:, 0].index_select(0, r_idx)) * step_size
    hit = near_fn(ray_points(rays_o, rays_d, r_idx, t_probe)).nonzero().squeeze(-1)
    r_idx, run_idx = r_idx.index_select(0, hit), run_idx.index_select(0, hit)
    steps = (run_idx.unsqueeze(-1) * run + torch.arange(run, device=dev)).reshape(-1)
    return r_idx.unsqueeze(-1).expand(-1, run).reshape(-1), steps, steps < n_steps


def contracted_samples(rays_o: Tensor, rays_d: Tensor, near: Tensor, aabb: Tensor, step_size: float,
                       occupied_fn, jitter: bool, max_samples: int = 1024,
                       generator: Optional[torch.Generator] = None) -> Tuple[Tensor, Tensor, Tensor]:
    """Samples for a contracted scene (``nerf_core.volume.contraction``): a fixed step inside the box, then
    uniform in disparity (1 / distance) out to ~``n`` times the exit distance, so that samples are
    about evenly spaced in contracted space; only those whose contracted midpoint is occupied are kept.

    Args:
        rays_o, rays_d: (n_rays, 3); near: (n_rays,) where each ray starts.
        aabb: (2, 3) the scene box (uncontracted region).
        step_size: distance between samples inside the box; the outer part gets as many samples as the
            box's mean half-size holds steps (the contracted shell is one half-size thick).
        occupied_fn: maps world points (m, 3) -> (m,) bool (squeezed into the outer box inside it).

    Returns:
        packed ``t_starts`` (k,), ``t_ends`` (k,), ``ray_indices`` (k,) long, sorted by ray then distance.
    """
    n_rays = rays_o.shape[0]
    _, t_exit, hit = ray_aabb_intersect(rays_o, rays_d, aabb)
    # Where the outer part begins: the box exit for rays that cross the box, else where the ray starts.
    t_split = torch.where(hit, torch.maximum(t_exit, near), near).clamp_min(1e-3)
    span = (t_split - near).clamp_min(0)
    n_in = int(min(max_samples, max(1, int(torch.ceil(span.max() / step_size).item()) if n_rays else 1)))
    half = float((0.5 * (aabb[1] - aabb[0])).mean())
    n_out = int(min(max_samples, max(8, round(half / step_size))))
    dev, dt = rays_o.device, rays_o.dtype
    shift = (torch.rand(n_rays, 1, device=dev, dtype=dt, generator=generator) if jitter
             else torch.full((n_rays, 1), 0.5, device=dev, dtype=dt))
    # Inside: midpoints at a fixed step from near, up to the split.
    t_in = near.unsqueeze(-1) + (torch.arange(n_in, device=dev, dtype=dt) + shift) * step_size
    ok_in = t_in < t_split.unsqueeze(-1)
    lo_in = (t_in - 0.5 * step_size).clamp_min(near.unsqueeze(-1))
    hi_in = torch.minimum(t_in + 0.5 * step_size, t_split.unsqueeze(-1))
    # Outside: edges t_split / (1 - s) for s evenly spaced in [0, 1), i.e. uniform in disparity.
    s = (torch.arange(n_out + 1, device=dev, dtype=dt) / (n_out + 1)).expand(n_rays, -1)
    if jitter:  # move the inner edges within their strata; the first stays at the split, so no gap opens
        s = torch.cat([s[:, :1], s[:, 1:] + shift / (n_out + 1)], -1)
    edges = t_split.unsqueeze(-1) / (1.0 - s)
    lo_out, hi_out = edges[:, :-1], edges[:, 1:]
    lo = torch.cat([lo_in, lo_out], -1)
    hi = torch.cat([hi_in, hi_out], -1)
    valid = torch.cat([ok_in, torch.ones_like(lo_out, dtype=torch.bool)], -1) & (hi > lo)
    flat = valid.reshape(-1).nonzero().squeeze(-1)  # one flat index: 2-D indexing gathers 1.5x slower
    ray_idx = flat // valid.shape[1]
    t0, t1 = lo.reshape(-1).index_select(0, flat), hi.reshape(-1).index_select(0, flat)
    keep = occupied_fn(ray_points(rays_o, rays_d, ray_idx, 0.5 * (t0 + t1)))
    return t0[keep], t1[keep], ray_idx[keep]
