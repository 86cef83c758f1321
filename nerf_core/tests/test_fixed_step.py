"""The fixed-shape training step (issue 55, part 3): compactions into buffers of a size the host chose
(``volume.padded``), the sizes and rays that follow the budget (``methods.sample_budget``), and
vmgrid's ``sample_budget`` render against the packed one."""
from __future__ import annotations


import pytest
import torch

from nerf_core.methods.registry import build_model
from nerf_core.methods.sample_budget import SampleBudget
from nerf_core.volume import padded, sampling
from nerf_core.volume.occupancy import OccupancyGrid

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def test_compact_keeps_the_true_positions_in_order_then_repeats_the_last_position():
    mask = torch.tensor([False, True, False, True, True, False])
    pos, pad, count = padded.compact(mask, 5)
    assert pos.tolist() == [1, 3, 4, 5, 5]
    assert pad.tolist() == [False, False, False, True, True]
    assert int(count) == 3
    pos, pad, count = padded.compact(mask, 2)  # overflow: the first two, and the count says 3 wanted
    assert pos.tolist() == [1, 3] and pad.tolist() == [False, False] and int(count) == 3


def test_the_rays_that_fit_are_those_whose_running_total_stays_within_the_buffer():
    assert padded.fitting_rays(torch.tensor([3, 0, 2, 4, 1]), 5).tolist() == [True, True, True, False, False]


def _rays(n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    o = torch.tensor([0.0, 0.0, 4.0]).expand(n, 3) + 0.3 * torch.randn(n, 3, generator=gen)
    target = 0.6 * (torch.rand(n, 3, generator=gen) - 0.5)
    d = torch.nn.functional.normalize(target - o, dim=-1)
    near, far, _ = sampling.ray_aabb_intersect(o, d, BOX)
    return o, d, near, far


def _grid():
    grid = OccupancyGrid(BOX, 16)
    centre = grid.cell_centers(jitter=False).norm(dim=-1) < 0.5  # a ball of occupied cells
    grid.binary.copy_(centre.reshape(16, 16, 16))
    return grid


@pytest.mark.parametrize("probe", [False, True])
def test_padded_samples_are_the_packed_samples_then_empty_intervals_on_the_last_ray(probe):
    o, d, near, far = _rays(24)
    grid, step = _grid(), 0.02
    reach = grid.near_reach() if probe else 0.0
    torch.manual_seed(1)
    t0, t1, ridx = sampling.occupied_samples(o, d, near, far, step, grid.query, jitter=True, max_samples=4096,
                                             near_fn=grid.query_near if probe else None, near_reach=reach)
    torch.manual_seed(1)  # the same jitter
    n_steps = padded.steps_for_box(BOX, step, 4096)
    k = t0.numel() + 37
    s = padded.occupied_samples_padded(o, d, near, far, step, n_steps, grid.query, k, jitter=True,
                                       near_fn=grid.query_near if probe else None, near_reach=reach,
                                       run_size=24 * n_steps if probe else 0)
    m = t0.numel()
    assert m > 100 and int(s.count) == m and bool(s.fits.all())
    assert torch.allclose(s.t_starts[:m], t0, atol=1e-6) and torch.allclose(s.t_ends[:m], t1, atol=1e-6)
    assert torch.equal(s.ray_indices[:m], ridx)
    assert s.padding.tolist() == [False] * m + [True] * 37
    assert torch.equal(s.t_starts[m:], s.t_ends[m:])  # padding weighs nothing
    assert bool((s.ray_indices[m:] == s.ray_indices[m - 1:].max()).all())  # and stays sorted
    assert bool((s.ray_indices[1:] >= s.ray_indices[:-1]).all())


def test_a_small_buffer_keeps_the_first_rays_whole_and_says_which_rays_were_cut():
    o, d, near, far = _rays(24)
    grid, step = _grid(), 0.02
    n_steps = padded.steps_for_box(BOX, step, 4096)
    torch.manual_seed(1)
    full = padded.occupied_samples_padded(o, d, near, far, step, n_steps, grid.query, 20000, jitter=True)
    per_ray = torch.bincount(full.ray_indices[~full.padding], minlength=24)
    size = int(per_ray.sum()) // 2
    torch.manual_seed(1)
    cut = padded.occupied_samples_padded(o, d, near, far, step, n_steps, grid.query, size, jitter=True)
    want = (per_ray.cumsum(0) <= size)
    assert torch.equal(cut.fits, want) and 0 < int(want.sum()) < 24
    whole = int(per_ray[want].sum())  # the rays that fit have every sample, equal to the full buffer's
    assert torch.equal(cut.t_starts[:whole], full.t_starts[:whole])


def test_the_budget_sizes_its_buffers_from_what_a_ray_wanted_with_a_margin_and_fills_the_samples():
    b = SampleBudget(samples=65536, max_rays=8192, steps_per_ray=100, steps_per_run=10)
    # a full grid: every ray takes every step, so 65536 / (1.25 * 100) = 524 -> 512 rays, whose
    # visible samples get 1.25 * 100 * 512 = 64000 places
    assert b.rays == 512 and b.visible == 64000 and b.coloured == 64000
    b.observe(512, torch.tensor(512 * 16), torch.tensor(512 * 4), torch.tensor(512 * 12), torch.tensor(512 * 6))
    b.observe(512, torch.tensor(512 * 20), torch.tensor(512 * 3), torch.tensor(512 * 10), torch.tensor(512 * 5))
    b.adapt()  # the most per ray: 20 samples, 4 runs, 12 visible, 6 coloured
    assert b.rays == 2560  # 65536 / (1.25 * 20) = 2621 -> a multiple of 64 below
    assert b.runs == 12800  # 1.25 * 4 * 2560 = 12800, a multiple of 256
    assert b.visible == 38400 and b.coloured == 19200
    b.rescale(2.0)  # the step halved right after a read: the read sizes double at once
    assert b.rays == 1280  # 65536 / (1.25 * 40) = 1310 -> 1280
    assert b.runs == 12800 and b.visible == 38400 and b.coloured == 19200  # 1.25 * (8, 24, 12) * 1280
    b.adapt()  # nothing observed since the read: the sizes stay
    assert b.rays == 1280
    b.observe(1280, torch.tensor(1280 * 40), torch.tensor(1280 * 8), torch.tensor(1280 * 24), torch.tensor(1280 * 12))
    b.rescale(2.0)  # halved again: the observed maxima, measured at the old step, double with the sizes
    assert b.rays == 640
    b.adapt()  # the observed 40 samples a ray, doubled to 80: 65536 / (1.25 * 80) = 655 -> 640
    assert b.rays == 640 and b.runs == 12800


def _model(**options):
    return build_model("vmgrid", BOX, res_init=16, res_final=16, density_rank=4, app_rank=4, app_dim=8,
                       mlp_width=16, upsample_at=[], **options)


def test_vmgrid_fixed_render_equals_the_packed_render_when_the_buffers_hold_every_sample():
    torch.manual_seed(0)
    ref = _model()
    fixed = _model(sample_budget=1 << 16)
    fixed.load_state_dict(ref.state_dict())
    for m in (ref, fixed):  # a formed, half-pruned grid: the fine step, probing in runs, early termination
        with torch.no_grad():
            m.field.density_planes_cl.add_(0.5)
        m.update_occupancy()
    assert fixed.rays_per_step(64) >= 64 and fixed.budget is not None
    fixed.budget.visible = fixed.budget.coloured = fixed.budget.samples  # room for everything
    fixed.budget.runs = 1 << 16
    o, d, near, far = _rays(64, seed=3)
    bg = torch.rand(64, 3)
    outs = []
    for m in (ref, fixed):
        torch.manual_seed(5)
        out = m.render_rays(o, d, near, far, bg, training=True)
        (out["rgb"].sum() + out["depth"].sum()).backward()
        outs.append((out, m.field.density_planes_cl.grad.clone()))
    (a, ga), (b, gb) = outs
    assert bool(b["fits"].all())
    for key in ("rgb", "acc", "depth"):
        assert torch.allclose(a[key], b[key], atol=1e-5), key
    assert torch.allclose(ga, gb, atol=1e-5)


def test_training_with_a_sample_budget_adapts_the_rays_and_learns(sphere_dataset, tmp_path):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    rays = []
    original = SampleBudget.adapt

    def adapt(self):
        original(self)
        rays.append(self.rays)

    SampleBudget.adapt = adapt
    try:
        summary = train(TrainConfig(dataset=str(sphere_dataset), out=str(tmp_path / "run"), max_steps=80,
                                    batch_rays=128, seed=0,
                                    options={"sample_budget": 4096, "res_init": 24, "res_final": 32},
                                    stdout_events=False, show_bar=False, eval_views=0))
    finally:
        SampleBudget.adapt = original
    assert summary["step"] == 80 and summary["loss"] < 0.05
    assert len(rays) >= 3 and len(set(rays)) > 1  # the rays per step followed what a ray cost
    assert all(64 <= r <= 4 * 128 for r in rays)


def test_padding_in_the_coloured_positions_adds_no_colour():
    from nerf_core.volume import marching

    weights = torch.tensor([0.5, 0.25])
    ridx = torch.tensor([0, 0])
    rgb = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])  # the last row repeats sample 1
    out = marching.composite(weights, ridx, torch.tensor([0.0, 1.0]), torch.tensor([1.0, 2.0]), 1,
                             torch.zeros(3), rgb, coloured=torch.tensor([0, 1, 1]),
                             coloured_pad=torch.tensor([False, False, True]))
    assert out["rgb"].tolist() == [[0.5, 0.25, 0.0]]  # not 0.5 green: the repeat weighs nothing


def test_a_steady_fixed_shape_step_reads_nothing_back_from_the_device():
    """The render, loss and backward of a sample_budget step make no data-dependent shape and no host
    read (``nonzero``, ``item``, ``float(t)``, ``bool(t)``, ``bincount``): what lets a GPU queue the
    step whole. The packed step makes several (the control)."""
    from torch.utils._python_dispatch import TorchDispatchMode

    reads = {"aten.nonzero.default", "aten._local_scalar_dense.default", "aten.is_nonzero.default",
             "aten.masked_select.default", "aten.item.default", "aten.bincount.default", "aten.unique.default"}

    class Count(TorchDispatchMode):
        def __init__(self):
            super().__init__()
            self.seen = []

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if str(func) in reads:
                self.seen.append(str(func))
            return func(*args, **(kwargs or {}))

    o, d, near, far = _rays(64, seed=3)
    bg, target = torch.rand(64, 3), torch.rand(64, 3)
    counts = {}
    for budget in (0, 1 << 14):
        torch.manual_seed(0)
        m = _model(sample_budget=budget)
        with torch.no_grad():
            m.field.density_planes_cl.add_(0.5)
        m.update_occupancy()
        for _ in range(70):  # past the near-camera gate's first checks (it reads on periodic steps only then)
            m.rays_per_step(64)
            m.render_rays(o, d, near, far, bg, training=True)
        m.rays_per_step(64)
        with Count() as seen:
            out = m.render_rays(o, d, near, far, bg, training=True)
            loss, _ = m.loss(out, target, None)
            loss.backward()
        counts[budget] = seen.seen
    assert counts[1 << 14] == [], counts[1 << 14]
    assert len(counts[0]) >= 3  # the packed step's compactions: what the control shows the count can see


def test_every_loss_term_leaves_out_the_rays_a_fixed_step_cut():
    from nerf_core.methods.base import ray_weights

    out = {"rgb": torch.zeros(3, 3), "fits": torch.tensor([True, False, True])}
    assert ray_weights(out, None).tolist() == [1.0, 0.0, 1.0]
    assert ray_weights(out, torch.tensor([0.5, 2.0, 3.0])).tolist() == [0.5, 0.0, 3.0]
    assert ray_weights({"rgb": torch.zeros(3, 3)}, None) is None  # the packed step: nothing to leave out
