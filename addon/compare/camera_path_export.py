"""A Blender camera's animation as nerfstudio's ``camera_path.json`` (``contract.camera_path``).

Each frame of the range becomes one ``camera_path`` entry: the camera's scale-free camera-to-world
matrix at that frame (``dataset.cameras.scale_free_matrix``, the render engine's rule, so a scaled
camera exports as it renders) and its own vertical field of view and
aspect at the scene's render size (``dataset.cameras.camera_intrinsics``: an animated focal length
gives a field of view per frame). ``python -m nerf_core render RUN --cameras camera_path.json`` then
renders the same pixels as ``scripts/render_nerf.py`` over those frames. With nerfstudio's
``dataparser_transforms.json`` the poses are written in nerfstudio's world instead, for ``ns-render``.
A lens shift or non-square pixels, which the format cannot hold, are refused naming the frames.
"""
from __future__ import annotations

import json
import os

from ..bridge.core_contract import contract
from ..dataset.cameras import camera_intrinsics, scale_free_matrix
from ..dataset.errors import ExportError
from ..file_writes import write_atomic
from ..scene.camera_checks import camera_shape_error


def path_views(scene, cam, frames) -> list:
    """One view per frame of ``frames``: ``c2w`` (4x4 rows), ``fx fy cx cy w h`` and ``label``."""
    if cam is None or cam.type != "CAMERA":
        raise ExportError(f"{getattr(cam, 'name', cam)!r} is not a camera")
    views = []
    saved = scene.frame_current
    try:
        for f in frames:
            scene.frame_set(f)
            # A scaled camera (a rig's scale, say) renders through the engine with its scale dropped;
            # the path takes the same scale-free pose. Shear or a mirror is no camera pose: refused.
            shape = camera_shape_error(cam)
            if shape:
                raise ExportError(f"frame {f}: {shape}")
            intr = camera_intrinsics(cam, scene.render)
            c2w = [[float(v) for v in row] for row in scale_free_matrix(cam)]
            views.append({"c2w": c2w, "fx": intr["fl_x"], "fy": intr["fl_y"], "cx": intr["cx"],
                          "cy": intr["cy"], "w": intr["w"], "h": intr["h"], "label": f"frame {f}"})
    finally:
        scene.frame_set(saved)
    return views


def camera_path(scene, cam, frames, dataparser: str | None = None) -> dict:
    """The camera_path.json object of ``cam`` over ``frames`` (the scene's fps). Raises ExportError."""
    frames = list(frames)
    if not frames:
        raise ExportError("no frames to export")
    views = path_views(scene, cam, frames)
    clip = (cam.data.clip_start, cam.data.clip_end)
    if dataparser:
        clip = None  # nerfstudio's world has another scale; its renderer picks its own range
    try:
        if dataparser:
            transform, scale = contract.nerfstudio_frame.read_dataparser_transform(dataparser)
            for v in views:
                v["c2w"] = contract.nerfstudio_frame.to_nerfstudio_pose(v["c2w"], transform, scale)
        # The camera's clip range is what the render engine renders with: written as near/far, the
        # same file renders the same pixels through `nerf_core render`.
        doc = contract.camera_path.camera_path_document(views, scene.render.fps / scene.render.fps_base,
                                                        where=f"camera {cam.name!r}", clip=clip)
    except (contract.camera_path.CameraPathError, contract.DatasetError) as exc:
        raise ExportError(str(exc)) from None
    doc["blender_frames"] = frames  # additive: which scene frame each entry shows
    return doc


def export_camera_path(scene, cam, frames, out: str, dataparser: str | None = None, overwrite: bool = False) -> dict:
    """Write ``camera_path(...)`` to ``out`` atomically; an existing file is refused unless ``overwrite``.
    Returns a summary (``out``, ``frames``, ``width``, ``height``, ``fov`` range in degrees)."""
    out = os.path.abspath(out)
    if os.path.lexists(out) and not overwrite:
        raise ExportError(f"{out} already exists; choose another file (or overwrite)")
    doc = camera_path(scene, cam, frames, dataparser)
    try:
        write_atomic(out, json.dumps(doc, indent=1))
    except OSError as exc:
        raise ExportError(f"could not write {out}: {exc.strerror or exc}") from None
    fovs = [c["fov"] for c in doc["camera_path"]]
    return {"out": out, "camera": cam.name, "frames": len(fovs), "width": doc["render_width"],
            "height": doc["render_height"], "fov_degrees": [min(fovs), max(fovs)],
            "world": "nerfstudio" if dataparser else "dataset"}
