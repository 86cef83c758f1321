"""addon/compare/camera_path_export.py without rendering: what each frame of a camera's animation
becomes in camera_path.json, for the cameras users animate (a rig's scale, a zoom) and the ones the
format cannot hold (shear, lens shift, orthographic), each refused naming the frame or the camera."""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from addon.compare import camera_path_export
from addon.dataset.errors import ExportError


def _camera(scene, name="Cam"):
    cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    scene.collection.objects.link(cam)
    cam.location = (0.5, -6.0, 1.5)
    cam.rotation_euler = (math.radians(80), 0.0, math.radians(5))
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 48, 100
    return cam


def test_a_camera_on_a_scaled_rig_exports_its_scale_free_pose_and_its_zoom():
    scene = bpy.context.scene
    cam = _camera(scene)
    rig = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(rig)
    rig.scale = (2.5, 2.5, 2.5)
    cam.parent = rig
    for frame, lens in ((1, 35.0), (3, 70.0)):
        cam.data.lens = lens
        cam.data.keyframe_insert("lens", frame=frame)
    doc = camera_path_export.camera_path(scene, cam, [1, 2, 3])
    entries = doc["camera_path"]
    assert len(entries) == 3 and doc["render_width"] == 64 and doc["render_height"] == 48
    fovs = [e["fov"] for e in entries]
    assert fovs[0] > fovs[1] > fovs[2]
    # vertical fov of a 36 mm sensor fitted horizontally (AUTO, landscape): sensor height 36 * 48 / 64
    assert fovs[0] == pytest.approx(math.degrees(2 * math.atan(36 * 48 / 64 / 2 / 35.0)), abs=1e-6)
    scene.frame_set(1)
    m = np.array(entries[0]["camera_to_world"], dtype=float).reshape(4, 4)
    assert np.linalg.norm(m[:3, :3], axis=0) == pytest.approx([1, 1, 1], abs=1e-6)
    world = np.array(cam.matrix_world)
    assert m[:3, 3] == pytest.approx(world[:3, 3], abs=1e-5)  # the rig's scale moves it; the pose keeps that
    assert m[:3, :3] == pytest.approx(world[:3, :3] / 2.5, abs=1e-6)


def test_what_the_format_cannot_hold_is_refused_naming_it():
    scene = bpy.context.scene
    cam = _camera(scene)
    rig = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(rig)
    rig.scale = (1.0, 3.0, 1.0)
    rig.rotation_euler = (0.0, 0.0, math.radians(30))  # rotate, then scale one axis: the camera is sheared
    cam.parent = rig
    cam.rotation_euler = (0.3, 0.4, 0.0)
    with pytest.raises(ExportError, match="frame 1: .*sheared"):
        camera_path_export.camera_path(scene, cam, [1, 2])
    cam.parent = None
    cam.data.shift_x = 0.1
    with pytest.raises(ExportError, match="lens shift"):
        camera_path_export.camera_path(scene, cam, [1])
    cam.data.shift_x = 0.0
    cam.data.type = "ORTHO"
    with pytest.raises(ExportError):
        camera_path_export.camera_path(scene, cam, [1])
