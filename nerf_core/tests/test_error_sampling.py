"""Error-weighted ray sampling (``train --ray-sampling error``, ``nerf_core.data.error_map``): the draws
and weights against hand-computed values, and a run through the CLI."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch

from nerf_core.data.error_map import REFRESH, UNIFORM, ErrorMap


def test_a_flat_map_draws_uniformly_with_unit_weights():
    m = ErrorMap(2, 5, 5, max_tiles=8)  # tiles of ceil(sqrt(50 / 8)) = 3 px: 2 x 2 a view, cut at the edge
    assert (m.tile, m.th, m.tw, m.tiles) == (3, 2, 2, 8)
    assert m.area.tolist() == [9, 6, 6, 4] * 2
    view, j, i, tile, w = m.draw(200_000, torch.Generator().manual_seed(0))
    assert torch.allclose(w, torch.ones_like(w))
    assert int(j.max()) == 4 and int(i.max()) == 4 and int(j.min()) == 0
    counts = torch.bincount((view * 25 + j * 5 + i), minlength=50).double()
    assert float((counts / counts.mean() - 1).abs().max()) < 0.05  # every pixel alike, edge tiles too
    assert torch.equal(tile, view * 4 + (j // 3) * 2 + (i // 3))


def test_a_tile_with_more_error_is_drawn_more_and_weighed_less_by_hand():
    m = ErrorMap(1, 2, 2)  # four one-pixel tiles, each starting at error 0.1
    for _ in range(REFRESH):  # each update moves tile 0 a quarter of the way to 1.1
        m.update(torch.tensor([0]), torch.tensor([1.1]))
    e0 = 1.1 - 1.0 * 0.75 ** REFRESH
    p0 = (1 - UNIFORM) * e0 / (e0 + 0.3) + UNIFORM / 4
    p1 = (1 - UNIFORM) * 0.1 / (e0 + 0.3) + UNIFORM / 4
    assert float(m.error[0]) == pytest.approx(e0)
    assert float(m.p_tile[0]) == pytest.approx(p0) and float(m.p_tile[1]) == pytest.approx(p1)
    view, j, i, tile, w = m.draw(100_000, torch.Generator().manual_seed(1))
    assert float((tile == 0).double().mean()) == pytest.approx(p0, abs=0.01)
    assert float(w[tile == 0][0]) == pytest.approx(0.25 / p0) and float(w[tile == 1][0]) == pytest.approx(0.25 / p1)
    assert float(w.max()) <= 1 / UNIFORM + 1e-6
    m.update(torch.tensor([1, 2]), torch.tensor([float("nan"), 0.5]))  # a NaN error teaches nothing
    assert float(m.error[1]) == pytest.approx(0.1) and float(m.error[2]) == pytest.approx(0.2)


def test_the_weighted_mean_estimates_the_uniform_mean():
    gen = torch.Generator().manual_seed(2)
    value = torch.rand(3, 8, 8, generator=gen) ** 4  # a few pixels carry most of it, as silhouettes do
    m = ErrorMap(3, 8, 8)  # one tile a pixel
    for _ in range(4 * REFRESH):  # learn the error where it is
        view, j, i, tile, _ = m.draw(256, gen)
        m.update(tile, value[view, j, i])
    view, j, i, tile, w = m.draw(400_000, gen)
    drawn = value[view, j, i]
    # the draws follow the error: 0.5 E[v] + 0.5 E[v^2] / E[v] = 0.38 against E[v] = 0.2 for v = u^4...
    assert float(drawn.mean()) > 1.6 * float(value.mean())
    assert float((w * drawn).sum() / w.sum()) == pytest.approx(float(value.mean()), rel=0.02)  # ...the loss does not


def test_a_run_with_error_sampling_trains_and_says_so(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    p = subprocess.run([sys.executable, "-m", "nerf_core", "train", str(sphere_dataset), "--out", str(run),
                        "--max-steps", "40", "--ray-sampling", "error", "--eval-views", "1", "--no-bar",
                        "--device", "cpu"], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["trained_with"]["ray_sampling"] == "error" and metrics["psnr"] > 12
    p = subprocess.run([sys.executable, "-m", "nerf_core", "train", str(sphere_dataset), "--out", str(tmp_path / "b"),
                        "--ray-sampling", "importance"], capture_output=True, text=True, env=env)
    assert p.returncode == 2 and "--ray-sampling" in p.stderr and "Traceback" not in p.stderr
