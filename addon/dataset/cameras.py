"""Blender cameras as dataset cameras and back: intrinsics (``intrinsics_from_params``), its exact inverse
(``camera_params``: lens, sensor, shift and pixel aspect for pinhole intrinsics; ``make_view_camera``),
scale-free camera-to-world matrices, and transforms files for ``nerf_core render``.
The only module of ``dataset`` that touches bpy objects.

A pinhole view in pixels (fx, fy, cx, cy, w, h) with an OpenGL camera-to-world matrix (Blender's own
camera axes: looking down -Z, +Y up) becomes a camera with a HORIZONTAL sensor fit (so the result does
not depend on which image side is longer), lens shift, and the scene's render resolution and pixel
aspect (fx != fy). Looking through it shows exactly the pixels of the view.
"""
from __future__ import annotations

from typing import Dict

import bpy
from mathutils import Matrix

from ..bridge.core_contract import contract
from ..scene.camera_checks import camera_label, camera_scale_error, camera_shape_error
from .errors import ExportError
from .transforms import transforms_document


def intrinsics_from_params(lens, sensor_width, sensor_height, sensor_fit, shift_x, shift_y,
                           res_x, res_y, pixel_aspect_x=1.0, pixel_aspect_y=1.0) -> dict:
    """Pinhole intrinsics in pixels matching Blender's viewplane (BKE_camera_params_compute_viewplane).

    Sensor fit picks which image side the sensor size spans (AUTO: the longer one, in pixel-aspect
    units). Lens shift is in units of that side: shift_x > 0 moves the view right, so the principal
    point moves left (cx = w/2 - shift_x * side); shift_y > 0 moves the view up, so in top-down pixel
    rows the principal point moves down (cy = h/2 + shift_y * side).
    """
    ycor = pixel_aspect_y / pixel_aspect_x
    if sensor_fit == "AUTO":
        sensor = sensor_width
        fit = "HORIZONTAL" if pixel_aspect_x * res_x >= pixel_aspect_y * res_y else "VERTICAL"
    elif sensor_fit == "HORIZONTAL":
        sensor, fit = sensor_width, "HORIZONTAL"
    elif sensor_fit == "VERTICAL":
        sensor, fit = sensor_height, "VERTICAL"
    else:
        raise ExportError(f"unknown sensor fit {sensor_fit!r}")
    viewfac = res_x if fit == "HORIZONTAL" else ycor * res_y
    fx = lens * viewfac / sensor
    fy = fx / ycor
    cx = 0.5 * res_x - shift_x * viewfac
    cy = 0.5 * res_y + shift_y * viewfac / ycor
    return {
        "camera_angle_x": contract.fov_from_focal(fx, res_x),
        "camera_angle_y": contract.fov_from_focal(fy, res_y),
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": int(res_x), "h": int(res_y),
        "camera_model": "OPENCV", "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
    }


def camera_intrinsics(cam_obj, render) -> dict:
    """Intrinsics of a Blender camera object for the scene's render settings (resolution %, aspect)."""
    cam = cam_obj.data
    if cam.type != "PERSP":
        raise ExportError(f"{camera_label(cam_obj)} is {cam.type.lower()}; only perspective "
                          f"cameras make a NeRF dataset")
    scale = render.resolution_percentage / 100.0
    res_x, res_y = int(render.resolution_x * scale), int(render.resolution_y * scale)
    return intrinsics_from_params(cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit, cam.shift_x,
                                  cam.shift_y, res_x, res_y, render.pixel_aspect_x, render.pixel_aspect_y)


def scale_free_matrix(cam_obj) -> Matrix:
    """The camera's pose: ``matrix_world`` with its scale removed (OpenGL axes, never pre-flipped).

    The one rule for every camera we hand to a NeRF (capture, camera-path export, render engine), so
    that they give the renderer the same float32 matrix bit for bit: columns normalised (a clean pose
    keeps its rotation as Blender stores it). A sheared or mirrored pose, which only the render engine
    accepts, becomes its nearest rotation (``decompose``)."""
    if camera_shape_error(cam_obj):
        loc, rot, _scale = cam_obj.matrix_world.decompose()
        return Matrix.LocRotScale(loc, rot, None)
    return cam_obj.matrix_world.normalized()


def camera_to_world(cam_obj) -> list[list[float]]:
    """``scale_free_matrix`` as 4 rows; a scaled, sheared or mirrored camera is refused (ExportError)."""
    err = camera_scale_error(cam_obj)
    if err:
        raise ExportError(err)
    return [[float(v) for v in row] for row in scale_free_matrix(cam_obj)]


def cameras_transforms(cameras, scene, size, frames=None, base: dict | None = None, prefix: str = "view") -> dict:
    """A transforms object (``transforms_document``) for Blender cameras rendered at ``size`` = (w, h),
    for ``nerf_core render`` (the Compare panel's selected cameras or fly-through).

    With ``frames``, ``cameras`` must hold one camera and one view is written per frame (a fly-through
    along its animation). ``base`` supplies near/far/aabb from the run's dataset. Raises ValueError
    (ExportError) when a camera's aspect differs from ``size`` (the run renders the aspect it trained
    on), for a camera that is not perspective, scaled or sheared, and without cameras.
    """
    w, h = int(size[0]), int(size[1])
    r = scene.render
    res_x, res_y = r.resolution_x * r.pixel_aspect_x, r.resolution_y * r.pixel_aspect_y
    if abs(res_x / res_y - w / h) > 0.005 * (w / h):
        names = ", ".join(repr(c.name) for c in cameras)
        raise ExportError(
            f"camera {names} renders at {r.resolution_x}x{r.resolution_y} in this scene "
            f"(aspect {res_x / res_y:.3f}) but the run was trained on {w}x{h} (aspect {w / h:.3f}): set "
            f"Output Properties > Resolution to the same aspect, or render the run's own cameras")
    common = {k: v for k, v in (base or {}).items() if k in ("near", "far", "aabb", "aabb_scale")}
    out_frames = []
    saved_frame = scene.frame_current
    try:
        shots = [(cameras[0], f) for f in frames] if frames is not None else [(c, None) for c in cameras]
        for cam, frame in shots:
            if cam.type != "CAMERA":
                raise ExportError(f"object {cam.name!r} is not a camera")
            if frame is not None:
                scene.frame_set(frame)
            data = cam.data
            if data.type != "PERSP":
                raise ExportError(f"camera {cam.name!r} is {data.type.lower()}; only perspective "
                                  f"cameras can be rendered")
            intr = intrinsics_from_params(data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                                          data.shift_x, data.shift_y, w, h, r.pixel_aspect_x, r.pixel_aspect_y)
            out_frames.append({"name": f"frame_{frame:04d}" if frame is not None else bpy.path.clean_name(cam.name),
                               "transform_matrix": camera_to_world(cam), "intrinsics": intr, "frame": frame,
                               "camera": cam.name})
    finally:
        scene.frame_set(saved_frame)
    if not out_frames:
        raise ExportError("no cameras to render")
    # Every frame carries its intrinsics, as camera files always have (the top level holds the first's).
    return transforms_document(out_frames, common, prefix, per_frame=True)


SENSOR_WIDTH = 36.0  # mm, Blender's default; any width works, the lens follows from it
LENS_RANGE = (1.0, 5000.0)  # mm: what Blender accepts for Camera.lens
SENSOR_RANGE = (1.0, 100.0)  # mm: what Blender accepts for Camera.sensor_width


def camera_params(intrinsics: Dict[str, float]) -> dict:
    """Blender camera + scene settings reproducing pinhole ``intrinsics`` (fx, fy, cx, cy, w, h, pixels).

    ``intrinsics_from_params(**result)`` gives back fx, fy, cx, cy, w, h (blender_tests/test_view_cameras.py):
    fx = lens * w / sensor (HORIZONTAL fit), fy = fx * pixel_aspect_x / pixel_aspect_y,
    cx = w / 2 - shift_x * w, cy = h / 2 + shift_y * w * pixel_aspect_x / pixel_aspect_y.
    Blender's pixel aspects are both >= 1, so the smaller one is 1. Raises ValueError for a view
    Blender cannot represent (non-integer size, focal length out of the lens/sensor range).
    """
    fx, fy, cx, cy, w, h = (float(intrinsics[k]) for k in ("fx", "fy", "cx", "cy", "w", "h"))
    if not (fx > 0 and fy > 0 and w >= 1 and h >= 1) or w != int(w) or h != int(h):
        raise ValueError(f"view intrinsics fx={fx:g} fy={fy:g} w={w:g} h={h:g}: need positive focal lengths "
                         "and a whole number of pixels")
    ycor = fx / fy  # = pixel_aspect_y / pixel_aspect_x
    pax, pay = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    sensor = SENSOR_WIDTH
    lens = fx * sensor / w
    if not LENS_RANGE[0] <= lens <= LENS_RANGE[1]:
        # A very wide or very long view: move the sensor instead, keeping fx = lens * w / sensor.
        lens = min(max(lens, LENS_RANGE[0]), LENS_RANGE[1])
        sensor = lens * w / fx
        if not SENSOR_RANGE[0] <= sensor <= SENSOR_RANGE[1]:
            raise ValueError(f"view focal length fx={fx:g} px for a {w:g} px wide image is outside what a "
                             "Blender camera can hold (lens 1-5000 mm, sensor 1-100 mm)")
    return {
        "lens": lens, "sensor_width": sensor, "sensor_height": sensor * h / w, "sensor_fit": "HORIZONTAL",
        "shift_x": (0.5 * w - cx) / w, "shift_y": (cy - 0.5 * h) * ycor / w,
        "res_x": int(w), "res_y": int(h), "pixel_aspect_x": pax, "pixel_aspect_y": pay,
    }


def make_view_camera(name: str, c2w, intrinsics: Dict[str, float], collection, clip=(0.01, 1000.0)):
    """A new perspective camera object ``name`` in ``collection`` at ``c2w`` (4x4, no scale) with the
    lens, sensor and shift of ``intrinsics``; returns it. The scene's resolution and pixel aspect
    are set separately (``use_view_resolution``): they belong to the scene, not the camera."""
    params = camera_params(intrinsics)
    data = bpy.data.cameras.new(name)
    data.type = "PERSP"
    data.sensor_fit = params["sensor_fit"]
    data.sensor_width, data.sensor_height = params["sensor_width"], params["sensor_height"]
    data.lens = params["lens"]
    data.shift_x, data.shift_y = params["shift_x"], params["shift_y"]
    data.clip_start, data.clip_end = clip
    ob = bpy.data.objects.new(name, data)
    collection.objects.link(ob)
    ob.matrix_world = Matrix(c2w).normalized()
    return ob


def use_view_resolution(scene, intrinsics: Dict[str, float]) -> None:
    """Render resolution (100 %) and pixel aspect of ``scene`` to the view's, so its cameras frame it."""
    params = camera_params(intrinsics)
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = params["res_x"], params["res_y"], 100
    r.pixel_aspect_x, r.pixel_aspect_y = params["pixel_aspect_x"], params["pixel_aspect_y"]
