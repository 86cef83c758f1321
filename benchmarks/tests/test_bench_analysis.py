"""The numbers a study draws from its runs, on synthetic events and hand-made renders (``bench.analysis``)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from bench import analysis


def test_summarize_training_counts_rollbacks_nan_and_median_rate():
    events = [
        {"event": "start", "n_params": 1234},
        {"event": "step", "step": 1, "loss": 0.1, "psnr": 10.0, "elapsed": 1.0, "samples_per_s": 10.0},
        {"event": "step", "step": 2, "loss": None, "psnr": None, "elapsed": 2.0, "samples_per_s": 1000.0},
        {"event": "rollback", "step": 2, "reason": "non-finite loss (NaN)", "lr": 0.001},
        {"event": "step", "step": 3, "loss": 0.05, "psnr": 13.0, "elapsed": 3.0, "samples_per_s": 100.0},
        {"event": "done", "step": 3, "elapsed": 3.5},
    ]
    s = analysis.summarize_training(events)
    assert s["n_params"] == 1234
    assert s["steps"] == 3
    assert s["elapsed"] == 3.5
    assert s["rollbacks"] == 1
    assert s["nan"] is True
    assert s["samples_per_s"] == 100.0  # median of 10, 1000, 100
    assert s["train_psnr"] == 13.0
    assert s["error"] is None
    assert analysis.summarize_training([{"event": "error", "message": "boom"}])["error"] == "boom"


def test_pareto_front_hand_computed():
    # (params, psnr): b dominates c (smaller and better); d is largest but best; e has no psnr.
    pts = [(100, 20.0), (200, 25.0), (300, 24.0), (800, 26.0), (50, None), (100, 19.0)]
    assert analysis.pareto_front(pts) == [0, 1, 3]


def test_pareto_front_ties_keep_one_of_equal_points():
    pts = [(100, 20.0), (100, 20.0), (200, 19.0)]
    # Equal points do not dominate each other; the smaller-worse point is dominated.
    assert analysis.pareto_front(pts) == [0, 1]


def test_auto_size_verdict_within_half_params():
    fixed = [(1000, 20.0), (4000, 24.0), (16000, 24.3)]
    v = analysis.auto_size_verdict((6000, 24.0), fixed)
    assert v["gap_db"] == pytest.approx(0.3)
    assert v["param_ratio"] == pytest.approx(6000 / 16000)
    assert v["within_half"] is True and v["ok"] is True
    # Same quality at twice the parameters of the best: near in dB but not economical.
    v = analysis.auto_size_verdict((32000, 24.2), fixed)
    assert v["within_half"] is False
    assert v["on_front"] is False and v["ok"] is False
    # 1.3 dB below the best, dominated by the 4000-parameter model: fails.
    v = analysis.auto_size_verdict((5000, 23.0), fixed)
    assert v["ok"] is False and v["within_half"] is False
    assert analysis.auto_size_verdict((5000, float("nan")), fixed)["ok"] is None


def test_size_analysis_reads_final_rows():
    finals = [
        {"scene": "s", "series": "grid small", "method": "grid", "n_params": 1000, "psnr": 22.0},
        {"scene": "s", "series": "grid large", "method": "grid", "n_params": 8000, "psnr": 25.0},
        {"scene": "s", "series": "grid auto", "method": "grid", "n_params": 3000, "psnr": 24.8},
        {"scene": "s", "series": "nerf", "method": "nerf", "n_params": 500000, "psnr": 23.0},
    ]
    (row,) = analysis.size_analysis(finals, "grid")
    assert row["within_0.5dB_at_half"] is True
    assert row["on_front"] is True
    assert row["front"] == "grid small, grid auto, grid large"


def test_mean_std_ignores_missing():
    m, sd, n = analysis.mean_std([1.0, 3.0, None, float("nan")])
    assert (m, n) == (2.0, 2) and sd == pytest.approx(math.sqrt(2))
    assert analysis.mean_std([None]) == (None, None, 0)


def test_floater_stats_on_hand_made_renders(tmp_path, tiny_dataset):
    src = tiny_dataset(tmp_path / "src")
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
    s = analysis.floater_stats(str(renders), str(src))
    assert s["n_views"] == 2
    assert s["floater_pixels"] == pytest.approx((0 + 3 / 12) / 2)
    assert s["floater_alpha"] == pytest.approx((0 + (3 + 100 / 255) / 12) / 2)


def test_eval_at_points_label_evaluations_in_mark_order():
    # A slow step crossing 10 s and 20 s evaluates twice at 23.5 s: by nearest time both would be
    # "20 s"; in order they are 10 s and 20 s. The final evaluation (no eval_wall) and other splits
    # are not checkpoint evaluations.
    events = [{"event": "step", "step": 3, "elapsed": 9.0},
              {"event": "eval", "split": "test", "step": 4, "elapsed": 23.5, "eval_wall": 1.0, "psnr": 12.0,
               "ssim": 0.3},
              {"event": "eval", "split": "test", "step": 4, "elapsed": 23.5, "eval_wall": 1.0, "psnr": 12.0,
               "ssim": 0.3},
              {"event": "eval", "split": "val", "step": 9, "elapsed": 41.0, "eval_wall": 1.0, "psnr": 1.0},
              {"event": "eval", "split": "test", "step": 9, "elapsed": 41.0, "eval_wall": 1.0, "psnr": 14.0,
               "ssim": 0.4},
              {"event": "eval", "split": "test", "step": 20, "elapsed": 80.0, "psnr": 16.0}]
    points = analysis.eval_at_points(events, [40.0, 10.0, 20.0])
    assert [(p["budget"], p["seconds"], p["step"], p["psnr"]) for p in points] == [
        (10.0, 23.5, 4, 12.0), (20.0, 23.5, 4, 12.0), (40.0, 41.0, 9, 14.0)]
    assert analysis.eval_at_points(events, [10.0]) == points[:1]
    assert analysis.eval_at_points(events, []) == []


def test_eval_at_points_expand_an_evaluation_that_stands_for_several_marks():
    # The trainer evaluates once when a slow step crosses 10 s and 20 s, and says so in eval_at.
    events = [{"event": "eval", "split": "test", "step": 4, "elapsed": 23.5, "eval_wall": 1.0, "psnr": 12.0,
               "ssim": 0.3, "eval_at": [10.0, 20.0]},
              {"event": "eval", "split": "test", "step": 9, "elapsed": 41.0, "eval_wall": 1.0, "psnr": 14.0,
               "ssim": 0.4, "eval_at": [40.0]}]
    points = analysis.eval_at_points(events, [40.0, 10.0, 20.0])
    assert [(p["budget"], p["seconds"], p["step"], p["psnr"]) for p in points] == [
        (10.0, 23.5, 4, 12.0), (20.0, 23.5, 4, 12.0), (40.0, 41.0, 9, 14.0)]


def test_pair_gap_table_subtracts_at_each_checkpoint():
    table = [{"scene": "a", "series": "nerf", "psnr@10s": 15.0, "psnr@20s": 19.5},
             {"scene": "a", "series": "nerf-nope", "psnr@10s": 15.5, "psnr@20s": 17.0},
             {"scene": "a", "series": "grid", "psnr@10s": 30.0, "psnr@20s": 31.0},
             {"scene": "b", "series": "nerf", "psnr@10s": 15.0, "psnr@20s": 16.0},
             {"scene": "c", "series": "nerf", "psnr@10s": 15.0, "psnr@20s": None},
             {"scene": "c", "series": "nerf-nope", "psnr@10s": 14.0, "psnr@20s": 16.0}]
    gaps = analysis.pair_gap_table(table, [10.0, 20.0])
    assert gaps == [{"scene": "a", "10s": pytest.approx(-0.5), "20s": pytest.approx(2.5)},  # b lacks nerf-nope
                    {"scene": "c", "10s": pytest.approx(1.0), "20s": None}]
