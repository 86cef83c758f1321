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
- ``far_levels`` (optional, int64, 0 when missing) and, for each level k = 1..far_levels, ``far{k}_density``,
  ``far{k}_color``, ``far{k}_box``, ``far{k}_spacing``: the world beyond the box of a run that models it
  (``unbounded``, scene contraction), as nested grids over the box grown 2^k times about its centre,
  each zero inside the one before (``far_grids``). A floor that runs to the horizon is geometry there:
  without it Cycles showed the learned world where the NeRF shows its floor (ground demo scene, 25.0
  against 34.7 dB with four levels).
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


FAR_LEVELS = 4  # the far grids of a contracted run by default: out to 16 times the box (15/16 of the shell)
FAR_RESOLUTION = 128  # nodes per axis of each far grid at most: detail shrinks with distance (contraction)


def far_box(box: np.ndarray, level: int) -> np.ndarray:
    """(2, 3) the box grown ``2 ** level`` times about its centre."""
    centre, half = box.mean(axis=0), 0.5 * (box[1] - box[0])
    return np.stack([centre - half * 2.0 ** level, centre + half * 2.0 ** level])


def far_grids(model, box: np.ndarray, levels: int, resolution: int,
              on_progress: Optional[Callable[[str, float], None]] = None) -> dict:
    """The ``far{k}_*`` arrays (the module docstring) of ``model`` beyond ``box`` (2, 3): level k spans
    ``far_box(box, k)`` with ``resolution`` nodes per axis and is zero at the nodes strictly inside
    level k - 1's box (the box itself for k = 1), so that the levels add up to the field without counting
    any place twice. Why nested grids: a contracted field's detail shrinks with the distance from the box
    (its cells grow as r^2 in the box's own units), so each doubling of the reach needs the same number
    of nodes; one grid over the whole reach would be 16x coarser in the box's neighbourhood."""
    say = on_progress or (lambda stage, share: None)
    out: dict = {"far_levels": np.int64(levels)}
    inner = np.asarray(box, dtype=np.float64)
    for k in range(1, levels + 1):
        b = far_box(box, k)
        arrays = volume_grids(model, b, resolution, lambda stage, share: say(f"far {k}/{levels} {stage}", share))
        xs, ys, zs = grid.axes(b, resolution)
        inside = [(v > inner[0, a]) & (v < inner[1, a]) for a, v in enumerate((xs, ys, zs))]
        hollow = inside[0][:, None, None] & inside[1][None, :, None] & inside[2][None, None, :]
        arrays["density"][hollow] = 0.0
        arrays["color"][hollow] = 0
        for name in ("density", "color", "box", "spacing"):
            out[f"far{k}_{name}"] = arrays[name]
        inner = b
    return out


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
    for k in range(1, int(arrays.get("far_levels", 0)) + 1):
        names = [f"far{k}_{n}" for n in ("density", "color", "box", "spacing")]
        if not set(names) <= set(arrays):
            raise ValueError(f"{path}: far level {k} of {int(arrays['far_levels'])} is missing")
        fd, fc = arrays[names[0]], arrays[names[1]]
        if fd.ndim != 3 or fc.shape != fd.shape + (3,) or arrays[names[2]].shape != (2, 3):
            raise ValueError(f"{path}: far level {k}'s grids of mismatched shapes {fd.shape} and {fc.shape}")
    return arrays
