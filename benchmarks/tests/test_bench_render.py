"""``benchmarks/bench_render.py`` and ``bench.render_speed``: arguments, rates from synthetic events and
renders.json files, the big-frame camera, the table, refusals, and one short real run."""
from __future__ import annotations

import json
import math
import os
import sys

import pytest

from bench import render_speed

SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench_render.py")


def test_methods_and_runs_are_parsed_and_bad_ones_named():
    assert render_speed.parse_methods("vmgrid, nerf,nerf-nope") == ["vmgrid", "nerf", "nerf-nope"]
    for bad, word in (("vmgrid,,nerf", "comma-separated"), ("nerf,nerf", "nerf given twice")):
        with pytest.raises(render_speed.SpeedInputError, match=word):
            render_speed.parse_methods(bad)
    methods = ["vmgrid", "nerf"]
    assert render_speed.parse_runs("vmgrid=/r/a, nerf = r/b", methods) == {"vmgrid": "/r/a", "nerf": "r/b"}
    assert render_speed.parse_runs(None, methods) == {}
    for bad, word in (("vmgrid", "METHOD=RUN_FOLDER"), ("tensorf=/x", "'tensorf' is not in --methods"),
                      ("nerf=/a,nerf=/b", "'nerf' given twice"), ("=/x", "METHOD=RUN_FOLDER")):
        with pytest.raises(render_speed.SpeedInputError, match=word):
            render_speed.parse_runs(bad, methods)


def test_training_rate_is_taken_over_the_second_half_of_training_time():
    events = [{"event": "start"},
              {"event": "step", "step": 10, "elapsed": 1.0}, {"event": "step", "step": 20, "elapsed": 2.0},
              {"event": "preview", "step": 20},
              {"event": "step", "step": 30, "elapsed": 4.0}, {"event": "rollback", "step": 31},
              {"event": "step", "step": 40, "elapsed": 6.0}, {"event": "eval", "step": 45, "elapsed": 8.0,
                                                              "psnr": 20.0},
              {"event": "done", "step": 45, "elapsed": 8.0}]
    rate = render_speed.training_rate(events, 1024)
    # Half of 8 s is 4 s: from step 30 at 4 s to step 45 at 8 s, 15 steps of 1024 rays in 4 s.
    assert rate["rays_per_s"] == pytest.approx(15 * 1024 / 4.0)
    assert (rate["from_step"], rate["to_step"], rate["seconds"], rate["rollbacks"]) == (30, 45, 4.0, 1)
    # A short run whose second half logged no step (regression: CI's 2-second run gave None): the span
    # starts at the last event before the half, from step 10 at 1 s to step 12 at 8 s.
    short = render_speed.training_rate([{"event": "step", "step": 10, "elapsed": 1.0},
                                        {"event": "done", "step": 12, "elapsed": 8.0}], 1024)
    assert short["rays_per_s"] == pytest.approx(2 * 1024 / 7.0) and short["from_step"] == 10
    # Nothing to measure: one event, or no step events at all.
    assert render_speed.training_rate([{"event": "done", "step": 5, "elapsed": 3.0}], 1024)["rays_per_s"] is None
    assert render_speed.training_rate([{"event": "error", "message": "x"}], 1024)["rays_per_s"] is None


def test_render_rate_counts_pixels_over_the_models_time_without_the_first_view():
    renders = {"frames": [{"w": 10, "h": 10, "render_seconds": 5.0}, {"w": 20, "h": 10, "render_seconds": 1.0},
                          {"w": 10, "h": 10, "render_seconds": 0.5}]}
    r = render_speed.render_rate(renders)
    assert (r["rays"], r["seconds"], r["frames"]) == (300, 1.5, 2)
    assert r["rays_per_s"] == pytest.approx(200.0)
    assert render_speed.render_rate(renders, skip_first=False)["rays_per_s"] == pytest.approx(400 / 6.5)
    one = {"frames": [{"w": 8, "h": 4, "render_seconds": 0.5}]}  # a single view is all there is
    assert render_speed.render_rate(one)["rays_per_s"] == pytest.approx(64.0)
    with pytest.raises(render_speed.SpeedInputError, match="render_seconds"):
        render_speed.render_rate({"frames": [{"w": 8, "h": 4}]})
    # frames that count their rays (the pixel filter adds rays at edges) are counted by them
    filtered = {"frames": [{"w": 8, "h": 4, "rays": 50, "render_seconds": 0.5}]}
    assert render_speed.render_rate(filtered)["rays_per_s"] == pytest.approx(100.0)


def test_big_frame_camera_keeps_the_test_views_pose_and_field_of_view(tmp_path, tiny_dataset):
    ds = tiny_dataset(tmp_path / "ds")
    cams = render_speed.camera_at_size(str(ds), 800, 800, copies=2)
    assert [c["name"] for c in cams] == ["frame800x800_0", "frame800x800_1"]
    test = json.loads((ds / "transforms_test.json").read_text())
    c = cams[0]
    assert c["transform_matrix"] == test["frames"][0]["transform_matrix"]
    assert (c["w"], c["h"], c["cx"], c["cy"]) == (800, 800, 400.0, 400.0)
    assert c["fl_x"] == pytest.approx(5.0 * 200) and c["fl_y"] == pytest.approx(5.0 * 200)  # 4 px -> 800 px
    # Same horizontal field of view as the 4-pixel view: 2 atan(w / 2f).
    assert 2 * math.atan(400 / c["fl_x"]) == pytest.approx(2 * math.atan(2 / 5.0))
    wide = render_speed.camera_at_size(str(ds), 800, 400)[0]  # the longer side keeps the field of view
    assert wide["fl_x"] == pytest.approx(1000.0) and (wide["cx"], wide["cy"]) == (400.0, 200.0)
    with pytest.raises(render_speed.SpeedInputError, match="not found"):
        render_speed.camera_at_size(str(tmp_path / "nowhere"), 800, 800)


def test_table_and_page():
    rows = render_speed.speed_rows([
        {"method": "vmgrid", "train_rays_per_s": 1000.4, "render_rays_per_s": 3500.2, "frame_seconds": 1.25,
         "steps": 100},
        {"method": "nerf", "train_rays_per_s": 200.0, "render_rays_per_s": None, "error": "render failed: boom"},
    ])
    assert rows[0]["ratio"] == pytest.approx(3500.2 / 1000.4) and rows[1]["ratio"] is None
    page = render_speed.markdown(rows, {"dataset": "/d", "frame_size": "800x800", "threads": 1, "contended": True,
                                        "machine": {"cpu": "CPU X", "cpus": 2, "torch": "2.13"},
                                        "command": "python benchmarks/bench_render.py --dataset /d",
                                        "commands": ["a b"]})
    assert "| vmgrid | 100 | 1000 | 3500 | 3.50 | 1.25 |" in page
    assert "| nerf | - | 200 | - | - | - |" in page
    assert "s per 800x800 frame" in page and "CPU X, 2 cores" in page and "threads: 1" in page
    assert "**Contended machine**" in page and "- nerf: render failed: boom" in page
    assert "    python benchmarks/bench_render.py --dataset /d" in page and "    a b" in page


def _run(*args):
    import subprocess

    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})


def test_bad_arguments_and_existing_outputs_are_one_line_errors(tmp_path, tiny_dataset):
    ds = tiny_dataset(tmp_path / "ds")
    res = _run("--dataset", str(ds), "--out", str(tmp_path / "o"), "--runs", f"vmgrid={tmp_path}",
               "--methods", "vmgrid")
    assert res.returncode == 2 and "no config.json there" in res.stderr and "Traceback" not in res.stderr
    res = _run("--dataset", str(ds), "--out", str(tmp_path / "o"), "--frame-size", "800")
    assert res.returncode == 2 and "--frame-size '800'" in res.stderr
    (tmp_path / "o" / "renders" / "vmgrid").mkdir(parents=True)
    (tmp_path / "o" / "renders" / "vmgrid" / "renders.json").write_text("{}")
    res = _run("--dataset", str(ds), "--out", str(tmp_path / "o"), "--methods", "vmgrid")
    assert res.returncode == 2 and "renders/vmgrid already exists" in res.stderr
    assert (tmp_path / "o" / "renders" / "vmgrid" / "renders.json").read_text() == "{}"  # left alone
    assert not (tmp_path / "o" / "runs").exists()  # refused before training anything
    # Into the dataset, its JSON at the root would make every loader refuse the dataset.
    before = sorted(os.listdir(ds))
    res = _run("--dataset", str(ds), "--out", str(ds), "--methods", "vmgrid")
    assert res.returncode == 2 and "is the dataset folder itself" in res.stderr and sorted(os.listdir(ds)) == before
    # A run of another method would be reported under the wrong name.
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"method": "vmgrid"}))
    res = _run("--dataset", str(ds), "--out", str(tmp_path / "o2"), "--methods", "nerf", "--runs", f"nerf={run}")
    assert res.returncode == 2 and "trained with method 'vmgrid', not 'nerf'" in res.stderr


def test_a_short_real_run_writes_the_table(tmp_path):
    from nerf_core.tests.conftest import make_dataset  # the analytic sphere: cameras that see the box

    ds = make_dataset(tmp_path / "ds", n_train=8, n_test=3, w=16, h=16, depth=False)
    out = tmp_path / "bench"
    res = _run("--dataset", str(ds), "--out", str(out), "--methods", "vmgrid", "--seconds", "2",
               "--frame-size", "16x12", "--threads", "1")
    assert res.returncode == 0, res.stderr[-2000:]
    data = json.loads((out / "render_speed.json").read_text())
    row = data["rows"][0]
    assert row["method"] == "vmgrid" and row["error"] is None
    assert row["train_rays_per_s"] > 0 and row["render_rays_per_s"] > 0 and row["frame_seconds"] > 0
    assert row["ratio"] == pytest.approx(row["render_rays_per_s"] / row["train_rays_per_s"])
    # The numbers are the ones the run's own files hold.
    result = data["results"][0]
    renders = json.loads((out / "renders" / "vmgrid" / "renders.json").read_text())
    assert row["render_rays_per_s"] == pytest.approx(render_speed.render_rate(renders)["rays_per_s"])
    frame = json.loads((out / "frame" / "vmgrid" / "renders.json").read_text())["frames"][0]
    assert (frame["w"], frame["h"]) == (16, 12) and row["frame_seconds"] == frame["render_seconds"]
    cfg = json.loads((out / "runs" / "vmgrid" / "config.json").read_text())
    assert result["rays_per_step"] == cfg["rays_per_step"]
    assert data["threads"] == 1 and data["machine"]["cpus"] == os.cpu_count()
    assert "--max-seconds 2" in data["commands"][0] and "s per 16x12 frame" in (out / "render_speed.md").read_text()
