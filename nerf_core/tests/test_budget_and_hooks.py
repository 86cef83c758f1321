"""The one budget fraction reaches the step events and the methods, each method sizes itself, and the
helpers split out of the trainer keep their rules (view spreading, step file names, PSNR)."""
import math
import re

import pytest
import torch

from nerf_core import contract
from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.evaluation.evaluate import spread_views
from nerf_core.image.losses import masked_mse
from nerf_core.image.metrics import mse_to_psnr as psnr_from_mse
from nerf_core.image.metrics import psnr
from nerf_core.methods.base import RadianceModel
from nerf_core.methods.registry import build_model, register
from nerf_core.methods.sizing import auto_size
from nerf_core.runs.events import read_events

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
SMALL_GRID = dict(res_init=16, res_final=32, upsample_at=[0.25], density_rank=8, app_rank=8, mlp_width=32,
                  occ_res=16, min_stage_steps=20)


def test_step_events_and_the_method_hook_get_the_same_budget_fraction(sphere_dataset, tmp_path, monkeypatch):
    from nerf_core.methods.registry import method_class

    seen = []
    monkeypatch.setattr(method_class("test-grid"), "training_hook", lambda self, step, frac: seen.append((step, frac)))
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(sphere_dataset), out=str(run), method="test-grid", max_steps=20, batch_rays=64,
                      stdout_events=False, show_bar=False, log_every=5, eval_views=0))
    assert seen == [(k, k / 20) for k in range(20)]  # before step k+1: k of 20 steps spent
    steps = [e for e in read_events(run / "progress.jsonl") if e["event"] == "step"]
    assert {1, 5, 10, 15, 20} <= {e["step"] for e in steps}  # (a slow machine adds events every 5 s)
    assert [e["frac"] for e in steps if e["step"] in (1, 5, 10, 20)] == [0.05, 0.25, 0.5, 1.0]
    assert all(e["frac"] == e["step"] / 20 for e in steps)


def test_vmgrid_without_a_budget_follows_its_budget_steps():
    for budget_steps, grows in ((200, False), (100, True)):  # step 25 is 12.5 % / 25 % of the assumed budget
        model = build_model("vmgrid", BOX, **SMALL_GRID, budget_steps=budget_steps)
        model.occupancy.binary[:2] = False  # pruned: geometry has formed, growth may happen
        assert model.training_hook(25, None) is grows
        assert model.field.resolution == (32 if grows else 16)


def test_budget_fraction_of_the_config_is_the_contract_one():
    cfg = TrainConfig(dataset="d", out="o", max_steps=100, max_seconds=40.0)
    assert cfg.budget_fraction(10, 30.0) == contract.budget_fraction(10, 30.0, 100, 40.0) == 0.75
    assert TrainConfig(dataset="d", out="o").budget_fraction(10, 3.0) == 0.0  # no budget: nothing spent


@register("test-sized")
class _Sized(RadianceModel):
    @classmethod
    def size_options(cls, fine_res, texture, fine_share):
        return {"cells": fine_res, "texture": texture, "share": fine_share}, ["sized by the method"]


def test_auto_size_hands_its_measurements_to_the_method():
    # No images: full, pixel-fine texture is assumed. Footprint 4 / 300 units, box 2 units: 150 cells.
    opts, why = auto_size("test-sized", BOX, 300.0, 96, 96, 4.0, None)
    assert opts == {"cells": pytest.approx(150.0), "texture": 1.0, "share": 1.0}
    assert why[-1] == "sized by the method" and any("pixel covers" in r for r in why)
    assert auto_size("test-grid", BOX, 300.0, 96, 96, 4.0, None)[0] == {}  # the default hook: no options


def test_nerf_nope_gets_no_encoding_frequencies():
    nerf, _ = auto_size("nerf", BOX, 300.0, 96, 96, 4.0, None)
    nope, _ = auto_size("nerf-nope", BOX, 300.0, 96, 96, 4.0, None)
    assert nerf == {"width": 128, "pos_freqs": 8} and nope == {"width": 128}  # ceil(log2(150)) = 8


def test_spread_views_includes_both_ends():
    assert spread_views(10, 5) == [0, 2, 4, 7, 9]  # 0, 2.25, 4.5, 6.75, 9 rounded (half to even)
    assert spread_views(10, 1) == [0] and spread_views(3, 3) == [0, 1, 2]


def test_step_file_names_and_their_pattern_agree():
    pat = contract.step_name_pattern(".pt")
    assert contract.step_name(12, ".pt") == "step_0000012.pt" and re.fullmatch(pat, "step_0000012.pt")
    assert not re.fullmatch(pat, "step_12.pt") and not re.fullmatch(pat, "step_0000012.pt.tmp")
    assert contract.step_glob(".png") == "step_*.png"


def test_one_psnr_formula():
    pred, gt = torch.zeros(4, 4, 3), torch.full((4, 4, 3), 0.1)  # mse 0.01: 20 dB
    assert psnr(pred, gt) == pytest.approx(20.0) and psnr_from_mse(0.01) == pytest.approx(20.0)
    assert psnr_from_mse(0.0) == math.inf
    # A mask weight of 0 removes a ray from the loss: only the second ray (error 0.04) counts.
    err = masked_mse(torch.zeros(2, 3), torch.tensor([[0.5, 0.5, 0.5], [0.2, 0.2, 0.2]]), torch.tensor([0.0, 1.0]))
    assert float(err) == pytest.approx(0.04)
