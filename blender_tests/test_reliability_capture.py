"""Reliability of capture (docs/RELIABILITY.md): arguments checked up front against Blender's limits,
no two cameras with one pose, resumed captures that verify what is on disk."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import bpy
import pytest

from addon.capture.files import verify
from addon.capture.layout import positions
from addon.capture.run import job as run_job
from addon.capture.plan import frame_plan, settings as plan_settings
from addon.capture.layout import collection, cameras

PY = sys.executable
SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "capture.py")


# ---------------------------------------------------------------------------------------------- 8. arguments


@pytest.mark.parametrize("args, flag", [
    (["--resolution", "70000"], "--resolution"),
    (["--resolution", "32x0"], "--resolution"),
    (["--resolution", "32", "--resolution-y", "0"], "--resolution-y"),
    (["--count", "0"], "--count"),
    (["--count", "1"], "--count"),  # a train split of one view: train and check would refuse the dataset
    (["--val-count", "-1"], "--val-count"),
    (["--val-count", "0"], "--val-count"),  # an empty split: train and check would refuse the dataset
    (["--test-count", "0"], "--test-count"),
    (["--samples", "0"], "--samples"),
    (["--focal-length", "0"], "--focal-length"),
    (["--radius", "-1"], "--radius"),
    (["--elevation-min", "-91"], "--elevation-min"),
    (["--elevation-min", "50", "--elevation-max", "10"], "--elevation-max"),
    (["--frame-step", "0"], "--frame-step"),
    (["--n-points", "0"], "--n-points"),
])
def test_capture_arguments_are_checked_before_anything_runs(tmp_path, args, flag):
    out = tmp_path / "ds"
    proc = subprocess.run([PY, SCRIPT, "--out", str(out), "--quiet", *args], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert flag in proc.stderr and "error" in proc.stderr
    assert not out.exists()


def test_save_blend_never_replaces_an_existing_file(tmp_path):
    other = tmp_path / "other_project.blend"
    other.write_bytes(b"BLENDER-v500 someone else's work")
    out = tmp_path / "ds"
    proc = subprocess.run([PY, SCRIPT, "--out", str(out), "--quiet", "--save-blend", str(other)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "--save-blend" in proc.stderr and "already exists" in proc.stderr, proc.stderr
    assert other.read_bytes() == b"BLENDER-v500 someone else's work" and not out.exists()
    # a folder that does not exist failed only after the whole capture, with a traceback
    proc = subprocess.run([PY, SCRIPT, "--out", str(out), "--quiet", "--save-blend", str(tmp_path / "no" / "x.blend")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and not out.exists()
    assert "--save-blend: folder" in proc.stderr and "does not exist" in proc.stderr, proc.stderr


def test_capture_settings_refuse_what_blender_would_clamp(tmp_path):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(train=2, val=0, test=0), 24, 16)
    with pytest.raises(frame_plan.CaptureError, match="70000.*65536"):
        run_job.CaptureJob(bpy.context.scene, plan_settings.CaptureSettings(out_dir=str(tmp_path / "ds"),
                                                                            engine="workbench",
                                                                      samples=1, res_x=70000, res_y=16))


# ---------------------------------------------------------------------------------------------- 9. poses


def _box():
    bpy.ops.mesh.primitive_cube_add(size=2.0)


def _matrices(cams):
    return [tuple(round(v, 5) for row in o.matrix_world for v in row) for o in cams]


def test_rings_default_to_the_panels_range_and_give_distinct_poses():
    _box()
    spec = positions.LayoutSpec(layout="rings", train=12, val=2, test=2)
    assert spec.elevation_range() == (10.0, 60.0)
    cams = cameras.create_cameras(bpy.context.scene, spec, 32, 32)
    assert len(set(_matrices(cams))) == len(cams) == 16


def test_a_ring_at_the_pole_is_refused_before_any_camera_changes():
    _box()
    first = cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(train=4, val=0, test=0), 32, 32)
    names = sorted(o.name for o in first)
    with pytest.raises(positions.LayoutError, match="same pose.*elevation"):
        cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(layout="rings", train=12, val=0, test=0,
                                                                     elevation_min=0.0, elevation_max=90.0), 32, 32)
    assert sorted(o.name for o in collection.nerf_collection(bpy.context.scene).objects) == names  # untouched


def test_a_still_camera_sampled_by_animation_is_refused(active_camera):
    cam = active_camera("Still", frames=(1, 30))
    scene = bpy.context.scene
    cam.location = (0.0, -6.0, 1.0)
    with pytest.raises(positions.LayoutError, match="same pose.*frame step"):
        cameras.create_cameras(scene, positions.LayoutSpec(layout="animation", frame_step=10, val=0, test=0), 32, 32)


def test_check_distinct_poses_is_exact_enough():
    a = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
    b = [[1, 0, 0, 0.01], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
    positions.check_distinct_poses([a, b])
    with pytest.raises(positions.LayoutError, match="cameras 0 and 2"):
        positions.check_distinct_poses([a, b, [list(r) for r in a]])


# ---------------------------------------------------------------------------------------------- 10. import_views


def _import_setup(tmp_path, captured_from):
    import hashlib

    scene = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(scene), copy=True)
    run, ds = tmp_path / "run", tmp_path / "dataset"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"not really a checkpoint")
    (run / "config.json").write_text(json.dumps({"dataset": str(ds), "method": "nerf"}))
    (ds / "nerf_capture").mkdir(parents=True)
    captured_from = captured_from or scene
    digest = hashlib.sha256(captured_from.read_bytes()).hexdigest()
    (ds / "nerf_capture" / "manifest.json").write_text(json.dumps({"blend_file": str(captured_from),
                                                                   "blend_sha256": digest}))
    script = os.path.join(os.path.dirname(SCRIPT), "import_views.py")

    def call(*args):
        return subprocess.run([PY, script, "--blend", str(scene), "--run", str(run), "--out",
                               str(tmp_path / "cmp.blend"), *args], capture_output=True, text=True, timeout=120)

    return scene, call


def test_import_views_refuses_a_run_captured_from_another_blend(tmp_path):
    other = tmp_path / "other.blend"
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    bpy.ops.wm.save_as_mainfile(filepath=str(other), copy=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene, call = _import_setup(tmp_path, other)
    proc = call()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert str(other) in proc.stderr and str(scene) in proc.stderr and "--force" in proc.stderr
    proc = call("--force")  # goes on (and fails later on the fake dataset), having only warned
    assert "warning" in proc.stderr and "pass --force" not in proc.stderr


def test_import_views_is_quiet_for_the_captured_blend(tmp_path):
    scene, call = _import_setup(tmp_path, None)
    proc = call()
    assert proc.returncode == 2  # the fake dataset has no transforms_test.json: a later refusal
    assert "would not line up" not in proc.stderr and "transforms_test.json" in proc.stderr


# ---------------------------------------------------------------------------------------------- 11. capture resume


def test_capture_resume_renders_again_what_fails_verification(tmp_path):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    cameras.create_cameras(scene, positions.LayoutSpec(train=3, val=1, test=1), 24, 16)
    out = tmp_path / "ds"

    def job():
        return run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(out), engine="workbench", samples=1,
                                                                 res_x=24, res_y=16, depth=True))

    assert job().run()["rendered"] == 5
    man = json.loads((out / "nerf_capture" / "manifest.json").read_text())
    entry = next(iter(man["frames"].values()))
    assert set(entry["sha256"]) == {"image", "depth_file_path"} and all(len(h) == 64 for h in entry["sha256"].values())
    png = out / "train" / "r_0.png"
    png.write_bytes(png.read_bytes()[: png.stat().st_size // 2])  # truncated
    (out / "depth" / "train" / "r_1.exr").write_bytes(b"")  # empty depth EXR
    again = job().run()
    assert (again["rendered"], again["kept"]) == (2, 3)
    assert verify.decodes_at(str(png), 24, 16)
    assert (out / "depth" / "train" / "r_1.exr").stat().st_size > 0


def test_capture_resume_catches_a_changed_file_that_still_decodes(tmp_path):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    cameras.create_cameras(scene, positions.LayoutSpec(train=2, val=0, test=0), 24, 16)
    out = tmp_path / "ds"
    settings = dict(out_dir=str(out), engine="workbench", samples=1, res_x=24, res_y=16)
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(**settings)).run()
    a, b = out / "train" / "r_0.png", out / "train" / "r_1.png"
    a.write_bytes(b.read_bytes())  # a valid PNG of the right size, but not the one written for r_0
    again = run_job.CaptureJob(scene, plan_settings.CaptureSettings(**settings)).run()
    assert (again["rendered"], again["kept"]) == (1, 1)
