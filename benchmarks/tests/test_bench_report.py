"""Tables and charts a study writes (``bench.report``)."""
from __future__ import annotations

import csv
import json

from PIL import Image

from bench import analysis, report


def test_rows_tables_and_markdown(tmp_path):
    results = [{
        "scene": "diffuse", "series": "nerf", "method": "nerf", "n_params": 100, "model_bytes": 400,
        "checkpoint_bytes": 900, "samples_per_s": 5e4, "rollbacks": 0, "error": None,
        "points": [{"seconds": 10.2, "budget": 10.0, "step": 50, "psnr": 15.0, "ssim": 0.5},
                   {"seconds": 20.1, "budget": 20.0, "step": 99, "psnr": 18.5, "ssim": 0.6}],
    }]
    rows, finals = analysis.rows_from_results(results)
    assert len(rows) == 2 and finals[0]["psnr"] == 18.5 and finals[0]["steps"] == 99
    table = analysis.psnr_at_table(rows, [10.0, 20.0])
    assert table[0]["psnr@10s"] == 15.0 and table[0]["psnr@20s"] == 18.5
    path = tmp_path / "t.csv"
    report.write_csv(str(path), rows)
    with open(path) as fh:
        read = list(csv.DictReader(fh))
    assert read[1]["psnr"] == "18.5" and read[0]["train_seconds"] == "10.2"
    md = report.markdown_table(table, ["scene", "series", "psnr@10s", "psnr@20s"])
    assert md.splitlines()[2] == "| diffuse | nerf | 15.00 | 18.50 |"
    report.write_json(str(tmp_path / "r.json"), {"x": float("nan")})
    assert json.loads((tmp_path / "r.json").read_text()) == {"x": None}


def test_charts_are_written(tmp_path):
    curves = {("diffuse", "nerf"): [(10, 15.0), (20, 18.0)], ("diffuse", "grid"): [(10, 20.0), (20, 22.0)],
              ("thin", "nerf"): [(10, 12.0), (20, float("nan"))]}
    p1 = report.chart_psnr_vs_time(curves, str(tmp_path / "t.png"), "t")
    pts = [{"scene": "diffuse", "series": "grid auto", "params": 3000, "psnr": 21.0},
           {"scene": "diffuse", "series": "grid small", "params": 1000, "psnr": 19.0},
           {"scene": "diffuse", "series": "nerf", "params": 500000, "psnr": 18.0}]
    p2 = report.chart_psnr_vs_size(pts, str(tmp_path / "s.png"), "s")
    p3 = report.chart_bars({"views": {"nerf": [("4", 12.0, 1.0), ("8", 15.0, 0.5)]}}, str(tmp_path / "b.png"),
                       "b", "PSNR", threshold=14.0)
    for p in (p1, p2, p3):
        with Image.open(p) as im:
            assert im.size[0] > 300 and im.size[1] > 200


def test_time_ticks_read_in_seconds_and_minutes():
    assert report.time_ticks(8, 390) == [(10, "10 s"), (30, "30 s"), (60, "1 min"), (120, "2 min"), (300, "5 min")]
    assert [label for _, label in report.time_ticks(46, 780)] == ["1 min", "2 min", "5 min", "10 min"]
    # A quick run's 20-40 s holds one coarse tick: the fine ones fill in.
    assert report.time_ticks(15, 52) == [(15, "15 s"), (20, "20 s"), (30, "30 s"), (40, "40 s")]


def test_series_styles_pair_nerf_with_nerf_nope():
    styles = report.series_styles({"nerf", "nerf-nope", "vmgrid", "vmgrid auto"})
    assert styles["nerf"]["color"] == styles["nerf-nope"]["color"] == report.PAIR_COLOUR
    assert (styles["nerf"]["ls"], styles["nerf-nope"]["ls"]) == ("-", "--")
    others = {styles["vmgrid"]["color"], styles["vmgrid auto"]["color"]}
    assert len(others) == 2 and report.PAIR_COLOUR not in others


def _keep_figures(monkeypatch):
    """The charts close their figure after saving; keep it open so a test can read the Axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    return kept


def test_psnr_vs_time_has_a_log_axis_markers_and_the_pair_band(tmp_path, monkeypatch):
    kept = _keep_figures(monkeypatch)
    times = [10, 20, 40, 60, 80, 120, 160, 300]
    curves = {("multi", "nerf"): [(t, 14 + t / 30) for t in times],
              ("multi", "nerf-nope"): [(t, 14 + t / 60) for t in times],
              ("multi", "vmgrid"): [(t, 30 + t / 100) for t in times],
              ("thin", "vmgrid"): [(t, 25.0) for t in times[:3]]}
    path = report.chart_psnr_vs_time(curves, str(tmp_path / "t.png"), "t")
    with Image.open(path) as im:
        assert im.size[0] > 300 and im.size[1] > 200
    ax = kept[-1].axes[0]
    assert ax.get_xscale() == "log"
    assert [t.get_text() for t in ax.get_xticklabels()] == ["10 s", "30 s", "1 min", "2 min", "5 min"]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    assert list(lines["nerf"].get_xdata()) == times and lines["nerf"].get_marker() == "o"
    assert lines["nerf-nope"].get_linestyle() == "--"
    assert len(ax.collections) == 1  # the shaded nerf - nerf-nope gap; thin has no pair and no band
    assert len(kept[-1].axes[1].collections) == 0
    # The written gap is the last one: (14 + 10) - (14 + 5) = +5.0 dB.
    assert [t.get_text() for t in ax.texts] == ["+5.0 dB"]


def test_bar_panel_draws_each_methods_rule_and_hatches_broken_bars():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    colours = {"a": "tab:blue", "b": "tab:orange", "c": "tab:green"}
    report.draw_bar_panel(ax, {"a": [("4", 20.0, 0.5), ("8", 25.0, 0.2, True)], "b": [("4", 30.0, 0.1)]}, colours,
                          threshold=15.0, rules={"a": 27.0, "b": 33.5, "c": 10.0}, rule_label="rule")
    # Horizontal lines only (y0 == y1): the whisker caps are Line2D markers too.
    flat = {(ln.get_ydata()[0], ln.get_color()) for ln in ax.get_lines()
            if len(ln.get_ydata()) == 2 and ln.get_ydata()[0] == ln.get_ydata()[1]}
    # The floor, and one rule per method in the panel (c is not in it), each in its method's colour.
    assert flat == {(15.0, "r"), (27.0, "tab:blue"), (33.5, "tab:orange")}
    assert "rule" in ax.get_legend_handles_labels()[1]
    hatched = [p.get_height() for p in ax.patches if p.get_hatch() and p.get_height() > 0]
    assert hatched == [25.0]
    plt.close(fig)


def _stored_run(scene, series, psnrs, checkpoints):
    return {"scene": scene, "series": series, "method": series, "flags": [], "n_params": 1000, "model_bytes": 4000,
            "checkpoint_bytes": 9000, "samples_per_s": 1e4, "steps": 10, "rollbacks": 0, "nan": False, "error": None,
            "points": [{"seconds": c + 0.4, "budget": c, "step": int(c), "psnr": p, "ssim": 0.5}
                       for c, p in zip(checkpoints, psnrs)]}


def test_benchmark_report_only_redraws_charts_and_the_gap_table(tmp_path, capsys):
    import benchmark

    cps = [10.0, 20.0, 40.0]
    runs = [_stored_run("multi", "nerf", [15.0, 17.25, 21.5], cps),
            _stored_run("multi", "nerf-nope", [15.5, 17.0, 19.0], cps),
            _stored_run("multi", "grid", [25.0, 28.0, 30.0], cps)]
    stored = {"machine": {"cpu": "test", "cpus": 2}, "wall_seconds": 60.0, "checkpoints_seconds": cps,
              "capture": {"resolution": 48, "count": 20, "test_count": 3}, "runs": runs, "size_study": [],
              "profile": None}
    (tmp_path / "results.json").write_text(json.dumps(stored))
    before = (tmp_path / "results.json").read_text()
    assert benchmark.main(["--out", str(tmp_path), "--report-only"]) == 0
    md = (tmp_path / "summary.md").read_text()
    # nerf - nerf-nope: 15 - 15.5, 17.25 - 17, 21.5 - 19.
    assert "| multi | -0.50 | 0.25 | 2.50 |" in md
    assert "| multi | nerf | 15.00 | 17.25 | 21.50 |" in md
    assert (tmp_path / "psnr_vs_time.png").stat().st_size > 0 and (tmp_path / "psnr_vs_size.png").stat().st_size > 0
    assert (tmp_path / "results.json").read_text() == before  # the stored numbers are never rewritten
    empty = tmp_path / "empty"
    empty.mkdir()
    assert benchmark.main(["--out", str(empty), "--report-only"]) == 1
    assert "results.json" in capsys.readouterr().err
    del runs[0]["points"]
    (empty / "results.json").write_text(json.dumps(stored))
    assert benchmark.main(["--out", str(empty), "--report-only"]) == 1
    assert "lacks a field" in capsys.readouterr().err
