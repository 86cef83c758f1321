"""Fixtures for tests that drive real Blender through the ``bpy`` module (5.0.1 from PyPI)."""
from __future__ import annotations

import os
import sys

import pytest

bpy = pytest.importorskip("bpy") if os.environ.get("NERF_ALLOW_NO_BPY") else __import__("bpy")

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    sys.path.insert(0, REPO_ROOT)


@pytest.fixture(autouse=True)
def empty_blend():
    """Every test starts from an empty factory file, so no test sees another's objects."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield
    bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.fixture
def repo_root() -> str:
    return REPO_ROOT


@pytest.fixture
def train_settings(tmp_path):
    """The Train panel's settings (its classes registered), with Dataset and Run folders under
    ``tmp_path`` that do not exist yet."""
    from addon import compare, train  # the Compare panel's operators use the Train panel's settings

    train.register()
    compare.register()
    settings = bpy.context.scene.nerf_train
    settings.dataset_dir = str(tmp_path / "dataset")
    settings.run_dir = str(tmp_path / "run")
    yield settings
    compare.unregister()
    train.unregister()


@pytest.fixture
def active_camera():
    """Factory: ``active_camera(name, frames=(start, end))`` adds a 2-unit box at the origin and a new
    camera, links it and makes it the scene's camera over that frame range; returns the camera. The
    layouts that read the scene's camera (``animation``) start from this."""
    def make(name: str, frames=(1, 40)):
        bpy.ops.mesh.primitive_cube_add(size=2.0)
        scene = bpy.context.scene
        cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
        scene.collection.objects.link(cam)
        scene.camera = cam
        scene.frame_start, scene.frame_end = frames
        return cam
    return make


@pytest.fixture(scope="session")
def cube_and_ball_blend():
    """Factory: ``cube_and_ball_blend(path, light="SUN")`` saves a small lit scene (a 1.5-unit cube at the
    origin and a 0.35-radius ball beside it) to ``path`` and leaves an empty file open; returns the path.
    The capture tests that run scripts in subprocesses start from it."""
    def make(path, light: str = "SUN"):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_cube_add(size=1.5)
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(1.3, 0.4, 0.5))
        lamp = bpy.data.objects.new(light.title(), bpy.data.lights.new(light.title(), light))
        if light == "AREA":
            lamp.data.energy = 500.0
            lamp.location = (2.0, -2.0, 3.0)
        bpy.context.scene.collection.objects.link(lamp)
        bpy.ops.wm.save_as_mainfile(filepath=str(path))
        bpy.ops.wm.read_factory_settings(use_empty=True)
        return path

    return make
