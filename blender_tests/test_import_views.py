"""scripts/import_views.py refuses bad input with a message naming what is wrong, before touching
anything (the full render-and-import path runs in test_full_loop.py)."""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import bpy
import pytest


@pytest.fixture
def setup(tmp_path, repo_root):
    scene = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(scene), copy=True)
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"not really a checkpoint")
    (run / "config.json").write_text(json.dumps({"dataset": str(tmp_path / "dataset"), "method": "nerf"}))
    script = os.path.join(repo_root, "scripts", "import_views.py")

    def call(*args):
        return subprocess.run([sys.executable, script, "--blend", str(scene), "--run", str(run), *args],
                              capture_output=True, text=True, timeout=120)

    return tmp_path, scene, run, call


def test_out_equal_to_scene_is_refused(setup):
    tmp, scene, run, call = setup
    before = scene.read_bytes()
    proc = call("--out", str(scene), "--overwrite")
    assert proc.returncode == 2 and "is the same file as" in proc.stderr and "never replaces an input" in proc.stderr
    assert scene.read_bytes() == before


def test_existing_out_needs_overwrite(setup):
    tmp, scene, run, call = setup
    out = tmp / "compare.blend"
    out.write_bytes(b"precious")
    proc = call("--out", str(out))
    assert proc.returncode == 2 and f"--out {out} already exists" in proc.stderr and "--overwrite" in proc.stderr
    assert out.read_bytes() == b"precious"


@pytest.mark.parametrize("distance", ["-3", "nan", "inf"])
def test_a_distance_behind_the_camera_is_refused(setup, distance):
    tmp, scene, run, call = setup
    proc = call("--out", str(tmp / "d.blend"), "--distance", distance)
    assert proc.returncode == 2 and "--distance" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp / "d.blend").exists()


def test_run_without_checkpoint_and_missing_split(setup):
    tmp, scene, run, call = setup
    proc = call("--out", str(tmp / "a.blend"), "--run", str(tmp / "nope"))
    assert proc.returncode == 2 and "no checkpoints/latest.pt" in proc.stderr
    proc = call("--out", str(tmp / "a.blend"))
    assert proc.returncode == 2 and "has no transforms_test.json" in proc.stderr
    proc = call("--out", str(tmp / "a.blend"), "--cameras", str(tmp / "missing.json"))
    assert proc.returncode == 2 and "missing.json: no such file" in proc.stderr
    assert not (tmp / "a.blend").exists()


def test_interpreter_without_torch_says_what_to_set(setup):
    tmp, scene, run, call = setup
    (tmp / "dataset").mkdir()
    (tmp / "dataset" / "transforms_test.json").write_text(json.dumps({"frames": []}))
    fake = tmp / "python-without-torch"
    fake.write_text("#!/bin/sh\necho \"ModuleNotFoundError: No module named 'torch'\" >&2\nexit 1\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    proc = call("--out", str(tmp / "a.blend"), "--python", str(fake))
    assert proc.returncode == 2
    assert "No module named 'torch'" in proc.stderr and "Python with torch" in proc.stderr
