"""The stability study's breakdown rules and report (``benchmarks/stability.py``), on synthetic runs."""
from __future__ import annotations

import json
import math

import pytest

import stability


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
    assert {(r["study"], r["breaks_at"]) for r in table} == {("base", "no breakdown"),
                                                             ("views", "4: PSNR -5.0 dB vs base (1/2 seeds)")}


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


def test_stability_seed_and_job_flags():
    args = stability.parse_args(["--out", "x", "--seeds", "3", "--other-seeds", "1", "--jobs", "2"])
    assert (args.base_seeds, args.other_seeds, args.jobs) == (3, 1, 2)
    args = stability.parse_args(["--out", "x", "--seeds", "2"])
    assert (args.base_seeds, args.other_seeds) == (2, 2)


def test_breakdown_rules_sit_at_each_methods_base_minus_drop():
    settings = [{"method": "grid", "study": "base", "setting": "default", "psnr_mean": 39.69},
                {"method": "grid", "study": "views", "setting": 4, "psnr_mean": 32.72},
                {"method": "nerf", "study": "base", "setting": "default", "psnr_mean": 19.55},
                {"method": "bad", "study": "base", "setting": "default", "psnr_mean": None}]
    rules = stability.breakdown_rules(settings, drop=3.0)
    assert rules == {"grid": pytest.approx(36.69), "nerf": pytest.approx(16.55)}


def test_chart_groups_mark_broken_settings():
    settings = [
        {"method": "m", "study": "base", "setting": "default", "psnr_mean": 30.0, "psnr_std": 0.1, "broken": ""},
        {"method": "m", "study": "views", "setting": 4, "psnr_mean": 20.0, "psnr_std": 0.2,
         "broken": "PSNR -10.0 dB vs base (1/1 seeds)"},
    ]
    groups = stability.chart_groups(settings, n_train=64)
    assert groups["views"]["m"] == [("4", 20.0, 0.2, True), ("64", 30.0, 0.1)]


def test_stability_chart_draws_the_rule_of_each_method_in_each_panel(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    runs = [_run("grid", "base", "default", 0, 30.0), _run("grid", "base", "default", 1, 32.0),
            _run("grid", "views", 4, 0, 26.0), _run("grid", "lr", "x10", 0, 29.5),
            _run("nerf", "base", "default", 0, 20.0), _run("nerf", "views", 4, 0, 19.0)]
    (tmp_path / "stability.json").write_text(json.dumps({
        "runs": runs, "capture": {"resolution": 48, "count": 64, "test_count": 4}, "scene": "diffuse",
        "seconds_per_run": 60, "threshold_db": 15.0, "drop_db": 3.0, "machine": {"cpus": 2}}))
    assert stability.main(["--out", str(tmp_path), "--report-only", "--drop", "2.5"]) == 0
    fig = kept[-1]
    panels = {ax.get_title(): ax for ax in fig.axes if ax.get_title()}
    assert set(panels) == {"views", "lr"}

    def flat_lines(ax):
        return sorted(round(float(ln.get_ydata()[0]), 6) for ln in ax.get_lines()
                      if len(ln.get_ydata()) == 2 and ln.get_ydata()[0] == ln.get_ydata()[1])

    # grid's base is the mean of 30 and 32; the rule is 2.5 dB under it; nerf's is 20 - 2.5.
    assert flat_lines(panels["views"]) == [15.0, 17.5, 28.5]
    assert flat_lines(panels["lr"]) == [15.0, 28.5]  # nerf has no lr runs, so no nerf rule there
    # grid at 4 views (26.0 < 28.5) is broken and hatched; grid at x10 (29.5) is not.
    hatched = [round(p.get_height(), 6) for ax in panels.values() for p in ax.patches
               if p.get_hatch() and p.get_height()]
    assert hatched == [26.0]
