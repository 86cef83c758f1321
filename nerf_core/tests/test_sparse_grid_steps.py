"""The sparse grid step (issue 55, part 2): the cells a batch touched (``fields.vm_touched``), the lazy
Adam over them (``optim.RowSparseAdam``) and vmgrid's ``grid_optimizer=sparse``."""
from __future__ import annotations

import pytest
import torch

from nerf_core.fields.tensorf import TensorVMField
from nerf_core.fields.vm_touched import TouchedRows
from nerf_core.methods.registry import build_model
from nerf_core.optim import RowSparseAdam

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


@pytest.mark.parametrize("native", ["1", "0"])
def test_the_touched_cells_are_exactly_where_the_lookups_wrote_gradient(monkeypatch, native):
    monkeypatch.setenv("NERF_CORE_NATIVE", native)  # the native kernel and grid_sample agree on the taps
    field = TensorVMField(BOX, resolution=12, density_rank=3, app_rank=2, app_dim=4, mlp_width=8)
    field.touched = TouchedRows()
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(40, 3, generator=gen) * 2.2 - 1.1  # some points outside the box: taps that weigh 0
    x[0] = torch.tensor([1.0, -1.0, 0.0])  # on the box's faces: the last and the first cell
    (field.density(x) * torch.rand(40, generator=gen)).sum().backward()
    for name, p in (("density_planes_cl", field.density_planes_cl), ("density_lines_cl", field.density_lines_cl)):
        written = (p.grad.reshape(-1, p.shape[-1]) != 0).any(-1).nonzero().squeeze(-1)
        marked = field.touched.rows(name)
        assert set(written.tolist()) <= set(marked.tolist()), name  # every gradient is stepped
        # and little more: a tap of weight 0 (a coordinate exactly on a node) is all a mark may add
        assert len(marked) <= len(written) + 8, (name, len(marked), len(written))
    assert field.touched.rows("app_planes_cl") is None  # no colour lookup: nothing marked there


def test_without_an_asker_nothing_is_recorded_and_no_grad_lookups_mark_nothing():
    field = TensorVMField(BOX, resolution=8, density_rank=2, app_rank=2, app_dim=4, mlp_width=8)
    field.density(torch.zeros(4, 3))
    assert field.touched is None
    field.touched = TouchedRows()
    with torch.no_grad():
        field.density(torch.zeros(4, 3))
    assert field.touched.rows("density_planes_cl") is None


def test_the_lazy_adam_over_every_row_is_adam_and_leaves_untouched_rows_and_their_moments_frozen():
    torch.manual_seed(0)
    p1 = torch.nn.Parameter(torch.randn(50, 4))
    p2 = torch.nn.Parameter(p1.detach().clone())
    lazy = RowSparseAdam([{"params": [p1], "lr": 1e-2, "row_sparse": True}], eps=1e-15)
    dense = torch.optim.Adam([p2], lr=1e-2, betas=(0.9, 0.99), eps=1e-15)
    for _ in range(5):
        g = torch.randn(50, 4)
        p1.grad, p2.grad = g.clone(), g.clone()
        lazy.step()
        dense.step()
    assert torch.allclose(p1, p2, atol=1e-6, rtol=0)
    before, moments = p1.detach().clone(), lazy.state[p1]["exp_avg"].clone()
    p1.grad = torch.randn(50, 4)
    lazy.step(rows={p1: torch.tensor([3, 7])})
    changed = (p1.detach() != before).any(-1).nonzero().squeeze(-1).tolist()
    assert changed == [3, 7]
    frozen = torch.ones(50, dtype=torch.bool)
    frozen[[3, 7]] = False
    assert torch.equal(lazy.state[p1]["exp_avg"][frozen], moments[frozen])
    assert lazy.state[p1]["row_step"].tolist() == [6.0 if k in (3, 7) else 5.0 for k in range(50)]


def test_a_row_first_seen_late_counts_its_own_steps_with_per_row_bias_and_none_without():
    # Two steps of gradient 1 on row 1 after ten on row 0: corrected, each moves by lr; uncorrected, the
    # second moves by lr * m / sqrt(v) = 0.19 / sqrt(0.0199) = 1.347 lr (beta1 0.9, beta2 0.99).
    for bias, want in (("per_row", 2e-2), ("none", 1e-2 + 1e-2 * 0.19 / 0.0199 ** 0.5)):
        p = torch.nn.Parameter(torch.zeros(4, 2))
        opt = RowSparseAdam([{"params": [p], "lr": 1e-2, "row_sparse": True}], eps=1e-15, bias=bias)
        for _ in range(10):  # row 0 alone
            p.grad = torch.ones(4, 2)
            opt.step(rows={p: torch.tensor([0])})
        for _ in range(2):  # row 1's first two steps
            p.grad = torch.ones(4, 2)
            opt.step(rows={p: torch.tensor([1])})
        assert float(p.detach()[1, 0]) == pytest.approx(-want, rel=1e-4), bias


def test_the_lazy_adams_own_check_takes_its_per_row_counts_and_refuses_wrong_ones():
    from nerf_core.errors import RunError

    p = torch.nn.Parameter(torch.zeros(6, 3))
    opt = RowSparseAdam([{"params": [p], "lr": 1e-2, "row_sparse": True}], eps=1e-15)
    p.grad = torch.ones(6, 3)
    opt.step()
    state = opt.state_dict()
    opt.check_state(state, "ck")
    state["state"][0]["row_step"] = torch.zeros(5)
    with pytest.raises(RunError, match=r"'row_step' of parameter 0 has shape \(5,\); it must be \(6,\)"):
        opt.check_state(state, "ck")


def test_vmgrid_with_the_sparse_optimiser_steps_only_touched_cells_and_trains(sphere_dataset):
    from nerf_core.data.loading import load_dataset

    ds = load_dataset(sphere_dataset)
    tiny_split = ds.split("train")
    model = build_model("vmgrid", ds.aabb, res_init=48, res_final=48, grid_optimizer="sparse", occ_res=8)
    model.train()
    opt = model.make_optimizer(1e-3)
    assert isinstance(opt, RowSparseAdam)
    batcher = model.make_batcher(tiny_split, "white", torch.Generator().manual_seed(0), torch.device("cpu"))
    losses = []
    for step in range(30):
        model.training_hook(step, step / 30)
        batch = batcher.sample(64)
        before = model.field.app_planes_cl.detach().clone()
        out = model.render_batch(batch.rays_o, batch.rays_d, batch.background, ds.near, ds.far, training=True)
        loss, _ = model.loss(out, batch.target, batch.weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        model.optimizer_step(opt, out)
        losses.append(float(loss))
        moved = (model.field.app_planes_cl.detach() != before).reshape(-1, before.shape[-1]).any(-1)
        marked = model.field.touched.rows("app_planes_cl")
        assert set(moved.nonzero().squeeze(-1).tolist()) <= set(marked.tolist())
    assert moved.float().mean() < 0.9  # a batch touches part of the grid
    assert losses[-1] < losses[0]


def test_the_l1_prior_acts_at_the_stepped_rows_only():
    p = torch.nn.Parameter(torch.tensor([[2.0, -2.0], [3.0, 3.0]]))
    opt = RowSparseAdam([{"params": [p], "lr": 0.1, "row_sparse": True}], eps=1e-15)
    p.grad = torch.zeros(2, 2)  # the rendering's gradient: nothing; the prior pulls towards 0
    opt.step(rows={p: torch.tensor([0])}, l1={p: 0.5})
    assert p.detach().reshape(-1).tolist() == pytest.approx([1.9, -1.9, 3.0, 3.0], abs=1e-6)
