"""Fast tests of the benchmark and stability scripts' analysis, on synthetic numbers (no training)."""
from __future__ import annotations

import csv
import json
import math
import os
import sys

import numpy as np
import pytest
from PIL import Image

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(REPO_ROOT, "scripts"))

import bench_common as bc  # noqa: E402
import benchmark  # noqa: E402
import stability  # noqa: E402


# ---------------------------------------------------------------- events


def test_parse_events_skips_warnings_and_partial_lines():
    lines = ['{"event": "start", "n_params": 10}', "UserWarning: something", '{"event": "step", "step": 1',
             "", '{"event": "done", "step": 5, "elapsed": 2.0}', "[1, 2]"]
    events = bc.parse_events(lines)
    assert [e["event"] for e in events] == ["start", "done"]


def test_summarize_training_counts_rollbacks_nan_and_median_rate():
    events = [
        {"event": "start", "n_params": 1234},
        {"event": "step", "step": 1, "loss": 0.1, "psnr": 10.0, "elapsed": 1.0, "samples_per_s": 10.0},
        {"event": "step", "step": 2, "loss": None, "psnr": None, "elapsed": 2.0, "samples_per_s": 1000.0},
        {"event": "rollback", "step": 2, "reason": "non-finite loss (NaN)", "lr": 0.001},
        {"event": "step", "step": 3, "loss": 0.05, "psnr": 13.0, "elapsed": 3.0, "samples_per_s": 100.0},
        {"event": "done", "step": 3, "elapsed": 3.5},
    ]
    s = bc.summarize_training(events)
    assert s["n_params"] == 1234
    assert s["steps"] == 3
    assert s["elapsed"] == 3.5
    assert s["rollbacks"] == 1
    assert s["nan"] is True
    assert s["samples_per_s"] == 100.0  # median of 10, 1000, 100
    assert s["train_psnr"] == 13.0
    assert s["error"] is None
    assert bc.summarize_training([{"event": "error", "message": "boom"}])["error"] == "boom"


def test_run_cli_streams_events_and_reports_errors(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(
        "import json, sys\n"
        "print('noise')\n"
        "print(json.dumps({'event': 'step', 'step': 1}))\n"
        "print(json.dumps({'event': 'error', 'message': 'dataset X: frame 3 missing'}))\n"
        "sys.stderr.write('traceback text\\n')\n"
        "sys.exit(3)\n"
    )
    seen = []
    res = bc.run_cli([sys.executable, str(script)], on_event=seen.append, log_path=str(tmp_path / "log.txt"))
    assert res.returncode == 3 and not res.ok
    assert [e["event"] for e in seen] == ["step", "error"]
    assert res.error_message() == "dataset X: frame 3 missing"
    assert res.stdout_tail == ["noise"]
    assert "traceback text" in (tmp_path / "log.txt").read_text()


def test_run_cli_passes_env_extra_to_the_child(tmp_path):
    script = tmp_path / "child.py"
    script.write_text("import json, os\nprint(json.dumps({'event': 'env', 'omp': os.environ.get('OMP_NUM_THREADS')}))\n")
    res = bc.run_cli([sys.executable, str(script)], env_extra={"OMP_NUM_THREADS": "1"})
    assert res.ok and res.events == [{"event": "env", "omp": "1"}]


def test_thread_env_splits_the_cores_between_jobs(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert bc.thread_env(1) == {}
    assert bc.thread_env(2)["OMP_NUM_THREADS"] == "4"
    assert bc.thread_env(16)["OMP_NUM_THREADS"] == "1"  # never zero threads


def test_run_parallel_overlaps_tasks_and_keeps_their_order():
    import threading

    barrier = threading.Barrier(2, timeout=10)  # both tasks must be running at once to pass it

    def task(x):
        barrier.wait()
        return x * 10

    assert bc.run_parallel([lambda: task(1), lambda: task(2)], jobs=2) == [10, 20]
    assert bc.run_parallel([lambda: 1, lambda: 2, lambda: 3], jobs=1) == [1, 2, 3]


def test_shared_progress_adds_live_runs_to_finished_work():
    from nerf_core.progressbar import ProgressBar

    bar = ProgressBar(total=100, enabled=False)
    p = bc.SharedProgress(bar)
    p.advance("a", 10)
    p.advance("b", 5)
    assert bar.done == 15
    p.finish("a", 40)  # a run books its planned cost, whatever its last step event said
    assert bar.done == 45
    p.advance("b", 20)
    assert bar.done == 60


# ---------------------------------------------------------------- Pareto and auto size


def test_pareto_front_hand_computed():
    # (params, psnr): b dominates c (smaller and better); d is largest but best; e has no psnr.
    pts = [(100, 20.0), (200, 25.0), (300, 24.0), (800, 26.0), (50, None), (100, 19.0)]
    assert bc.pareto_front(pts) == [0, 1, 3]


def test_pareto_front_ties_keep_one_of_equal_points():
    pts = [(100, 20.0), (100, 20.0), (200, 19.0)]
    # Equal points do not dominate each other; the smaller-worse point is dominated.
    assert bc.pareto_front(pts) == [0, 1]


def test_auto_size_verdict_within_half_params():
    fixed = [(1000, 20.0), (4000, 24.0), (16000, 24.3)]
    v = bc.auto_size_verdict((6000, 24.0), fixed)
    assert v["gap_db"] == pytest.approx(0.3)
    assert v["param_ratio"] == pytest.approx(6000 / 16000)
    assert v["within_half"] is True and v["ok"] is True
    # Same quality at twice the parameters of the best: near in dB but not economical.
    v = bc.auto_size_verdict((32000, 24.2), fixed)
    assert v["within_half"] is False
    assert v["on_front"] is False and v["ok"] is False
    # 1.3 dB below the best, dominated by the 4000-parameter model: fails.
    v = bc.auto_size_verdict((5000, 23.0), fixed)
    assert v["ok"] is False and v["within_half"] is False
    assert bc.auto_size_verdict((5000, float("nan")), fixed)["ok"] is None


def test_size_analysis_reads_final_rows():
    finals = [
        {"scene": "s", "series": "grid small", "method": "grid", "n_params": 1000, "psnr": 22.0},
        {"scene": "s", "series": "grid large", "method": "grid", "n_params": 8000, "psnr": 25.0},
        {"scene": "s", "series": "grid auto", "method": "grid", "n_params": 3000, "psnr": 24.8},
        {"scene": "s", "series": "nerf", "method": "nerf", "n_params": 500000, "psnr": 23.0},
    ]
    (row,) = benchmark.size_analysis(finals, "grid")
    assert row["within_0.5dB_at_half"] is True
    assert row["on_front"] is True
    assert row["front"] == "grid small, grid auto, grid large"


def test_size_series_use_presets_and_auto():
    help_text = "usage: ... [--size {auto}] [--set KEY=VALUE] [--max-seconds S]"
    series = benchmark.size_series("vmgrid", help_text)
    assert [s.label for s in series] == ["vmgrid small", "vmgrid medium", "vmgrid auto"]
    small = series[0].extra
    assert small[0] == "--set" and all(small[i] == "--set" for i in range(0, len(small), 2))
    assert series[-1].extra == ["--size", "auto"]
    # A method without presets still gets its auto series; a trainer without --size gets none.
    assert [s.label for s in benchmark.size_series("grid", help_text)] == ["grid auto"]
    assert benchmark.size_series("vmgrid", "usage: [--max-seconds S]") == []


def test_plan_quick_runs_size_series_on_first_scene_only():
    args = benchmark.parse_args(["--quick", "--out", "x", "--methods", "nerf,grid"])
    help_text = "--max-seconds --size {auto}"
    orig = benchmark.default_fast_method
    benchmark.default_fast_method = lambda: "grid"
    try:
        plan = benchmark.make_plan(args, help_text)
    finally:
        benchmark.default_fast_method = orig
    runs = [(scene, s.label) for scene, s in plan.runs()]
    assert ("diffuse", "grid auto") in runs and ("thin", "grid auto") not in runs
    assert ("thin", "nerf") in runs
    assert plan.checkpoints == pytest.approx([20.0, 40.0])


def test_plan_size_scenes_and_jobs_flags():
    args = benchmark.parse_args(["--out", "x", "--methods", "nerf", "--scenes", "a,b,c", "--size-scenes", "b",
                                 "--jobs", "2"])
    orig = benchmark.default_fast_method
    benchmark.default_fast_method = lambda: "grid"
    try:
        plan = benchmark.make_plan(args, "--max-seconds --size {auto}")
    finally:
        benchmark.default_fast_method = orig
    runs = [(scene, s.label) for scene, s in plan.runs()]
    assert ("b", "grid auto") in runs and ("a", "grid auto") not in runs and ("c", "nerf") in runs
    assert args.jobs == 2
    with pytest.raises(SystemExit):
        benchmark.parse_args(["--out", "x", "--jobs", "0"])


# ---------------------------------------------------------------- tables


def test_rows_tables_and_markdown(tmp_path):
    results = [{
        "scene": "diffuse", "series": "nerf", "method": "nerf", "n_params": 100, "model_bytes": 400,
        "checkpoint_bytes": 900, "samples_per_s": 5e4, "rollbacks": 0, "error": None,
        "points": [{"seconds": 10.2, "budget": 10.0, "step": 50, "psnr": 15.0, "ssim": 0.5},
                   {"seconds": 20.1, "budget": 20.0, "step": 99, "psnr": 18.5, "ssim": 0.6}],
    }]
    rows, finals = benchmark.rows_from_results(results)
    assert len(rows) == 2 and finals[0]["psnr"] == 18.5 and finals[0]["steps"] == 99
    table = benchmark.psnr_at_table(rows, [10.0, 20.0])
    assert table[0]["psnr@10s"] == 15.0 and table[0]["psnr@20s"] == 18.5
    path = tmp_path / "t.csv"
    bc.write_csv(str(path), rows)
    with open(path) as fh:
        read = list(csv.DictReader(fh))
    assert read[1]["psnr"] == "18.5" and read[0]["train_seconds"] == "10.2"
    md = bc.markdown_table(table, ["scene", "series", "psnr@10s", "psnr@20s"])
    assert md.splitlines()[2] == "| diffuse | nerf | 15.00 | 18.50 |"
    bc.write_json(str(tmp_path / "r.json"), {"x": float("nan")})
    assert json.loads((tmp_path / "r.json").read_text()) == {"x": None}


def test_mean_std_ignores_missing():
    m, sd, n = bc.mean_std([1.0, 3.0, None, float("nan")])
    assert (m, n) == (2.0, 2) and sd == pytest.approx(math.sqrt(2))
    assert bc.mean_std([None]) == (None, None, 0)


def test_charts_are_written(tmp_path):
    curves = {("diffuse", "nerf"): [(10, 15.0), (20, 18.0)], ("diffuse", "grid"): [(10, 20.0), (20, 22.0)],
              ("thin", "nerf"): [(10, 12.0), (20, float("nan"))]}
    p1 = bc.chart_psnr_vs_time(curves, str(tmp_path / "t.png"), "t")
    pts = [{"scene": "diffuse", "series": "grid auto", "params": 3000, "psnr": 21.0},
           {"scene": "diffuse", "series": "grid small", "params": 1000, "psnr": 19.0},
           {"scene": "diffuse", "series": "nerf", "params": 500000, "psnr": 18.0}]
    p2 = bc.chart_psnr_vs_size(pts, str(tmp_path / "s.png"), "s")
    p3 = bc.chart_bars({"views": {"nerf": [("4", 12.0, 1.0), ("8", 15.0, 0.5)]}}, str(tmp_path / "b.png"),
                       "b", "PSNR", threshold=14.0)
    for p in (p1, p2, p3):
        with Image.open(p) as im:
            assert im.size[0] > 300 and im.size[1] > 200


# ---------------------------------------------------------------- derived datasets


def _tiny_dataset(root, n_train=6):
    root.mkdir()
    for split, n in (("train", n_train), ("test", 2)):
        (root / split).mkdir()
        frames = []
        for k in range(n):
            a = 2 * math.pi * k / n
            c2w = np.eye(4)
            c2w[:3, 3] = [4 * math.cos(a), 4 * math.sin(a), 0.0]
            alpha = np.zeros((4, 4), np.uint8)
            alpha[1:3, 1:3] = 255
            Image.fromarray(np.dstack([alpha] * 4)).save(root / split / f"r_{k}.png")
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": c2w.tolist()})
        meta = {"camera_angle_x": 0.7, "w": 4, "h": 4, "fl_x": 5.0, "fl_y": 5.0, "cx": 2.0, "cy": 2.0,
                "aabb": [[-1, -1, -1], [1, 1, 1]], "frames": frames}
        (root / f"transforms_{split}.json").write_text(json.dumps(meta))
    (root / "transforms.json").write_text("{}")
    (root / "nerfstudio").mkdir()
    (root / "nerfstudio" / "transforms.json").write_text("{}")
    return root


def test_subset_views_keeps_spread_frames_and_leaves_source(tmp_path):
    src = _tiny_dataset(tmp_path / "src", n_train=8)
    before = (src / "transforms_train.json").read_text()
    dst = bc.subset_views(str(src), str(tmp_path / "sub"), 4)
    meta = json.loads(open(os.path.join(dst, "transforms_train.json")).read())
    assert [f["file_path"] for f in meta["frames"]] == ["./train/r_0", "./train/r_2", "./train/r_4", "./train/r_6"]
    assert bc.count_frames(dst, "test") == 2
    assert not os.path.exists(os.path.join(dst, "transforms.json"))  # would list the unedited cameras
    assert not os.path.exists(os.path.join(dst, "nerfstudio"))  # the same file where captures now write it
    assert os.path.isfile(os.path.join(dst, "train", "r_7.png"))
    assert (src / "transforms_train.json").read_text() == before
    with pytest.raises(bc.BenchError, match="transforms_train.json has 8"):
        bc.subset_views(str(src), str(tmp_path / "sub2"), 9)


def test_perturb_poses_rotates_and_moves_by_the_asked_amount(tmp_path):
    src = _tiny_dataset(tmp_path / "src")
    dst = bc.perturb_poses(str(src), str(tmp_path / "noisy"), rot_deg=3.0, trans_frac=0.05, seed=1)
    a = json.loads((src / "transforms_train.json").read_text())["frames"]
    b = json.loads(open(os.path.join(dst, "transforms_train.json")).read())["frames"]
    for fa, fb in zip(a, b):
        pa, pb = np.asarray(fa["transform_matrix"]), np.asarray(fb["transform_matrix"])
        # Rotation angle between the two orientations, and the centre's shift (radius 4 -> 0.2).
        r = pa[:3, :3].T @ pb[:3, :3]
        angle = math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(3.0, abs=1e-6)
        assert np.linalg.norm(pb[:3, 3] - pa[:3, 3]) == pytest.approx(0.2, abs=1e-9)
        assert np.allclose(pb[:3, :3] @ pb[:3, :3].T, np.eye(3), atol=1e-9)  # still a rotation
    test_a = json.loads((src / "transforms_test.json").read_text())
    test_b = json.loads(open(os.path.join(dst, "transforms_test.json")).read())
    assert test_a == test_b


def test_floater_stats_on_hand_made_renders(tmp_path):
    src = _tiny_dataset(tmp_path / "src")
    renders = tmp_path / "renders"
    renders.mkdir()
    # View 0: background (12 px) fully transparent; view 1: 3 background pixels opaque, one faint.
    a0 = np.zeros((4, 4), np.uint8)
    a0[1:3, 1:3] = 255
    a1 = a0.copy()
    a1[0, 0] = a1[0, 1] = a1[3, 3] = 255
    a1[3, 0] = 100  # 0.39: counts in the mean alpha, not as an opaque pixel
    for k, a in enumerate((a0, a1)):
        Image.fromarray(np.dstack([a] * 4)).save(renders / f"r_{k}.png")
    s = bc.floater_stats(str(renders), str(src))
    assert s["n_views"] == 2
    assert s["floater_pixels"] == pytest.approx((0 + 3 / 12) / 2)
    assert s["floater_alpha"] == pytest.approx((0 + (3 + 100 / 255) / 12) / 2)


def test_ensure_dataset_reuses_matching_capture_only(tmp_path, monkeypatch):
    calls = []

    def fake_run(cmd, **kw):
        calls.append(os.path.basename(cmd[1]))
        if cmd[1].endswith("make_demo_scene.py"):
            open(cmd[cmd.index("--out") + 1], "w").close()
        else:
            out = cmd[cmd.index("--out") + 1]
            os.makedirs(out, exist_ok=True)
            for split in ("train", "test"):
                open(os.path.join(out, f"transforms_{split}.json"), "w").write("{}")
        return bc.CliResult(args=cmd, returncode=0)

    monkeypatch.setattr(bc, "run_cli", fake_run)
    ds1, reused1 = bc.ensure_dataset("diffuse", str(tmp_path), {"resolution": 64, "count": 10})
    ds2, reused2 = bc.ensure_dataset("diffuse", str(tmp_path), {"resolution": 64, "count": 10})
    ds3, reused3 = bc.ensure_dataset("diffuse", str(tmp_path), {"resolution": 32, "count": 10})
    assert (reused1, reused2, reused3) == (False, True, False)
    assert ds1 == ds2 != ds3
    assert calls == ["make_demo_scene.py", "capture.py", "make_demo_scene.py", "capture.py"]
    assert bc.default_capture_args("s.blend", "o", {"val_count": 1, "depth": True, "x": None}) == [
        "--blend", "s.blend", "--out", "o", "--val-count", "1", "--depth"]


# ---------------------------------------------------------------- stability breakdown


def test_breakdown_reasons():
    thr = 18.0
    assert stability.breakdown_reason({"psnr": 25.0, "rollbacks": 0, "nan": False, "error": None,
                                       "floater_pixels": 0.0}, thr) == ""
    assert stability.breakdown_reason({"psnr": 12.0}, thr) == "PSNR < 18"
    assert stability.breakdown_reason({"psnr": 20.0}, thr, base_psnr=24.0) == "PSNR -4.0 dB vs base"
    assert stability.breakdown_reason({"psnr": 22.0, "rollbacks": 1}, thr, base_psnr=24.0) == ""
    assert stability.breakdown_reason({"psnr": None, "nan": True}, thr).startswith("NaN")
    assert "diverged" in stability.breakdown_reason({"psnr": 20.0, "rollbacks": 3}, thr)
    assert "floaters" in stability.breakdown_reason({"psnr": 20.0, "floater_pixels": 0.2}, thr)
    assert stability.breakdown_reason({"psnr": None, "error": "dataset: no frames"}, thr).startswith("error")


def test_breakdown_table_finds_first_failing_setting():
    rows = [
        {"method": "nerf", "study": "views", "setting": 4, "psnr_mean": 12.0, "broken": "PSNR < 18"},
        {"method": "nerf", "study": "views", "setting": 8, "psnr_mean": 16.0, "broken": "PSNR < 18"},
        {"method": "nerf", "study": "views", "setting": 16, "psnr_mean": 20.0, "broken": ""},
        {"method": "grid", "study": "views", "setting": 4, "psnr_mean": 19.0, "broken": ""},
        {"method": "grid", "study": "pose_noise", "setting": "0.5deg", "psnr_mean": 19.0, "broken": ""},
        {"method": "grid", "study": "pose_noise", "setting": "2deg", "psnr_mean": 10.0, "broken": "PSNR < 18"},
    ]
    table = {(r["method"], r["study"]): r["breaks_at"] for r in stability.breakdown_table(rows)}
    assert table[("nerf", "views")] == "4: PSNR < 18; 8: PSNR < 18"
    assert table[("grid", "views")] == "no breakdown"
    assert table[("grid", "pose_noise")] == "2deg: PSNR < 18"


def _run(method, study, setting, seed, psnr, **kw):
    return {"method": method, "study": study, "setting": setting, "seed": seed, "psnr": psnr, "ssim": None,
            "rollbacks": 0, "nan": False, "error": None, "floater_pixels": 0.0, **kw}


def test_summarise_judges_each_seed_against_the_methods_base():
    runs = [_run("grid", "base", "default", 0, 30.0), _run("grid", "base", "default", 1, 32.0),
            _run("grid", "views", 4, 0, 28.5), _run("grid", "views", 4, 1, 26.0),  # mean 27.25, one seed 5 dB down
            _run("grid", "views", 8, 0, 30.5)]
    settings, table = stability.summarise(runs, threshold=18.0, drop=3.0)
    by = {(s["study"], s["setting"]): s for s in settings}
    assert by[("base", "default")]["psnr_mean"] == pytest.approx(31.0)
    assert by[("base", "default")]["psnr_std"] == pytest.approx(math.sqrt(2.0))  # sample std of 30, 32
    assert by[("views", 4)]["broken"] == "PSNR -5.0 dB vs base (1/2 seeds)"
    assert by[("views", 8)]["broken"] == ""
    assert {(r["study"], r["breaks_at"]) for r in table} == {("base", "no breakdown"), ("views", "4: PSNR -5.0 dB vs base (1/2 seeds)")}


def test_chart_groups_put_the_base_inside_every_sweep():
    settings = [
        {"method": "m", "study": "base", "setting": "default", "psnr_mean": 30.0, "psnr_std": 0.1},
        {"method": "m", "study": "views", "setting": 4, "psnr_mean": 20.0, "psnr_std": 0.2},
        {"method": "m", "study": "lr", "setting": "x0.3", "psnr_mean": 25.0, "psnr_std": 0.3},
        {"method": "m", "study": "lr", "setting": "x3", "psnr_mean": 28.0, "psnr_std": 0.4},
        {"method": "m", "study": "pose_noise", "setting": "2deg/0.02", "psnr_mean": 22.0, "psnr_std": 0.5},
    ]
    groups = stability.chart_groups(settings, n_train=64)
    assert "base" not in groups
    assert groups["views"]["m"] == [("4", 20.0, 0.2), ("64", 30.0, 0.1)]
    assert [p[0] for p in groups["lr"]["m"]] == ["x0.3", "x1", "x3"]
    assert [p[0] for p in groups["pose_noise"]["m"]] == ["0deg/0", "2deg/0.02"]


def test_report_only_rejudges_stored_runs_without_training(tmp_path, capsys):
    runs = [_run("grid", "base", "default", 0, 30.0), _run("grid", "views", 4, 0, 20.0)]
    (tmp_path / "stability.json").write_text(json.dumps({
        "runs": runs, "capture": {"resolution": 48, "count": 64, "test_count": 4}, "scene": "diffuse",
        "seconds_per_run": 60, "threshold_db": 15.0, "drop_db": 3.0, "machine": {"cpus": 2}}))
    assert stability.main(["--out", str(tmp_path), "--report-only", "--drop", "20"]) == 0
    stored = json.loads((tmp_path / "stability.json").read_text())
    assert stored["drop_db"] == 20.0 and stored["threshold_db"] == 15.0  # given flag wins, the rest is kept
    assert [r["broken"] for r in stored["runs"]] == ["", ""]  # 10 dB down is within a 20 dB drop
    assert (tmp_path / "stability.png").stat().st_size > 0
    assert "| grid | views | no breakdown | 1 |" in (tmp_path / "stability.md").read_text()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert stability.main(["--out", str(empty), "--report-only"]) == 1
    assert "stability.json" in capsys.readouterr().err


# ---------------------------------------------------------------- stage profile accounting


def test_stage_timer_charges_nested_time_to_the_inner_stage(monkeypatch):
    clock = {"t": 0.0}
    monkeypatch.setattr(benchmark.time, "perf_counter", lambda: clock["t"])
    timer = benchmark.StageTimer(sync=lambda: None)

    def field(pts):
        clock["t"] += 2.0  # 2 s inside the field
        return pts

    def sampling(x):
        clock["t"] += 1.0  # 1 s of sampling's own work ...
        field_w(x)  # ... plus a nested field call
        clock["t"] += 0.5
        return x

    field_w = timer.wrap(field, "field")
    sampling_w = timer.wrap(sampling, "sampling")
    assert sampling_w(3) == 3
    field_w(1)
    assert timer.totals == {"field": 4.0, "sampling": 1.5}
    assert timer.stack == []


def test_stability_seed_and_job_flags():
    args = stability.parse_args(["--out", "x", "--seeds", "3", "--other-seeds", "1", "--jobs", "2"])
    assert (args.base_seeds, args.other_seeds, args.jobs) == (3, 1, 2)
    args = stability.parse_args(["--out", "x", "--seeds", "2"])
    assert (args.base_seeds, args.other_seeds) == (2, 2)


def test_reuse_takes_only_matching_finished_runs_of_named_series(tmp_path, capsys):
    args = benchmark.parse_args(["--out", str(tmp_path), "--methods", "nerf,grid", "--scenes", "a,b", "--no-sizes"])
    plan = benchmark.make_plan(args, "--max-seconds")
    settings = {"seed": 0, "eval_views": None, "jobs": 1}
    run = {"method": "nerf", "flags": [], "points": [], "error": None}
    stored = {"capture": plan.capture, "checkpoints_seconds": plan.checkpoints, **settings,
              "runs": [{**run, "scene": "a", "series": "nerf"},
                       {**run, "scene": "b", "series": "nerf", "error": "boom"},  # failed: trained again
                       {**run, "scene": "a", "series": "grid", "method": "grid"}]}  # not named in --reuse
    (tmp_path / "results.json").write_text(json.dumps(stored))
    found = benchmark.reusable_results(str(tmp_path), plan, {"nerf"}, settings)
    assert list(found) == [("a", "nerf")] and found[("a", "nerf")]["reused"] is True
    # Other capture settings or another seed: nothing is reused, and the reason is printed.
    assert benchmark.reusable_results(str(tmp_path), plan, {"nerf"}, {**settings, "seed": 1}) == {}
    assert "seed" in capsys.readouterr().err
    (tmp_path / "results.json").write_text(json.dumps({**stored, "capture": {**plan.capture, "resolution": 1}}))
    assert benchmark.reusable_results(str(tmp_path), plan, {"nerf"}, settings) == {}
