"""Blender camera objects for rendered views: the exact inverse of ``dataset/cameras.intrinsics_from_params``.

A rendered view (``renders.json``) is a pinhole camera in pixels, fx, fy, cx, cy, w, h, with an OpenGL
camera-to-world matrix (Blender's own camera axes: looking down -Z, +Y up). ``camera_params`` turns
it back into what a Blender camera and its scene hold: lens, sensor width with a HORIZONTAL sensor
fit (so the result does not depend on which image side is longer), lens shift, the render resolution
and the pixel aspect (fx != fy). Looking through the camera made by ``make_view_camera`` with the
scene set by ``use_view_resolution`` shows exactly the pixels the NeRF rendered.
"""
from __future__ import annotations

from typing import Dict

import bpy
from mathutils import Matrix

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
