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
