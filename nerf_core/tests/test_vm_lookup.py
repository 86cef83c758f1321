"""The read-only lookup tables of the VM field (``fields.vm_lookup``) give the field's own values."""
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
    state = {k: v + 0.1 if k == "app_planes" else v for k, v in f.state_dict().items()}
    f.load_state_dict(state)  # copied in place
    assert f.lookup() is not lk3
    assert "_lookup" not in "".join(f.state_dict())  # never saved in checkpoints
