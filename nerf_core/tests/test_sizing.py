"""--size auto: a flat-coloured cube gets a smaller model than a high-frequency texture, and the
pixel footprint is taken at the box's nearest point to the cameras."""
import pytest
import torch

from nerf_core.methods.registry import build_model
from nerf_core.methods.sizing import auto_size, detail_score, fine_detail_share, nearest_box_distance

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _images(textured: bool, n=6, size=96):
    """A cube-like square on white: two flat-shaded faces, or covered in per-pixel noise."""
    g = torch.Generator().manual_seed(0)
    im = torch.ones(n, size, size, 3)
    a, b, c = size // 4, size // 2 + size // 8, 3 * size // 4
    im[:, a:c, a:b] = torch.tensor([0.8, 0.3, 0.2])
    im[:, a:c, b:c] = torch.tensor([0.6, 0.2, 0.15])
    if textured:
        im[:, a:c, a:c] = torch.rand(n, c - a, c - a, 3, generator=g)
    return im


def test_detail_score_separates_flat_from_textured():
    flat, tex = detail_score(_images(False)), detail_score(_images(True))
    assert flat < 0.1 < 0.5 < tex
    assert detail_score(torch.ones(2, 32, 32, 3)) == 0.0  # nothing but background


@pytest.mark.parametrize("method", ["vmgrid", "nerf"])
def test_flat_cube_gets_a_smaller_model_than_a_texture(method):
    args = (method, BOX, 300.0, 96, 96, 4.0)
    flat_opts, flat_why = auto_size(*args, _images(False))
    tex_opts, tex_why = auto_size(*args, _images(True))
    flat_m, tex_m = build_model(method, BOX, **flat_opts), build_model(method, BOX, **tex_opts)
    if method == "vmgrid":
        # Compare the final (grown) size: that is what training ends with.
        flat_m.field.upsample(flat_opts["res_final"])
        tex_m.field.upsample(tex_opts["res_final"])
    assert flat_m.num_parameters() < 0.6 * tex_m.num_parameters(), (flat_opts, tex_opts)
    assert len(flat_why) >= 3 and any("detail" in r for r in flat_why)


def test_resolution_follows_the_pixel_footprint():
    tex = _images(True)
    near_opts, _ = auto_size("vmgrid", BOX, 300.0, 96, 96, 2.0, tex)  # footprint 2/300: 300 cells
    far_opts, _ = auto_size("vmgrid", BOX, 300.0, 96, 96, 8.0, tex)  # footprint 8/300: 75 cells
    assert far_opts["res_final"] < near_opts["res_final"] <= 320
    assert abs(far_opts["res_final"] - 75) <= 8
    nerf_near, _ = auto_size("nerf", BOX, 300.0, 96, 96, 2.0, tex)
    nerf_far, _ = auto_size("nerf", BOX, 300.0, 96, 96, 8.0, tex)
    assert nerf_far["pos_freqs"] < nerf_near["pos_freqs"]


def test_without_images_full_detail_is_assumed_and_said():
    opts, why = auto_size("vmgrid", BOX, 300.0, 96, 96, 4.0, 12)
    assert (opts["app_rank"], opts["density_rank"]) == (16, 8) and any("no images" in r for r in why)
    with pytest.raises(ValueError, match="fx"):
        auto_size("vmgrid", BOX, 0.0, 96, 96, 4.0, None)
    assert auto_size("something-else", BOX, 300.0, 96, 96, 4.0, None)[0] == {}


def test_alpha_gives_the_object_mask():
    """With alpha, only the pixels it marks as object are probed, whatever the border looks like."""
    im = _images(True)
    square = (im != 1.0).any(-1).float()  # the textured square
    flat = torch.zeros_like(square)
    flat[:, :20, :] = 1.0  # a band of plain white
    assert detail_score(im, alphas=square) == pytest.approx(detail_score(im), abs=0.02)
    assert detail_score(im, alphas=square) > 0.5
    assert detail_score(im, alphas=flat) == 0.0
    assert detail_score(im, alphas=torch.zeros_like(square)) == 0.0


def _checker(period: int, size=96, n=3):
    """A grey square (rows/cols 16..80) carrying a checker of ``period`` pixels, on white, with alpha."""
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    check = (((yy // (period // 2)) + (xx // (period // 2))) % 2).float() * 0.5 + 0.25
    alpha = torch.zeros(size, size)
    alpha[16:80, 16:80] = 1.0
    im = torch.where(alpha.bool(), check, torch.ones(())).unsqueeze(-1).expand(size, size, 3)
    return im.expand(n, -1, -1, -1).clone(), alpha.expand(n, -1, -1).clone()


def test_fine_detail_share_tells_pixel_fine_from_coarse_texture():
    share = lambda im_alpha: fine_detail_share(im_alpha[0], alphas=im_alpha[1])  # noqa: E731
    fine, coarse = share(_checker(2)), share(_checker(16))
    # A 1-pixel checker is all L0 detail (its 2x2 averages are flat grey); 8-pixel squares leave only
    # their edges, about as strong in L1 as in L0.
    assert fine == pytest.approx(1.0, abs=1e-6)
    assert 0.2 < coarse < 0.6
    flat_im, flat_alpha = _checker(2)
    flat_im[:] = 0.5
    assert fine_detail_share(flat_im, alphas=flat_alpha) == 0.0  # no texture at all
    rods = torch.ones(2, 96, 96, 3)
    rods[:, 8:88, 20] = 0.3  # a one-pixel rod: object without interior
    assert fine_detail_share(rods) == 1.0
    assert fine_detail_share(torch.ones(2, 32, 32, 3)) == 0.0  # no object


def test_grid_resolution_follows_the_texture_scale():
    fine_opts, why = auto_size("vmgrid", BOX, 300.0, 96, 96, 8.0, *_checker(2))  # footprint 8/300: 75 cells
    coarse_opts, _ = auto_size("vmgrid", BOX, 300.0, 96, 96, 8.0, *_checker(16))
    assert fine_opts["res_final"] == 72 and coarse_opts["res_final"] < fine_opts["res_final"]
    assert coarse_opts["res_final"] >= 40  # never below half the footprint's resolution (37.5 -> 40)
    assert any("pixel scale" in r for r in why)


def test_nearest_box_distance_hand_computed():
    origins = torch.tensor([[4.0, 0.0, 0.0], [0.0, 0.0, -6.0], [3.0, 4.0, 1.0], [0.0, 0.5, 0.0]])
    # Distances to the box [-1, 1]^3: 3, 5, |(2, 3, 0)| = sqrt(13), and 0 (inside: floored to 0.05 * 2).
    assert nearest_box_distance(origins, BOX) == pytest.approx(
        3.0
    )  # torch's median of 0.1, 3, 3.606, 5: the lower middle
    assert nearest_box_distance(origins[:3], BOX) == pytest.approx(13 ** 0.5)
    assert nearest_box_distance(origins[3:], BOX) == pytest.approx(0.1)
