"""Blender cameras as dataset cameras: intrinsics (``intrinsics_from_params``, the exact inverse of
``compare/view_cameras``), scale-free camera-to-world matrices, and transforms files for ``nerf_core render``.
The only module of ``dataset`` that touches bpy objects.
"""
from __future__ import annotations

import bpy

from ..bridge.core_contract import contract
from ..scene.camera_checks import camera_label, camera_scale_error
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
        raise ExportError(f"{camera_label(cam_obj)} is {cam.type.lower()}; only perspective cameras make a NeRF dataset")
    scale = render.resolution_percentage / 100.0
    res_x, res_y = int(render.resolution_x * scale), int(render.resolution_y * scale)
    return intrinsics_from_params(cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit, cam.shift_x,
                                  cam.shift_y, res_x, res_y, render.pixel_aspect_x, render.pixel_aspect_y)


def camera_to_world(cam_obj) -> list[list[float]]:
    """``matrix_world`` with scale removed, as 4 rows (OpenGL axes, never pre-flipped)."""
    err = camera_scale_error(cam_obj)
    if err:
        raise ExportError(err)
    m = cam_obj.matrix_world.normalized()
    return [[float(v) for v in row] for row in m]


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
                raise ExportError(f"camera {cam.name!r} is {data.type.lower()}; only perspective cameras can be rendered")
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
