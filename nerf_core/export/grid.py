"""Sampling a trained field on a regular grid over the scene box, in chunks (memory stays bounded at
any resolution), and the memory check that refuses a grid that would not fit.

Layout: ``grid[i, j, k]`` is the sample at ``box[0] + (i, j, k) * spacing`` with ``spacing = (box[1] -
box[0]) / (n - 1)``: the first and last samples lie on the box's faces, like the grid field's own nodes.
"""
from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np
import torch

from nerf_core.export import field
from nerf_core.utils.memory import available_memory, size_text

Tensor = torch.Tensor
MAX_RESOLUTION = 2048
CHUNK_POINTS = 1 << 18  # points per model call: ~100 MB of activations for the nerf MLP, far less for vmgrid
# The bounded working set of one chunk outside the model (slab points, their float64 coordinates,
# directions and colours; measured 183 B a point at 64^3 = one chunk, nerf_core/tests/test_export_memory.py)
CHUNK_BYTES = CHUNK_POINTS * 200


def check_fits(resolution: int, bytes_per_sample: float, flag: str = "--resolution", fixed: int = 0) -> None:
    """Refuse (ValueError naming ``flag`` and the memory needed) a grid of ``resolution``^3 samples of
    ``bytes_per_sample`` bytes each, plus ``fixed`` bytes of bounded working set, that is above
    MAX_RESOLUTION or needs more than ``utils.memory.available_memory`` (free memory, ``ulimit -v``, a
    container's limit: the smallest)."""
    if resolution < 2:
        raise ValueError(f"{flag} {resolution}: a grid needs at least 2 samples per axis")
    need = float(resolution) ** 3 * bytes_per_sample + fixed
    avail = available_memory()
    if resolution > MAX_RESOLUTION or (avail is not None and need > avail):
        have = f"{size_text(avail)} is available" if avail is not None else f"the limit is {MAX_RESOLUTION} per axis"
        raise ValueError(f"{flag} {resolution}: a {resolution}^3 grid needs {size_text(need)} of memory and {have}; "
                         "lower the resolution")


def axes(box: np.ndarray, resolution: int) -> list[np.ndarray]:
    """The sample coordinates along x, y, z: three (resolution,) float64 arrays spanning the box."""
    return [np.linspace(box[0, a], box[1, a], resolution) for a in range(3)]


def spacing(box: np.ndarray, resolution: int) -> np.ndarray:
    """(3,) distance between neighbouring samples along x, y, z, in scene units."""
    return (box[1] - box[0]) / (resolution - 1)


def slab_points(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, i0: int, i1: int) -> Tensor:
    """World points (k * ny * nz, 3) of the grid slab ``i0 <= i < i1``, in ``grid[i, j, k]`` order."""
    gx, gy, gz = np.meshgrid(xs[i0:i1], ys, zs, indexing="ij")
    return torch.from_numpy(np.stack([gx, gy, gz], axis=-1).reshape(-1, 3).astype(np.float32))


def sample_density(model, box: np.ndarray, resolution: int,
                   on_progress: Optional[Callable[[float], None]] = None) -> np.ndarray:
    """Density per scene unit on the grid: (resolution, resolution, resolution) float32 [x, y, z].

    The model is called on slabs of at most ``CHUNK_POINTS`` points, so the memory besides the grid
    itself stays bounded. ``on_progress`` gets the share done, in [0, 1], after every slab.
    """
    xs, ys, zs = axes(box, resolution)
    out = np.empty((resolution,) * 3, dtype=np.float32)
    per_slab = max(1, CHUNK_POINTS // (resolution * resolution))
    device = model.aabb.device
    for i0 in range(0, resolution, per_slab):
        i1 = min(resolution, i0 + per_slab)
        pts = slab_points(xs, ys, zs, i0, i1).to(device)
        sigma = torch.cat([field.density(model, pts[s:s + CHUNK_POINTS])
                           for s in range(0, pts.shape[0], CHUNK_POINTS)])
        out[i0:i1] = sigma.reshape(i1 - i0, resolution, resolution).float().cpu().numpy()
        if on_progress:
            on_progress(i1 / resolution)
    return out


def colour_at(model, pts: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Colours (m, 3) float32 in [0, 1] at world points (m, 3) seen along unit directions (m, 3), in chunks."""
    device = model.aabb.device
    out = np.empty((len(pts), 3), dtype=np.float32)
    for s in range(0, len(pts), CHUNK_POINTS):
        p = torch.from_numpy(np.ascontiguousarray(pts[s:s + CHUNK_POINTS], dtype=np.float32)).to(device)
        d = torch.from_numpy(np.ascontiguousarray(dirs[s:s + CHUNK_POINTS], dtype=np.float32)).to(device)
        out[s:s + len(p)] = field.colour(model, p, d).float().cpu().numpy()
    return out


FIXED_STEP_OPACITY = 0.05


def iso_level(box: np.ndarray, resolution: int, opacity: float = FIXED_STEP_OPACITY) -> float:
    """The fixed surface level: the sigma at which one sample step turns ``opacity`` opaque,
    ``-ln(1 - opacity) / voxel`` (voxel: the mean sample spacing, scene units). ``export.level``
    says when it is used and how it compares."""
    return -math.log1p(-opacity) / float(spacing(box, resolution).mean())
