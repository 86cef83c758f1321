"""Bring NeRF renders into Blender as image planes, with Blender's own ``image.import_as_mesh_planes``.

Two layouts:

* camera-aligned (``import_camera_aligned``): each render on a plane inside its camera's frustum at
  ``distance``, sized from the render's intrinsics so that looking through the camera shows the
  plane exactly over the image (lens shift, sensor fit and aspect are all in fx, fy, cx, cy);
* comparison gallery (``import_gallery``): per view a row NeRF | Blender (the dataset image) | error
  heat-map, with PSNR / SSIM on text objects. ``nerf_core render`` computes those metrics and writes
  the heat-maps (with eval's own functions); the gallery only reads them from ``renders.json``.

Intrinsics and the names of render outputs follow ``nerf_core.contract`` (``core_contract``).

Camera-aligned planes come with their cameras (``view_cameras``: one Blender camera per view, the
exact inverse of the capture's intrinsics rule, in the child collection ``NeRF View Cameras``); each
plane is parented to its camera and names it in the custom property ``nerf_camera``. The gallery is
placed beside the scene's visible objects and framed by an orthographic camera (``gallery_frame``).

Everything created is tagged ``nerf_bridge`` and lives in its own collection; importing again first
removes what the previous import created there (objects, meshes, cameras, materials, images, text
curves), so re-importing replaces instead of piling up. Objects the user put in the collection are
left alone.
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

from ..bridge.core_contract import contract
from . import gallery_frame, view_cameras

VIEWS_COLLECTION = "NeRF Views"
VIEW_CAMERAS_COLLECTION = "NeRF View Cameras"  # a child of VIEWS_COLLECTION: hiding the views hides both
GALLERY_COLLECTION = "NeRF Gallery"
GALLERY_CAMERA = "NeRF Gallery Camera"
TAG = "nerf_bridge"


@dataclass
class View:
    """One rendered view.

    ``c2w`` is the 4x4 camera-to-world (OpenGL, no scale); ``intrinsics`` holds fx, fy, cx, cy, w, h
    in pixels of the rendered image; ``ground_truth`` is the dataset image for the same camera;
    ``metrics`` (psnr, ssim) and ``error_map`` (heat-map PNG, mean absolute error, ``error_vmax`` and
    above at full brightness) are what ``nerf_core render`` wrote for it.
    """

    name: str
    image: str
    c2w: List[List[float]]
    intrinsics: Dict[str, float]
    ground_truth: Optional[str] = None
    depth: Optional[str] = None
    metrics: Dict[str, float] = field(default_factory=dict)
    lens: Optional[str] = None  # "OPENCV" / "OPENCV_FISHEYE" when the render is distorted; None: a pinhole
    error_map: Optional[str] = None
    error_vmax: Optional[float] = None


# -- reading render folders ----------------------------------------------------------------------
def intrinsics_from(meta: dict, frame: dict, image_size: Optional[Sequence[int]] = None) -> Dict[str, float]:
    """fx, fy, cx, cy, w, h of a transforms frame by the contract's rule (``contract.resolve_intrinsics``:
    per-frame keys override the file's, ``fl_x`` before ``camera_angle_x``); ValueError when incomplete."""
    try:
        fx, fy, cx, cy, w, h = contract.resolve_intrinsics(meta, frame, image_size, "transforms")
    except contract.DatasetError as exc:
        raise ValueError(str(exc).split(": ", 1)[-1]) from None
    return {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "w": w, "h": h}


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


def views_from_render(render_dir: str, cameras_json: Optional[str] = None) -> List[View]:
    """The views in ``render_dir`` (``renders.json`` from ``nerf_core render``) with the metrics and
    error maps it lists. A view's ground truth is the image renders.json names, else (older render
    folders) the frame of ``cameras_json`` whose output name matches (``contract.output_stems``)."""
    listing = os.path.join(render_dir, "renders.json")
    source = listing if os.path.isfile(listing) else cameras_json
    if source is None:
        raise ValueError(f"{render_dir}: no renders.json (was it written by 'nerf_core render'?)")
    meta = _load_json(source)
    gt_by_stem = {}
    if cameras_json and os.path.isfile(cameras_json):
        gt_frames = _load_json(cameras_json)["frames"]
        base = os.path.dirname(os.path.abspath(cameras_json))
        for stem, fr in zip(contract.output_stems(gt_frames), gt_frames):
            fp = fr.get("file_path") if isinstance(fr, dict) else None
            if isinstance(fp, str) and fp:
                gt_by_stem[stem] = str(contract.resolve_image(base, fp, add_png=not os.path.splitext(fp)[1]))
    views = []
    for i, (stem, fr) in enumerate(zip(contract.output_stems(meta["frames"]), meta["frames"])):
        if not isinstance(fr, dict):
            raise ValueError(f"{source}: frame {i} is not an object")
        image = os.path.join(render_dir, contract.render_files(stem)["image"])
        if not os.path.isfile(image):
            raise ValueError(f"{render_dir}: frame {i} ({stem}): render {stem}.png is missing")
        if "transform_matrix" not in fr:
            raise ValueError(f"{source}: frame {i} ({stem}) has no transform_matrix")
        try:
            intr = intrinsics_from(meta, fr)
        except ValueError as exc:
            raise ValueError(f"{source}: frame {i} ({stem}): {exc}") from None
        gt = fr.get("ground_truth") or gt_by_stem.get(stem)
        if gt is not None and not isinstance(gt, str):
            raise ValueError(f"{source}: frame {i} ({stem}): field 'ground_truth' must be an image path, got {gt!r}")
        depth = os.path.join(render_dir, contract.render_files(stem)["depth"])
        view = View(stem, os.path.abspath(image), fr["transform_matrix"], intr,
                    gt if gt and os.path.isfile(gt) else None, depth if os.path.isfile(depth) else None)
        lens, _ = contract.parse_lens(meta, fr)  # render wrote each distorted camera's lens fields
        view.lens = lens.model if lens is not None else None
        if isinstance(fr.get("psnr"), (int, float)) and isinstance(fr.get("ssim"), (int, float)):
            view.metrics = {"psnr": float(fr["psnr"]), "ssim": float(fr["ssim"])}
        heat = os.path.join(render_dir, fr["error_map"]) if isinstance(fr.get("error_map"), str) else None
        view.error_map = heat if heat and os.path.isfile(heat) else None
        vmax = meta.get("error_map_vmax")
        finite = isinstance(vmax, (int, float)) and not isinstance(vmax, bool) and math.isfinite(vmax) and vmax > 0
        view.error_vmax = vmax if finite else None  # damaged: the heat-map's legend shows no scale
        views.append(view)
    return views


def lens_note(views: Sequence[View]) -> str:
    """A warning for views rendered through a distorted lens, else '': Blender's cameras and image
    planes are pinholes, so such an image lines up with the scene only near its centre."""
    distorted = [v for v in views if v.lens]
    if not distorted:
        return ""
    models = " / ".join(sorted({v.lens for v in distorted}))
    return (f"{len(distorted)} of {len(views)} views were rendered through a distorted {models} lens, which a Blender "
            "camera cannot reproduce: their cameras and planes are pinhole views and line up with the scene only "
            "near the image centre (the images and metrics are right)")


# -- collections and cleanup -----------------------------------------------------------------------
def ensure_collection(name: str, scene=None, parent=None) -> bpy.types.Collection:
    """Collection ``name``, linked under ``parent`` (a collection; default the scene's master collection)."""
    scene = scene or bpy.context.scene
    parent = parent if parent is not None else scene.collection
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    if coll.name not in parent.children:
        parent.children.link(coll)
    return coll


def clear_collection(name: str) -> int:
    """Remove what earlier imports created in collection ``name`` and its child collections; returns
    the objects removed."""
    coll = bpy.data.collections.get(name)
    if coll is None:
        return 0
    objects = [ob for ob in coll.all_objects if ob.get(TAG)]
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
    removed = {ob.as_pointer() for ob in objects}
    for scene in bpy.data.scenes:
        # A scene looking through a view camera (as the README suggests) would be left with none, and
        # F12 would fail: it gets one of its own cameras back (the first, by name).
        if scene.camera is not None and scene.camera.as_pointer() in removed:
            own = sorted((o for o in scene.objects if o.type == "CAMERA" and o.as_pointer() not in removed
                          and not o.get(TAG)), key=lambda o: o.name)
            scene.camera = own[0] if own else None
    for ob in objects:
        bpy.data.objects.remove(ob, do_unlink=True)
    for data in datas:
        if data.users == 0:
            if isinstance(data, bpy.types.Mesh):
                bpy.data.meshes.remove(data)
            elif isinstance(data, bpy.types.Camera):
                bpy.data.cameras.remove(data)
            else:
                bpy.data.curves.remove(data)
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
                          scene=None, set_scene_camera: bool = False) -> List[bpy.types.Object]:
    """Replace the planes in ``collection_name`` with one plane per view inside its camera's frustum,
    ``distance`` in front of it (one number for all views, or one per view), and one camera per view
    (``NeRF Cam <view>`` in ``VIEW_CAMERAS_COLLECTION``) that the plane is parented to.

    ``set_scene_camera``: make the first view's camera the scene's camera and the scene's resolution
    and pixel aspect the views' (what a compare file wants; the add-on leaves the user's scene alone).
    Returns the planes; ``ob.parent`` is each one's camera.
    """
    distances = list(distance) if isinstance(distance, (list, tuple)) else [distance] * len(views)
    if len(distances) != len(views) or any(d <= 0 for d in distances):
        raise ValueError(f"plane distances must be positive, one per view; got {distance}")
    scene = scene or bpy.context.scene
    # Looking through a view camera, the scene looks through the same view's new camera after a re-import.
    looking = scene.camera.get("nerf_view") if scene.camera is not None and scene.camera.get(TAG) else None
    clear_collection(collection_name)
    coll = ensure_collection(collection_name, scene)
    cam_coll = ensure_collection(VIEW_CAMERAS_COLLECTION, scene, parent=coll)
    made = []
    for view, dist in zip(views, distances):
        try:
            cam = view_cameras.make_view_camera(f"NeRF Cam {view.name}", view.c2w, view.intrinsics, cam_coll,
                                                clip=(min(0.01, dist / 10), max(1000.0, dist * 10)))
        except ValueError as exc:
            raise ValueError(f"view {view.name}: {exc}") from None
        cam["nerf_view"] = view.name
        _tag(cam, cam.data)
        ob = import_image_plane(view.image, coll, f"NeRF {view.name}")
        matrix, width, height = frustum_plane(view.c2w, view.intrinsics, dist)
        _resize_plane(ob, width, height)
        # Parented with an identity inverse: the plane's own transform is its place in camera space,
        # so moving the camera carries the plane along and it stays over the frame.
        ob.parent = cam
        ob.matrix_parent_inverse = Matrix.Identity(4)
        ob.matrix_basis = cam.matrix_world.inverted() @ matrix
        ob["nerf_view"] = view.name
        ob["nerf_camera"] = cam.name
        made.append(ob)
    if set_scene_camera and made:
        scene.camera = made[0].parent
        view_cameras.use_view_resolution(scene, views[0].intrinsics)
    elif looking is not None:
        scene.camera = next((ob.parent for ob in made if ob.get("nerf_view") == looking), scene.camera)
    bpy.context.view_layer.update()  # children's matrix_world follow their new parents
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


def _text_material() -> bpy.types.Material:
    """Near-white, unlit-looking text: Workbench draws ``diffuse_color``, Cycles/EEVEE an emission."""
    mat = bpy.data.materials.new("NeRF Gallery Text")
    mat.diffuse_color = (0.95, 0.95, 0.95, 1.0)
    if mat.node_tree is None:  # Blender 4.x; 5.x materials always have nodes (use_nodes is deprecated)
        mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Color"].default_value = (0.95, 0.95, 0.95, 1.0)
    out = nodes.new("ShaderNodeOutputMaterial")
    mat.node_tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    _tag(mat)
    return mat


def _text(collection, name: str, body: str, location, size: float, material=None) -> bpy.types.Object:
    curve = bpy.data.curves.new(name, "FONT")
    curve.body = body
    curve.size = size
    if material is not None:
        curve.materials.append(material)
    ob = bpy.data.objects.new(name, curve)
    ob.location = location
    ob.rotation_euler = (math.pi / 2, 0.0, 0.0)
    collection.objects.link(ob)
    _tag(ob, curve)
    return ob


def import_gallery(views: Sequence[View], out_dir: str = "", origin=None, row_height: float = 1.0,
                   background=None, collection_name: str = GALLERY_COLLECTION, scene=None,
                   set_scene_camera: bool = False) -> List[View]:
    """Replace the gallery: one row per view (NeRF | Blender | error), upright in the XZ plane facing
    -Y (the front view), rows going down from ``origin``; returns the views.

    ``origin`` None: beside the scene's other visible objects, clear of their bounding box
    (``gallery_frame.place_beside``). The orthographic camera ``GALLERY_CAMERA`` (in the gallery's
    collection) frames every tile and text at the scene's aspect; ``set_scene_camera`` also sets the
    scene's resolution to the gallery's aspect (a tile at its rendered pixel size) and makes that
    camera the scene's camera (what a compare file wants; the add-on leaves the user's scene alone).

    Metrics and heat-maps are the ones ``nerf_core render`` wrote (``views_from_render``), computed
    on the run's evaluation background; ``out_dir`` and ``background`` are accepted for older callers
    and not used (nothing is computed or written here).
    """
    scene = scene or bpy.context.scene
    clear_collection(collection_name)
    coll = ensure_collection(collection_name, scene)
    _build_gallery(views, coll, Vector(origin or (0.0, 0.0, 0.0)), row_height)
    built = [ob for ob in coll.objects if ob.get(TAG)]
    if origin is None:
        gallery_frame.place_beside(built, gallery_frame.other_objects_box(scene, coll), gap=0.5 * row_height)
    cam = bpy.data.objects.new(GALLERY_CAMERA, bpy.data.cameras.new(GALLERY_CAMERA))
    coll.objects.link(cam)
    _tag(cam, cam.data)
    box = gallery_frame.bounds(built)
    if box is not None:
        if set_scene_camera and views:
            gallery_frame.fit_resolution(scene, box, pixels_per_unit=views[0].intrinsics["h"] / row_height)
        gallery_frame.frame_ortho(scene, cam, box)
    if set_scene_camera:
        scene.camera = cam
    return list(views)


def _build_gallery(views: Sequence[View], coll, origin: Vector, row_height: float) -> None:
    """The gallery's tiles and texts in ``coll``, rows going down from ``origin``."""
    gap = 0.1 * row_height
    label = 0.12 * row_height
    upright = Matrix.Rotation(math.pi / 2, 4, "X")
    text_mat = _text_material() if views else None
    if views:
        aspect = views[0].intrinsics["w"] / views[0].intrinsics["h"]
        col_w = aspect * row_height
        vmax = next((v.error_vmax for v in views if v.error_vmax), None)
        headers = ("NeRF", "Blender", f"|error| (bright = {vmax:g}+)" if vmax else "|error|")
        for col, title in enumerate(headers):
            _text(coll, f"Gallery {title.split()[0]}", title, origin + Vector((col * (col_w + gap), 0, gap)), label,
                  text_mat)
    for row, view in enumerate(views):
        z = -row * (row_height + 2 * label + 2 * gap)
        aspect = view.intrinsics["w"] / view.intrinsics["h"]
        col_w = aspect * row_height
        for col, (kind, path) in enumerate((("NeRF", view.image), ("Blender", view.ground_truth),
                                            ("Error", view.error_map))):
            if not path:
                continue
            ob = import_image_plane(path, coll, f"Gallery {kind} {view.name}")
            _resize_plane(ob, col_w, row_height)
            ob.matrix_world = Matrix.Translation(
                origin + Vector((col * (col_w + gap) + col_w / 2, 0.0, z - row_height / 2))) @ upright
            ob["nerf_view"] = view.name
        if view.metrics:
            body = f"{view.name}   PSNR {view.metrics['psnr']:.2f} dB   SSIM {view.metrics['ssim']:.3f}"
        elif view.ground_truth:
            body = f"{view.name}   (no metrics in renders.json)"
        else:
            body = f"{view.name}   (no ground truth image)"
        _text(coll, f"Label {view.name}", body, origin + Vector((0.0, 0.0, z - row_height - label - gap / 2)), label,
              text_mat)
