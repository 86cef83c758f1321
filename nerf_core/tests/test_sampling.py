"""Ray/box intersection by hand, stratified and importance sampling, occupancy-restricted marching."""
import pytest
import torch

from nerf_core.volume import sampling

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def test_aabb_hit_from_outside_inside_miss_and_parallel():
    o = torch.tensor([[0.0, 0, 5], [0.0, 0, 0], [3.0, 3, 5], [0.5, 0, 5], [2.0, 0, 5], [0, 0, 5]])
    d = torch.tensor([[0.0, 0, -1], [1.0, 0, 0], [0.0, 0, -1], [0.0, 0, -1], [0.0, 0, -1], [0, 0, 1]])
    near, far, hit = sampling.ray_aabb_intersect(o, d, BOX)
    assert hit.tolist() == [True, True, False, True, False, False]
    # Straight down the axis: enters at z=1 (t=4), leaves at z=-1 (t=6).
    assert (near[0].item(), far[0].item()) == pytest.approx((4.0, 6.0))
    # Starting inside: near clamps to 0, far is the exit at x=1.
    assert (near[1].item(), far[1].item()) == pytest.approx((0.0, 1.0))
    # Parallel to the x and y slabs and inside them: hits; parallel and outside (x=2): misses.
    assert (near[3].item(), far[3].item()) == pytest.approx((4.0, 6.0))
    # Pointing away from the box (behind the origin) is a miss.
    assert not hit[5]


def test_aabb_diagonal_ray():
    o = torch.tensor([[-3.0, -3.0, -3.0]])
    d = torch.nn.functional.normalize(torch.tensor([[1.0, 1.0, 1.0]]), dim=-1)
    near, far, hit = sampling.ray_aabb_intersect(o, d, BOX)
    s3 = 3 ** 0.5
    assert hit.item() and near.item() == pytest.approx(2 * s3) and far.item() == pytest.approx(4 * s3)


def test_stratified_samples_tile_the_interval():
    near, far = torch.tensor([1.0, 2.0]), torch.tensor([3.0, 6.0])
    for jitter in (False, True):
        e = sampling.stratified_samples(near, far, 16, jitter=jitter, generator=torch.Generator().manual_seed(0))
        assert e.shape == (2, 17)
        assert torch.allclose(e[:, 0], near) and torch.allclose(e[:, -1], far)
        assert torch.all(e[:, 1:] >= e[:, :-1])
    uniform = sampling.stratified_samples(near, far, 4, jitter=False)
    assert torch.allclose(uniform[0], torch.tensor([1.0, 1.5, 2.0, 2.5, 3.0]))


def test_importance_sampling_concentrates_where_weights_are():
    edges = torch.linspace(0, 10, 11).expand(3, -1)
    w = torch.zeros(3, 10)
    w[:, 6] = 1.0  # all weight in bin [6, 7]
    for det in (True, False):
        t = sampling.importance_samples(edges, w, 64, deterministic=det, generator=torch.Generator().manual_seed(0))
        assert t.shape == (3, 64) and torch.all(t[:, 1:] >= t[:, :-1])
        inside = ((t >= 6) & (t <= 7)).float().mean().item()
        assert inside > 0.95, inside
    # Two equal peaks get about half of the samples each.
    w2 = torch.zeros(1, 10)
    w2[0, 1] = w2[0, 8] = 1.0
    t = sampling.importance_samples(edges[:1], w2, 100, deterministic=True)
    assert abs(((t >= 1) & (t <= 2)).sum().item() - 50) <= 2


def test_importance_sampling_with_zero_weights_is_uniform():
    edges = torch.linspace(0, 1, 5).expand(1, -1)
    t = sampling.importance_samples(edges, torch.zeros(1, 4), 8, deterministic=True)
    assert torch.allclose(t, (torch.arange(8) + 0.5) / 8, atol=1e-3)


def test_occupied_samples_skip_empty_space():
    o = torch.tensor([[0.0, 0, 5], [0.5, 0.5, 5]])
    d = torch.tensor([[0.0, 0, -1], [0.0, 0, -1]])
    near, far, _ = sampling.ray_aabb_intersect(o, d, BOX)
    only_upper_half = lambda p: p[:, 2] > 0  # noqa: E731
    t0, t1, ridx = sampling.occupied_samples(o, d, near, far, 0.1, only_upper_half, jitter=False)
    mids = 0.5 * (t0 + t1)
    # Each ray crosses z in (0, 1] -> t in [4, 5): 10 samples each, none below z = 0.
    assert ridx.tolist() == [0] * 10 + [1] * 10
    assert torch.all(mids < 5.0) and torch.all(t0 >= 4.0 - 1e-6)
    assert torch.all(t1 - t0 <= 0.1 + 1e-6)
    none = sampling.occupied_samples(
        o, d, near, far, 0.1, lambda p: torch.zeros(p.shape[0], dtype=torch.bool), jitter=True
    )
    assert none[2].numel() == 0
