"""Scene contraction: the warp, the sampler that runs past the box, and a contracted vmgrid."""
from __future__ import annotations

import pytest
import torch

from nerf_core.methods.registry import build_model
from nerf_core.volume.contraction import outer_box, squeeze_into_outer_box
from nerf_core.volume.sampling import contracted_samples

BOX = torch.tensor([[-1.0, -2.0, 0.0], [1.0, 2.0, 2.0]])  # centre (0, 0, 1), half-size (1, 2, 1)


def test_the_box_is_unwarped_and_the_world_fills_a_shell_of_the_same_thickness():
    inside = torch.tensor([[0.9, -1.9, 0.1], [1.0, 2.0, 2.0], [0.0, 0.0, 1.0]])  # a corner included
    assert torch.allclose(squeeze_into_outer_box(inside, BOX), inside)
    # Along +x at max-norm distance r (box half-sizes): 2 - 1/r half-sizes from the centre.
    for r in (1.5, 4.0, 100.0):
        p = torch.tensor([[r * 1.0, 0.0, 1.0]])
        assert squeeze_into_outer_box(p, BOX)[0, 0].item() == pytest.approx(2.0 - 1.0 / r)
    far = torch.tensor([[1e6, -3e6, 5e5], [-1e9, 0.0, 0.0]])
    c = squeeze_into_outer_box(far, BOX)
    ob = outer_box(BOX)
    assert ((c >= ob[0] - 1e-4) & (c <= ob[1] + 1e-4)).all()
    assert torch.allclose(ob, torch.tensor([[-2.0, -4.0, -1.0], [2.0, 4.0, 3.0]]))


def test_contraction_is_monotonic_along_a_ray():
    t = torch.linspace(0, 500, 2000)
    pts = torch.tensor([0.0, 0.0, 1.0]) + t[:, None] * torch.tensor([0.6, 0.3, 0.74])
    x = squeeze_into_outer_box(pts, BOX)[:, 0]
    assert torch.all(x[1:] >= x[:-1])


def test_samples_step_evenly_in_the_box_then_evenly_in_disparity_beyond_it():
    o = torch.tensor([[0.0, 0.0, 1.0]])  # a camera at the box centre, looking along +x
    d = torch.tensor([[1.0, 0.0, 0.0]])
    t0, t1, idx = contracted_samples(
        o,
        d,
        torch.zeros(1),
        BOX,
        step_size=0.1,
        occupied_fn=lambda p: torch.ones(len(p), dtype=torch.bool),
        jitter=False,
    )
    assert torch.all(idx == 0) and torch.all(t1 > t0)
    assert torch.allclose(t1[:-1], t0[1:], atol=1e-5)  # the intervals tile the ray: no gap, no overlap
    inner = t1 <= 1.0 + 1e-6
    assert torch.allclose(t1[inner] - t0[inner], torch.full_like(t0[inner], 0.1), atol=1e-5)
    outer = ~inner
    disparity = 1.0 / t0[outer]
    steps = disparity[:-1] - disparity[1:]
    assert torch.allclose(steps, steps[0].expand_as(steps), rtol=1e-3)  # uniform in 1 / distance
    assert t0[outer][0].item() == pytest.approx(1.0)  # the outer part starts where the ray leaves the box
    assert t1[-1].item() > 10.0  # and runs far past the box
    # In contracted space the outer samples are about as far apart as the inner ones (0.1 here).
    mids = squeeze_into_outer_box(o + d * (0.5 * (t0 + t1))[:, None], BOX)[:, 0]
    gaps = mids[outer][1:] - mids[outer][:-1]
    assert float(gaps.max()) < 0.2


def test_a_contracted_vmgrid_renders_the_world_beyond_the_box_and_trains():
    torch.manual_seed(0)
    model = build_model("vmgrid", BOX, unbounded=True, res_init=16, res_final=16, upsample_at=[],
                        environment={"width": 32, "levels": 2})
    assert torch.allclose(model.field.aabb, outer_box(BOX))
    o = torch.tensor([[0.0, -10.0, 1.0]]).repeat(64, 1)
    d = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    near, far = model.ray_interval(o, d, 0.1, 5.0)
    assert torch.all(near == 0.1) and torch.isinf(far).all()  # no box clipping: the whole ray
    bg = model.background(d, torch.ones(3))
    out = model.render_rays(o, d, near, far, bg, training=True)
    assert out["n_samples"] > 0 and torch.isfinite(out["rgb"]).all()
    loss = (out["rgb"] - 0.3).square().mean() + out.get("aux_loss", 0.0)
    loss.backward()
    assert model.field.density_planes_cl.grad is not None and model.field.density_planes_cl.grad.abs().sum() > 0


def test_a_method_without_contraction_says_so(tmp_path, dataset_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train
    from nerf_core.errors import TrainError

    ds = dataset_factory(tmp_path / "ds", depth=False)
    with pytest.raises(TrainError, match="unbounded"):
        train(TrainConfig(dataset=str(ds), out=str(tmp_path / "run"), method="nerf", max_steps=1,
                          options={"unbounded": True}, stdout_events=False, show_bar=False))


def test_a_checkpoint_written_with_the_old_option_name_contract_loads_unbounded():
    # Checkpoints from before the rename say ``contract``; they must rebuild the same (contracted) model.
    from nerf_core.runs.checkpoints import model_from_checkpoint

    model = build_model("vmgrid", BOX, unbounded=True, res_init=16, res_final=16, upsample_at=[])
    options = {("contract" if k == "unbounded" else k): v for k, v in model.options.items()}
    assert options["contract"] is True and "unbounded" not in options
    ckpt = {"format": 1, "method": "vmgrid", "options": options, "aabb": BOX,
            "model": {k: v.detach().clone() for k, v in model.state_dict().items()}}
    loaded = model_from_checkpoint(ckpt, torch.device("cpu"))
    assert loaded.contracted and loaded.options["unbounded"] is True and "contract" not in loaded.options
    assert torch.allclose(loaded.field.aabb, outer_box(BOX))


def test_the_old_and_new_option_names_must_agree():
    from nerf_core.methods.registry import current_option_names

    assert current_option_names({"contract": False, "seed": 3}) == {"unbounded": False, "seed": 3}
    assert current_option_names({"contract": True, "unbounded": True}) == {"unbounded": True}
    with pytest.raises(ValueError, match="'contract' is the old name of 'unbounded'"):
        current_option_names({"contract": True, "unbounded": False})
