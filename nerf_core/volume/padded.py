"""Occupancy-guided samples in buffers of a size fixed before the step: the fixed-shape training step.

``sampling.occupied_samples`` sizes its tensors from the data (how far the longest ray goes, how many
steps fall in occupied cells), so each compaction makes the host wait for the device (on a GPU; on the
CPU each is still a data-dependent shape). Here every size is known on the host before the step: the
steps per ray follow from the box's diagonal, and each compaction is a ``torch.nonzero_static`` into
a buffer whose size the caller chose (``budget.SampleBudget``).

Padding: the entries past a buffer's kept ones repeat its last candidate with an empty interval
(t_start = t_end). They belong to the batch's last ray and lie at its far end, so the packed layout
stays sorted by ray then distance, and they weigh nothing in the compositing (alpha = 0) and get no
gradient. A buffer too small for a batch keeps the first rays whole and cuts the rest: ``fits``
(n_rays,) says which rays kept every sample, and the loss leaves the others out.

Every function here takes and returns tensors on the rays' device and reads nothing back to the host.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional, Tuple

import torch

from nerf_core.volume.sampling import ray_points

Tensor = torch.Tensor


@dataclass
class PaddedSamples:
    """Packed samples in a buffer of fixed size k (``volrend``'s layout, sorted by ray then distance).

    t_starts, t_ends: (k,) each sample's interval; padding has t_starts == t_ends.
    ray_indices: (k,) long, the ray of each sample (padding: the batch's last ray).
    padding: (k,) bool, True at the padding.
    fits: (n_rays,) bool, the rays all of whose samples are in the buffer.
    count: () long, the samples that wanted a place (more than k when the buffer overflowed).
    runs: () long, the marching runs that wanted a place (0 when the rays were not probed in runs).
    """

    t_starts: Tensor
    t_ends: Tensor
    ray_indices: Tensor
    padding: Tensor
    fits: Tensor
    count: Tensor
    runs: Tensor


def compact(mask: Tensor, size: int) -> Tuple[Tensor, Tensor, Tensor]:
    """The positions of ``mask``'s True entries in a buffer of ``size``, without a host read.

    Args:
        mask: (m,) bool, m >= 1.
        size: the buffer's length (>= 1).

    Returns:
        positions: (size,) long, the True entries in order, then the last position (m - 1) repeated;
        padded: (size,) bool, True at the repeated entries past the True ones;
        count: () long, the True entries (above ``size`` when they did not all fit).
    """
    pos = torch.nonzero_static(mask, size=size, fill_value=mask.numel() - 1).squeeze(-1)
    count = mask.sum()
    return pos, torch.arange(size, device=mask.device) >= count, count


def fitting_rays(per_ray: Tensor, size: int) -> Tensor:
    """(n_rays,) bool: the rays whose entries all lie in a buffer of ``size`` filled ray after ray,
    from each ray's number of entries ``per_ray`` (n_rays,)."""
    return per_ray.cumsum(0) <= size


def steps_for_box(aabb: Tensor, step_size: float, max_samples: int) -> int:
    """Marching steps that cover any unit ray's stretch inside ``aabb`` (2, 3): its diagonal over the
    step, at most ``max_samples``. A host number from the box alone: no batch is read."""
    diag = math.sqrt(sum(float(e) ** 2 for e in (aabb[1] - aabb[0]).tolist()))
    return int(min(max_samples, max(1, math.ceil(diag / step_size))))


def occupied_samples_padded(rays_o: Tensor, rays_d: Tensor, near: Tensor, far: Tensor, step_size: float,
                            n_steps: int, occupied_fn: Callable[[Tensor], Tensor], size: int, jitter: bool,
                            near_fn: Optional[Callable[[Tensor], Tensor]] = None, near_reach: float = 0.0,
                            run_size: int = 0, generator: Optional[torch.Generator] = None) -> PaddedSamples:
    """``sampling.occupied_samples`` into a buffer of ``size`` samples, with every shape fixed on the host.

    Args:
        rays_o, rays_d: (n_rays, 3), n_rays >= 1; ``rays_d`` of unit length (the batchers' rays are).
        near, far: (n_rays,) each ray's interval (a ray with far <= near gets nothing).
        step_size: distance between samples; n_steps: steps per ray (``steps_for_box``).
        occupied_fn: points (m, 3) -> (m,) bool.
        size: the sample buffer's length.
        jitter: shift each ray's samples by a random fraction of a step (training).
        near_fn, near_reach: as in ``sampling.occupied_samples``: each ray is probed once per run of
            steps within ``near_reach`` of the probe, and only runs whose probe says yes are tested
            step by step. The runs that pass go into a buffer of ``run_size`` runs (0: no probing).

    Returns:
        ``PaddedSamples`` of length ``size``.
    """
    n_rays, dev, dt = rays_o.shape[0], rays_o.device, rays_o.dtype
    if jitter:
        shift = torch.rand(n_rays, 1, device=dev, dtype=dt, generator=generator)
    else:
        shift = torch.full((n_rays, 1), 0.5, device=dev, dtype=dt)
    run = int(2 * near_reach / step_size) + 1 if near_fn is not None else 1  # unit rays: |d| = 1
    fits = None
    if run >= 3 and n_steps > run and run_size > 0:
        n_runs = (n_steps + run - 1) // run
        first = torch.arange(n_runs, device=dev, dtype=dt) * run  # each run's first step
        started = near.unsqueeze(-1) + (first + shift) * step_size < far.unsqueeze(-1)  # (n_rays, n_runs)
        t_probe = near.unsqueeze(-1) + (first + (0.5 * (run - 1)) + shift) * step_size
        probes = torch.addcmul(rays_o.unsqueeze(1), rays_d.unsqueeze(1), t_probe.unsqueeze(-1))
        hit = started & near_fn(probes.reshape(-1, 3)).view(n_rays, n_runs)
        runs, run_pad, n_runs_wanted = compact(hit.reshape(-1), run_size)
        fits = fitting_rays(hit.sum(1), run_size)
        ray_idx = torch.div(runs, n_runs, rounding_mode="floor")
        step_idx = (runs - ray_idx * n_runs).unsqueeze(-1) * run + torch.arange(run, device=dev)  # (run_size, run)
        ray_idx = ray_idx.unsqueeze(-1).expand(-1, run).reshape(-1)
        step_idx = step_idx.reshape(-1)
        ok = (step_idx < n_steps) & ~run_pad.unsqueeze(-1).expand(-1, run).reshape(-1)
    else:
        ray_idx = torch.arange(n_rays, device=dev).unsqueeze(-1).expand(-1, n_steps).reshape(-1)
        step_idx = torch.arange(n_steps, device=dev).repeat(n_rays)
        ok = None
        n_runs_wanted = torch.zeros((), dtype=torch.long, device=dev)
    near_s = near.index_select(0, ray_idx)
    far_s = far.index_select(0, ray_idx)
    t = near_s + (step_idx.to(dt) + shift[:, 0].index_select(0, ray_idx)) * step_size
    keep = (t < far_s) & occupied_fn(ray_points(rays_o, rays_d, ray_idx, t))
    if ok is not None:
        keep = keep & ok
    sel, pad, count = compact(keep, size)
    per_ray = torch.zeros(n_rays, dtype=torch.long, device=dev).index_add_(0, ray_idx, keep.long())
    fits = fitting_rays(per_ray, size) if fits is None else fits & fitting_rays(per_ray, size)
    ray_idx, t = ray_idx.index_select(0, sel), t.index_select(0, sel)
    half = 0.5 * step_size
    t0 = (t - half).clamp_min(near_s.index_select(0, sel))
    t1 = torch.where(pad, t0, (t + half).clamp_max(far_s.index_select(0, sel)))
    return PaddedSamples(t0, t1, ray_idx, pad, fits, count, n_runs_wanted)


def keep_padded(mask: Tensor, size: int, t_starts: Tensor, t_ends: Tensor, ray_indices: Tensor,
                n_rays: int) -> Tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The packed samples where ``mask`` (k,) is True, into a buffer of ``size`` (the survivors of early
    termination, say), padded as above. ``mask`` must be False at the input's own padding.

    Returns (positions (size,) long into the input, t_starts, t_ends, ray_indices, padding (size,)
    each, fits (n_rays,) bool, count () long)."""
    pos, pad, count = compact(mask, size)
    t0 = t_starts.index_select(0, pos)
    t1 = torch.where(pad, t0, t_ends.index_select(0, pos))
    per_ray = torch.zeros(n_rays, dtype=torch.long, device=mask.device).index_add_(0, ray_indices, mask.long())
    return pos, t0, t1, ray_indices.index_select(0, pos), pad, fitting_rays(per_ray, size), count
