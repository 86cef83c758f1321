"""The pixel filter (``nerf_core.image.pixel_filter``): its distribution, the dataset field, and rendering
edge pixels as the mean of rays drawn from it."""
import json
import math

import numpy as np
import pytest
import torch

from nerf_core.cameras.rays import Cameras, rays_for_pixels
from nerf_core.cli.main import main
from nerf_core.image import pixel_filter as pf
from nerf_core.methods.base import RadianceModel
from nerf_core.render.frame import render_view


def _variance(filt: pf.PixelFilter) -> float:
    """The filter's variance by quadrature of its weight (the reference the samples must meet)."""
    x = torch.linspace(-filt.width / 2, filt.width / 2, 200001, dtype=torch.float64)
    w = filt.weight(x)
    return float((w * x * x).sum() / w.sum())


@pytest.mark.parametrize("kind,width", [("BLACKMAN_HARRIS", 1.5), ("GAUSSIAN", 1.5), ("BOX", 1.0), ("BOX", 2.0)])
def test_offsets_follow_the_filter(kind, width):
    filt = pf.PixelFilter(kind, width)
    off = filt.offsets(20000, 9, torch.Generator().manual_seed(0))
    assert off.shape == (20000, 9, 2)
    assert float(off.abs().max()) <= width / 2 + 1e-6  # never outside the footprint
    flat = off.reshape(-1, 2).double()
    assert flat.mean(0).abs().max() < 0.01
    # per axis, the variance of the filter itself (a box of width 1 has 1/12)
    np.testing.assert_allclose(flat.var(0).numpy(), [_variance(filt)] * 2, rtol=0.02)
    if kind == "BOX":
        assert _variance(filt) == pytest.approx(width ** 2 / 12, rel=1e-4)


def test_blackman_harris_is_narrower_than_its_width():
    # Blender's default: 1.5 px wide, but its weight is concentrated: the spread of a box of about 0.6 px.
    sd = math.sqrt(_variance(pf.DEFAULT))
    assert 0.15 < sd < 0.25


def test_stratified_offsets_cover_every_cell_once():
    filt = pf.PixelFilter("BOX", 1.0)
    off = filt.offsets(50, 16, torch.Generator().manual_seed(1))  # 4 x 4 cells of a quarter pixel
    cells = torch.floor((off + 0.5) * 4).long()
    keys = cells[..., 0] * 4 + cells[..., 1]
    for row in keys:
        assert sorted(row.tolist()) == list(range(16))


def test_a_downscaled_filter_adds_the_box_of_the_original_pixels():
    base = pf.PixelFilter("BOX", 1.0)
    half = base.downscaled(2)  # 2 x 2 original pixels, each a box of half a new pixel: a box of 1
    assert half.full_resolution() == base
    off = half.offsets(20000, 4, torch.Generator().manual_seed(2)).reshape(-1, 2).double()
    assert float(off.abs().max()) <= 0.5 + 1e-6
    np.testing.assert_allclose(off.var(0).numpy(), [1 / 12] * 2, rtol=0.03)
    assert pf.parse(half.to_json(), "x") == half


def test_the_dataset_field_is_read_and_checked():
    assert pf.parse(None, "t.json") == pf.DEFAULT
    assert pf.parse({"type": "gaussian", "width": 2}, "t.json") == pf.PixelFilter("GAUSSIAN", 2.0)
    assert pf.parse({"type": "NONE"}, "t.json").is_point
    with pytest.raises(ValueError, match=r"t\.json: field 'pixel_filter\.type'"):
        pf.parse({"type": "MITCHELL", "width": 1.5}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: field 'pixel_filter\.width'"):
        pf.parse({"type": "BOX", "width": -1}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: field 'pixel_filter' must be an object"):
        pf.parse("BOX", "t.json")


def test_sub_pixel_rays_pass_through_the_offset_point():
    cams = Cameras.create(np.eye(4)[None], 10.0, 20.0, 4.0, 3.0, 8, 6)
    i, j, v = torch.tensor([1, 5]), torch.tensor([2, 0]), torch.zeros(2, dtype=torch.long)
    off = torch.tensor([[0.25, -0.5], [-0.75, 0.1]])
    _, d, _ = rays_for_pixels(cams, v, i, j, off)
    # pinhole: x = (u - cx) / fx, y = -(v - cy) / fy at u = i + 0.5 + dx, v = j + 0.5 + dy
    u, w = i + 0.5 + off[:, 0], j + 0.5 + off[:, 1]
    want = torch.stack([(u - 4.0) / 10.0, -(w - 3.0) / 20.0, -torch.ones(2)], -1)
    torch.testing.assert_close(d, want / want.norm(dim=-1, keepdim=True))
    # with a distorting lens the offset path and the per-pixel tables agree at offset 0
    from nerf_core.contract.lens import Lens

    lens_cams = Cameras.create(
        np.eye(4)[None], 10.0, 10.0, 4.0, 3.0, 8, 6, lenses=[Lens("OPENCV", (0.1, 0, 0, 0, 0, 0))]
    )
    _, centre, _ = rays_for_pixels(lens_cams, v, i, j)
    _, zero, _ = rays_for_pixels(lens_cams, v, i, j, torch.zeros(2, 2))
    torch.testing.assert_close(zero, centre, atol=1e-6, rtol=0)


class _HalfPlane(RadianceModel):
    """A fake model: opaque white where a ray's camera-space x exceeds ``edge`` (a vertical edge in the
    image), nothing elsewhere."""

    def __init__(self, edge: float):
        super().__init__(torch.tensor([[-10.0, -10, -10], [10, 10, 10]]))
        self.edge = edge

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        x = rays_d[:, 0] / -rays_d[:, 2]
        acc = (x > self.edge).float()
        rgb = acc[:, None] + background * (1 - acc[:, None])
        return {"rgb": rgb, "depth": torch.full_like(acc, 2.0), "acc": acc}


def test_edge_pixels_render_as_the_filters_average():
    # 8 x 4 image, fx = 1: pixel column i spans x in [i - 4, i - 3]. The edge at x = -0.3 lies 0.2 px
    # right of column 3's centre (x = -0.5), so a 1-px box over that pixel covers 0.3 of it.
    cams = Cameras.create(np.eye(4)[None], 1.0, 1.0, 4.0, 2.0, 8, 4)
    model = _HalfPlane(-0.3)
    centre = render_view(model, cams, 0, background=(0.0, 0.0, 0.0))
    assert centre["n_rays"] == 32
    np.testing.assert_array_equal(centre["acc"][0].numpy(), [0, 0, 0, 0, 1, 1, 1, 1])
    boxed = render_view(model, cams, 0, background=(0.0, 0.0, 0.0), pixel_filter=pf.PixelFilter("BOX", 1.0),
                        filter_samples=400)
    # columns 3 and 4 hold the edge in their 3x3 neighbourhood; the box covers column 3 by 0.3 and
    # column 4 fully (20 x 20 strata: within 1/20), and the other columns are centre rays
    np.testing.assert_allclose(boxed["acc"][:, 3].numpy(), [0.3] * 4, atol=0.05)
    np.testing.assert_allclose(
        boxed["acc"][:, [0, 1, 2, 4, 5, 6, 7]].numpy(), centre["acc"][:, [0, 1, 2, 4, 5, 6, 7]].numpy()
    )
    torch.testing.assert_close(boxed["rgb"][..., 0], boxed["acc"])  # white on black: colour follows coverage
    # columns 3 and 4 of every row were refined, after the ring of 2 * 10 + 2 * 4 pixels around the image
    assert boxed["n_rays"] == 32 + 28 + 2 * 4 * 400
    # a depth exactly where the filtered opacity is at least a half: the opacity-weighted mean of the
    # filter rays' z-depth at refined pixels (here within the pixel's own range), the centre ray's elsewhere
    assert torch.equal(boxed["z_depth"] > 0, boxed["acc"] >= 0.5)
    others = [0, 1, 2, 5, 6, 7]
    torch.testing.assert_close(boxed["z_depth"][:, others], centre["z_depth"][:, others])
    torch.testing.assert_close(boxed["z_depth"][:, 4], centre["z_depth"][:, 4], atol=0.15, rtol=0)
    # reproducible: the draws are seeded by the view
    again = render_view(model, cams, 0, background=(0.0, 0.0, 0.0), pixel_filter=pf.PixelFilter("BOX", 1.0),
                        filter_samples=400)
    torch.testing.assert_close(again["rgb"], boxed["rgb"])
    none = render_view(model, cams, 0, background=(0.0, 0.0, 0.0), pixel_filter=pf.POINT)
    torch.testing.assert_close(none["rgb"], centre["rgb"])


def test_a_crop_of_a_frame_renders_the_frames_pixels():
    # A Blender Render Region is the same camera with its principal point moved into the crop: its
    # pixels must get the rays they get in the whole frame, also at the crop's border (the edge test
    # sees the pixels beyond it) and with the filter's draws (keyed by place, not by index).
    model = _HalfPlane(-0.3)
    filt = pf.PixelFilter("GAUSSIAN", 2.0)  # wide enough to reach the edge from column 4's centre
    full = render_view(model, Cameras.create(np.eye(4)[None], 1.0, 1.0, 4.0, 2.0, 8, 4), 0, pixel_filter=filt)
    # columns 4..6, rows 1..2: the edge between columns 3 and 4 lies just left of the crop
    crop = render_view(model, Cameras.create(np.eye(4)[None], 1.0, 1.0, 4.0 - 4, 2.0 - 1, 3, 2), 0, pixel_filter=filt)
    torch.testing.assert_close(crop["rgb"], full["rgb"][1:3, 4:7])
    torch.testing.assert_close(crop["acc"], full["acc"][1:3, 4:7])
    assert 0.0 < float(full["acc"][1, 4]) < 1.0  # the crop's first column is an edge pixel, filtered


def test_eval_and_render_use_the_datasets_filter_and_say_so(run_copy, tmp_path, capsys):
    run = run_copy  # eval records its scores in metrics.json, which other tests compare with training's
    config = json.loads((run / "config.json").read_text())
    assert config["pixel_filter"] == {"type": "BLACKMAN_HARRIS", "width": 1.5}  # no field: Blender's default
    capsys.readouterr()
    assert main(["eval", str(run), "--no-bar"]) == 0
    auto = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert main(["eval", str(run), "--no-bar", "--pixel-filter", "none"]) == 0
    none = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert auto["pixel_filter"] == {"type": "BLACKMAN_HARRIS", "width": 1.5}
    assert none["pixel_filter"] == {"type": "NONE"}
    assert none["rays"] == 2 * 24 * 20 < auto["rays"]  # the sphere's outline was refined
    assert auto["psnr"] != none["psnr"]
    out = tmp_path / "r"
    assert main(["render", str(run), "--out", str(out), "--no-bar", "--pixel-filter", "none"]) == 0
    meta = json.loads((out / "renders.json").read_text())
    assert meta["pixel_filter"] == {"type": "NONE"} and meta["rays"] == 2 * 24 * 20
    # render's per-view scores are eval's, view for view (eval reports their mean)
    assert np.mean([f["psnr"] for f in meta["frames"]]) == pytest.approx(none["psnr"], abs=1e-3)


def test_a_datasets_filter_is_loaded_downscaled_and_a_bad_one_is_named(tmp_path, dataset_factory):
    from nerf_core.contract.errors import DatasetError
    from nerf_core.data.loading import load_dataset

    ds = dataset_factory(tmp_path / "ds", n_train=3, n_test=1, layouts=("synthetic",))
    for name in ("transforms_train.json", "transforms_val.json", "transforms_test.json"):
        meta = json.loads((ds / name).read_text())
        meta["pixel_filter"] = {"type": "BOX", "width": 1.0}
        (ds / name).write_text(json.dumps(meta))
    assert load_dataset(ds).pixel_filter == pf.PixelFilter("BOX", 1.0)
    half = load_dataset(ds, downscale=2).pixel_filter
    assert half == pf.PixelFilter("BOX", 0.5, 2) and half.full_resolution() == pf.PixelFilter("BOX", 1.0)
    meta = json.loads((ds / "transforms_train.json").read_text())
    meta["pixel_filter"] = {"type": "MITCHELL", "width": 1.5}
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=r"transforms_train\.json: field 'pixel_filter\.type' must be one of"):
        load_dataset(ds)
