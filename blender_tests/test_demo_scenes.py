"""Demo scenes: each builds quickly and deterministically, fits in about +-1.5 units, and is lit."""
from __future__ import annotations

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
from PIL import Image

from addon import capture, demo_scenes, layouts, scene_bounds

PY = sys.executable
SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "make_demo_scene.py")


def fingerprint(scene):
    out = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        n = len(ev.data.vertices) if obj.type == "MESH" else 0
        out.append((obj.name, obj.type, n, tuple(round(v, 6) for v in obj.matrix_world.translation)))
    return out


@pytest.mark.parametrize("name", sorted(demo_scenes.SCENES))
def test_scene_builds_within_bounds_lit_and_deterministic(name):
    scene = demo_scenes.build(name)
    lo, hi = scene_bounds.scene_bounds(scene)
    assert max(map(abs, list(lo) + list(hi))) <= 1.6, (name, lo, hi)
    assert any(o.type == "LIGHT" for o in scene.objects) and scene.world is not None
    meshes = [o for o in scene.objects if o.type == "MESH"]
    assert meshes and all(o.material_slots and o.material_slots[0].material for o in meshes)
    first = fingerprint(scene)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert fingerprint(demo_scenes.build(name)) == first


def test_unknown_scene_is_named():
    with pytest.raises(demo_scenes.DemoSceneError, match="unknown demo scene 'lego'.*cube"):
        demo_scenes.build("lego")


def test_workbench_render_of_the_flat_cube_shows_it_lit(tmp_path):
    scene = demo_scenes.build("cube")
    layouts.create_cameras(scene, layouts.LayoutSpec(train=1, val=0, test=0, elevation_min=30, elevation_max=30), 32, 32)
    capture.CaptureJob(scene, capture.CaptureSettings(out_dir=str(tmp_path / "ds"), engine="workbench",
                                                      res_x=32, res_y=32)).run()
    rgba = np.asarray(Image.open(tmp_path / "ds" / "train" / "r_0.png")).astype(float)
    obj = rgba[..., 3] == 255
    assert 0.1 < obj.mean() < 0.9
    red = rgba[obj][:, :3]
    assert (red[:, 0] > red[:, 1] + 40).mean() > 0.9 and red[:, 0].mean() > 60  # red and not black


def test_make_demo_scene_script_writes_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "thin.blend"
    proc = subprocess.run([PY, SCRIPT, "thin", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and out.is_file(), proc.stderr
    size = out.stat().st_size
    proc = subprocess.run([PY, SCRIPT, "cube", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "exists" in proc.stderr and out.stat().st_size == size
    bpy.ops.wm.open_mainfile(filepath=str(out))
    assert "Wire lattice" in bpy.data.objects
