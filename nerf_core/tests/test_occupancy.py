"""Occupancy grid: updates mark occupied cells, marching skips the rest, an emptied grid recovers."""
import pytest
import torch

from nerf_core.volume import sampling
from nerf_core.volume.occupancy import OccupancyGrid

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def ball(p):
    return 50.0 * (p.norm(dim=-1) < 0.4).float()


def test_update_marks_cells_near_density_and_queries_agree():
    g = OccupancyGrid(BOX, resolution=16)
    assert g.binary.all()  # nothing known yet: everything may be occupied
    g.update(ball, step_size=0.02, decay=0.0)
    assert bool(g.query(torch.zeros(1, 3)))
    far_pts = torch.tensor([[0.9, 0.9, 0.9], [-0.9, 0.1, 0.0], [0.0, 0.0, 0.95]])
    assert not g.query(far_pts).any()
    # Points outside the box are never occupied.
    assert not g.query(torch.tensor([[2.0, 0.0, 0.0]])).any()
    # Ball volume fraction ~3.4%, one-cell dilation makes it larger but still a small part of the box.
    assert 0.02 < g.occupied_fraction < 0.3


def test_marching_through_the_grid_only_samples_occupied_cells():
    torch.manual_seed(0)  # the update probes one random point per cell: 62 samples on some draws
    g = OccupancyGrid(BOX, resolution=16)
    g.update(ball, step_size=0.02, decay=0.0)
    o = torch.tensor([[0.0, 0.0, 3.0], [0.9, 0.9, 3.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    near, far, _ = sampling.ray_aabb_intersect(o, d, BOX)
    t0, t1, ridx = sampling.occupied_samples(o, d, near, far, 0.02, g.query, jitter=False)
    assert (ridx == 1).sum() == 0  # the corner ray misses the ball: no samples at all
    n0 = (ridx == 0).sum().item()
    assert 0 < n0 < 100 * 0.6  # the central ray samples only around the ball, not the whole 2-unit box
    z = 3.0 - 0.5 * (t0 + t1)
    assert z.abs().max() < 0.4 + 2 * 2 / 16  # within the ball plus the dilation margin


def test_emptied_grid_recovers_and_ema_remembers():
    g = OccupancyGrid(BOX, resolution=8)
    g.update(ball, step_size=0.02, decay=0.95)
    frac = g.occupied_fraction
    # A collapsed density does not make the grid forget the ball at once (the EMA decays slowly)...
    g.update(lambda p: torch.zeros(p.shape[0]), step_size=0.02, decay=0.95)
    assert g.occupied_fraction == frac
    # ...and a grid whose every cell is below threshold reopens instead of staying empty.
    g.reset()
    g.binary.fill_(False)
    g.update(lambda p: torch.zeros(p.shape[0]), step_size=0.02)
    assert g.binary.all() and g.n_resets == 1


def test_update_without_dilation_keeps_only_cells_that_hold_density():
    dilated, tight = OccupancyGrid(BOX, resolution=16), OccupancyGrid(BOX, resolution=16)
    torch.manual_seed(0)
    dilated.update(ball, step_size=0.02, decay=0.0)
    torch.manual_seed(0)  # the same jittered cell points for both
    tight.update(ball, step_size=0.02, decay=0.0, dilate=False)
    # Exactly the cells whose point fell in the ball; the dilated grid holds them and a one-cell shell.
    centres_in_ball = (tight.cell_centers(jitter=False).norm(dim=-1) < 0.4 - 2 / 16 * 3 ** 0.5).reshape(16, 16, 16)
    assert tight.binary[centres_in_ball].all()
    assert (tight.binary & ~dilated.binary).sum() == 0
    assert dilated.binary.sum() > 1.5 * tight.binary.sum()
    # No occupied cell lies wholly outside the ball: its nearest corner is inside the radius.
    lo = tight.cell_centers(jitter=False) - 1 / 16
    nearest = torch.maximum(lo, torch.minimum(torch.zeros(3), lo + 2 / 16))
    assert (nearest.norm(dim=-1).reshape(16, 16, 16)[tight.binary] < 0.4).all()


def test_marching_with_the_near_probe_gives_the_same_samples_with_fewer_tests():
    """``occupied_samples`` with ``near_fn`` probes runs of steps before testing each step: the output
    must equal testing every step, on a sparse grid with isolated single cells (no dilation, so a run
    can clip a lone cell's corner), non-unit directions, rays starting inside the box, and jitter."""
    box = torch.tensor([[-1.0, -0.5, -2.0], [1.0, 0.5, 2.0]])  # cells of three different sizes
    g = OccupancyGrid(box, resolution=16)
    gen = torch.Generator().manual_seed(0)
    g.binary.copy_(torch.rand(16, 16, 16, generator=gen) < 0.01)
    n = 3000
    o = torch.randn(n, 3, generator=gen) * torch.tensor([2.0, 1.0, 4.0])
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=-1)
    d = d * (0.5 + torch.rand(n, 1, generator=gen))  # not unit: reach is in scene units, t is not
    near, far, _ = sampling.ray_aabb_intersect(o, d, box)
    tested = []

    def counting(fn):
        def count(p):
            tested.append(p.shape[0])
            return fn(p)
        return count

    for jitter in (False, True):
        ref = sampling.occupied_samples(o, d, near, far, 0.01, counting(g.query), jitter=jitter,
                                        generator=torch.Generator().manual_seed(1))
        full = sum(tested)
        tested.clear()
        out = sampling.occupied_samples(o, d, near, far, 0.01, counting(g.query), jitter=jitter,
                                        generator=torch.Generator().manual_seed(1), near_fn=counting(g.query_near),
                                        near_reach=g.near_reach())
        assert ref[2].numel() > 300  # rays do cross occupied cells
        for a, b in zip(ref, out):
            assert torch.equal(a, b)
        assert sum(tested) < 0.5 * full, (sum(tested), full)
        tested.clear()


def test_query_near_sees_the_neighbouring_cells_and_follows_updates():
    g = OccupancyGrid(BOX, resolution=8)
    g.binary.zero_()
    g.binary[4, 4, 4] = True  # cell [0, 0.25)^3
    c = g.cell_size()[0].item()
    inside = torch.tensor([[0.1, 0.1, 0.1]])
    assert g.query_near(inside) and g.query_near(inside - c) and g.query_near(inside + c)
    assert not g.query_near(inside - 2 * c).any() and not g.query_near(inside + 2 * c).any()
    g.binary.zero_()  # an update in place: the cached neighbourhood follows
    assert not g.query_near(inside).any()
    full = torch.ones_like(g.binary)
    g.binary = full  # a replaced mask (as a device move does): followed too
    assert g.query_near(inside + 2 * c).all()
    import io

    buf = io.BytesIO()
    torch.save(g, buf)  # the cache (weak reference) is left out of a pickled grid
    buf.seek(0)
    assert torch.load(buf, weights_only=False).query_near(inside + 2 * c).all()


def test_each_point_finds_its_own_cell_by_hand_worked_indices():
    # A 4x2x3-unit box on a 4-cell grid: cells are 1 x 0.5 x 0.75; the flat index is (i * 4 + j) * 4 + k.
    g = OccupancyGrid(torch.tensor([[0.0, -1.0, 0.0], [4.0, 1.0, 3.0]]), resolution=4)
    pts = torch.tensor([
        [0.0, -1.0, 0.0],     # the min corner: cell (0, 0, 0)
        [3.99, 0.99, 2.99],   # just inside the max corner: (3, 3, 3)
        [4.0, 1.0, 3.0],      # on the max corner: inside, in the last cell
        [1.5, -0.2, 1.6],     # (1, 1, 2)
        [2.0, 0.0, 0.75],     # on cell faces: the upper cell (2, 2, 1)
        [-0.01, 0.0, 1.0],    # outside in x: clamped to (0, 2, 1), not inside
        [9.0, -5.0, 1.0],     # far outside: clamped to (3, 0, 1), not inside
    ])
    idx, inside = g._cell_index(pts)
    want = [(0, 0, 0), (3, 3, 3), (3, 3, 3), (1, 1, 2), (2, 2, 1), (0, 2, 1), (3, 0, 1)]
    assert idx.tolist() == [(i * 4 + j) * 4 + k for i, j, k in want]
    assert inside.tolist() == [True, True, True, True, True, False, False]
    g.binary.zero_()
    g.binary[1, 1, 2] = True
    assert g.query(pts).tolist() == [False, False, False, True, False, False, False]
    # Points at infinity or NaN (a contracted ray's end) lie in no cell, and never fail the lookup.
    odd = torch.tensor([[float("nan"), 0.0, 1.0], [float("inf"), 0.0, 1.0], [0.0, -float("inf"), 1.0]])
    g.binary.fill_(True)
    assert not g.query(odd).any() and g.query_near(odd).shape == (3,)


def test_near_reach_is_read_once_per_box_and_follows_a_new_box():
    g = OccupancyGrid(torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 3.0]]), resolution=8)
    assert g.near_reach() == pytest.approx(0.999 * 0.25)  # the smallest cell edge, 2 / 8
    calls = []
    g.cell_size = lambda: calls.append(1) or torch.tensor([9.0, 9.0, 9.0])  # a read would show here
    assert g.near_reach() == pytest.approx(0.999 * 0.25) and not calls  # cached: no read of the device
    g.aabb.mul_(2.0)  # the box changes (in place, as a load or a tightening does)
    assert g.near_reach() == pytest.approx(0.999 * 9.0) and calls == [1]
