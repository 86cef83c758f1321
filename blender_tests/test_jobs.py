"""One modal follower (addon/common/jobs.py) advances capture, training and rendering jobs together; Esc
stops a capture only; loading a file stops every child; the panels share one header."""
from __future__ import annotations

import json
import os
import sys
import time
from types import SimpleNamespace

import bpy
import pytest

import addon
from addon.capture.ui import panel as ui_panel
from addon.capture.run import job as run_job
from addon.common import jobs, ui_common
from addon.compare import compare_ui
from addon.train import train_ui, train_job
from addon.bridge import child_process


@pytest.fixture
def registered():
    addon.register()
    yield
    addon.unregister()


def _follower():
    """The follower's modal method on a stand-in instance (headless: no event loop delivers timers)."""
    op = SimpleNamespace(_timer=None, reports=[])
    op.report = lambda kind, msg: op.reports.append((kind, msg))
    ctx = SimpleNamespace(scene=bpy.context.scene, screen=None,
                          window_manager=SimpleNamespace(event_timer_remove=lambda timer: None))
    return op, lambda event_type: jobs.NERF_OT_follow_jobs.modal(op, ctx, SimpleNamespace(type=event_type))


def _prepared_capture(tmp_path, frames=2):
    bpy.ops.mesh.primitive_cube_add()
    s = bpy.context.scene.nerf_capture
    s.train_count, s.val_count, s.test_count = frames, 1, 1
    s.resolution_x, s.resolution_y, s.engine, s.output_dir = 16, 16, "workbench", str(tmp_path / "ds")
    bpy.ops.nerf.generate_cameras()
    job = run_job.CaptureJob(bpy.context.scene, s.capture_settings(), progress=lambda d, t, i: None)
    job.prepare()
    return job


def _fake_trainer(tmp_path, body: str) -> list:
    script = tmp_path / "trainer.py"
    script.write_text("import json, sys, time\n"
                      "def emit(**ev):\n"
                      "    print(json.dumps({'time': time.time(), **ev}), flush=True)\n" + body)
    return [sys.executable, str(script)]


def _train_job(cmd):
    job = train_job.TrainJob(bpy.context.scene.name, sys.executable, "", "", cmd, check=False)
    job.on_update, job.on_end = train_ui.sync_train_settings, None
    return jobs.add(train_ui.TRAIN, job)


def test_one_follower_advances_a_capture_and_a_training_together(registered, tmp_path):
    task = ui_panel.follow_capture(bpy.context.scene, _prepared_capture(tmp_path))
    # A trainer that reports frac 0.6 at step 10 of 100: the panel must show the trainer's 0.6, not 10/100.
    train = _train_job(_fake_trainer(tmp_path, (
        "emit(event='start', run='r', method='fake', max_steps=100, max_seconds=None)\n"
        "emit(event='step', step=10, loss=0.5, psnr=12.0, lr=0.01, elapsed=1.0, eta=2.0, frac=0.6)\n"
        "time.sleep(1.5)\n"
        "emit(event='done', step=10, elapsed=2.5, metrics={})\n")))
    op, tick = _follower()
    s_train, s_cap = bpy.context.scene.nerf_train, bpy.context.scene.nerf_capture
    assert tick("MOUSEMOVE") == {"PASS_THROUGH"}
    seen_fraction, results, deadline = None, [], time.monotonic() + 60
    while True:
        results.append(tick("TIMER"))
        # Between reading the trainer's `done` line and seeing it exit, the job still runs with
        # fraction 1.0 (done); the step-10 fraction is the one before that.
        if s_train.step == 10 and train.state == "running" and not train.process.progress.done:
            seen_fraction = s_train.fraction
        if results[-1] not in ({"RUNNING_MODAL"}, {"PASS_THROUGH"}):
            break
        assert time.monotonic() < deadline, train.process.log_tail()
        time.sleep(0.05)
    # 4 frames, one per tick while the capture runs; it keeps its timer event, a child alone does not.
    assert results[:3] == [{"RUNNING_MODAL"}] * 3 and task.state == "done"
    assert results[-1] == {"FINISHED"} and results[-2] == {"PASS_THROUGH"}
    assert seen_fraction == pytest.approx(0.6)
    assert train.state == "done" and not s_train.running and s_train.status.startswith("Training finished")
    assert s_train.fraction == 1.0  # done
    assert s_cap.status.startswith("done: 4 frames") and not s_cap.is_running
    with open(tmp_path / "ds" / "nerf_capture" / "manifest.json") as fh:
        assert json.load(fh)["status"] == "complete"
    messages = [msg for kind, msg in op.reports if kind == {"INFO"}]
    assert any(m.startswith("done: 4 frames") for m in messages)
    assert any(m.startswith("Training finished") for m in messages)
    assert bpy.context.scene.nerf_train.dataset_dir == os.path.join(str(tmp_path), "ds")  # handed on to Train


def test_esc_stops_a_capture_but_not_a_training(registered, tmp_path):
    task = ui_panel.follow_capture(bpy.context.scene, _prepared_capture(tmp_path))
    train = _train_job(_fake_trainer(tmp_path, "emit(event='start', run='r')\nwhile True: time.sleep(0.1)\n"))
    pid = train.process.pid
    op, tick = _follower()
    assert tick("TIMER") == {"RUNNING_MODAL"}
    assert tick("ESC") == {"PASS_THROUGH"}  # the capture stopped; the training goes on
    assert task.state == "cancelled" and "resume" in bpy.context.scene.nerf_capture.status
    assert op.reports[-1][0] == {"WARNING"}
    assert train.state == "running" and child_process.pid_alive(pid)
    assert tick("ESC") == {"PASS_THROUGH"}  # nothing left that Esc stops
    assert train.state == "running"
    assert bpy.ops.nerf.train_cancel() == {"FINISHED"}
    deadline = time.monotonic() + 30
    while (result := tick("TIMER")) == {"PASS_THROUGH"}:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert result == {"CANCELLED"} and train.state == "cancelled"
    assert op.reports[-1] == ({"INFO"}, "Training cancelled")
    assert not child_process.pid_alive(pid)


def test_loading_a_file_stops_running_children(registered, tmp_path):
    job = _train_job(_fake_trainer(tmp_path, "while True: time.sleep(0.1)\n"))
    pid = job.process.pid
    assert child_process.pid_alive(pid)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert job.state == "cancelled" and not child_process.pid_alive(pid)
    assert child_process.group_pids(pid) == []


def test_headless_there_is_no_follower_to_start(registered):
    assert jobs.follow(bpy.context) is False
    assert bpy.ops.nerf.follow_jobs() == {"CANCELLED"}


def test_a_second_job_under_a_running_key_is_refused(registered, tmp_path):
    _train_job(_fake_trainer(tmp_path, "while True: time.sleep(0.1)\n"))
    other = train_job.TrainJob(bpy.context.scene.name, sys.executable, "", "",
                          _fake_trainer(tmp_path, "pass\n"), check=False)
    with pytest.raises(child_process.SetupError, match="already running"):
        jobs.add(train_ui.TRAIN, other)
    other.process.wait(timeout=30)


def test_every_panel_takes_its_place_from_one_mixin(registered):
    for panel in (ui_panel.NERF_PT_capture, train_ui.NERF_PT_train, compare_ui.NERF_PT_compare):
        assert issubclass(panel, ui_common.NerfPanel)
        assert not {"bl_space_type", "bl_region_type", "bl_category"} & set(vars(panel))
        registered_panel = getattr(bpy.types, panel.bl_idname)
        assert (registered_panel.bl_space_type, registered_panel.bl_region_type,
                registered_panel.bl_category) == ("VIEW_3D", "UI", "NeRF")
