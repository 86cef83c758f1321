"""Every bad input to Train / Compare gets a clear message, and nothing the user made is lost."""
from __future__ import annotations

import errno
import json
import os
import stat
import subprocess
import sys
import time

import bpy
import numpy as np
import pytest

from addon import file_writes
from addon.compare import compare_views as compare
from addon.common import jobs, prefs
from addon.train import train_ui, train_job
from addon.bridge import child_process, runs
from addon.bridge.child_process import SetupError


@pytest.fixture
def s(train_settings):  # conftest.train_settings, under the short name these tests use
    return train_settings


@pytest.fixture
def no_torch_python(tmp_path):
    fake = tmp_path / "python-without-torch"
    fake.write_text("#!/bin/sh\necho \"ModuleNotFoundError: No module named 'torch'\" >&2\nexit 1\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    return str(fake)


def finish(job, timeout=120.0):
    deadline = time.monotonic() + timeout
    while job.update() == "running":
        assert time.monotonic() < deadline, job.process.log_tail()
        time.sleep(0.05)
    if isinstance(job, train_job.TrainJob):
        train_ui.sync_train_settings(job)
    return job


def test_no_dataset(s, tmp_path):
    s.dataset_dir = ""
    # Called from a script, an operator's ERROR report surfaces as a RuntimeError with the message.
    with pytest.raises(RuntimeError, match="No dataset folder is set"):
        bpy.ops.nerf.train()
    assert "No dataset folder is set" in s.error
    s.dataset_dir = str(tmp_path / "nowhere")
    with pytest.raises(SetupError, match=r"nowhere does not exist: capture a dataset first"):
        train_ui.start_training(bpy.context)
    # an empty field takes the Capture panel's Output: a failure names where that path came from, and
    # the field stays as the user left it
    from addon import capture as capture_feature

    capture_feature.register()
    try:
        s.dataset_dir = ""
        bpy.context.scene.nerf_capture.output_dir = str(tmp_path / "captured")
        with pytest.raises(SetupError, match=r"captured \(the Capture panel's Output, as the Dataset field is empty\) "
                                             r"does not exist"):
            train_ui.start_training(bpy.context)
        assert s.dataset_dir == ""
    finally:
        capture_feature.unregister()
    # a transforms file is a dataset too (nerf_core train reads it); another file is not
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "transforms_train.json").write_text("{}")
    (tmp_path / "notes.txt").write_text("mine")
    s.dataset_dir = str(tmp_path / "notes.txt")
    with pytest.raises(SetupError, match=r"notes.txt is a file: choose the dataset's folder"):
        train_ui.start_training(bpy.context)
    s.dataset_dir = str(tmp_path / "ds" / "transforms_train.json")
    with pytest.raises(SetupError, match=r"No run folder is set|run"):  # past the dataset check
        s.run_dir = ""
        train_ui.start_training(bpy.context)


def test_paths_relative_to_an_unsaved_blend_or_home_are_not_the_working_folder(s, tmp_path, monkeypatch):
    # In an unsaved file "//my_run/" trained into <Blender's working folder>/my_run, and "~/x" into
    # a folder named "~" there.
    from addon.common import ui_common

    monkeypatch.chdir(tmp_path)
    s.run_dir = "//my_run/"
    with pytest.raises(SetupError, match="relative to the .blend, which is not saved yet"):
        train_ui.start_training(bpy.context, resume=False)
    assert not (tmp_path / "my_run").exists()
    with pytest.raises(RuntimeError, match="not saved yet"):  # New Name reports it too
        bpy.ops.nerf.run_new_name()
    assert ui_common.abs_path("~/runs/a") == os.path.join(os.path.expanduser("~"), "runs", "a")


def test_broken_dataset_shows_the_checkers_message(s, tmp_path):
    os.makedirs(s.dataset_dir)
    with open(os.path.join(s.dataset_dir, "transforms_train.json"), "w") as fh:
        fh.write('{"frames": [')  # truncated JSON
    job = finish(train_ui.start_training(bpy.context))
    assert job.state == "failed" and job.stage == "check"
    assert s.error.startswith(f"Dataset {s.dataset_dir} is not usable")
    assert "transforms_train.json" in s.error
    assert not os.path.exists(s.run_dir) and not s.running


def test_interpreter_without_torch(s, tmp_path, no_torch_python, monkeypatch):
    os.makedirs(s.dataset_dir)
    with pytest.raises(SetupError) as exc:
        child_process.resolve_interpreter(no_torch_python)
    assert "Python with torch" in str(exc.value) and "No module named 'torch'" in str(exc.value)
    monkeypatch.setattr(prefs, "python_preference", lambda context=None: no_torch_python)
    with pytest.raises(RuntimeError, match="cannot run NeRF training"):
        bpy.ops.nerf.train()
    assert "cannot run NeRF training" in s.error
    # No preference set and Blender's own Python lacks torch: say where to set one.
    monkeypatch.setattr(child_process.sys, "executable", no_torch_python)
    with pytest.raises(SetupError,
                       match=r"Blender's Python .* cannot import torch .*Preferences > Add-ons > NeRF Bridge"):
        child_process.resolve_interpreter("")
    assert not child_process.probe_interpreter(str(tmp_path / "missing")).ok


def test_existing_run_folder_is_never_overwritten(s, tmp_path):
    os.makedirs(s.dataset_dir)
    os.makedirs(os.path.join(s.run_dir, "checkpoints"))
    for name, data in (("config.json", "{}"), ("checkpoints/latest.pt", "weights")):
        with open(os.path.join(s.run_dir, name), "w") as fh:
            fh.write(data)
    with pytest.raises(SetupError,
                       match=r"holds a training run: press Resume to continue it, or press New Name.*run_2"):
        train_ui.start_training(bpy.context)
    # latest.pt gone, a step_*.pt intact: the trainer resumes from it, so the panel must let Resume
    # through (Resume said "press Train instead", and Train said "press Resume").
    os.rename(os.path.join(s.run_dir, "checkpoints", "latest.pt"),
              os.path.join(s.run_dir, "checkpoints", "step_0000121.pt"))
    assert runs.run_folder_state(s.run_dir) == "resumable"
    with pytest.raises(SetupError, match=r"holds a training run: press Resume"):
        train_ui.start_training(bpy.context)
    os.remove(os.path.join(s.run_dir, "checkpoints", "step_0000121.pt"))
    # a run stopped before its first checkpoint: both buttons point to New Name, which exists
    with pytest.raises(SetupError,
                       match=r"is not empty and holds no run to resume: press New Name to train into .*run_2"):
        train_ui.start_training(bpy.context)
    with pytest.raises(SetupError, match=r"no checkpoint to resume .*step_\*\.pt.*press New Name"):
        train_ui.start_training(bpy.context, resume=True)
    assert open(os.path.join(s.run_dir, "config.json")).read() == "{}"
    assert bpy.ops.nerf.run_new_name() == {"FINISHED"} and s.run_dir == str(tmp_path / "run_2")
    with pytest.raises(SetupError, match=r"holds no run to resume: press Train"):
        train_ui.start_training(bpy.context, resume=True)
    with open(tmp_path / "notes.txt", "w") as fh:
        fh.write("mine")
    s.run_dir = str(tmp_path / "notes.txt")  # "already is not empty", and New Name offered notes.txt_2
    with pytest.raises(SetupError, match=r"notes.txt is a file, not a folder"):
        train_ui.start_training(bpy.context)
    assert open(tmp_path / "notes.txt").read() == "mine"


def test_trainer_that_dies_is_reported_with_its_log_tail(s, tmp_path):
    script = tmp_path / "dies.py"
    script.write_text("import sys\nprint('{\"event\": \"start\", \"time\": 0}', flush=True)\n"
                      "for i in range(50): print(f'log line {i}', file=sys.stderr)\n"
                      "raise MemoryError('out of memory in the trainer')\n")
    job = train_job.TrainJob(bpy.context.scene.name, sys.executable, s.dataset_dir, s.run_dir,
                            [sys.executable, str(script)], check=False)
    finish(job)
    assert job.state == "failed"
    assert s.error.startswith("Training stopped: ") and "exited with code 1" in s.error
    assert "MemoryError: out of memory in the trainer" in s.error and "log line 49" in s.error
    assert "log line 5\n" not in s.error  # the tail, not the whole log
    assert not s.running


def test_disk_full_is_named(s, tmp_path, monkeypatch):
    target = str(tmp_path / "views" / "cameras.json")

    def no_space(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(child_process.json, "dump", no_space)
    with pytest.raises(child_process.DiskFullError, match=r"Disk full while writing .*cameras.json"):
        child_process.write_json_atomic(target, {"frames": []})
    assert os.listdir(tmp_path / "views") == []  # no truncated or temporary file left behind
    monkeypatch.undo()

    png = str(tmp_path / "heat.png")
    with open(png, "wb") as fh:
        fh.write(b"earlier heat-map")
    real_open = open
    monkeypatch.setattr(file_writes, "open", lambda p, *a, **k: no_space() if ".tmp" in p else real_open(p, *a, **k),
                        raising=False)
    with pytest.raises(OSError, match=r"Disk full while writing .*heat.png"):
        file_writes.write_png(png, np.zeros((4, 4, 3)))
    assert open(png, "rb").read() == b"earlier heat-map"


def _fake_run(tmp_path, w=100, h=100):
    data = tmp_path / "dataset"
    data.mkdir(exist_ok=True)
    (data / "transforms_test.json").write_text(json.dumps({"w": w, "h": h, "fl_x": 80.0, "frames": []}))
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"x")
    (run / "config.json").write_text(json.dumps({"dataset": str(data)}))
    return str(run)


def test_camera_with_another_aspect_is_refused(s, tmp_path):
    run = _fake_run(tmp_path)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
    cam = bpy.data.objects.new("Wide Cam", bpy.data.cameras.new("Wide Cam"))
    scene.collection.objects.link(cam)
    with pytest.raises(SetupError, match=r"No camera is selected"):
        compare.write_cameras_file(bpy.context, run, "SELECTED")
    bpy.context.view_layer.objects.active = cam
    cam.select_set(True)
    with pytest.raises(SetupError, match=r"'Wide Cam' renders at 1920x1080 .*trained on 100x100"):
        compare.write_cameras_file(bpy.context, run, "SELECTED")
    scene.render.resolution_x = scene.render.resolution_y = 400  # same aspect, other size: fine
    path, n, label = compare.write_cameras_file(bpy.context, run, "SELECTED")
    assert n == 1 and label == "selected" and json.load(open(path))["frames"][0]["w"] == 100


def test_render_without_a_trained_run(s, tmp_path):
    with pytest.raises(RuntimeError, match="no trained checkpoint"):
        bpy.ops.nerf.render_views()
    assert "has no trained checkpoint yet: train first" in s.error


def test_notes_of_the_render_reach_the_user_beside_the_import(tmp_path):
    # nerf_core render notes a run whose dataset was re-captured since training (its scores compare the
    # model with other images); the Compare panel said only "Imported 3 view(s)".
    out = tmp_path / "views"
    out.mkdir()
    (out / "renders.json").write_text(json.dumps({"frames": [],
                                                  "notes": ["DS changed since the run trained on it", 5]}))
    assert compare.render_notes(str(out)) == ["DS changed since the run trained on it"]
    (out / "renders.json").write_text("[1]")
    assert compare.render_notes(str(out)) == [] and compare.render_notes(str(tmp_path / "none")) == []

    class Op:
        def __init__(self):
            self.reports = []

        def report(self, kind, text):
            self.reports.append((sorted(kind)[0], text))

    job = jobs.Job(bpy.context.scene.name)
    job.state, job.message = "done", "Imported 3 view(s) from V"
    job.warnings = ["DS changed since the run trained on it"]
    op = Op()
    jobs._report(op, job)
    assert op.reports == [("INFO", "Imported 3 view(s) from V"), ("WARNING", "DS changed since the run trained on it")]


def test_quitting_blender_leaves_no_orphan_trainer(tmp_path, repo_root):
    """The trainer runs in its own session; the add-on stops it when Blender's Python exits."""
    script = tmp_path / "session.py"
    script.write_text(f"""
import sys, time
sys.path.insert(0, {repo_root!r})
import bpy
from addon.common import jobs
from addon import train
from addon.train import train_ui, train_job
train.register()
cmd = [sys.executable, "-c", "import time\\nwhile True: time.sleep(0.1)"]
job = train_job.TrainJob(bpy.context.scene.name, sys.executable, "", "", cmd, check=False)
jobs.add(train_ui.TRAIN, job)
print(job.process.pid, flush=True)
time.sleep(0.5)
""")  # ...and exits without cancelling, as a user quitting Blender would
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    pid = int(proc.stdout.strip().splitlines()[-1])
    deadline = time.monotonic() + 10
    while child_process.pid_alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not child_process.pid_alive(pid), "the trainer outlived Blender"
