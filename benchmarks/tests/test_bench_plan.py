"""The benchmark's plan and flags, and which stored runs ``--reuse`` takes (``bench.plan``, ``benchmark``)."""
from __future__ import annotations

import json

import pytest

import benchmark
from bench import plan as bench_plan


def test_size_series_use_presets_and_auto():
    help_text = "usage: ... [--size {auto}] [--set KEY=VALUE] [--max-seconds S]"
    series = bench_plan.size_series("vmgrid", help_text)
    assert [s.label for s in series] == ["vmgrid small", "vmgrid medium", "vmgrid auto"]
    small = series[0].extra
    assert small[0] == "--set" and all(small[i] == "--set" for i in range(0, len(small), 2))
    assert series[-1].extra == ["--size", "auto"]
    # A method without presets still gets its auto series; a trainer without --size gets none.
    assert [s.label for s in bench_plan.size_series("grid", help_text)] == ["grid auto"]
    assert bench_plan.size_series("vmgrid", "usage: [--max-seconds S]") == []


def test_plan_quick_runs_size_series_on_first_scene_only():
    args = benchmark.parse_args(["--quick", "--out", "x", "--methods", "nerf,grid"])
    help_text = "--max-seconds --size {auto}"
    orig = bench_plan.default_fast_method
    bench_plan.default_fast_method = lambda: "grid"
    try:
        plan = bench_plan.make_plan(args, help_text)
    finally:
        bench_plan.default_fast_method = orig
    runs = [(scene, s.label) for scene, s in plan.runs()]
    assert ("diffuse", "grid auto") in runs and ("thin", "grid auto") not in runs
    assert ("thin", "nerf") in runs
    assert plan.checkpoints == pytest.approx([20.0, 40.0])


def test_plan_size_scenes_and_jobs_flags():
    args = benchmark.parse_args(["--out", "x", "--methods", "nerf", "--scenes", "a,b,c", "--size-scenes", "b",
                                 "--jobs", "2"])
    orig = bench_plan.default_fast_method
    bench_plan.default_fast_method = lambda: "grid"
    try:
        plan = bench_plan.make_plan(args, "--max-seconds --size {auto}")
    finally:
        bench_plan.default_fast_method = orig
    runs = [(scene, s.label) for scene, s in plan.runs()]
    assert ("b", "grid auto") in runs and ("a", "grid auto") not in runs and ("c", "nerf") in runs
    assert args.jobs == 2
    with pytest.raises(SystemExit):
        benchmark.parse_args(["--out", "x", "--jobs", "0"])


def test_reuse_takes_only_matching_finished_runs_of_named_series(tmp_path, capsys):
    args = benchmark.parse_args(["--out", str(tmp_path), "--methods", "nerf,grid", "--scenes", "a,b", "--no-sizes"])
    plan = bench_plan.make_plan(args, "--max-seconds")
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


def test_log_checkpoints_double_from_10s_and_keep_the_minute_marks():
    # 5 min: doubling gives 10, 20, 40, 80, 160 (320 > 300); marks 60, 120 and the budget 300 are kept;
    # no doubling point lies within 15 % of a kept one (80 vs 60: 33 %, 160 vs 120: 33 %).
    assert bench_plan.log_checkpoints(300.0) == [10, 20, 40, 60, 80, 120, 160, 300]
    # 10 min: doubling adds 320, which is 6.7 % from the 5-minute mark and goes; 600 is the budget.
    assert bench_plan.log_checkpoints(600.0) == [10, 20, 40, 60, 80, 120, 160, 300, 600]
    # 90 s: 80 is 11 % from the budget and goes; 60 is inside the budget and stays.
    assert bench_plan.log_checkpoints(90.0) == [10, 20, 40, 60, 90]
    # 30 min: 640 is 6.7 % from 600 and goes, the 15-minute mark is kept, 1280 is 29 % from 1800 and stays.
    assert bench_plan.log_checkpoints(1800.0) == [10, 20, 40, 60, 80, 120, 160, 300, 600, 900, 1280, 1800]
    # Budgets at or under the first point: the budget alone.
    assert bench_plan.log_checkpoints(10.0) == [10] and bench_plan.log_checkpoints(6.0) == [6]
    with pytest.raises(ValueError):
        bench_plan.log_checkpoints(0.0)


def test_checkpoints_flag_log_minutes_and_default(capsys):
    def plan_for(*flags):
        return bench_plan.make_plan(benchmark.parse_args(["--out", "x", "--methods", "nerf", "--no-sizes", *flags]),
                                    "--max-seconds")

    assert plan_for().checkpoints == [10, 20, 40, 60, 80, 120, 160, 300]  # default: log-spaced, 5 min
    assert plan_for("--checkpoints", "log", "--minutes", "2").checkpoints == [10, 20, 40, 60, 80, 120]
    assert plan_for("--checkpoints", "5,1,2").checkpoints == [60, 120, 300]  # minutes, sorted
    assert plan_for("--quick", "--checkpoints", "log").checkpoints == [10, 20, 40]
    for bad in ("1,x", "0,5", "-1", "nan"):
        with pytest.raises(SystemExit):
            benchmark.parse_args(["--out", "x", "--checkpoints", bad])
        err = capsys.readouterr().err
        assert "--checkpoints" in err and "Traceback" not in err


def test_unknown_scenes_and_methods_are_named_before_anything_runs():
    args = benchmark.parse_args(["--out", "x", "--methods", "nerf,gaussians", "--scenes", "multi,nosuch,multi",
                                 "--no-sizes"])
    plan = bench_plan.make_plan(args, "--max-seconds")
    scenes, methods = ["multi", "thin"], ["nerf", "vmgrid"]
    assert bench_plan.unknown_names(plan, scenes, methods) == (
        "--scenes: unknown scene 'nosuch'; choose from multi, thin")
    plan.scenes = plan.size_scenes = ["multi"]
    assert bench_plan.unknown_names(plan, scenes, methods) == (
        "--methods: unknown method 'gaussians'; choose from nerf, vmgrid")
    plan.size_scenes = ["glossy"]  # --size-scenes is checked too
    assert "unknown scene 'glossy'" in bench_plan.unknown_names(plan, scenes, methods)
    plan.size_scenes, plan.series = ["multi"], [bench_plan.Series("nerf", "nerf")]
    assert bench_plan.unknown_names(plan, scenes, methods) == ""
    assert bench_plan.unknown_names(plan, [], []) == ""  # lists that could not be read check nothing


def test_benchmark_refuses_an_unknown_scene_before_making_its_folder(tmp_path, capsys):
    """The real lists: the demo scenes of addon/capture/demo/capture_flags.py and `python -m nerf_core methods`."""
    from bench import datasets, runner

    assert {"diffuse", "interior", "ground"} <= set(datasets.demo_scene_names())
    assert {"nerf", "nerf-nope", "vmgrid"} <= set(runner.method_names())
    out = tmp_path / "bench"
    assert benchmark.main(["--out", str(out), "--scenes", "multi,nosuch", "--methods", "vmgrid", "--no-sizes"]) == 2
    err = capsys.readouterr().err
    assert "benchmark: --scenes: unknown scene 'nosuch'; choose from cube, diffuse" in err
    assert not out.exists()


@pytest.mark.parametrize("script, args, message", [
    ("stability", ["--quick", "--scene", "nosuch"], "stability: --scene: unknown scene 'nosuch'; choose from cube,"),
    ("stability", ["--quick", "--methods", "vmgrid,nosuch"],
     "stability: --methods: unknown method 'nosuch'; choose from nerf,"),
    ("bench_render", ["--dataset", "DS", "--methods", "nosuch"],
     "--methods: unknown method 'nosuch'; choose from nerf,"),
    ("bench_ddp", ["--method", "nosuch"], "bench_ddp: --method: unknown method 'nosuch'; choose from nerf,"),
])
def test_the_other_studies_refuse_unknown_names_before_making_their_folder(tmp_path, capsys, script, args, message):
    import importlib

    module = importlib.import_module(script)
    out = tmp_path / "study"
    args = [str(tmp_path) if a == "DS" else a for a in args]
    try:
        code = module.main(["--out", str(out), *args])
    except SystemExit as exc:  # bench_render stops through _bootstrap.fail, as on its other flags
        code = exc.code
    assert code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
