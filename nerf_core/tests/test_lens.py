"""Distorting lenses (OPENCV, OPENCV_FISHEYE): rays against hand-worked values and an independent
numpy projection, the fold check, and a distorted dataset carried through loading, training and render."""
import json
import math

import numpy as np
import pytest
import torch

from nerf_core.cameras.distortion import fold_pixel
from nerf_core.cameras.rays import Cameras, project_points, rays_for_pixels, rays_for_view
from nerf_core.contract.lens import Lens, parse_lens


def _one_camera(lens, fx=100.0, fy=100.0, cx=50.0, cy=40.0, w=120, h=80):
    return Cameras.create(np.eye(4)[None], fx, fy, cx, cy, w, h, lenses=[lens])


def _ray_through(cams, i, j):
    """Camera-space (c2w is the identity) unit ray through the centre of pixel (i, j), and its z per distance."""
    _, d, z = rays_for_pixels(cams, torch.tensor([0]), torch.tensor([i]), torch.tensor([j]))
    return d[0].double(), float(z[0])


def test_opencv_radial_by_hand():
    # k1 = 0.1: the point x = 0.5, y = 0 (OpenCV axes) lands at x_d = 0.5 (1 + 0.1 * 0.25) = 0.5125, so the
    # pixel whose centre is 51.25 px right of cx (column 100 with cx = 49.25) sees direction (0.5, 0, -1).
    cams = _one_camera(Lens("OPENCV", (0.1, 0, 0, 0, 0, 0)), cx=49.25, cy=40.5)
    d, z = _ray_through(cams, 100, 40)
    d = d * (-1.0 / d[2])
    assert d[0] == pytest.approx(0.5, abs=1e-6) and d[1] == pytest.approx(0.0, abs=1e-6)
    assert z == pytest.approx(1 / math.sqrt(1.25), abs=1e-6)  # z-depth per unit distance: cos of the angle


def test_opencv_tangential_by_hand():
    # p1 = 0.02 at x = 0, y = 0.5 (down): y_d = 0.5 + p1 (0.25 + 2 * 0.25) = 0.515 and x_d = 0, so row 60
    # with cy = 9 (60.5 - 51.5) and column 50 with cx = 50.5. OpenGL's y is up: the ray has y = -0.5.
    cams = _one_camera(Lens("OPENCV", (0, 0, 0, 0, 0.02, 0)), cx=50.5, cy=9.0)
    d, _ = _ray_through(cams, 50, 60)
    d = d * (-1.0 / d[2])
    assert d[0] == pytest.approx(0.0, abs=1e-6) and d[1] == pytest.approx(-0.5, abs=1e-6)


def test_fisheye_by_hand():
    # Equidistant with k1 = 0.1: a ray 0.5 rad off the axis lands at θ_d = 0.5 (1 + 0.1 * 0.25) = 0.5125,
    # 51.25 px right of cx. A fisheye sees past 90 degrees too: with no coefficients the pixel 200 px
    # above cy (θ_d = 2.0) sees a ray 2 rad off the axis, pointing up and backwards.
    cams = _one_camera(Lens("OPENCV_FISHEYE", (0.1, 0, 0, 0, 0, 0)), cx=49.25, cy=40.5)
    d, z = _ray_through(cams, 100, 40)
    assert math.acos(-d[2]) == pytest.approx(0.5, abs=1e-6) and d[0] > 0 and abs(d[1]) < 1e-9
    assert z == pytest.approx(math.cos(0.5), abs=1e-6)
    wide = _one_camera(Lens("OPENCV_FISHEYE", (0,) * 6), cx=50.5, cy=210.5)
    d, _ = _ray_through(wide, 50, 10)
    assert math.acos(-d[2]) == pytest.approx(2.0, abs=1e-6) and d[1] > 0 and d[2] > 0


def _numpy_project(points, fx, fy, cx, cy, k, fisheye):
    """An independent forward model: camera-space (OpenGL) points to pixels, straight from the formulas."""
    X, Y, Z = points[:, 0], -points[:, 1], -points[:, 2]
    k1, k2, k3, k4, p1, p2 = k
    if fisheye:
        rho = np.hypot(X, Y)
        th = np.arctan2(rho, Z)
        thd = th * (1 + k1 * th ** 2 + k2 * th ** 4 + k3 * th ** 6 + k4 * th ** 8)
        xd, yd = thd * X / rho, thd * Y / rho
    else:
        x, y = X / Z, Y / Z
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3 + k4 * r2 ** 4
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([cx + fx * xd, cy + fy * yd], -1)


@pytest.mark.parametrize("model, coeffs", [
    ("OPENCV", (-0.28, 0.09, -0.01, 0.0, 0.0012, -0.0007)),  # barrel, as a phone or GoPro in linear mode
    ("OPENCV", (0.15, 0.02, 0.0, 0.001, -0.002, 0.003)),  # pincushion
    ("OPENCV_FISHEYE", (0.02, -0.004, 0.001, -0.0002, 0.0, 0.0)),
])
def test_every_pixel_ray_projects_back_onto_its_pixel(model, coeffs, monkeypatch):
    # Undistortion (Newton) against the plain forward formulas in numpy, over a whole image with a
    # principal point off the centre and non-square pixels.
    fx, fy, cx, cy, w, h = 70.0, 74.0, 61.3, 39.8, 120, 90
    cams = _one_camera(Lens(model, coeffs), fx, fy, cx, cy, w, h)
    _, d, _ = rays_for_view(cams, 0)
    uv = _numpy_project(d.double().numpy() * 2.0, fx, fy, cx, cy, coeffs, model == "OPENCV_FISHEYE")
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    centres = np.stack([ii.reshape(-1) + 0.5, jj.reshape(-1) + 0.5], -1)
    assert np.abs(uv - centres).max() < 1e-3
    # The model's own projection agrees (it is what maps points into views elsewhere).
    uv2, depth = project_points(cams, 0, d * 2.0)
    assert (uv2.double().numpy() - centres).__abs__().max() < 1e-3 and bool((depth > 0).all())
    # The distortion is strong enough to matter: a pinhole reading puts corner rays pixels away.
    pin = _numpy_project(d.double().numpy(), fx, fy, cx, cy, (0,) * 6, False)
    assert np.abs(pin - centres).max() > 3.0
    # Rays come from a per-lens table of every pixel; without it (cameras of several sizes, or too
    # many distinct lenses) each ray is undistorted on its own, to the same result.
    import nerf_core.cameras.rays as cameras_module

    monkeypatch.setattr(cameras_module, "LENS_TABLE_PIXELS", 0)
    _, d_direct, _ = rays_for_view(_one_camera(Lens(model, coeffs), fx, fy, cx, cy, w, h), 0)
    assert (d_direct - d).abs().max() < 1e-6


def test_downscaling_keeps_the_rays():
    # Distortion acts on normalised coordinates: the centre of a 2x2 block of the full image and the
    # matching pixel of the half-size image see the same ray wherever the block's centre is a pixel corner.
    lens = Lens("OPENCV", (-0.2, 0.05, 0, 0, 0.001, 0.002))
    full = _one_camera(lens, 80.0, 80.0, 50.0, 40.0, 100, 80)
    half = full.scaled(0.5)
    _, d_half, _ = rays_for_view(half, 0)
    # Pixel (i, j) of the half image has its centre at full-image (2i + 1, 2j + 1): the full image's
    # pixel corner, so compare with the direction computed at that point from the full camera directly.
    from nerf_core.cameras.distortion import pixel_directions

    jj, ii = torch.meshgrid(torch.arange(40), torch.arange(50), indexing="ij")
    xd = ((2 * ii + 1).double().reshape(-1) - 50.0) / 80.0
    yd = ((2 * jj + 1).double().reshape(-1) - 40.0) / 80.0
    n = xd.shape[0]
    ref, ok = pixel_directions(xd, yd, torch.tensor([lens.coeffs], dtype=torch.float64).expand(n, 6),
                               torch.zeros(n, dtype=torch.bool))
    assert bool(ok.all()) and (d_half.double() - ref).abs().max() < 1e-6
    assert half.lens(0) == lens


def test_fold_check():
    # r_d = r (1 - 0.6 r²) peaks at r = 0.745 (r_d = 0.497): an image whose corners lie further out
    # (0.87 here) cannot be undone there; the same lens on a narrower view can.
    assert fold_pixel(150, 160, 100, 90, 200, 180, (-0.6, 0, 0, 0, 0, 0), False) is not None
    assert fold_pixel(400, 400, 100, 90, 200, 180, (-0.6, 0, 0, 0, 0, 0), False) is None
    assert fold_pixel(150, 160, 100, 90, 200, 180, (-0.2, 0.05, 0, 0, 0.001, 0), False) is None
    # An equidistant fisheye with no coefficients (θ_d = θ) does not fold past 90 degrees (2.24 rad at
    # the corners here); but a focal length that puts the corners beyond π (4.48 rad) claims a view
    # wider than all directions, which no lens has.
    assert fold_pixel(60, 60, 100, 90, 200, 180, (0,) * 6, True) is None
    assert fold_pixel(30, 30, 100, 90, 200, 180, (0,) * 6, True) is not None


def test_lens_fields_frame_over_file():
    meta = {"camera_model": "OPENCV", "k1": 0.1, "p1": 0.01}
    lens, problem = parse_lens(meta, {"k1": 0.2})
    assert problem is None and lens == Lens("OPENCV", (0.2, 0, 0, 0, 0.01, 0))
    assert parse_lens(meta, {"k1": 0, "p1": 0})[0] is None  # a frame may undo the file's lens
    assert parse_lens({"k1": 0.1}, None)[0].model == "OPENCV"  # nerfstudio's default model
    assert parse_lens({"camera_model": "PINHOLE"}, None) == (None, None)
    assert parse_lens({"camera_model": "opencv_fisheye"}, None)[0].fisheye  # a fisheye even with zeros
    assert parse_lens({"k1": float("nan")}, None)[1][0] == "k1"
    assert parse_lens({"k1": True}, None)[1][0] == "k1"


def test_instant_ngp_is_fisheye_means_the_fisheye_model():
    # colmap2nerf writes "is_fisheye": true and k1-k4, no camera_model: read as OPENCV, a ray 15 px off
    # the centre at f = 10 px was 24 degrees from the true fisheye ray.
    meta = {"is_fisheye": True, "k1": 0.05, "k2": -0.02, "k3": 0.005, "k4": 0.0}
    lens, problem = parse_lens(meta, None)
    assert problem is None and lens == Lens("OPENCV_FISHEYE", (0.05, -0.02, 0.005, 0.0, 0.0, 0.0))
    assert parse_lens({"is_fisheye": True}, None)[0].fisheye  # a fisheye bends rays with zero coefficients too
    assert parse_lens({"is_fisheye": False, "k1": 0.1}, None)[0].model == "OPENCV"
    assert parse_lens({"is_fisheye": "yes"}, None)[1][0] == "is_fisheye"
    assert parse_lens({"is_fisheye": True, "camera_model": "OPENCV"}, None)[1] == (
        "is_fisheye", "says the camera is a fisheye, but camera_model is 'OPENCV'")


def test_a_distorted_capture_loads_trains_and_renders_with_its_lens(dataset_factory, tmp_path):
    from nerf_core.data.loading import load_dataset
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train
    from nerf_core.render.views import render_run

    lens = {"camera_model": "OPENCV", "k1": -0.25, "k2": 0.05, "p1": 0.002, "p2": -0.001}
    ds = dataset_factory(tmp_path / "ds", n_train=8, n_test=2, w=32, h=24, lens=lens)
    from nerf_core.check.dataset import check_dataset

    report = check_dataset(ds)
    assert report.ok, report.format()
    assert any("OPENCV lens distortion" in str(w) and "3DGS" in str(w) for w in report.warnings), report.format()
    data = load_dataset(ds)
    train_split = data.split("train")
    assert train_split.cameras.dist is not None and train_split.cameras.lens(0).coeffs[:2] == (-0.25, 0.05)
    # The loaded rays see the sphere (radius 0.6 at the origin) exactly where the images are opaque:
    # the JSON's lens reached the rays. Read as pinholes, the silhouette moves (by a fraction of a pixel
    # at this size: the sphere sits near the centre, where the lens bends least).
    for cams in (train_split.cameras, Cameras(*(getattr(train_split.cameras, f) for f in
                                               ("c2w", "fx", "fy", "cx", "cy", "width", "height")))):
        o, d, _ = rays_for_view(cams, 3)
        b = (o * d).sum(-1)
        hit = (b * b - ((o * o).sum(-1) - 0.36)) > 0
        alpha = train_split.images[3].reshape(-1, 4)[:, 3] > 127
        mismatched = int((hit != alpha).sum())
        if cams.dist is not None:
            assert mismatched == 0
        else:
            assert mismatched > 0
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=5, batch_rays=128, seed=0,
                      stdout_events=False, show_bar=False, eval_views=1))
    out = tmp_path / "renders"
    render_run(run, str(ds), out, split="test", show_progress=False)
    meta = json.loads((out / "renders.json").read_text())
    assert meta["frames"][0]["camera_model"] == "OPENCV" and meta["frames"][0]["k1"] == -0.25
