"""Density and colour grids of a trained field, saved as one ``.npz`` (format: docs/CONTRACTS.md,
"Volume export"), which the add-on turns into an OpenVDB Volume object inside Blender.

- ``density``: (nx, ny, nz) float32, sigma per scene unit at the grid's nodes (``grid`` layout).
  Cycles' volume coefficients are per Blender unit, and the capture's frame is Blender's world, so
  Blender's density is this sigma unchanged (no unit conversion; see docs/CONTRACTS.md).
- ``color``: (nx, ny, nz, 3) uint8, the field's colour (display-referred, as the NeRF renders it)
  seen head-on, looking up the density's gradient into the object (the mesh's vertex colour rule); black where
  one grid step is less than 0.1 % opaque, where colour cannot show (and costs the most queries), unless a
  neighbouring node is more opaque (``_near_opaque``: interpolation must not fade the colour at a surface).
- ``box`` (2, 3) float64, ``spacing`` (3,) float64, ``level`` (the mesh's surface density),
  ``format`` "nerf_bridge.volume", ``version`` 1.
- ``color_management`` (optional; a JSON object as a string): the view transform the capture's images
  were rendered with (``contract.colour_management``), which the import undoes to turn ``color`` back
  into scene-linear light; "{}" when unknown (the colours are then taken as sRGB).
"""
from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from nerf_core.export import grid
from nerf_core.utils.atomic import atomic_file

FORMAT, VERSION = "nerf_bridge.volume", 1
MIN_STEP_ALPHA = 1e-3  # colour only where one grid step is more opaque than this
BYTES_PER_SAMPLE = 4 + 3 + 1  # density, colour, slack; the colouring's working set is bounded (grid.CHUNK_BYTES)


def _into(density: np.ndarray, idx: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Unit directions (m, 3) up the density's gradient at nodes ``idx`` (m, 3) (central differences,
    one-sided at the box's faces); +z where the density is flat."""
    n = np.array(density.shape)
    g = np.empty((len(idx), 3), dtype=np.float64)
    for a in range(3):
        hi, lo = idx.copy(), idx.copy()
        hi[:, a] = np.minimum(idx[:, a] + 1, n[a] - 1)
        lo[:, a] = np.maximum(idx[:, a] - 1, 0)
        dist = (hi[:, a] - lo[:, a]).clip(1) * step[a]
        g[:, a] = (density[hi[:, 0], hi[:, 1], hi[:, 2]] - density[lo[:, 0], lo[:, 1], lo[:, 2]]) / dist
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    flat = norm[:, 0] < 1e-12
    d = g / norm.clip(1e-12)
    d[flat] = (0.0, 0.0, 1.0)
    return d  # the gradient points into the object: a camera looking at the surface looks along it


def _near_opaque(density: np.ndarray, i0: int, i1: int, threshold: float) -> np.ndarray:
    """(i1 - i0, ny, nz) bool: the nodes of slab ``i0 <= i < i1`` with a node above ``threshold`` among
    themselves and their 26 neighbours. Why the neighbours: a renderer interpolates the colour grid
    trilinearly, so between a coloured node and a black one just outside the surface the colour fades
    to black while the density there is still high (a dark rim on every silhouette)."""
    lo, hi = max(0, i0 - 1), min(density.shape[0], i1 + 1)
    m = density[lo:hi] > threshold
    for a in range(3):  # the 3x3x3 box as three 1-D maxima
        d = m.copy()
        src, dst = [slice(None)] * 3, [slice(None)] * 3
        src[a], dst[a] = slice(0, -1), slice(1, None)
        d[tuple(dst)] |= m[tuple(src)]
        d[tuple(src)] |= m[tuple(dst)]
        m = d
    return m[i0 - lo:i0 - lo + (i1 - i0)]


def volume_grids(model, box: np.ndarray, resolution: int,
                 on_progress: Optional[Callable[[str, float], None]] = None) -> dict:
    """The arrays of the volume file (see the module docstring) for ``model`` inside ``box`` (2, 3)."""
    say = on_progress or (lambda stage, share: None)
    density = grid.sample_density(model, box, resolution, lambda s: say("density", s))
    step = grid.spacing(box, resolution)
    threshold = -np.log1p(-MIN_STEP_ALPHA) / float(step.mean())
    color = np.zeros(density.shape + (3,), dtype=np.uint8)
    say("colour", 0.0)
    # slab by slab: the coloured nodes' indices (24 B each) and their float64 points and directions never
    # cover the whole grid, so a fog (every node coloured) needs no more than a surface (BYTES_PER_SAMPLE)
    res = density.shape[0]
    per_slab = max(1, grid.CHUNK_POINTS // (res * res))
    for i0 in range(0, res, per_slab):
        i1 = min(res, i0 + per_slab)
        part = np.argwhere(_near_opaque(density, i0, i1, threshold))
        part[:, 0] += i0
        for s in range(0, len(part), grid.CHUNK_POINTS):
            idx = part[s:s + grid.CHUNK_POINTS]
            rgb = grid.colour_at(model, box[0] + idx * step, _into(density, idx, step))
            color[idx[:, 0], idx[:, 1], idx[:, 2]] = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
        say("colour", i1 / res)
    return {"density": density, "color": color, "box": np.asarray(box, dtype=np.float64), "spacing": step,
            "level": np.float64(grid.iso_level(box, resolution)), "format": np.str_(FORMAT),
            "version": np.int64(VERSION)}


def colour_record(cm: Optional[dict]) -> np.ndarray:
    """The ``color_management`` member: ``cm`` (``contract.colour_management.recorded``) as JSON text."""
    return np.str_(json.dumps(cm or {}, sort_keys=True))


def write_volume(path: Path | str, arrays: dict) -> None:
    """Save the volume arrays as an uncompressed ``.npz`` at ``path``, atomically: ``np.savez``'s layout
    (one ``NAME.npy`` member per array, zip64), written here so that a write that fails (a full disk,
    ``ulimit -f``) closes the zip file once, raising, instead of again at garbage collection."""
    with atomic_file(path) as fh:  # a file object: np.savez would append ".npz" to a bare path
        with zipfile.ZipFile(fh, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, value in arrays.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def read_volume(path: Path | str) -> dict:
    """The arrays of a volume file, checked (ValueError naming the file and what is wrong)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError) as exc:
        raise ValueError(f"{path}: not a volume file written by `export volume` ({exc})") from exc
    missing = {"density", "color", "box", "format"} - set(arrays)
    if missing or str(arrays["format"]) != FORMAT:
        raise ValueError(f"{path}: not a volume file written by `export volume` (missing {sorted(missing)})")
    d, c = arrays["density"], arrays["color"]
    if d.ndim != 3 or c.shape != d.shape + (3,) or arrays["box"].shape != (2, 3):
        raise ValueError(f"{path}: grids of mismatched shapes {d.shape} and {c.shape}")
    return arrays
