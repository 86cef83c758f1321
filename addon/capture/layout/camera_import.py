"""Cameras from a transforms file into the scene: one Blender camera per view, in their own collection.

``import_cameras(scene, path)`` reads any format ``contract.camera_files`` reads (the synthetic layout,
nerfstudio's and instant-ngp's ``transforms.json``, nerfstudio's ``camera_path.json``) and makes each
view a camera whose projection is the view's exactly (``dataset.cameras.camera_params``: lens, sensor
fit, lens shift from the principal point; the scene's resolution and pixel aspect from the views).
Optionally the poses are first brought back from nerfstudio's world (``dataparser_transforms.json``).

Each camera records where it came from (``IMPORT_*`` custom properties): its split, its place in the
file and its name. The ``scene-cameras`` layout (``layout.cameras``) then re-renders exactly these
cameras, keeping the file's split and order, so a capture of them reproduces the file's images.
"""
from __future__ import annotations

import json
import os

import bpy
import numpy as np

from ...bridge.core_contract import contract
from ...dataset.cameras import camera_params, make_view_camera, use_view_resolution

COLLECTION = "Imported Cameras"
COLLECTION_TAG = "nerf_imported_cameras"  # the collection's own tag: the file it holds
IMPORT_SPLIT = "nerf_import_split"  # "train" | "val" | "test"; absent when the file has no splits
IMPORT_INDEX = "nerf_import_index"  # the camera's place among the file's views (0, 1, ...)
IMPORT_NAME = "nerf_import_name"  # the frame's stem (r_0, frame_00000)
IMPORT_FILE = "nerf_import_file"
IMPORT_FRAME = "nerf_frame"  # the scene frame an animation-layout view was rendered at
RATIO_TOLERANCE = 1e-9  # relative: fx/fy ratios closer than this are one pixel aspect


class CameraImportError(ValueError):
    """A transforms file that cannot become Blender cameras; the message names the file, frame and field."""


def imported_collection(scene, create: bool = True):
    """The scene's collection of imported cameras (tagged ``COLLECTION_TAG``), made when asked."""
    for coll in scene.collection.children_recursive:
        if COLLECTION_TAG in coll:
            return coll
    if not create:
        return None
    coll = bpy.data.collections.new(COLLECTION)
    coll[COLLECTION_TAG] = ""
    scene.collection.children.link(coll)
    return coll


def is_imported(obj) -> bool:
    return obj.type == "CAMERA" and IMPORT_INDEX in obj


def _clear(coll) -> int:
    gone = [o for o in coll.objects if is_imported(o)]
    for obj in gone:
        data = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)
    return len(gone)


def _label(view) -> str:
    return f"{view.split}/{view.name}" if view.split else view.name


def _mismatch_warnings(views) -> list:
    """Sentences for views the scene's one resolution and pixel aspect cannot show as they are."""
    first = views[0]
    out = []
    size = [_label(v) for v in views if (v.w, v.h) != (first.w, first.h)]
    if size:
        out.append(f"{len(size)} camera(s) have another image size than {first.w}x{first.h} (the scene renders one "
                   f"size): {', '.join(size[:8])}{', ...' if len(size) > 8 else ''}. Their lens and shift are exact "
                   "for their own size; render them at it")
    ratio = first.fx / first.fy
    aspect = [_label(v) for v in views if abs(v.fx / v.fy - ratio) > RATIO_TOLERANCE * ratio]
    if aspect:
        out.append(f"{len(aspect)} camera(s) have another pixel aspect (fx/fy) than {_label(first)}'s {ratio:.6g} (the "
                   f"scene has one): {', '.join(aspect[:8])}{', ...' if len(aspect) > 8 else ''}")
    return out


def read_views(path: str, dataparser: str | None = None):
    """(format, views, notes) of ``path`` (``contract.camera_files.read_camera_file``), poses taken
    back from nerfstudio's world when ``dataparser`` names its ``dataparser_transforms.json``."""
    try:
        fmt, views, notes = contract.camera_files.read_camera_file(path)
        if dataparser:
            transform, scale = contract.nerfstudio_frame.read_dataparser_transform(dataparser)
            for v in views:
                v.c2w = contract.nerfstudio_frame.to_dataset_pose(v.c2w, transform, scale)
            notes.append(f"poses taken from nerfstudio's world back into the dataset's with {dataparser} "
                         f"(scale {scale:g})")
    except contract.DatasetError as exc:
        raise CameraImportError(str(exc)) from None
    if not views:
        raise CameraImportError(f"{path}: no cameras in it")
    return fmt, views, notes


def import_cameras(scene, path: str, dataparser: str | None = None, clip=None) -> dict:
    """Make one camera per view of ``path`` in the scene's "Imported Cameras" collection (replacing
    the cameras an earlier import made there; nothing else is touched) and set the scene's resolution
    (100 %) and pixel aspect to the first view's. Returns a summary: ``format``, ``cameras``,
    ``collection``, ``splits`` ({split: count}), ``notes`` and ``warnings`` (distortion Blender cannot
    model, naming the frames; views whose size or pixel aspect differ from the scene's).

    ``clip``: (clip_start, clip_end) of the cameras; default from the file's ``near``/``far`` when it
    has them. Raises CameraImportError naming the file and frame.
    """
    path = os.path.abspath(path)
    fmt, views, notes = read_views(path, dataparser)
    for v in views:
        try:
            camera_params(v.intrinsics())
        except ValueError as exc:
            raise CameraImportError(f"{v.where}: {exc}") from None
    warnings = [w for w in [contract.camera_files.distortion_warning(views)] if w] + _mismatch_warnings(views)
    coll = imported_collection(scene)
    replaced = _clear(coll)
    if replaced:
        notes.append(f"replaced the {replaced} camera(s) of an earlier import in {coll.name!r}")
    coll[COLLECTION_TAG] = path
    clip = clip or _clip_from_file(path, fmt)
    made = []
    for k, v in enumerate(views):
        ob = make_view_camera(_label(v).replace("/", "_"), v.c2w, v.intrinsics(), coll, clip=clip)
        ob[IMPORT_INDEX] = k
        ob[IMPORT_NAME] = v.name
        ob[IMPORT_FILE] = path
        ob["nerf_intrinsics"] = json.dumps(v.intrinsics())
        if v.split:
            ob[IMPORT_SPLIT] = v.split
        if v.blender_frame is not None:
            ob[IMPORT_FRAME] = v.blender_frame
        made.append(ob)
    use_view_resolution(scene, views[0].intrinsics())
    if scene.camera is None:
        scene.camera = made[0]
    splits = {}
    for v in views:
        splits[v.split or "none"] = splits.get(v.split or "none", 0) + 1
    return {"format": fmt, "file": path, "cameras": len(made), "collection": coll.name, "splits": splits,
            "resolution": [views[0].w, views[0].h], "notes": notes, "warnings": warnings}


def _clip_from_file(path: str, fmt: str):
    """(clip_start, clip_end) from the file's ``near``/``far``: the scene range the views were made for."""
    near = far = None
    if fmt != "camera_path":
        files = [path] if os.path.isfile(path) else []
        if os.path.isdir(path):
            files = [os.path.join(path, f) for f in ("transforms_train.json", "transforms.json")]
        for f in files:
            try:
                meta = contract.read_json(f)
            except contract.DatasetError:
                continue
            near, far = meta.get("near"), meta.get("far")
            break
    ok = [isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in (near, far)]
    start = min(0.01, 0.5 * near) if ok[0] else 0.01
    end = max(1000.0, 4.0 * far) if ok[1] else 1000.0
    return start, end


POINTS_TAG = "nerf_import_points"  # the points object's tag: the model it came from


def import_points(scene, xyz, rgb, source: str, name: str = "Imported Points"):
    """The sparse points of a reconstruction as one mesh of loose vertices (every renderer and exporter
    reads a mesh; Blender's point-cloud objects are not yet everywhere) with a byte colour attribute
    ``Col`` (the points' sRGB colours), in the "Imported Cameras" collection; an earlier import's points
    object there is replaced. ``xyz`` (n, 3) float in the scene's frame, ``rgb`` (n, 3) uint8."""
    coll = imported_collection(scene)
    for old in [o for o in coll.objects if POINTS_TAG in o]:
        data = old.data
        bpy.data.objects.remove(old, do_unlink=True)
        if data is not None and data.users == 0:
            bpy.data.meshes.remove(data)
    mesh = bpy.data.meshes.new(name)
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    mesh.vertices.add(len(xyz))
    mesh.vertices.foreach_set("co", xyz.ravel())
    col = mesh.color_attributes.new("Col", "BYTE_COLOR", "POINT")
    rgba = np.concatenate([np.asarray(rgb, np.float32).reshape(-1, 3) / 255.0, np.ones((len(xyz), 1), np.float32)], 1)
    col.data.foreach_set("color_srgb", rgba.ravel())
    mesh.update()
    ob = bpy.data.objects.new(name, mesh)
    ob[POINTS_TAG] = source
    coll.objects.link(ob)
    return ob
