"""Whether a Blender camera object is a camera pose a dataset can hold: no shear, no mirror, no scale
(``camera_scale_error``), and how messages name it (``camera_label``)."""
from __future__ import annotations

import bpy


def camera_label(obj) -> str:
    """How messages name a camera: a layout's copy also names the user's camera it copies."""
    src = obj.get("nerf_source")
    return f"camera {obj.name!r}" + (f" (the copy of {src!r})" if src else "")


def _scale_owner(obj) -> str:
    """Where a camera's scale comes from, for messages: its own, or the first scaled parent's (of the
    user's camera, for a layout's copy)."""
    cur = bpy.data.objects.get(obj.get("nerf_source") or "") or obj
    if any(abs(v - 1.0) > 1e-4 for v in cur.scale):
        return "its own scale"
    parent = cur.parent
    while parent is not None and all(abs(v - 1.0) <= 1e-4 for v in parent.scale):
        parent = parent.parent
    if parent is not None:
        return f"the scale of its parent {parent.name!r}"
    # Neither its own scale nor a parent's: a constraint (Child Of, Copy Transforms, Copy Scale...)
    # brings it, and Ctrl+A would change nothing.
    active = [c for c in getattr(cur, "constraints", ()) if c.enabled and c.influence > 0]
    if active:
        return f"its constraint {active[-1].name!r}"
    return "its own scale"


def camera_shape_error(obj) -> str | None:
    """Why a camera's transform is no camera pose at all, whatever its scale (shear, mirror), else None.
    Normalising the scale cannot fix these."""
    m = obj.matrix_world.to_3x3()
    cols = [m.col[i].normalized() for i in range(3)]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        if abs(cols[i].dot(cols[j])) > 1e-4:
            return (f"{camera_label(obj)} is sheared (a parent with non-uniform scale?); clear the scale of "
                    "its parents")
    if m.determinant() < 0:
        # A mirrored view is no picture a real camera takes; every dataset reader refuses it (check does).
        return (f"{camera_label(obj)} is mirrored by {_scale_owner(obj)} (a negative scale); clear the "
                "negative scale")
    return None


def camera_scale_error(obj) -> str | None:
    """Why a camera object's transform cannot be exported as-is (``camera_shape_error``, or a scale),
    else None. A scale alone, the capture can normalise (``CaptureSettings.normalize_camera_scale``)."""
    shape = camera_shape_error(obj)
    if shape:
        return shape
    lengths = [obj.matrix_world.col[i].xyz.length for i in range(3)]
    if any(abs(length - 1.0) > 1e-4 for length in lengths):
        owner = _scale_owner(obj)
        fix = ("apply or clear it (Ctrl+A > Scale)" if owner == "its own scale" else
               "turn off its scale (or clear its target's)" if owner.startswith("its constraint") else
               "clear that scale")
        return (f"{camera_label(obj)} has scale {tuple(round(v, 4) for v in lengths)} from {owner}; {fix}, or "
                "let the capture normalise camera scale (--normalize-camera-scale, or the panel's Normalise "
                "Camera Scale)")
    return None
