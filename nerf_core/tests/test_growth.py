"""The final grid follows the budget (``methods.growth``): hand-computed sizes, and runs predicted to
make at most ``BASE_STEPS`` steps grow exactly as before the rule."""
import pytest
import torch

from nerf_core.methods import growth
from nerf_core.methods.registry import build_model, method_class
from nerf_core.methods.sizing import auto_size

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
# Two growth stages 16 -> 23 -> 32; occupancy updates never due (the hook is called at a few steps only).
GRID = dict(res_init=16, res_final=32, upsample_at=[0.25, 0.5], density_rank=2, app_rank=2, mlp_width=8,
            occ_every=10 ** 9, min_stage_steps=1)


@pytest.mark.parametrize("steps, expected", [
    (1000, 160), (5030, 160), (8000, 160),  # up to BASE_STEPS: today's 160
    (8001, 160),  # 160 * 1.00004^(1/3) rounds to 160
    (21000, 224),  # 160 * 2.625^(1/3) = 220.7 -> 224 (multiple of 8)
    (27000, 240),  # 160 * 3.375^(1/3) = 160 * 1.5
    (64000, 320),  # 160 * 8^(1/3) = 320
    (10 ** 7, 320),  # capped at res_max
])
def test_budget_resolution_by_hand(steps, expected):
    assert growth.BASE_STEPS == 8000
    assert growth.budget_resolution(160, steps, 8000, 320) == expected


def test_budget_resolution_off_and_capped():
    assert growth.budget_resolution(160, 10 ** 6, 0, 320) == 160  # rule off
    assert growth.budget_resolution(160, 10 ** 6, 8000, 128) == 160  # a cap below res_final never shrinks
    assert growth.budget_resolution(64, 27000, 8000, 320) == 96  # 64 * 1.5


def _sizes(total_steps, seconds=None, **extra):
    """Resolutions a vmgrid reaches when its hook sees a run of ``total_steps`` steps (a step budget,
    or a time budget of ``seconds`` covering that many steps at an even rate)."""
    model = build_model("vmgrid", BOX, **{**GRID, **extra})
    sizes = []
    for share in (0.1, 0.26, 0.3, 0.51, 0.6, 0.9):
        step = int(total_steps * share)
        frac = step / total_steps if seconds is None else (share * seconds) / seconds
        model.training_hook(step, frac)
        sizes.append(model.field.resolution)
    return sizes, model


@pytest.mark.parametrize("total", [300, 5030, 8000])
def test_short_runs_grow_exactly_as_without_the_rule(total):
    with_rule, model = _sizes(total)
    without, _ = _sizes(total, budget_growth_steps=0)
    assert with_rule == without == [16, 23, 23, 32, 32, 32]
    assert model.res_final_budget == 32


def test_a_long_run_grows_further_and_records_it():
    sizes, model = _sizes(27000)  # 32 * 1.5 = 48
    assert sizes == [16, 23, 23, 48, 48, 48]
    assert model.run_state() == {"resolution": 48, "res_final_budget": 48}
    rebuilt = build_model("vmgrid", BOX, **model.options)  # what resuming does: the same schedule
    rebuilt.restore_run_state(model.run_state())
    rebuilt.load_state_dict(model.state_dict())
    assert rebuilt.resolution_schedule() == [23, 48] and rebuilt.field.resolution == 48


def test_a_time_budget_predicts_from_the_rate():
    sizes, _ = _sizes(27000, seconds=90.0)  # 13500 steps at half of 90 s: 27000 predicted
    assert sizes[-1] == 48


def test_no_budget_keeps_res_final():
    model = build_model("vmgrid", BOX, **{**GRID, "budget_steps": 100000})
    for step in (10000, 30000, 60000):
        model.training_hook(step, None)
    assert model.res_final_budget == 32 and model.field.resolution == 32


def test_size_auto_explains_the_rule_and_stops_at_the_pixel_footprint():
    # Pixel-fine texture assumed (no images): the grid is at the footprint already, so it stays there.
    opts, reasons = auto_size("vmgrid", BOX, 300.0, 96, 96, 4.0, None)
    assert opts["res_final"] == opts["res_budget_max"] == 152  # 150 footprints -> 152
    assert any("final grid 152 cells per axis whatever the budget" in r for r in reasons)
    # Coarse texture: 5-minute size at half the footprint (80 of 160 cells); a long run may reach 160.
    opts, reasons = method_class("vmgrid").size_options(80.0, 1.0, 0.0)
    assert (opts["res_final"], opts["res_budget_max"]) == (80, 160)
    assert any("final grid follows the budget: 80 cells per axis for runs of up to 8000 steps" in r for r in reasons)
