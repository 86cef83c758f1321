"""Metrics against hand-computed values, and ``eval`` printing one JSON object last."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from nerf_core.cli.main import main
from nerf_core.image.metrics import depth_mae, depth_rel, gaussian_window, psnr, ssim

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_psnr_hand_value():
    a = torch.zeros(4, 4, 3)
    b = torch.full((4, 4, 3), 0.1)  # mse 0.01 -> 20 dB
    assert psnr(a, b) == pytest.approx(20.0)
    mask = torch.zeros(4, 4, dtype=torch.bool)
    mask[0, 0] = True
    b[1:, :] = 0.5
    assert psnr(a, b, mask) == pytest.approx(20.0)
    assert psnr(a, a) == math.inf


def test_ssim_of_constant_images_matches_the_formula():
    # Constant images have zero variance, so SSIM = (2ab + C1) / (a^2 + b^2 + C1) with C1 = 0.01^2.
    a, b = 0.3, 0.6
    expected = (2 * a * b + 1e-4) / (a * a + b * b + 1e-4)
    got = ssim(torch.full((16, 20, 3), a), torch.full((16, 20, 3), b))
    assert got == pytest.approx(expected, abs=1e-6)
    assert ssim(torch.full((11, 11, 3), a), torch.full((11, 11, 3), a)) == pytest.approx(1.0)


def _ssim_reference(x, y):
    """Direct per-window evaluation of Wang et al.'s SSIM with an 11x11 Gaussian (sigma 1.5) window."""
    g = gaussian_window().numpy()
    w2 = np.outer(g, g)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    vals = []
    for c in range(x.shape[2]):
        for r in range(x.shape[0] - 10):
            for q in range(x.shape[1] - 10):
                px, py = x[r:r + 11, q:q + 11, c], y[r:r + 11, q:q + 11, c]
                mx, my = (w2 * px).sum(), (w2 * py).sum()
                vx = (w2 * (px - mx) ** 2).sum()
                vy = (w2 * (py - my) ** 2).sum()
                cov = (w2 * (px - mx) * (py - my)).sum()
                vals.append((2 * mx * my + c1) * (2 * cov + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def test_ssim_matches_direct_window_computation():
    rng = np.random.default_rng(0)
    x = rng.random((15, 17, 3))
    y = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1)
    assert gaussian_window()[5] == gaussian_window().max() and float(gaussian_window().sum()) == pytest.approx(1.0)
    got = ssim(torch.tensor(x, dtype=torch.float32), torch.tensor(y, dtype=torch.float32))
    assert got == pytest.approx(_ssim_reference(x, y), abs=1e-5)
    assert 0.3 < got < 0.99
    with pytest.raises(ValueError, match="11x11"):
        ssim(torch.zeros(5, 5, 3), torch.zeros(5, 5, 3))


def test_depth_mae_uses_pixels_with_depth_and_alpha():
    gt = torch.tensor([[2.0, 0.0], [3.0, 4.0]])
    pred = torch.tensor([[2.5, 9.0], [2.0, 9.0]])
    alpha = torch.tensor([[1.0, 1.0], [1.0, 0.0]])
    assert depth_mae(pred, gt, alpha) == pytest.approx((0.5 + 1.0) / 2)  # (0,1) no depth, (1,1) transparent
    assert depth_mae(pred, torch.zeros(2, 2)) is None
    assert depth_rel(pred, gt, alpha) == pytest.approx((0.5 / 2 + 1.0 / 3) / 2)  # the same pixels, over true depth
    assert depth_rel(pred, torch.zeros(2, 2)) is None


@pytest.mark.parametrize("metric", [depth_mae, depth_rel])
def test_depth_metrics_count_the_same_pixels_by_hand(metric):
    """Truth 2 everywhere but an infinite (the world) and a zero (no depth) pixel; the prediction NaN
    at one pixel and inf at another: only the two pixels with both count, |1.5-2| and |3-2|."""
    gt = torch.tensor([[2.0, float("inf")], [0.0, 2.0], [2.0, 2.0]])
    pred = torch.tensor([[1.5, 9.0], [9.0, 3.0], [float("nan"), float("inf")]])
    want = (0.5 + 1.0) / 2 if metric is depth_mae else (0.5 / 2 + 1.0 / 2) / 2
    assert metric(pred, gt) == pytest.approx(want)
    assert metric(pred, gt, mask=torch.tensor([[True, True], [True, False], [True, True]])) == pytest.approx(
        0.5 if metric is depth_mae else 0.25)
    with pytest.raises(ValueError, match=metric.__name__):
        metric(pred, gt[:2])


def test_eval_prints_per_view_lines_and_json_last(trained_run, capsys):
    run = trained_run["run"]
    assert main(["eval", str(run), "--split", "test", "--no-bar"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 3 and lines[0].startswith("view   0 r_0: psnr")
    last = json.loads(lines[-1])
    assert last["split"] == "test" and last["n_views"] == 2 and last["step"] == 30
    assert math.isfinite(last["psnr"]) and 0 < last["ssim"] <= 1 and last["depth_mae"] >= 0
    assert last["depth_rel"] >= 0 and "depth_rel" in lines[0]
    # The same numbers as training's final evaluation (same checkpoint, same views).
    assert last["psnr"] == pytest.approx(trained_run["summary"]["metrics"]["psnr"], abs=1e-4)
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["splits"]["test"]["n_views"] == 2


def test_eval_scores_at_the_runs_downscale_unless_told_and_says_when_told(tmp_path, dataset_factory, capsys):
    # eval took max(--downscale, the run's): an explicit --downscale 1 on a run trained at 2 scored
    # at half resolution without a word.
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds = dataset_factory(tmp_path / "ds", w=48, h=40, n_train=4, n_test=1)
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=2, batch_rays=64, downscale=2,
                      stdout_events=False, show_bar=False, eval_views=1))
    capsys.readouterr()
    # (one ray a pixel: the rays count the pixels scored)
    assert main(["eval", str(run), "--no-bar", "--pixel-filter", "none"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out.strip().splitlines()[-1])["rays"] == 24 * 20 and "note" not in out.err
    assert main(["eval", str(run), "--no-bar", "--downscale", "1", "--pixel-filter", "none"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out.strip().splitlines()[-1])["rays"] == 48 * 40
    assert "evaluating at --downscale 1, finer than the --downscale 2 the run trained at" in out.err


def test_a_split_of_cameras_only_is_not_evaluated_but_renders(tmp_path, dataset_factory, capsys):
    # BlenderNeRF writes test poses without images; with no 'aabb' either, eval estimated the box from
    # the cameras of the loaded split alone, found none, and stopped on torch.cat of an empty list.
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds = dataset_factory(tmp_path / "ds", n_train=4, n_test=2, aabb=False, layouts=("synthetic",))
    for png in (ds / "test").glob("*.png"):
        png.unlink()
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=2, batch_rays=64,
                      stdout_events=False, show_bar=False, eval_views=1))
    capsys.readouterr()
    assert main(["eval", str(run), "--no-bar"]) == 2
    err = capsys.readouterr().err
    assert "no 'test' views with images" in err and "none of its 2 images exists" in err, err
    assert "Traceback" not in err and "torch.cat" not in err
    # ...and `render RUN`, which the note points to, draws those views (it said "no frames in split 'test'")
    assert "render RUN` renders those views" in err, err
    assert main(["render", str(run), "--out", str(tmp_path / "views"), "--no-bar"]) == 0, capsys.readouterr().err
    manifest = json.loads((tmp_path / "views" / "renders.json").read_text())
    assert sorted(p.name for p in (tmp_path / "views").glob("*.png")) == ["r_0.png", "r_1.png"]
    assert all("psnr" not in fr for fr in manifest["frames"]), manifest  # no ground truth to score against


def test_eval_as_a_subprocess_with_a_plugin_method(trained_run):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest")
    proc = subprocess.run([sys.executable, "-m", "nerf_core", "eval", str(trained_run["run"]), "--split", "val",
                           "--no-bar"], capture_output=True, text=True, cwd=REPO_ROOT, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    assert last["split"] == "val" and last["n_views"] == 1


def test_eval_errors_are_one_line(tmp_path, trained_run, capsys):
    assert main(["eval", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert "nothing" in err and "not found" in err and "Traceback" not in err
    assert main(["eval", str(trained_run["run"]), "--split", "bogus"]) == 2
    assert "bogus" in capsys.readouterr().err
