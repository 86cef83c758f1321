"""Volume rendering, as flat functions (in the style of nerfacc's ``volrend.py``).

Quadrature of the emission-absorption model along a ray:
    alpha_i = 1 - exp(-sigma_i * delta_i),   T_i = prod_{j<i} (1 - alpha_j),   w_i = T_i * alpha_i,
    C = sum_i w_i c_i + (1 - sum_i w_i) * background.

Two layouts:
- *dense*: every ray has the same number of samples, tensors shaped (n_rays, n_samples).
- *packed*: ragged samples concatenated in ray order, with ``ray_indices`` (n_samples_total,) saying
  which ray each sample belongs to (samples of one ray are contiguous and sorted by distance). This is
  what empty-space skipping produces.

Weights are always computed in float32 (float64 for the packed prefix sums) whatever the input dtype:
transmittance is a product of many numbers close to 1 and half precision loses it.
"""
from __future__ import annotations

from typing import Optional, Tuple

import torch

Tensor = torch.Tensor


def _as_float(x: Tensor) -> Tensor:
    return x.float() if x.dtype in (torch.float16, torch.bfloat16) else x


# --------------------------------------------------------------------------------------- dense


def render_transmittance_from_density(t_starts: Tensor, t_ends: Tensor, sigmas: Tensor) -> Tuple[Tensor, Tensor]:
    """Transmittance before each sample and each sample's alpha.

    Args:
        t_starts: (n_rays, n_samples) start of each sample's interval along its ray.
        t_ends: (n_rays, n_samples) end of each interval.
        sigmas: (n_rays, n_samples) non-negative densities.

    Returns:
        transmittance: (n_rays, n_samples) T_i = exp(-sum_{j<i} sigma_j delta_j).
        alphas: (n_rays, n_samples) 1 - exp(-sigma_i delta_i).
        Both float32 (float16/bfloat16 inputs are computed in float32; float64 stays float64).
    """
    sigma_delta = _as_float(sigmas) * (_as_float(t_ends) - _as_float(t_starts))
    alphas = 1.0 - torch.exp(-sigma_delta)
    # Exclusive cumsum in log space: exact T_i = exp(-sum_{j<i} sigma_j delta_j), no product underflow.
    excl = torch.cumsum(sigma_delta, dim=-1) - sigma_delta
    transmittance = torch.exp(-excl)
    return transmittance, alphas


def optical_depth(t_starts: Tensor, t_ends: Tensor, sigmas: Tensor) -> Tensor:
    """Optical depth after each sample, sum_{j<=i} sigma_j delta_j: (n_rays, n_samples), from the same
    (n_rays, n_samples) inputs as ``render_transmittance_from_density`` (T after sample i is exp(-it))."""
    return torch.cumsum(_as_float(sigmas) * (_as_float(t_ends) - _as_float(t_starts)), dim=-1)


def render_weight_from_density(t_starts: Tensor, t_ends: Tensor, sigmas: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
    """Compositing weights of a dense batch of samples.

    Args:
        t_starts: (n_rays, n_samples) start of each sample's interval along its ray.
        t_ends: (n_rays, n_samples) end of each interval.
        sigmas: (n_rays, n_samples) non-negative densities.

    Returns:
        weights: (n_rays, n_samples) w_i = T_i * alpha_i.
        transmittance: (n_rays, n_samples) T_i.
        alphas: (n_rays, n_samples) alpha_i.
        All float32 (float64 inputs stay float64).
    """
    transmittance, alphas = render_transmittance_from_density(t_starts, t_ends, sigmas)
    return transmittance * alphas, transmittance, alphas


def accumulate_along_rays(weights: Tensor, values: Optional[Tensor] = None) -> Tensor:
    """Sum ``weights * values`` over the samples of each ray.

    Args:
        weights: (n_rays, n_samples) compositing weights.
        values: (n_rays, n_samples, d) per-sample values (colours: d = 3), or None to accumulate the
            weights themselves (opacity).

    Returns:
        (n_rays, d) accumulated values, or (n_rays,) opacity when ``values`` is None.
    """
    if values is None:
        return weights.sum(dim=-1)
    return (weights.unsqueeze(-1) * _as_float(values)).sum(dim=-2)


def composite_background(rgb: Tensor, acc: Tensor, background: Tensor) -> Tensor:
    """Put ``background`` (n_rays, 3) behind premultiplied ``rgb`` (n_rays, 3) with opacity ``acc`` (n_rays,).

    Args:
        rgb: (n_rays, 3) accumulated (premultiplied) colour, ``accumulate_along_rays(weights, rgbs)``.
        acc: (n_rays,) accumulated opacity in [0, 1].
        background: (n_rays, 3) colour behind each ray (or anything that broadcasts, e.g. (3,)).

    Returns:
        (n_rays, 3) rgb + (1 - acc) * background.
    """
    return rgb + (1.0 - acc).unsqueeze(-1) * background


def render_rays_dense(t_starts: Tensor, t_ends: Tensor, sigmas: Tensor, rgbs: Tensor, background: Tensor) -> dict:
    """Render dense samples into colour, expected depth and opacity.

    Args:
        t_starts, t_ends, sigmas: (n_rays, n_samples); rgbs: (n_rays, n_samples, 3); background: (n_rays, 3).

    Returns:
        dict with ``rgb`` (n_rays, 3) composited on the background, ``depth`` (n_rays,) expected distance
        of the visible surface (weighted mean of interval midpoints, normalised by opacity so that it
        stays a distance on partly transparent rays), ``acc`` (n_rays,) and ``weights`` (n_rays, n_samples).
    """
    weights, _, _ = render_weight_from_density(t_starts, t_ends, sigmas)
    acc = accumulate_along_rays(weights)
    rgb = composite_background(accumulate_along_rays(weights, rgbs), acc, background.to(weights.dtype))
    mids = 0.5 * (_as_float(t_starts) + _as_float(t_ends))
    depth = accumulate_along_rays(weights, mids.unsqueeze(-1)).squeeze(-1) / acc.clamp_min(1e-6)
    return {"rgb": rgb, "depth": depth, "acc": acc, "weights": weights}


# -------------------------------------------------------------------------------------- packed


def packed_info_from_ray_indices(ray_indices: Tensor, n_rays: int) -> Tuple[Tensor, Tensor]:
    """(first sample index, sample count) of each ray, both (n_rays,) long, from sorted ``ray_indices``.

    Args:
        ray_indices: (n_samples_total,) long, the ray of each packed sample, sorted.
        n_rays: number of rays.

    Returns:
        starts: (n_rays,) long index of each ray's first sample in the packed arrays.
        counts: (n_rays,) long number of samples of each ray (0 for a ray without samples).
    """
    counts = torch.bincount(ray_indices, minlength=n_rays)
    starts = torch.cumsum(counts, 0) - counts
    return starts, counts


def ray_starts(ray_indices: Tensor, n_rays: int) -> Tensor:
    """(n_rays,) long index of each ray's first sample in the packed arrays (for a ray without samples:
    where its samples would begin), from sorted ``ray_indices`` (n_samples_total,) long.

    The same numbers as ``packed_info_from_ray_indices``' starts, by a search instead of a count:
    ``bincount`` sizes its output from the largest index, which a GPU must read back to the host."""
    return torch.searchsorted(ray_indices, torch.arange(n_rays, device=ray_indices.device, dtype=ray_indices.dtype))


def render_transmittance_from_density_packed(
    t_starts: Tensor, t_ends: Tensor, sigmas: Tensor, ray_indices: Tensor, n_rays: int
) -> Tuple[Tensor, Tensor]:
    """Packed version of :func:`render_transmittance_from_density`.

    Args:
        t_starts: (n_samples_total,) start of each packed sample's interval.
        t_ends: (n_samples_total,) end of each interval.
        sigmas: (n_samples_total,) non-negative densities.
        ray_indices: (n_samples_total,) long, the ray of each sample, sorted (a ray's samples contiguous
            and in order of distance).
        n_rays: number of rays.

    Returns:
        transmittance: (n_samples_total,) T_i within each sample's ray.
        alphas: (n_samples_total,) alpha_i.
        Both float32 (float64 inputs stay float64); the prefix sums are float64.
    """
    sigma_delta = _as_float(sigmas) * (_as_float(t_ends) - _as_float(t_starts))
    alphas = 1.0 - torch.exp(-sigma_delta)
    if sigma_delta.numel() == 0:
        return torch.ones_like(sigma_delta), alphas
    # One global prefix sum instead of a Python loop over rays; float64 because the running total over
    # every ray in the batch is large and float32 would lose the small per-ray differences.
    cs = torch.cumsum(sigma_delta.double(), 0)
    excl = cs - sigma_delta.double()
    starts = ray_starts(ray_indices, n_rays)
    # Exclusive sum at the first sample of each ray = offset to subtract for all samples of that ray.
    ray_offset = excl[starts.clamp_max(excl.numel() - 1)]
    per_sample = excl - ray_offset[ray_indices]
    transmittance = torch.exp(-per_sample).to(sigma_delta.dtype)
    return transmittance, alphas


def render_weight_from_density_packed(
    t_starts: Tensor, t_ends: Tensor, sigmas: Tensor, ray_indices: Tensor, n_rays: int
) -> Tuple[Tensor, Tensor, Tensor]:
    """Packed compositing weights: returns weights, transmittance, alphas, each (n_samples_total,) float32.

    Args:
        t_starts: (n_samples_total,) start of each packed sample's interval.
        t_ends: (n_samples_total,) end of each interval.
        sigmas: (n_samples_total,) non-negative densities.
        ray_indices: (n_samples_total,) long, the ray of each sample, sorted.
        n_rays: number of rays.

    Returns:
        weights: (n_samples_total,) w_i = T_i * alpha_i.
        transmittance: (n_samples_total,) T_i.
        alphas: (n_samples_total,) alpha_i.
        All float32 (float64 inputs stay float64).
    """
    transmittance, alphas = render_transmittance_from_density_packed(t_starts, t_ends, sigmas, ray_indices, n_rays)
    return transmittance * alphas, transmittance, alphas


def accumulate_along_rays_packed(weights: Tensor, ray_indices: Tensor, n_rays: int,
                                 values: Optional[Tensor] = None) -> Tensor:
    """Sum ``weights * values`` per ray in the packed layout.

    Args:
        weights: (n_samples_total,) compositing weights.
        ray_indices: (n_samples_total,) long, the ray of each sample (need not be sorted here).
        n_rays: number of rays.
        values: (n_samples_total, d) per-sample values, or None for opacity.

    Returns:
        (n_rays, d) accumulated values, or (n_rays,) opacity when ``values`` is None; 0 for rays
        without samples.
    """
    if values is None:
        return torch.zeros(n_rays, dtype=weights.dtype, device=weights.device).index_add(0, ray_indices, weights)
    src = weights.unsqueeze(-1) * _as_float(values)
    out = torch.zeros(n_rays, src.shape[-1], dtype=src.dtype, device=src.device)
    return out.index_add(0, ray_indices, src)


def distortion_loss_packed(weights: Tensor, t_starts: Tensor, t_ends: Tensor, ray_indices: Tensor,
                           n_rays: int) -> Tensor:
    """mip-NeRF 360's distortion loss per ray, in the packed layout (samples sorted per ray):

        L = sum_{i,j} w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (t_end_i - t_start_i),   m = interval midpoints.

    It is small when a ray's weight sits in one short stretch (a surface) and large when it is spread
    along the ray (fog, floaters in front of the camera). The double sum is computed in O(n) with
    per-ray prefix sums: sum_{i,j} w_i w_j |m_i - m_j| = 2 sum_i w_i (m_i W_<i - S_<i), with
    W_<i = sum_{j<i} w_j and S_<i = sum_{j<i} w_j m_j.

    Args:
        weights: (n_samples_total,) compositing weights.
        t_starts: (n_samples_total,) start of each sample's interval.
        t_ends: (n_samples_total,) end of each interval.
        ray_indices: (n_samples_total,) long, the ray of each sample, sorted.
        n_rays: number of rays.

    Returns:
        (n_rays,) float32 loss per ray, in the units of ``t`` (divide ``t`` beforehand to normalise);
        0 for rays without samples.
    """
    if weights.numel() == 0:
        return torch.zeros(n_rays, dtype=weights.dtype, device=weights.device)
    w = weights.float()
    mids = 0.5 * (t_starts + t_ends).float()
    starts = ray_starts(ray_indices, n_rays)
    first = starts.clamp_max(w.numel() - 1)[ray_indices]

    def exclusive_per_ray(x: Tensor) -> Tensor:
        cs = torch.cumsum(x.double(), 0)
        excl = cs - x.double()
        return (excl - excl[first]).to(x.dtype)

    w_before = exclusive_per_ray(w)
    wm_before = exclusive_per_ray(w * mids)
    inter = 2.0 * w * (mids * w_before - wm_before)
    intra = (w * w) * (t_ends - t_starts).float() / 3.0
    out = torch.zeros(n_rays, dtype=w.dtype, device=w.device)
    return out.index_add(0, ray_indices, inter + intra)
