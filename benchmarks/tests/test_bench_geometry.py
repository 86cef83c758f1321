"""The geometry benchmark's report (``benchmarks/bench_geometry.py report``): chart and tables from run JSONs."""
from __future__ import annotations

import json

from PIL import Image

import bench_geometry


def _result(scene, method, steps, f1, extract=True, variants=False):
    def scores(f):
        return {"0.005": {"precision": f / 2, "recall": f / 2, "fscore": f / 2, "chamfer": 0.01,
                          "normal_consistency": 0.8},
                "0.01": {"precision": f, "recall": f, "fscore": f, "chamfer": 0.01, "normal_consistency": 0.8}}

    ckpts = [{"step": s, "train_seconds": 60.0 * (k + 1), "scores": scores(f1 * (k + 1) / len(steps))}
             for k, s in enumerate(steps)]
    final = {"default": {"summary": {"faces": 1000}, "scores": scores(f1)}}
    if variants:
        final["level x4"] = {"summary": {"faces": 900}, "scores": scores(f1 / 2)}
    r = {"scene": scene, "method": method, "checkpoints": ckpts, "final": final,
         "eval": {"psnr": 30.0, "depth_mae": 0.05, "depth_rel": 0.01}}
    if extract:
        r["extract_256"] = {"seconds": 12.5, "faces": 5000, "error": None}
    return r


def test_report_draws_one_panel_per_scene_and_prints_the_tables(tmp_path, capsys):
    scenes = ["cube", "diffuse", "ground", "hdri", "interior", "multi", "thin"]  # 7: a 2 x 4 grid, one hidden
    for k, scene in enumerate(scenes):
        for method in ("nerf", "vmgrid"):
            r = _result(scene, method, [250, 500, 886] if method == "vmgrid" else [170], 0.5 + 0.05 * k,
                        extract=method == "vmgrid", variants=(scene, method) == ("diffuse", "vmgrid"))
            (tmp_path / f"{scene}_{method}.json").write_text(json.dumps(r))
    assert bench_geometry.main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    with Image.open(tmp_path / "geometry.png") as im:
        w, h = im.size
    assert w > h  # four panels a row, two rows
    assert "| diffuse | vmgrid | 886 | 0.275 | 0.550 |" in out
    assert "| thin | nerf | 170 |" in out and out.count("| nerf | 170 |") == 7
    assert "| 12.5 s |" in out and "| - |" in out  # nerf runs made with --no-256
    variants = out.split("| variant |")[1]
    assert "| diffuse | vmgrid | level x4 | 900 |" in variants and "multi" not in variants
