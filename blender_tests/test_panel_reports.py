"""Train / Compare / render-engine operators that used to finish silently, print absurd numbers or
name the wrong thing: each now says what happened, naming the setting, field or file."""
from __future__ import annotations

import json
import os
import re

import bpy
import pytest

import addon
from addon.compare import compare_views as compare
from addon.common import jobs, ui_common
from addon.bridge import render_client, child_process
from addon.render_engine import engine as render_engine
from addon.compare import compare_ui
from addon.train import train_props, train_ui
from addon.bridge.child_process import SetupError
from test_register import _draw, _labels


@pytest.fixture
def s(train_settings):  # conftest.train_settings, under the short name these tests use
    return train_settings


def reports(capfd) -> str:
    """What the operators called since the last call reported (bpy prints an operator's non-error
    reports, e.g. 'Warning: ...', 'Info: ...', to the terminal)."""
    out, err = capfd.readouterr()
    return out + err


def fake_run(root, config=None, checkpoints=("latest.pt",)):
    """RUN with a 100x100 dataset, ``config`` (dict, or raw text) and the named checkpoint files."""
    data = root / "dataset"
    data.mkdir(exist_ok=True)
    (data / "transforms_test.json").write_text(json.dumps({"w": 100, "h": 100, "fl_x": 80.0, "frames": []}))
    run = root / "run"
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    for name in checkpoints:
        (run / "checkpoints" / name).write_bytes(b"x")
    config = {"dataset": str(data)} if config is None else config
    (run / "config.json").write_text(config if isinstance(config, str) else json.dumps(config))
    return str(run)


# -- 1. Time Budget and the panel's clock ----------------------------------------------------------------
def test_time_budget_is_bounded_and_the_panel_never_prints_an_absurd_eta(s, tmp_path):
    s.max_seconds = 1e30  # the field clamps what it is given
    assert s.max_seconds == 7 * 24 * 3600 == train_props.MAX_TIME_BUDGET_S
    for seconds, text in ((75.2, "1:15"), (3725, "1:02:05"), (604800, "7d 0:00:00"), (90061, "1d 1:01:01"),
                          (1e30, "> 99 days"), (float("inf"), "?"), (-3, "?"), (None, "?")):
        assert ui_common.format_seconds(seconds) == text, seconds
    s.step, s.eta, s.elapsed = 5, 1e30, 12.0  # a trainer's ETA for a huge step budget
    labels = _labels(_draw(train_ui.NERF_PT_train))
    assert "ETA > 99 days" in labels and "Elapsed 0:12" in labels
    assert not re.search(r"\d{4,}:", labels)
    # A .blend saved by an older add-on keeps an out-of-range value: Train refuses it, naming the field.
    os.makedirs(s.dataset_dir)
    s["max_seconds"] = 1e30
    with pytest.raises(SetupError, match=r"Time Budget is 1e\+30 s, more than 7 days \(604800 s\): lower it"):
        train_ui.start_training(bpy.context)
    assert not os.path.exists(s.run_dir) and not jobs.is_running(train_ui.TRAIN)


# -- 2. buttons that had nothing to do -------------------------------------------------------------------
def test_refresh_runs_and_use_run_say_why_nothing_was_done(s, tmp_path, capfd):
    reports(capfd)
    s.run_dir = ""
    assert bpy.ops.nerf.refresh_runs() == {"FINISHED"}
    assert "Warning: No runs listed: the Run folder is not set" in reports(capfd)
    s.run_dir = str(tmp_path / "nowhere" / "run")
    bpy.ops.nerf.refresh_runs()
    assert f"Warning: No runs listed: folder {tmp_path / 'nowhere'} (the Run folder's parent) does not exist" \
        in reports(capfd)
    s.run_dir = str(tmp_path / "run")
    bpy.ops.nerf.refresh_runs()
    assert f"Info: No training runs found in {tmp_path}" in reports(capfd)
    assert bpy.ops.nerf.use_run() == {"CANCELLED"}
    assert "Warning: No run is highlighted in the Runs list: press Refresh Runs, then click a run" in reports(capfd)
    run = fake_run(tmp_path)
    bpy.ops.nerf.refresh_runs()
    assert f"Info: Listed 1 run(s) in {tmp_path}" in reports(capfd)
    s.run_dir, s.dataset_dir, s.runs_index = "", "", 0
    assert bpy.ops.nerf.use_run() == {"FINISHED"}
    assert s.run_dir == run and f"Info: Using run {run} (dataset {tmp_path / 'dataset'})" in reports(capfd)


# -- 3. Compare with a damaged config.json -------------------------------------------------------------
@pytest.mark.parametrize("config, why", [
    ('{"dataset": ', r"config\.json: invalid JSON \("),
    ("[1, 2]", r"config\.json: expected the JSON object that training writes, got a list"),
    (b"\xff\xfe{}", r"config\.json: invalid JSON \("),
    ({"method": "nerf"}, r"config\.json records no dataset \(key 'dataset'\)"),
])
def test_compare_names_an_unreadable_config(s, tmp_path, config, why):
    run = fake_run(tmp_path, config=config if not isinstance(config, bytes) else "")
    if isinstance(config, bytes):
        (tmp_path / "run" / "config.json").write_bytes(config)
    for source in ("TEST", "SELECTED"):
        with pytest.raises(SetupError, match=re.escape(os.path.join(run, "")) + why) as exc:
            compare.prepare_render(bpy.context, run, source)
        assert "has no dataset" not in str(exc.value)
    assert not os.path.exists(os.path.join(run, compare.VIEWS_DIR))  # refused before anything was written


def test_compare_says_when_config_json_cannot_be_read(s, tmp_path):
    run = fake_run(tmp_path)
    os.remove(os.path.join(run, "config.json"))
    os.mkdir(os.path.join(run, "config.json"))  # an OSError other than "not found"
    with pytest.raises(SetupError, match=re.escape(os.path.join(run, "config.json")) + r": cannot read \("):
        compare.prepare_render(bpy.context, run, "TEST")


# -- 4. Compare of a run whose latest.pt is gone ----------------------------------------------------------
def test_compare_renders_the_newest_step_checkpoint_when_latest_is_gone(s, tmp_path):
    run = fake_run(tmp_path, checkpoints=("step_0000100.pt", "step_0000200.pt"))
    newest = os.path.join(run, "checkpoints", "step_0000200.pt")
    plan = compare.prepare_render(bpy.context, run, "TEST")
    assert plan.checkpoint == newest
    cmd = child_process.render_command("py", run, plan.cameras, plan.out, checkpoint=plan.checkpoint)
    assert cmd[-2:] == ["--checkpoint", newest]  # nerf_core render loads latest.pt unless told otherwise
    open(os.path.join(run, "checkpoints", "latest.pt"), "wb").close()
    assert compare.prepare_render(bpy.context, run, "TEST").checkpoint == ""  # the CLI's default
    for name in os.listdir(os.path.join(run, "checkpoints")):
        os.remove(os.path.join(run, "checkpoints", name))
    with pytest.raises(SetupError, match=r"has no trained checkpoint yet: train first"):
        compare.prepare_render(bpy.context, run, "TEST")


def test_compare_of_a_real_run_without_latest_pt_renders_from_its_step_checkpoint(s, tmp_path):
    """Through the real nerf_core CLI: train, lose latest.pt, render the test views from step_*.pt."""
    from test_full_loop import drive, tiny_capture

    s.dataset_dir = tiny_capture(str(tmp_path))
    s.max_seconds, s.max_steps = 0.0, 4
    drive(train_ui.start_training(bpy.context))
    ckpts = os.path.join(s.run_dir, "checkpoints")
    os.remove(os.path.join(ckpts, "latest.pt"))
    [step] = [n for n in os.listdir(ckpts) if n.startswith("step_")]
    s.view_source, s.layout = "TEST", "CAMERA"
    job = drive(compare_ui.start_render(bpy.context))
    assert [v.name for v in job.views] == ["r_0", "r_1"]
    assert job.warnings[0] == f"Rendered from {os.path.join(ckpts, step)}: the run has no checkpoints/latest.pt"
    assert os.listdir(ckpts) == [step]  # nothing rewritten


# -- 5. RUN/views is the user's file --------------------------------------------------------------------
def test_selected_cameras_refuse_a_file_named_views_and_keep_it(s, tmp_path):
    run = fake_run(tmp_path)
    views = os.path.join(run, "views")
    with open(views, "w") as fh:
        fh.write("my notes")
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 100
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    bpy.context.view_layer.objects.active = cam
    cam.select_set(True)
    for source in ("SELECTED", "TEST"):
        with pytest.raises(SetupError, match=re.escape(views) + r" is a file, not a folder: .*move it away"):
            compare.prepare_render(bpy.context, run, source)
    assert open(views).read() == "my notes" and sorted(os.listdir(run)) == ["checkpoints", "config.json", "views"]


# -- 6. the render engine's size limit -------------------------------------------------------------------
@pytest.fixture
def nerf_engine_scene():
    addon.register()
    scene = bpy.context.scene
    scene.render.engine = render_engine.ENGINE_ID
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    yield scene
    if hasattr(bpy.types.Scene, "nerf_render"):
        addon.unregister()


def test_f12_above_the_size_limit_names_the_resolution_setting(nerf_engine_scene, tmp_path):
    from nerf_core.render import server as render_server

    scene = nerf_engine_scene
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 16385, 8, 100
    r.filepath = str(tmp_path / "x.png")
    with pytest.raises(RuntimeError, match=r"Output Properties > Resolution asks for 16385x8 px \(16385x8 at 100%\); "
                                           r"the NeRF renders at most 16384 px a side") as exc:
        bpy.ops.render.render(write_still=True)
    assert "'w'" not in str(exc.value) and not render_client._CLIENTS
    r.resolution_x, r.resolution_percentage = 20000, 50  # 10000 px: within the limit, on to the next check
    with pytest.raises(RuntimeError, match="No NeRF run is chosen"):
        bpy.ops.render.render(write_still=True)
    assert not os.path.exists(tmp_path / "x.png")
    assert render_client.MAX_SIDE == render_server.MAX_SIDE  # the add-on's copy of the server's limit
