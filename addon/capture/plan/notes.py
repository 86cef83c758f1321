"""Warnings a capture gives before rendering about what no radiance field can learn from the scene as
set up: clipping that cuts the scene box, holdouts, missing files, depth PNGs out of range."""
from __future__ import annotations

import bpy
import numpy as np

from ...dataset import aabb
from ...scene import passes, scene_bounds, scene_files


def _box_depths(fr: dict, corners: np.ndarray) -> tuple[float, float]:
    """(nearest, farthest) planar depth of the box ``corners`` (8, 3) along a planned frame's view axis
    (the camera looks down -Z); negative where a corner is behind the camera."""
    c2w = np.asarray(fr["transform_matrix"], float)
    depths = -(corners - c2w[:3, 3]) @ c2w[:3, 2]
    return float(depths.min()), float(depths.max())


def clipping_notes(frames: list, bounds) -> list:
    """A warning when cameras' clipping planes cut into the scene box (empty when none).

    Generated layouts set clipping to fit the box (``layout.cameras.create_cameras``); cameras the user set
    up keep theirs, and a clip_end short of the far side (or a clip_start beyond the near side of a
    box in front of the camera) leaves part of the scene out of some pictures only: views that
    disagree about what is there, which a radiance field turns into floaters or holes. The planes are
    the user's choice (clipping into a room is a way to look inside), so this is said, not changed.
    """
    if bounds is None:
        return []
    corners = aabb.box_corners(*bounds)
    cut = []
    for fr in frames:
        obj = bpy.data.objects.get(fr["camera"])
        if obj is None or obj.type != "CAMERA":
            continue
        near, far = _box_depths(fr, corners)
        if far <= 0:
            continue  # the box is behind this camera
        start, end = obj.data.clip_start, obj.data.clip_end
        if end < far or (near > 0 and start > near):
            cut.append((obj.name, start, end, max(near, 0.0), far))
    if not cut:
        return []
    name, start, end, near, far = cut[0]
    return [f"{len(cut)} camera(s) clip the scene box, e.g. {name!r}: clip {start:g}-{end:g}, the box lies "
            f"{near:.3g}-{far:.3g} away along its view; parts of the scene will be missing from some views "
            "only, which a NeRF learns as holes or floaters. Widen Clip Start/End (Camera properties) unless "
            "the cut is meant"]


def capture_notes(scene) -> list:
    """Warnings about what the scene will render that no radiance field can learn (empty when none);
    the panel reports them and ``scripts/capture.py`` prints them before rendering."""
    notes = scene_files.missing_file_notes(scene)
    held = scene_bounds.holdout_objects(scene)
    if not held:
        return notes
    shown = ", ".join(repr(n) for n in held[:5]) + (f" and {len(held) - 5} more" if len(held) > 5 else "")
    return notes + [f"{shown} render(s) as holdout: a holdout cuts a transparent hole (alpha 0) through everything "
            "behind it, blocking what lies behind yet adding no opacity, which a radiance field cannot represent, "
            "so the NeRF will show gaps or fog there. Turn Holdout off for the capture (object or collection "
            "visibility, or the material's Holdout shader), or leave them out of the render"]


# Fewer millimetre levels than this across the scene make a depth map of a few steps.
NERFSTUDIO_DEPTH_MIN_LEVELS = 256


def depth_png_notes(frames: list, bounds) -> list:
    """A warning when the scene box lies (partly) where nerfstudio's millimetre depth PNGs cannot
    hold it: farther than 65.535 units from a camera (written as 0, no depth) or so close and small
    that its depth takes under 256 millimetre steps. The EXR depth maps hold every depth; only the
    PNGs under nerfstudio/depth/ are affected."""
    if bounds is None or not frames:
        return []
    corners = aabb.box_corners(*bounds)
    far = max(_box_depths(fr, corners)[1] for fr in frames)
    top = passes.MAX_DEPTH_MM / 1000.0
    if far > top:
        return [f"the scene box reaches {far:.4g} units from the cameras, but nerfstudio's depth PNGs hold "
                f"millimetres in 16 bits (up to {top:g} units): depth farther away is written there as 0 (no "
                "depth), so nerfstudio learns no depth for it (the EXR depth maps keep all of it). Scale the "
                "scene down for nerfstudio's depth supervision"]
    levels = far * 1000.0
    if levels < NERFSTUDIO_DEPTH_MIN_LEVELS:
        return [f"the scene box lies within {far:.3g} units of the cameras: nerfstudio's millimetre depth PNGs "
                f"hold its depth in at most {max(int(levels), 0)} steps (the EXR depth maps keep full precision). "
                "Scale the scene up for nerfstudio's depth supervision"]
    return []
