"""Saving one rendered frame: the RGBA PNG and the per-pass files (depth, normals, mask, points).

Every file is written under a temporary name and renamed, so it is whole or absent. Temporary
names carry the host and process (``files.shards.unique_suffix``): shards of one capture may run
at once on machines sharing the folder, and none may touch another's files.
"""
from __future__ import annotations

import os

import bpy
import numpy as np

from ...dataset import points
from ...file_writes import partial_file, partial_path, write_png_gray
from ...scene import passes, point_normals
from ..plan.frame_plan import CaptureError
from .shards import unique_suffix

PARTIAL_TAG = ".partial"


def render_still() -> None:
    """Render the scene's active camera into "Render Result" (F12); RuntimeError when Blender cannot."""
    bpy.ops.render.render()


def save_png(scene, result, path: str) -> None:
    """The render result as an 8-bit RGBA PNG at ``path``."""
    img = scene.render.image_settings
    if hasattr(img, "media_type"):  # Blender 5.0 split the format into media type + file format
        img.media_type = "IMAGE"
    img.file_format = "PNG"
    img.color_mode = "RGBA"
    img.color_depth = "8"
    with partial_path(path, path[:-4] + PARTIAL_TAG + ".png") as tmp:  # a new name, never through a link
        result.save_render(tmp, scene=scene)


def read_png_rgba(path: str) -> np.ndarray:
    """(h, w, 4) uint8 of a PNG via Blender's loader (rows flipped to top-first)."""
    image = bpy.data.images.load(path, check_existing=False)
    try:
        w, h = image.size
        buf = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(buf)
    finally:
        bpy.data.images.remove(image)
    return np.round(buf.reshape(h, w, 4)[::-1] * 255).astype(np.uint8)


def _render_channels(scene, result, scratch_dir: str) -> dict:
    img = scene.render.image_settings
    if hasattr(img, "media_type"):
        img.media_type = "MULTI_LAYER_IMAGE"
    else:
        img.file_format = "OPEN_EXR_MULTILAYER"
    img.color_depth = "32"
    img.exr_codec = "NONE"  # passes.read_exr_channels reads uncompressed, single-part files
    if hasattr(img, "use_exr_interleave"):
        img.use_exr_interleave = True
    tmp = os.path.join(scratch_dir, f"render_passes.{unique_suffix()}{PARTIAL_TAG}.exr")
    result.save_render(tmp, scene=scene)
    try:
        return passes.read_exr_channels(tmp)
    finally:
        os.remove(tmp)


def save_passes(scene, result, fr: dict, out: str, s, engine: str, scratch_dir: str, points_budget: int) -> None:
    """Write frame ``fr``'s depth / normal / mask files and its point cache, as settings ``s`` ask.

    The point cache keeps at most ``points_budget`` points, drawn with a generator seeded by the
    capture's seed and the frame's plan index: the same points whichever machine renders the frame.
    """
    ch = _render_channels(scene, result, scratch_dir)
    depth = None
    if s.depth or s.points:
        z = passes.find_pass(ch, "Depth", "Z")
        if z is None:
            raise CaptureError(f"{fr['key']}: the render has no Depth pass ({engine})")
        depth = passes.planar_depth(z[..., 0], scene.camera.data.clip_end if scene.camera else None)
    if s.depth:
        passes.write_exr(os.path.join(out, fr["depth_file_path"]), {"Z": depth})
    normal = passes.find_pass(ch, "Normal", "XYZ") if (s.normals or s.points) else None
    if s.normals:
        if normal is None:
            raise CaptureError(f"{fr['key']}: the render has no Normal pass ({engine})")
        passes.write_exr(os.path.join(out, fr["normal_file_path"]),
                         {"X": normal[..., 0], "Y": normal[..., 1], "Z": normal[..., 2]})
    if s.masks:
        if engine == "CYCLES":
            idx = passes.find_pass(ch, "Object Index", "X")
            if idx is None:
                idx = passes.find_pass(ch, "IndexOB", "X")
            mask = np.abs(idx[..., 0] - 1.0) < 0.5
        else:
            alpha = passes.find_pass(ch, "Combined", "A")
            mask = alpha[..., 0] > 0.5
        write_png_gray(os.path.join(out, fr["mask_path"]), mask.astype(np.uint8) * 255)
    if s.points and fr["split"] == "train":
        rgba = read_png_rgba(os.path.join(out, fr["image"]))
        d = np.where(rgba[..., 3] > 127, depth, np.inf)
        pts, cols = points.backproject(d, rgba[..., :3], fr["intrinsics"], fr["transform_matrix"])
        nrm = point_normals.point_normals(d, fr["intrinsics"], fr["transform_matrix"], normal)
        if len(pts) > points_budget:
            pick = np.random.default_rng(s.seed + fr["index"]).choice(len(pts), points_budget, replace=False)
            pts, cols, nrm = pts[pick], cols[pick], nrm[pick]
        path = os.path.join(out, fr["points_cache"])
        with partial_file(path, f"{path}.{unique_suffix()}{PARTIAL_TAG}") as fh:
            np.savez(fh, points=pts, colors=cols, normals=nrm)
