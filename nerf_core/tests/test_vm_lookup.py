"""The read-only lookup tables of the VM field (``fields.vm_lookup``) give the field's own values."""
import math

import pytest
import torch

from nerf_core.fields.tensorf import TensorVMField
from nerf_core.fields.vm_lookup import VMLookup, dense_density

BOX = torch.tensor([[-1.0, -0.5, 0.0], [1.5, 0.5, 3.0]])  # non-cubic: each axis has its own cell size


def _field(res=12):
    f = TensorVMField(BOX, resolution=res, density_rank=4, app_rank=6, app_dim=9, mlp_width=16, view_freqs=2,
                      density_shift=0.0, init_scale=0.5, seed=3)
    with torch.no_grad():  # colours spread over [0, 1] rather than all near 0.5
        f.mlp[-1].weight.mul_(30.0)
    return f


def _points(m=3000, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = BOX[0] + torch.rand(m, 3, generator=g) * (BOX[1] - BOX[0])
    # The box's faces, edges and corners too, where the last cell's upper corner is read.
    corners = torch.stack(torch.meshgrid(*[b for b in BOX.t()], indexing="ij"), dim=-1).reshape(-1, 3)
    faces = x[:50].clone()
    faces[:, 0] = BOX[1, 0]
    return torch.cat([x, corners, faces])


@pytest.mark.parametrize("dense", [True, False])
def test_lookup_density_and_colour_equal_the_field(dense):
    f = _field()
    x = _points()
    d = torch.nn.functional.normalize(torch.randn(x.shape[0], 3, generator=torch.Generator().manual_seed(1)), dim=-1)
    lk = VMLookup(f, dense_max_cells=f.resolution ** 3 if dense else 0)
    assert (lk.density_volume is not None) == dense
    with torch.no_grad():
        ref_s, ref_c = f.density(x), f.color(x, d)
        s, c = lk.density(x), lk.color(x, d)
    assert ref_s.std() > 0.1 and ref_c.std() > 0.1  # a field whose values vary over the box
    assert torch.allclose(s, ref_s, rtol=1e-4, atol=1e-5)
    assert torch.allclose(c, ref_c, rtol=1e-5, atol=1e-6)
    assert lk.density(x[:0]).shape == (0,) and lk.color(x[:0], d[:0]).shape == (0, 3)


def test_dense_density_is_the_sum_of_plane_line_products_at_the_nodes():
    f = _field(res=5)
    vol = dense_density(f.density_planes, f.density_lines)  # [z, y, x]
    i, j, k = 1, 3, 4
    p, l_ = f.density_planes.detach(), f.density_lines.detach()[..., 0]
    # Plane k's rows are its second axis: plane (x, y) [y, x], (x, z) [z, x], (y, z) [z, y].
    by_hand = (p[0, :, j, i] * l_[0, :, k]).sum() + (p[1, :, k, i] * l_[1, :, j]).sum() \
        + (p[2, :, k, j] * l_[2, :, i]).sum()
    assert torch.allclose(vol[k, j, i], by_hand, atol=1e-6)


def test_lookup_is_cached_until_a_grid_changes():
    f = _field()
    lk = f.lookup()
    assert f.lookup() is lk  # unchanged weights: no rebuild per render call
    x = _points(200)
    opt = torch.optim.Adam(f.grid_parameters(), lr=0.1)
    f.density(x).sum().backward()
    opt.step()  # in place: the version counters move
    lk2 = f.lookup()
    assert lk2 is not lk
    with torch.no_grad():
        assert torch.allclose(lk2.density(x), f.density(x), rtol=1e-4, atol=1e-5)
        assert not torch.allclose(lk.density(x), f.density(x), rtol=1e-4, atol=1e-5)  # the old tables are stale
    f.upsample(17)  # new Parameters
    lk3 = f.lookup()
    assert lk3 is not lk2 and lk3.n == 17
    with torch.no_grad():
        assert torch.allclose(lk3.density(x), f.density(x), rtol=1e-4, atol=1e-5)
    state = {k: v + 0.1 if k == "app_planes_cl" else v for k, v in f.state_dict().items()}
    f.load_state_dict(state)  # copied in place
    assert f.lookup() is not lk3
    assert "_lookup" not in "".join(f.state_dict())  # never saved in checkpoints


@pytest.mark.parametrize("fused", [True, False])
def test_an_optimiser_step_makes_the_tables_stale_even_without_a_version_bump(fused):
    # The trainer's Adam is fused (nerf_core.engine.optim), and a fused step writes the weights without moving
    # their version counters: the tables must still follow, or previews and evaluations during
    # training render old grids.
    f = _field()
    x = _points(200)
    opt = torch.optim.Adam(f.grid_parameters(), lr=0.1, fused=fused)
    lk = f.lookup()
    versions = [p._version for p in f.grid_parameters()]
    f.density(x).sum().backward()
    opt.step()
    if fused:
        assert [p._version for p in f.grid_parameters()] == versions  # what made the cache stale
    lk2 = f.lookup()
    assert lk2 is not lk
    with torch.no_grad():
        assert torch.allclose(lk2.density(x), f.density(x), rtol=1e-4, atol=1e-5)
    assert f.lookup() is lk2  # and cached again until the next step


def test_density_cell_max_bounds_every_point_of_each_cell_and_is_reached():
    f = _field(res=13)  # field nodes that do not line up with the cells
    cells = 5
    cm = f.density_cell_max(cells)
    assert cm.shape == (cells, cells, cells)
    g = torch.Generator().manual_seed(2)
    ijk = torch.stack(torch.meshgrid(*[torch.arange(cells)] * 3, indexing="ij"), dim=-1).reshape(-1, 3)
    best = torch.zeros(cells ** 3)
    with torch.no_grad():
        for _ in range(200):  # many random points per cell, corners and faces included by chance
            u = (ijk + torch.rand(ijk.shape, generator=g)) / cells
            s = f.density(BOX[0] + u * (BOX[1] - BOX[0]))
            assert (s <= cm.reshape(-1) * (1 + 1e-5) + 1e-5).all()  # never above the cell's maximum
            best = torch.maximum(best, s)
    # ... and it is the largest density at the field's nodes of the field cells that each cell overlaps
    # (where trilinear interpolation has its extremes), worked out here node by node.
    n = f.resolution
    node = torch.stack(torch.meshgrid(*[torch.arange(n)] * 3, indexing="ij"), dim=-1).reshape(-1, 3)
    with torch.no_grad():
        s_node = f.density(BOX[0] + node / (n - 1) * (BOX[1] - BOX[0])).reshape(n, n, n)
    for c in ijk.tolist():
        lo = [(k * (n - 1)) // cells for k in c]
        hi = [math.ceil((k + 1) * (n - 1) / cells) for k in c]
        by_hand = s_node[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1].max()
        assert torch.allclose(cm[tuple(c)], by_hand, rtol=1e-4), c
    assert (best / cm.reshape(-1)).median() > 0.5  # a bound random points in the cell come near


def test_vmgrid_occupancy_from_cell_maxima():
    from nerf_core.methods.registry import build_model

    with pytest.raises(ValueError, match="occ_probe"):
        build_model("vmgrid", BOX, occ_probe="corners")
    model = build_model("vmgrid", BOX, res_init=12, occ_res=8, occ_probe="max", occ_decay=0.0, occ_dilate_formed=False)
    with torch.no_grad():
        model.field.density_planes.zero_()
        model.field.density_lines.zero_()
        model.field.density_planes[0, 0, 5, 3] = 200.0  # one bump in plane (x, y) ...
        model.field.density_lines[0, 0, 7, 0] = 1.0  # ... times one node of line z
    model.update_occupancy()  # the first update dilates (nothing formed yet)
    model.update_occupancy()
    assert model.formed()
    # Density rises above the floor only within one field cell of node (x, y, z) = (3, 5, 7) of 11
    # cells: the occupancy cells (of 8) that overlap (2/11, 4/11) x (4/11, 6/11) x (6/11, 8/11).
    expected = torch.zeros(8, 8, 8, dtype=torch.bool)
    expected[1:3, 2:5, 4:6] = True
    assert torch.equal(model.occupancy.binary, expected)


def test_a_field_with_cached_tables_pickles_and_its_copy_rebuilds_them():
    import copy
    import io

    f = _field()
    x = _points(100)
    lk = f.lookup()
    buf = io.BytesIO()
    torch.save(f, buf)  # a whole module, as some users save models; the cache holds weak references
    buf.seek(0)
    g = torch.load(buf, weights_only=False)
    assert g._lookup.empty and f.lookup() is lk  # the original keeps its tables
    h = copy.deepcopy(f)
    with torch.no_grad():
        for other in (g, h):
            assert other.lookup() is not lk
            assert torch.allclose(other.lookup().density(x), f.density(x), rtol=1e-4, atol=1e-5)
