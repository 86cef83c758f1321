"""Geometry of a real trained run: ``export mesh`` and ``export volume`` of a small vmgrid run on the
sphere dataset, and ``scripts/import_geometry.py`` putting them into a .blend in the scene's frame."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from nerf_core.tests.conftest import make_dataset

pytestmark = pytest.mark.slow
RADIUS = 0.6  # the sphere of ``make_dataset``, coloured by its normal: rgb = n / 2 + 1 / 2


@pytest.fixture(scope="module")
def sphere_run(tmp_path_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    base = tmp_path_factory.mktemp("geometry")
    ds = make_dataset(base / "ds", n_train=16, n_test=2, w=48, h=40)
    run = base / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="vmgrid", max_steps=300, batch_rays=512, seed=0,
                      stdout_events=False, show_bar=False, eval_views=0,
                      options={"res_init": 24, "res_final": 32}))
    return run


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=os.getcwd(), OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_the_mesh_of_a_trained_sphere_lies_on_it_with_its_colours(sphere_run, tmp_path):
    from nerf_core.export.ply import read_geometry

    summary = _cli("-m", "nerf_core", "export", "mesh", str(sphere_run), "--out", str(tmp_path / "m.ply"))
    geo = read_geometry(tmp_path / "m.ply")
    voxel = 2.0 / (summary["resolution"] - 1)
    r = np.linalg.norm(geo.points, axis=1)
    assert abs(np.median(r) - RADIUS) < voxel and np.mean(np.abs(r - RADIUS) < 2 * voxel) > 0.9
    n = geo.points / r[:, None]
    assert np.median(np.abs(geo.colors - (n * 0.5 + 0.5) * 255)) < 20  # colour from the field, seen head-on


def test_the_volume_of_a_trained_sphere_is_dense_inside_and_empty_outside(sphere_run, tmp_path):
    from nerf_core.export.volume import read_volume

    summary = _cli("-m", "nerf_core", "export", "volume", str(sphere_run), "--out", str(tmp_path / "v.npz"))
    v = read_volume(tmp_path / "v.npz")
    d, box, step = v["density"], v["box"], v["spacing"]
    idx = np.indices(d.shape).reshape(3, -1).T
    r = np.linalg.norm(box[0] + idx * step, axis=1).reshape(d.shape)
    level = summary["level"]
    assert np.mean(d[r < RADIUS - 0.15] > level) > 0.95 and np.mean(d[r > RADIUS + 0.15] < level) > 0.95
    assert v["color"][r < RADIUS - 0.15].any() and not v["color"][(r > RADIUS + 0.3) & (d < 1e-3)].any()


@pytest.mark.parametrize("kind", ["mesh", "volume"])
def test_import_geometry_script_lands_in_the_scene_frame(sphere_run, tmp_path, kind):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=RADIUS)
    scene = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(scene))
    out = tmp_path / f"with_{kind}.blend"
    summary = _cli(os.path.join("scripts", "import_geometry.py"), "--blend", str(scene), "--run", str(sphere_run),
                   "--kind", kind, "--out", str(out), "--python", sys.executable)
    assert summary["collection"] == ("NeRF Mesh" if kind == "mesh" else "NeRF Volume")
    bpy.ops.wm.open_mainfile(filepath=str(out))
    obj = bpy.data.objects[summary["object"]]
    assert np.allclose(np.array(obj.matrix_world), np.eye(4))
    if kind == "mesh":
        world = np.array([tuple(obj.matrix_world @ v.co) for v in obj.data.vertices])
        assert abs(np.median(np.linalg.norm(world, axis=1)) - RADIUS) < 0.07
    else:
        obj.data.grids.load()
        grid = obj.data.grids["density"]
        m = np.array(grid.matrix_object)
        # node 0 at the corner of the box the run trained in: the declared [-1, 1]^3 grown 1.25 % per side
        # (``scene_box.pad_box_for_faces``)
        box = json.loads((sphere_run / "config.json").read_text())["aabb"]
        assert np.allclose(m[:3, 3], box[0], atol=1e-6) and np.allclose(box[0], [-1.025] * 3, atol=1e-6)
        assert os.path.isfile(bpy.path.abspath(obj.data.filepath))
    assert os.path.isfile(summary["geometry"]) and summary["geometry"].startswith(str(sphere_run))


def test_import_geometry_world_of_a_run_without_a_world_is_one_line(sphere_run, tmp_path):
    """A run on a transparent film learned no world: the script says so in one line, and writes nothing."""
    bpy.ops.mesh.primitive_uv_sphere_add(radius=RADIUS)
    scene = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(scene))
    out = tmp_path / "with_world.blend"
    env = dict(os.environ, PYTHONPATH=os.getcwd(), OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, os.path.join("scripts", "import_geometry.py"), "--blend", str(scene),
                           "--run", str(sphere_run), "--kind", "world", "--out", str(out), "--python", sys.executable],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 2 and "learned no world" in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists() and not list((sphere_run / "geometry").glob("world_*"))
    proc = subprocess.run([sys.executable, os.path.join("scripts", "import_geometry.py"), "--blend", str(scene),
                           "--run", str(sphere_run), "--kind", "world", "--out", str(out), "--resolution", "64"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 2 and "--resolution: the world samples no grid" in proc.stderr
