"""Pixel intrinsics of a transforms frame: THE focal-length rule (standard library only).

Precedence, field by field (docs/CONTRACTS.md, "Intrinsics"):

1. a frame's own value overrides the file's top-level value of the same field;
2. ``fx`` = ``fl_x``; else from ``camera_angle_x`` and ``w`` (``0.5 w / tan(angle / 2)``); else ``fl_y``;
3. ``fy`` = ``fl_y``; else ``fx`` (square pixels, what the original NeRF loader assumes);
   ``camera_angle_y`` is never read: every writer we know also writes ``camera_angle_x`` or ``fl_*``;
4. ``cx``, ``cy`` = the given values, else the image centre ``w / 2``, ``h / 2``;
5. ``w``, ``h`` = the given values, else ``size`` (the image's own size), else an error.

So ``fl_x``/``fl_y`` beat ``camera_angle_x``: a file that has both uses the focal lengths, which carry
non-square pixels; ``nerf_core check`` reports a file where the two disagree.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

from .transforms import DatasetError, parse_intrinsics


def focal_from_fov(fov: float, size: float) -> float:
    """Focal length in pixels for a field of view ``fov`` (radians) spanning ``size`` pixels."""
    return 0.5 * size / math.tan(0.5 * fov)


def fov_from_focal(focal: float, size: float) -> float:
    """Field of view in radians spanning ``size`` pixels at focal length ``focal`` (pixels)."""
    return 2.0 * math.atan(0.5 * size / focal)


def declaring(meta: Optional[dict], frame: Optional[dict], key: str) -> Optional[dict]:
    """Rule 1: the object whose ``key`` holds for ``frame``: the frame itself when it has the field,
    else the file's top level ``meta`` when that has it, else None. ``resolve_intrinsics`` applies the
    same rule to every field at once; ``nerf_core check`` asks field by field to name where a bad
    value was written."""
    if frame and key in frame:
        return frame
    if meta and key in meta:
        return meta
    return None


def resolve_intrinsics(meta: Optional[dict], frame: Optional[dict], size: Optional[Sequence[float]] = None,
                       where: str = "transforms") -> Tuple[float, float, float, float, float, float]:
    """(fx, fy, cx, cy, w, h) in pixels of the declared image for one frame (rules in the module doc).

    ``meta`` is the file's top-level object and ``frame`` one of its frames (either may be None; raw
    JSON values are validated). ``size`` = (w, h) of the image, used when the JSON gives none.
    Raises DatasetError naming ``where`` and the field.
    """
    intr = parse_intrinsics(meta or {}, where)
    intr.update(parse_intrinsics(frame or {}, where))
    w, h = intr.get("w"), intr.get("h")
    if (w is None or h is None) and size is None:
        raise DatasetError(f"{where}: fields 'w' and 'h' (image size in pixels) are required")
    w = float(size[0]) if w is None else w
    h = float(size[1]) if h is None else h
    if "fl_x" in intr:
        fx = intr["fl_x"]
    elif "camera_angle_x" in intr:
        fx = focal_from_fov(intr["camera_angle_x"], w)
    elif "fl_y" in intr:
        fx = intr["fl_y"]
    else:
        raise DatasetError(f"{where}: no focal length (fields 'fl_x' or 'camera_angle_x' missing)")
    fy = intr.get("fl_y", fx)
    return fx, fy, intr.get("cx", w / 2.0), intr.get("cy", h / 2.0), float(w), float(h)


# The loaders that take one ``camera_angle_x`` for every view and assume square pixels centred on
# the image (../shared/CONVENTIONS.md): what they cannot represent is legal, but they misplace it.
ANGLE_ONLY_LOADERS = "original NeRF, nerfstudio blender-data, 3DGS, TensoRF"


def angle_only_caveats(intrinsics: Sequence[dict]) -> list:
    """[(field, message)] for what loaders that read only ``camera_angle_x`` misread in these views.

    ``intrinsics``: one dict per view with ``fl_x fl_y cx cy w h`` in pixels (other keys are ignored:
    the capture's intrinsics and ``check``'s resolved ones both pass). Three things, each said once: a
    principal point off the image centre (lens shift), non-square pixels (fl_y != fl_x), and views
    that differ in focal length, principal point or size (one top-level angle cannot hold them).
    The capture says these before rendering and ``nerf_core check`` says them of each split file.
    """
    cams = [tuple(float(i[k]) for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")) for i in intrinsics]
    if not cams:
        return []
    n = len(cams)
    out = []
    shifted = [c for c in cams if abs(c[2] - c[4] / 2) > 0.5 or abs(c[3] - c[5] / 2) > 0.5]
    if shifted:
        fx, fy, cx, cy, w, h = max(shifted, key=lambda c: abs(c[2] - c[4] / 2) + abs(c[3] - c[5] / 2))
        out.append(("cx/cy", f"principal point off the image centre by up to ({cx - w / 2:+.2f}, {cy - h / 2:+.2f}) px "
                             f"in {len(shifted)} of {n} view(s) (lens shift): loaders that read only camera_angle_x "
                             f"({ANGLE_ONLY_LOADERS}) assume the centre"))
    skewed = [c for c in cams if abs(c[1] - c[0]) > 1e-4 * c[0]]
    if skewed:
        fx, fy = skewed[0][:2]
        out.append(("fl_y", f"fl_y {fy:.6g} differs from fl_x {fx:.6g} in {len(skewed)} of {n} view(s) (non-square "
                            f"pixels, Blender's pixel aspect): loaders that read only camera_angle_x "
                            f"({ANGLE_ONLY_LOADERS}) assume fl_y = fl_x"))
    distinct = {tuple(round(v, 4) for v in c) for c in cams}
    if len(distinct) > 1:
        out.append(("fl_x", f"the views have {len(distinct)} different cameras (focal length, principal point or "
                            f"size): loaders that read one top-level camera_angle_x ({ANGLE_ONLY_LOADERS}) use "
                            "the first view's for all; nerfstudio-data (nerfstudio/transforms.json) and instant-ngp "
                            "read each view's own"))
    return out
