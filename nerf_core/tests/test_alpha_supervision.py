"""Alpha as supervision (``train --alpha-weight``, issue 56): the loss against hand-computed values, the
batches that carry the alpha, the refusal of a dataset without a transparent film, and a short run."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from nerf_core.data.alpha import check_alpha, with_alpha_term
from nerf_core.data.batcher import BatchOptions, RayBatcher
from nerf_core.data.loading import load_dataset
from nerf_core.errors import DatasetError
from nerf_core.image.io import read_png, write_png
from nerf_core.image.losses import alpha_loss
from nerf_core.tests.conftest import make_dataset


def _cli(*args):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "nerf_core", *map(str, args)], capture_output=True, text=True,
                          env=env)


def test_alpha_loss_by_hand():
    acc = torch.tensor([1.0, 0.5, 0.0, 0.9])
    alpha = torch.tensor([1.0, 0.0, 0.5, 0.6])  # squared errors 0, 0.25, 0.25, 0.09
    assert float(alpha_loss(acc, alpha, None)) == pytest.approx(0.59 / 4)
    # weighted like the colour loss (masked_mse): sum(w e) / max(sum(w), 1)
    weight = torch.tensor([2.0, 1.0, 0.0, 0.5])
    assert float(alpha_loss(acc, alpha, weight)) == pytest.approx((0.25 + 0.5 * 0.09) / 3.5)
    loss = torch.tensor(0.5)
    out = {"acc": acc}
    assert float(with_alpha_term(loss, out, alpha, weight, 0.1)) == pytest.approx(0.5 + 0.1 * (0.295 / 3.5))
    # off (weight 0) or no alpha in the batch: the step's loss itself, no op more
    assert with_alpha_term(loss, out, alpha, weight, 0.0) is loss
    assert with_alpha_term(loss, out, None, weight, 0.1) is loss


def test_the_step_adds_the_alpha_term_as_the_run_says():
    from nerf_core.data.batcher import RayBatch
    from nerf_core.engine.batches import with_supervision
    from nerf_core.engine.config import TrainConfig

    n = 4
    batch = RayBatch(torch.zeros(n, 3), torch.zeros(n, 3), torch.ones(n, 3), torch.ones(n, 3), None,
                     alpha=torch.tensor([1.0, 0.0, 0.5, 0.6]))
    out = {"acc": torch.tensor([1.0, 0.5, 0.0, 0.9]), "depth": torch.ones(n)}
    loss = torch.tensor(0.5)
    cfg = TrainConfig(dataset="ds", out="run", alpha_weight=2.0)
    assert float(with_supervision(loss, out, batch, cfg)) == pytest.approx(0.5 + 2.0 * 0.59 / 4)
    assert with_supervision(loss, out, batch, TrainConfig(dataset="ds", out="run")) is loss  # colours only
    # a method's batcher that ignores the flags: refused, not trained on colours alone in silence
    from nerf_core.errors import RunError

    bare = batch._replace(alpha=None)
    with pytest.raises(RunError, match="--alpha-weight: the method's batcher"):
        with_supervision(loss, out, bare, cfg)
    with pytest.raises(RunError, match="--depth: the method's batcher"):
        with_supervision(loss, out, bare, TrainConfig(dataset="ds", out="run", depth=True))


def test_batches_carry_the_alpha_the_target_was_composited_with(tmp_path):
    train = load_dataset(make_dataset(tmp_path / "ds", depth=False, layouts=("synthetic",))).split("train")
    gen = torch.Generator().manual_seed(0)
    batch = RayBatcher(train, "random", gen, torch.device("cpu"), BatchOptions(alpha=True)).sample(512)
    assert batch.alpha.shape == (512,) and 0 < float(batch.alpha.mean()) < 1  # the sphere and empty space
    plain = RayBatcher(train, "random", torch.Generator().manual_seed(0), torch.device("cpu")).sample(512)
    assert plain.alpha is None and torch.equal(plain.target, batch.target)  # the same draws: no extra number


def test_alpha_on_a_dataset_without_a_transparent_film_is_one_line_before_the_run_folder(tmp_path):
    root = make_dataset(tmp_path / "ds", depth=False, layouts=("synthetic",))
    for js in root.glob("transforms_*.json"):  # the capture says its film was opaque
        js.write_text(json.dumps({**json.loads(js.read_text()), "film_transparent": False}))
    run = tmp_path / "run"
    p = _cli("train", root, "--out", run, "--max-steps", 5, "--alpha-weight", 0.1, "--no-bar", "--device", "cpu")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    lines = [line for line in p.stderr.splitlines() if "--alpha-weight" in line]
    assert len(lines) == 1 and str(root) in lines[0] and "film_transparent: false" in lines[0], p.stderr
    assert not run.exists()


def test_check_alpha_refuses_opaque_images_and_accepts_a_cut_out(tmp_path):
    root = make_dataset(tmp_path / "ds", depth=False, layouts=("synthetic",))
    check_alpha(load_dataset(root))  # the sphere on a transparent film
    for png in root.glob("train/*.png"):
        px = read_png(png).copy()
        px[..., 3] = 255
        write_png(png, px)
    with pytest.raises(DatasetError, match=r"^--alpha-weight: .*alpha is opaque everywhere"):
        check_alpha(load_dataset(root))
    for png in root.glob("train/*.png"):
        write_png(png, np.ascontiguousarray(read_png(png)[..., :3]))
    with pytest.raises(DatasetError, match=r"^--alpha-weight: .*without an alpha channel"):
        check_alpha(load_dataset(root))


@pytest.mark.parametrize("weight", [-1.0, math.inf, math.nan, 1e9])
def test_alpha_weight_out_of_range_is_refused_naming_the_flag(sphere_dataset, tmp_path, weight):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.errors import TrainError

    with pytest.raises(TrainError, match=r"alpha[-_]weight"):
        TrainConfig(dataset=str(sphere_dataset), out=str(tmp_path / "r"), alpha_weight=weight).check()


def test_an_alpha_run_trains_records_what_it_trained_with_and_eval_says_so(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    p = _cli("train", sphere_dataset, "--out", run, "--max-steps", 30, "--alpha-weight", 0.1, "--eval-views", 1,
             "--no-bar", "--device", "cpu")
    assert p.returncode == 0, p.stderr
    assert json.loads((run / "config.json").read_text())["alpha_weight"] == 0.1
    used = {"depth": False, "depth_weight": None, "train_rays": "centre", "ray_sampling": "uniform",
            "alpha_weight": 0.1}
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["trained_with"] == used and metrics["psnr"] > 10
    p = _cli("eval", run, "--views", 1, "--device", "cpu", "--no-bar")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout.strip().splitlines()[-1])["trained_with"] == used


def test_a_run_from_before_the_flag_resumes_without_alpha():
    from nerf_core.engine.config import TrainConfig, merge_resumed_config

    old = {"config": {"method": "vmgrid", "dataset": "D", "max_steps": 10}}
    assert merge_resumed_config(TrainConfig(dataset="D", out="R"), old).alpha_weight == 0.0
    with_alpha = {"config": {**old["config"], "alpha_weight": 0.1}}
    resumed = merge_resumed_config(TrainConfig(dataset="D", out="R"), with_alpha)
    assert resumed.alpha_weight == 0.1  # the run's own weight
