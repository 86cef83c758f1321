"""--size auto: a flat-coloured cube gets a smaller model than a high-frequency texture, and the
pixel footprint is taken at the box's nearest point to the cameras."""
import pytest
import torch

from nerf_core.methods import build_model
from nerf_core.sizing import auto_size, detail_score, nearest_box_distance

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
        flat_m = build_model(method, BOX, **{**flat_opts, "resolution": flat_opts["res_final"]})
        tex_m = build_model(method, BOX, **{**tex_opts, "resolution": tex_opts["res_final"]})
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


def test_nearest_box_distance_hand_computed():
    origins = torch.tensor([[4.0, 0.0, 0.0], [0.0, 0.0, -6.0], [3.0, 4.0, 1.0], [0.0, 0.5, 0.0]])
    # Distances to the box [-1, 1]^3: 3, 5, |(2, 3, 0)| = sqrt(13), and 0 (inside: floored to 0.05 * 2).
    assert nearest_box_distance(origins, BOX) == pytest.approx(3.0)  # torch's median of 0.1, 3, 3.606, 5: the lower middle
    assert nearest_box_distance(origins[:3], BOX) == pytest.approx(13 ** 0.5)
    assert nearest_box_distance(origins[3:], BOX) == pytest.approx(0.1)
