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
