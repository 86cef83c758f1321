"""A volume export (``python -m nerf_core export volume``'s ``.npz``, docs/CONTRACTS.md) as an OpenVDB
file that Blender's Volume object reads. numpy and OpenVDB's Python module only: no bpy, no torch.

Blender ships ``openvdb`` inside its own Python (importable directly in Blender; in the ``bpy`` wheel it
lies in Blender's bundled site-packages, which ``load_openvdb`` is given).

Grids written (``shared/CONVENTIONS.md``, "A volume for Blender"):
- ``density`` (float): sigma per scene unit, unchanged: the capture's frame is Blender's world, so a
  Blender unit is a scene unit and Cycles' density (per Blender unit) is the field's sigma.
- ``color`` (vec3 float): the field's colour, converted from the display values the NeRF renders to
  Blender's scene-linear values by the caller's ``to_linear`` (``display_colours.to_linear_for``: the
  inverse of the capture's recorded view transform); the sRGB curve by default, right for a capture
  rendered under Standard. Under the capture's own view transform an opaque surface then shows the
  colour the NeRF shows.
Both on one transform: voxel (i, j, k) is the grid node at ``box[0] + (i, j, k) * spacing``.
- ``density_far{k}``, ``color_far{k}`` for each far level k of an unbounded run's volume (its ``far{k}_*``
  arrays: the world beyond the box, in nested grids twice as large each), on their own transforms;
  each Volume object of the import reads one level (``level_grids``).
"""
from __future__ import annotations

import json
import os
import sys
from typing import Callable, Optional, Sequence

import numpy as np

from ..file_writes import PARTIAL_SUFFIX, partial_path

DENSITY, COLOR = "density", "color"
FORMAT = "nerf_bridge.volume"


class VolumeFileError(ValueError):
    """A volume file that cannot be converted (the message names it), or no OpenVDB module."""


def load_openvdb(extra_dirs: Sequence[str] = ()):
    """Blender's ``openvdb`` module, looking in ``extra_dirs`` (Blender's bundled site-packages) too.
    Imported here, not at the top: only a volume import needs it, and outside Blender it is absent."""
    for d in extra_dirs:
        if os.path.isdir(d) and d not in sys.path:
            sys.path.append(d)  # after everything else: a user's own openvdb, if any, comes first
    try:
        import openvdb
    except ImportError as exc:
        raise VolumeFileError(f"Blender's OpenVDB Python module is not available ({exc}); "
                              f"looked in {', '.join(extra_dirs) or 'the default path'}") from exc
    return openvdb


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve undone: display values in [0, 1] -> scene-linear values."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(np.clip(c, 0, None), 1 / 2.4) - 0.055)


def read_npz(path: str) -> dict:
    """The arrays of a volume ``.npz``, checked: density (nx, ny, nz), color (nx, ny, nz, 3), box (2, 3),
    spacing (3,)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError) as exc:
        raise VolumeFileError(f"{path}: not a volume file of `nerf_core export volume` ({exc})") from exc
    if str(arrays.get("format", "")) != FORMAT or not {"density", "color", "box", "spacing"} <= set(arrays):
        raise VolumeFileError(f"{path}: not a volume file of `nerf_core export volume` (format or grids missing)")
    for level in range(far_levels(arrays) + 1):
        d, c, box, spacing = (arrays.get(level_member(level, n)) for n in ("density", "color", "box", "spacing"))
        if d is None or c is None or box is None or spacing is None:
            raise VolumeFileError(f"{path}: far level {level} of {far_levels(arrays)} is missing")
        if d.ndim != 3 or c.shape != d.shape + (3,) or box.shape != (2, 3) or spacing.shape != (3,):
            raise VolumeFileError(f"{path}: grids of mismatched shapes {d.shape}, {c.shape}"
                                  + (f" (far level {level})" if level else ""))
    return arrays


def far_levels(arrays: dict) -> int:
    """How many far grids the volume has beyond its box (0 for a bounded run's, and for older files)."""
    try:
        return max(0, int(arrays.get("far_levels", 0)))
    except (TypeError, ValueError):
        return 0


def level_member(level: int, name: str) -> str:
    """The ``.npz`` member of grid ``name`` ("density", "color", "box", "spacing") at ``level`` (0: the box)."""
    return name if level == 0 else f"far{level}_{name}"


def level_grids(level: int) -> tuple[str, str]:
    """The ``.vdb``'s density and colour grid names at ``level`` (0: the box's)."""
    return (DENSITY, COLOR) if level == 0 else (f"{DENSITY}_far{level}", f"{COLOR}_far{level}")


def recorded_colour_management(arrays: dict) -> dict:
    """The volume file's ``color_management`` (the capture's view transform, exposure...); {} when the
    file has none (older files) or it cannot be read."""
    try:
        cm = json.loads(str(arrays.get("color_management", "{}")))
    except ValueError:
        return {}
    return cm if isinstance(cm, dict) else {}


def linear_colours(color: np.ndarray, to_linear: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """(..., 3) uint8 display colours -> (..., 3) float32 scene-linear, ``to_linear`` called once on the
    distinct colours (a few thousand, where the grid has millions of nodes); black stays black."""
    flat = color.reshape(-1, 3)
    keys = (flat[:, 0].astype(np.int32) << 16) | (flat[:, 1].astype(np.int32) << 8) | flat[:, 2]
    uniq, inverse = np.unique(keys, return_inverse=True)
    rgb = np.stack([(uniq >> 16) & 255, (uniq >> 8) & 255, uniq & 255], axis=1).astype(np.float32) / 255.0
    lin = np.asarray(to_linear(rgb), dtype=np.float32).reshape(-1, 3)
    lin[uniq == 0] = 0.0  # nodes left uncoloured are no light, whatever a view transform makes of black
    return lin[inverse.reshape(-1)].reshape(color.shape)


def grid_matrix(box: np.ndarray, spacing: np.ndarray) -> list:
    """OpenVDB's 4x4 index-to-world matrix (row vectors: translation in the last row)."""
    m = np.diag([*np.asarray(spacing, dtype=np.float64), 1.0])
    m[3, :3] = np.asarray(box, dtype=np.float64)[0]
    return m.tolist()


def npz_to_vdb(npz_path: str, vdb_path: str, openvdb_dirs: Sequence[str] = (),
               to_linear: Optional[Callable[[np.ndarray], np.ndarray]] = None, arrays: Optional[dict] = None) -> dict:
    """Write ``vdb_path`` (grids ``density`` and ``color``, and each far level's) from a volume ``.npz`` (or
    its ``arrays``, already read), the colours through ``to_linear`` ((m, 3) display values in [0, 1] -> scene-linear;
    default: the sRGB curve); returns its arrays."""
    vdb = load_openvdb(openvdb_dirs)
    arrays = read_npz(npz_path) if arrays is None else arrays
    undo = to_linear or (lambda c: srgb_to_linear(c).astype(np.float32))
    grids = []
    for level in range(far_levels(arrays) + 1):
        member = lambda name: arrays[level_member(level, name)]  # noqa: E731
        xform = vdb.createLinearTransform(grid_matrix(member("box"), member("spacing")))
        names = level_grids(level)
        density = vdb.FloatGrid()
        density.copyFromArray(np.ascontiguousarray(member("density"), dtype=np.float32))  # exact: tolerance 0
        density.name, density.transform = names[0], xform
        color = vdb.Vec3SGrid()
        color.copyFromArray(np.ascontiguousarray(linear_colours(member("color"), undo)))  # default tolerance: exact
        color.name, color.transform = names[1], xform
        grids += [density, color]
    with partial_path(vdb_path, os.path.splitext(vdb_path)[0] + PARTIAL_SUFFIX + ".vdb") as tmp:  # never through a link
        vdb.write(tmp, grids=grids)
    return arrays


def read_vdb(vdb_path: str, shape, openvdb_dirs: Sequence[str] = ()) -> dict:
    """Grids of a written ``.vdb`` back: {name: (nx, ny, nz[, 3]) float32 array}, and for each grid
    ``<name>_origin`` (the world position of voxel 0) and ``<name>_step`` (of voxel (1, 1, 1) minus it).
    ``shape``: (nx, ny, nz) of the box's grids, or {grid name: shape} for the grids to read."""
    vdb = load_openvdb(openvdb_dirs)
    out = {}
    for g in vdb.readAllGridMetadata(vdb_path):
        grid = vdb.read(vdb_path, g.name)
        if isinstance(shape, dict):  # a shape for each grid name
            if g.name not in shape:
                continue
            arr = np.zeros(tuple(shape[g.name]) + ((3,) if g.name.startswith(COLOR) else ()), dtype=np.float32)
        else:
            arr = np.zeros(tuple(shape) + ((3,) if g.name == COLOR else ()), dtype=np.float32)
        grid.copyToArray(arr)
        out[g.name] = arr
        origin = np.asarray(grid.transform.indexToWorld((0, 0, 0)))
        out[f"{g.name}_origin"] = origin
        out[f"{g.name}_step"] = np.asarray(grid.transform.indexToWorld((1, 1, 1))) - origin
    return out
