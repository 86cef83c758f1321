"""benchmarks/bench_cpu_speed.py: its reading of the runs' events and its summary, against hand-made runs
(a real pair needs two 200 px captures and minutes of training: a benchmark, not a test)."""
from __future__ import annotations

import json

import pytest

import bench_cpu_speed as bcs


def _run(tmp_path, name, steps, psnr, step_s):
    """A run folder whose progress.jsonl has ``steps`` step events, one every ``step_s`` s over a
    100 s budget, and one final eval."""
    run = tmp_path / name
    run.mkdir()
    events = [{"event": "start", "model": {"options": {"res_final": 160}}, "notes": []}]
    events += [{"event": "step", "step": k, "elapsed": k * step_s, "frac": k * step_s / 100.0}
               for k in range(1, steps + 1)]
    events += ["not json, as a library warning might be", {"event": "eval", "psnr": psnr}]
    (run / "progress.jsonl").write_text("\n".join(e if isinstance(e, str) else json.dumps(e) for e in events) + "\n")
    return str(run)


def test_step_rate_counts_only_after_growth_and_psnr_is_the_last_eval(tmp_path):
    stats = bcs.run_stats(_run(tmp_path, "a", steps=100, psnr=30.5, step_s=1.0), after=0.4)
    assert stats["steps"] == 100 and stats["psnr"] == 30.5 and stats["resolution"] == 160
    assert stats["steps_per_s_after_growth"] == pytest.approx(1.0)  # steps 40..100 over 40..100 s


def test_summary_gives_ratios_and_gains(tmp_path):
    base = bcs.run_stats(_run(tmp_path, "b", steps=50, psnr=30.0, step_s=2.0), 0.4)
    new = bcs.run_stats(_run(tmp_path, "n", steps=100, psnr=31.0, step_s=1.0), 0.4)
    results = {"command": "python benchmarks/bench_cpu_speed.py --baseline X --out Y", "baseline_commit": "abc",
               "commit": "def", "machine": {"cpu": "test cpu", "cpus": 2, "torch": "2.x", "load_avg": [1, 1, 1]},
               "seconds": 100, "eval_views": 5, "after": 0.4,
               "scenes": {"diffuse": {"baseline": base, "new": new}}}
    text = bcs.summary(results)
    assert "| diffuse | 50 / 100 | 0.50 / 1.00 | 2.00x | 30.00 | 31.00 | +1.00 |" in text
    assert "geometric mean 2.00x" in text and "test cpu" in text


def test_bad_flags_are_refused_by_name(capsys, tmp_path):
    for argv, word in ((["--baseline", "x", "--out", "y", "--after", "1.5"], "--after"),
                       (["--baseline", "x", "--out", "y", "--seconds", "0"], "--seconds")):
        with pytest.raises(SystemExit):
            bcs.parse_args(argv)
        assert word in capsys.readouterr().err
    with pytest.raises(SystemExit, match="unknown demo scene"):
        bcs.main(["--baseline", ".", "--out", str(tmp_path / "out"), "--scenes", "nosuchscene"])


def test_chart_draws_both_runs_per_scene(tmp_path):
    pytest.importorskip("matplotlib")
    base = bcs.run_stats(_run(tmp_path, "b", steps=50, psnr=30.0, step_s=2.0), 0.4)
    new = bcs.run_stats(_run(tmp_path, "n", steps=100, psnr=31.0, step_s=1.0), 0.4)
    results = {"baseline_commit": "abc", "commit": "def", "seconds": 100,
               "scenes": {"diffuse": {"baseline": base, "new": new}, "thin": {"baseline": base, "new": new}}}
    assert bcs.chart(results, str(tmp_path / "c.png"))
    assert (tmp_path / "c.png").stat().st_size > 10_000
