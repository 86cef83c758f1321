"""Bring NeRF renders into Blender as image planes, with Blender's own ``image.import_as_mesh_planes``.

Two layouts:

* camera-aligned (``import_camera_aligned``): each render on a plane inside its camera's frustum at
  ``distance``, sized from the render's intrinsics so that looking through the camera shows the
  plane exactly over the image (lens shift, sensor fit and aspect are all in fx, fy, cx, cy);
* comparison gallery (``import_gallery``): per view a row NeRF | Blender (the dataset image) | error
  heat-map, with PSNR / SSIM on text objects.

Everything created is tagged ``nerf_bridge`` and lives in its own collection; importing again first
removes what the previous import created there (objects, meshes, materials, images, text curves),
so re-importing replaces instead of piling up. Objects the user put in the collection are left alone.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import bpy
import numpy as np
from mathutils import Matrix, Vector

from . import image_metrics

VIEWS_COLLECTION = "NeRF Views"
GALLERY_COLLECTION = "NeRF Gallery"
TAG = "nerf_bridge"
HEATMAP_VMAX = 0.25  # mean absolute error drawn at full brightness; fixed so views are comparable


@dataclass
class View:
    """One rendered view.

    ``c2w`` is the 4x4 camera-to-world (OpenGL, no scale); ``intrinsics`` holds fx, fy, cx, cy, w, h
    in pixels of the rendered image; ``ground_truth`` is the dataset image for the same camera.
    """

    name: str
    image: str
    c2w: List[List[float]]
    intrinsics: Dict[str, float]
    ground_truth: Optional[str] = None
    depth: Optional[str] = None
    metrics: Dict[str, float] = field(default_factory=dict)


# -- reading render folders ----------------------------------------------------------------------
def intrinsics_from(meta: dict, frame: dict, image_size: Optional[Sequence[int]] = None) -> Dict[str, float]:
    """fx, fy, cx, cy, w, h from a transforms frame (per-frame keys override the file's)."""

    def get(key):
        return frame.get(key, meta.get(key))

    w, h = get("w"), get("h")
    if (w is None or h is None) and image_size is not None:
        w, h = image_size
    if w is None or h is None:
        raise ValueError("transforms has no 'w'/'h' and the image size is unknown")
    w, h = float(w), float(h)
    fx, fy = get("fl_x"), get("fl_y")
    if fx is None:
        angle = get("camera_angle_x")
        if angle is None:
            raise ValueError("transforms has neither 'fl_x' nor 'camera_angle_x'")
        fx = 0.5 * w / math.tan(0.5 * float(angle))
    fy = fx if fy is None else fy
    cx, cy = get("cx"), get("cy")
    return {"fx": float(fx), "fy": float(fy), "cx": float(w / 2 if cx is None else cx),
            "cy": float(h / 2 if cy is None else cy), "w": w, "h": h}


def _load_json(path: str) -> dict:
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise ValueError(f"{path}: expected an object with a 'frames' list")
    return data


def frame_stem(frame: dict, index: int) -> str:
    """The output name nerf_core render uses for a frame: basename of file_path, else view_XXX."""
    path = frame.get("file_path")
    if isinstance(path, str) and path:
        return os.path.splitext(os.path.basename(path))[0]
    return f"view_{index:03d}"


def views_from_render(render_dir: str, cameras_json: Optional[str] = None) -> List[View]:
    """The views in ``render_dir`` (``renders.json`` from ``nerf_core render``), each matched by name to
    its frame in ``cameras_json`` to find the dataset's ground-truth image (when the file exists)."""
    listing = os.path.join(render_dir, "renders.json")
    source = listing if os.path.isfile(listing) else cameras_json
    if source is None:
        raise ValueError(f"{render_dir}: no renders.json (was it written by 'nerf_core render'?)")
    meta = _load_json(source)
    gt_meta, gt_by_stem = None, {}
    if cameras_json and os.path.isfile(cameras_json):
        gt_meta = _load_json(cameras_json)
        base = os.path.dirname(os.path.abspath(cameras_json))
        for i, fr in enumerate(gt_meta["frames"]):
            fp = fr.get("file_path")
            if isinstance(fp, str) and fp:
                path = os.path.normpath(os.path.join(base, fp))
                gt_by_stem[frame_stem(fr, i)] = path if os.path.splitext(path)[1] else path + ".png"
    views = []
    for i, fr in enumerate(meta["frames"]):
        stem = frame_stem(fr, i)
        image = os.path.join(render_dir, stem + ".png")
        if not os.path.isfile(image):
            raise ValueError(f"{render_dir}: frame {i} ({stem}): render {stem}.png is missing")
        if "transform_matrix" not in fr:
            raise ValueError(f"{source}: frame {i} ({stem}) has no transform_matrix")
        try:
            intr = intrinsics_from(meta, fr)
        except ValueError as exc:
            raise ValueError(f"{source}: frame {i} ({stem}): {exc}") from None
        gt = gt_by_stem.get(stem)
        depth = os.path.join(render_dir, stem + "_depth.exr")
        views.append(View(stem, os.path.abspath(image), fr["transform_matrix"], intr,
                          gt if gt and os.path.isfile(gt) else None, depth if os.path.isfile(depth) else None))
    return views


# -- collections and cleanup -----------------------------------------------------------------------
def ensure_collection(name: str, scene=None) -> bpy.types.Collection:
    scene = scene or bpy.context.scene
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def clear_collection(name: str) -> int:
    """Remove what earlier imports created in collection ``name``; returns the objects removed."""
    coll = bpy.data.collections.get(name)
    if coll is None:
        return 0
    objects = [ob for ob in coll.objects if ob.get(TAG)]
    datas, materials, images = set(), set(), set()
    for ob in objects:
        if ob.data is not None:
            datas.add(ob.data)
            for slot_mat in getattr(ob.data, "materials", []):
                if slot_mat is not None and slot_mat.get(TAG):
                    materials.add(slot_mat)
    for mat in materials:
        if mat.node_tree:
            for node in mat.node_tree.nodes:
                if node.bl_idname == "ShaderNodeTexImage" and node.image is not None and node.image.get(TAG):
                    images.add(node.image)
    for ob in objects:
        bpy.data.objects.remove(ob, do_unlink=True)
    for data in datas:
        if data.users == 0:
            (bpy.data.meshes if isinstance(data, bpy.types.Mesh) else bpy.data.curves).remove(data)
    for mat in materials:
        if mat.users == 0:
            bpy.data.materials.remove(mat)
    for img in images:
        if img.users == 0:
            bpy.data.images.remove(img)
    return len(objects)


def _tag(*ids) -> None:
    for idb in ids:
        if idb is not None:
            idb[TAG] = True


# -- planes ------------------------------------------------------------------------------------------
def import_image_plane(path: str, collection: bpy.types.Collection, name: str) -> bpy.types.Object:
    """One unit-height plane (width = image aspect) in the local XY plane facing +Z, via Blender's
    importer, moved into ``collection``; its object, mesh, material and image are tagged."""
    if not os.path.isfile(path):
        raise ValueError(f"image {path} does not exist")
    before = set(bpy.data.objects)
    result = bpy.ops.image.import_as_mesh_planes(
        files=[{"name": os.path.basename(path)}], directory=os.path.dirname(os.path.abspath(path)) + os.sep,
        shader="SHADELESS", relative=False, align_axis="+Z", size_mode="ABSOLUTE", height=1.0,
        offset=False, use_transparency=True, overwrite_material=False, force_reload=True,
    )
    created = [ob for ob in bpy.data.objects if ob not in before]
    if "FINISHED" not in result or len(created) != 1:
        raise RuntimeError(f"importing {path} as a plane failed ({result})")
    ob = created[0]
    for coll in list(ob.users_collection):
        coll.objects.unlink(ob)
    collection.objects.link(ob)
    ob.name = name
    ob.data.name = name
    mats = [m for m in ob.data.materials if m is not None]
    for mat in mats:
        mat.name = name
        _tag(mat)
        for node in mat.node_tree.nodes if mat.node_tree else ():
            if node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
                _tag(node.image)
    _tag(ob, ob.data)
    return ob


def plane_image_path(ob: bpy.types.Object) -> Optional[str]:
    """Absolute path of the image shown by a plane made here (its material's image texture)."""
    for mat in ob.data.materials:
        if mat and mat.node_tree:
            for node in mat.node_tree.nodes:
                if node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
                    return bpy.path.abspath(node.image.filepath)
    return None


def frustum_plane(c2w, intrinsics: Dict[str, float], distance: float):
    """World matrix and (width, height) of the rectangle that covers the image at ``distance`` in front
    of the camera: the image corners (0, 0), (w, 0), (w, h), (0, h) back-projected to z = -distance.

    Returns (Matrix 4x4, width, height); the rectangle is centred on the matrix origin in its XY plane.
    """
    fx, fy, cx, cy, w, h = (intrinsics[k] for k in ("fx", "fy", "cx", "cy", "w", "h"))
    centre = Vector(((w / 2 - cx) / fx * distance, -(h / 2 - cy) / fy * distance, -distance))
    width, height = w / fx * distance, h / fy * distance
    return Matrix(c2w) @ Matrix.Translation(centre), width, height


def _resize_plane(ob: bpy.types.Object, width: float, height: float) -> None:
    # Scale the mesh, not the object, so the plane keeps a clean unit scale the user can edit.
    dims = [max(abs(v.co.x) for v in ob.data.vertices) * 2, max(abs(v.co.y) for v in ob.data.vertices) * 2]
    ob.data.transform(Matrix.Diagonal((width / dims[0], height / dims[1], 1.0, 1.0)))
    ob.data.update()


def import_camera_aligned(views: Sequence[View], distance, collection_name: str = VIEWS_COLLECTION,
                          scene=None) -> List[bpy.types.Object]:
    """Replace the planes in ``collection_name`` with one plane per view inside its camera's frustum,
    ``distance`` in front of it (one number for all views, or one per view)."""
    distances = list(distance) if isinstance(distance, (list, tuple)) else [distance] * len(views)
    if len(distances) != len(views) or any(d <= 0 for d in distances):
        raise ValueError(f"plane distances must be positive, one per view; got {distance}")
    clear_collection(collection_name)
    coll = ensure_collection(collection_name, scene)
    made = []
    for view, dist in zip(views, distances):
        ob = import_image_plane(view.image, coll, f"NeRF {view.name}")
        matrix, width, height = frustum_plane(view.c2w, view.intrinsics, dist)
        _resize_plane(ob, width, height)
        ob.matrix_world = matrix
        ob["nerf_view"] = view.name
        made.append(ob)
    return made


# -- gallery -------------------------------------------------------------------------------------------
def load_image_array(path: str) -> np.ndarray:
    """(h, w, 4) float32 in [0, 1], row 0 at the top, the file's values as stored (no colour conversion)."""
    img = bpy.data.images.load(path, check_existing=False)
    try:
        w, h = img.size
        if w == 0 or h == 0:
            raise ValueError(f"{path}: Blender could not read this image")
        buf = np.empty(w * h * img.channels, np.float32)
        img.pixels.foreach_get(buf)
        arr = buf.reshape(h, w, img.channels)[::-1]
    finally:
        bpy.data.images.remove(img)
    if arr.shape[2] == 3:
        arr = np.concatenate([arr, np.ones_like(arr[..., :1])], axis=2)
    return np.ascontiguousarray(arr)


def compare_view(view: View, out_dir: str, background=(1.0, 1.0, 1.0)) -> Optional[str]:
    """PSNR / SSIM of the render against the ground truth into ``view.metrics``; writes the error
    heat-map ``<out_dir>/<name>_error.png`` and returns its path (None without ground truth)."""
    if not view.ground_truth:
        return None
    nerf = image_metrics.composite(load_image_array(view.image), background)
    gt = image_metrics.composite(load_image_array(view.ground_truth), background)
    if nerf.shape != gt.shape:
        raise ValueError(f"view {view.name}: render {nerf.shape[1]}x{nerf.shape[0]} and ground truth "
                         f"{view.ground_truth} {gt.shape[1]}x{gt.shape[0]} differ in size")
    view.metrics = {"psnr": image_metrics.psnr(nerf, gt), "ssim": image_metrics.ssim(nerf, gt)}
    path = os.path.join(out_dir, f"{view.name}_error.png")
    image_metrics.write_png(path, image_metrics.error_heatmap(nerf, gt, vmax=HEATMAP_VMAX))
    return path


def _text(collection, name: str, body: str, location, size: float) -> bpy.types.Object:
    curve = bpy.data.curves.new(name, "FONT")
    curve.body = body
    curve.size = size
    ob = bpy.data.objects.new(name, curve)
    ob.location = location
    ob.rotation_euler = (math.pi / 2, 0.0, 0.0)
    collection.objects.link(ob)
    _tag(ob, curve)
    return ob


def import_gallery(views: Sequence[View], out_dir: str, origin=(0.0, 0.0, 0.0), row_height: float = 1.0,
                   background=(1.0, 1.0, 1.0), collection_name: str = GALLERY_COLLECTION,
                   scene=None) -> List[View]:
    """Replace the gallery: one row per view (NeRF | Blender | error), upright in the XZ plane facing
    -Y (the front view), rows going down from ``origin``. Fills ``view.metrics``; returns the views."""
    clear_collection(collection_name)
    coll = ensure_collection(collection_name, scene)
    gap = 0.1 * row_height
    label = 0.12 * row_height
    upright = Matrix.Rotation(math.pi / 2, 4, "X")
    origin = Vector(origin)
    if views:
        aspect = views[0].intrinsics["w"] / views[0].intrinsics["h"]
        col_w = aspect * row_height
        headers = ("NeRF", "Blender", f"|error| (bright = {HEATMAP_VMAX:g}+)")
        for col, title in enumerate(headers):
            _text(coll, f"Gallery {title.split()[0]}", title, origin + Vector((col * (col_w + gap), 0, gap)), label)
    for row, view in enumerate(views):
        heat = compare_view(view, out_dir, background)
        z = -row * (row_height + 2 * label + 2 * gap)
        aspect = view.intrinsics["w"] / view.intrinsics["h"]
        col_w = aspect * row_height
        for col, (kind, path) in enumerate((("NeRF", view.image), ("Blender", view.ground_truth), ("Error", heat))):
            if not path:
                continue
            ob = import_image_plane(path, coll, f"Gallery {kind} {view.name}")
            _resize_plane(ob, col_w, row_height)
            ob.matrix_world = Matrix.Translation(
                origin + Vector((col * (col_w + gap) + col_w / 2, 0.0, z - row_height / 2))) @ upright
            ob["nerf_view"] = view.name
        if view.metrics:
            body = f"{view.name}   PSNR {view.metrics['psnr']:.2f} dB   SSIM {view.metrics['ssim']:.3f}"
        else:
            body = f"{view.name}   (no ground truth image)"
        _text(coll, f"Label {view.name}", body, origin + Vector((0.0, 0.0, z - row_height - label - gap / 2)), label)
    return list(views)


# -- Blender cameras to a transforms file for ``nerf_core render`` ---------------------------------------
def _camera_intrinsics(cam_ob, scene, w: int, h: int) -> Dict[str, float]:
    """Pixel intrinsics of ``cam_ob`` rendered at w x h, from the capture helper's function, so that
    capture and comparison can never disagree on lens shift or sensor fit."""
    from .export import intrinsics_from_params

    cam = cam_ob.data
    if cam.type != "PERSP":
        raise ValueError(f"camera {cam_ob.name!r} is {cam.type.lower()}; only perspective cameras can be rendered")
    r = scene.render
    intr = intrinsics_from_params(cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit, cam.shift_x,
                                  cam.shift_y, w, h, r.pixel_aspect_x, r.pixel_aspect_y)
    return {"fx": intr["fl_x"], "fy": intr["fl_y"], "cx": intr["cx"], "cy": intr["cy"], "w": float(w), "h": float(h)}


def cameras_transforms(cameras: Sequence, scene, size: Sequence[int], frames: Optional[Sequence[int]] = None,
                       base: Optional[dict] = None, prefix: str = "view") -> dict:
    """A transforms dict (docs/CONTRACTS.md) for Blender cameras rendered at ``size`` = (w, h).

    With ``frames``, ``cameras`` must hold one camera and one view is written per frame (a fly-through
    along its animation). ``base`` supplies near/far/aabb from the run's dataset. Raises ValueError
    when a camera's aspect differs from ``size`` (the run can only render the aspect it trained on).
    """
    from .export import camera_to_world  # raises (a ValueError) for scaled or sheared cameras

    w, h = int(size[0]), int(size[1])
    res_x = scene.render.resolution_x * scene.render.pixel_aspect_x
    res_y = scene.render.resolution_y * scene.render.pixel_aspect_y
    if abs(res_x / res_y - w / h) > 0.005 * (w / h):
        names = ", ".join(repr(c.name) for c in cameras)
        raise ValueError(
            f"camera {names} renders at {scene.render.resolution_x}x{scene.render.resolution_y} in this scene "
            f"(aspect {res_x / res_y:.3f}) but the run was trained on {w}x{h} (aspect {w / h:.3f}): set "
            f"Output Properties > Resolution to the same aspect, or render the run's own cameras")
    meta = {k: v for k, v in (base or {}).items() if k in ("near", "far", "aabb", "aabb_scale")}
    out_frames = []
    saved_frame = scene.frame_current
    try:
        shots = [(cameras[0], f) for f in frames] if frames is not None else [(c, None) for c in cameras]
        for i, (cam, frame) in enumerate(shots):
            if cam.type != "CAMERA":
                raise ValueError(f"object {cam.name!r} is not a camera")
            if frame is not None:
                scene.frame_set(frame)
            intr = _camera_intrinsics(cam, scene, w, h)
            stem = f"frame_{frame:04d}" if frame is not None else bpy.path.clean_name(cam.name)
            out_frames.append({
                "file_path": f"./{prefix}/{stem}",
                "transform_matrix": camera_to_world(cam),
                "fl_x": intr["fx"], "fl_y": intr["fy"], "cx": intr["cx"], "cy": intr["cy"], "w": w, "h": h,
                "camera": cam.name,
            })
    finally:
        scene.frame_set(saved_frame)
    if not out_frames:
        raise ValueError("no cameras to render")
    first = out_frames[0]
    meta.update({"camera_angle_x": 2 * math.atan(0.5 * w / first["fl_x"]), "fl_x": first["fl_x"],
                 "fl_y": first["fl_y"], "cx": first["cx"], "cy": first["cy"], "w": w, "h": h,
                 "frames": out_frames})
    return meta
