"""Training rays drawn from the capture's pixel filter (``train --train-rays``, ``data.batcher.footprint``).

A Cycles pixel is the mean over its pixel filter, so a ray cast at an offset drawn from that filter has
the pixel as its expected colour. These tests recover each ray's offset in its pixel from its direction
(a pinhole camera: u = cx + fx x/-z, v = cy - fy y/-z) and compare the offsets' spread with the
filter's, computed by hand.
"""
from __future__ import annotations

import math

import pytest
import torch

from nerf_core.data.batcher import BatchOptions, RayBatcher, footprint
from nerf_core.data.loading import load_dataset
from nerf_core.engine.config import TrainConfig, merge_resumed_config
from nerf_core.image.pixel_filter import DEFAULT, POINT, PixelFilter


def _pixel_coords(split, batch, n):
    """(n, 2) pixel coordinates (u right, v down) where each ray of ``batch`` meets the image plane,
    found from the ray's direction in its camera."""
    cams = split.cameras
    # the rays' views: match each origin to its camera (every camera of the sphere dataset is apart)
    centres = cams.c2w[:, :3, 3]
    view = torch.cdist(batch.rays_o.double(), centres.double()).argmin(-1)
    rot = cams.c2w[view, :3, :3].double()
    d_cam = torch.einsum("mji,mj->mi", rot, batch.rays_d.double())  # world -> camera: R^T d
    x, y = d_cam[:, 0] / -d_cam[:, 2], d_cam[:, 1] / -d_cam[:, 2]
    u = cams.cx[view].double() + cams.fx[view].double() * x
    v = cams.cy[view].double() - cams.fy[view].double() * y
    return torch.stack([u, v], dim=-1)


@pytest.fixture()
def split(sphere_dataset):
    return load_dataset(sphere_dataset).split("train")


def test_centre_rays_go_through_the_pixel_centres(split):
    batch = RayBatcher(split, "white", torch.Generator().manual_seed(3), torch.device("cpu")).sample(2000)
    uv = _pixel_coords(split, batch, 2000)
    frac = uv - uv.floor()
    assert torch.allclose(frac, torch.full_like(frac, 0.5), atol=1e-3)


def test_filter_rays_spread_as_the_filter_and_keep_the_centre_rays_pixels_and_colours(split):
    box = PixelFilter("BOX", 1.0)  # uniform over the pixel: offsets have variance 1/12 a side
    n = 20000
    centre = RayBatcher(split, "white", torch.Generator().manual_seed(5), torch.device("cpu")).sample(n)
    drawn = RayBatcher(split, "white", torch.Generator().manual_seed(5), torch.device("cpu"),
                       BatchOptions(box)).sample(n)
    # the same pixels and colours: offsets are drawn after them from the same generator
    assert torch.equal(centre.target, drawn.target) and torch.equal(centre.rays_o, drawn.rays_o)
    off = _pixel_coords(split, drawn, n) - _pixel_coords(split, centre, n)
    assert off.abs().max() <= 0.5 + 1e-3
    assert off.mean(0).abs().max() < 0.01
    assert off.var(0).tolist() == pytest.approx([1 / 12, 1 / 12], rel=0.05)


def test_blackman_harris_offsets_have_the_filters_variance(split):
    # Blackman-Harris over width W: w(t) = a0 - a1 cos 2pi t + a2 cos 4pi t - a3 cos 6pi t, t = x/W + 1/2.
    # Its variance, by hand: integral of x^2 w / integral of w over s = x/W in [-1/2, 1/2]. There
    # cos(2 pi k (s + 1/2)) = (-1)^k cos(2 pi k s), and integral s^2 cos(2 pi k s) ds = (-1)^k / (2 pi^2 k^2),
    # so each cosine term gives 1 / (2 pi^2 k^2); integral of s^2 is 1/12 and integral of w is a0.
    a = (0.35875, 0.48829, 0.14128, 0.01168)
    second = a[0] / 12 - a[1] / (2 * math.pi ** 2) + a[2] / (8 * math.pi ** 2) - a[3] / (18 * math.pi ** 2)
    width = 1.5
    var = width ** 2 * second / a[0]  # 0.0432 px^2: a standard deviation of 0.21 px
    n = 40000
    centre = RayBatcher(split, "white", torch.Generator().manual_seed(7), torch.device("cpu")).sample(n)
    drawn = RayBatcher(split, "white", torch.Generator().manual_seed(7), torch.device("cpu"),
                       BatchOptions(PixelFilter("BLACKMAN_HARRIS", width))).sample(n)
    off = _pixel_coords(split, drawn, n) - _pixel_coords(split, centre, n)
    assert off.abs().max() <= width / 2 + 1e-3
    assert off.var(0).tolist() == pytest.approx([var, var], rel=0.05)


def test_the_footprint_follows_the_flag_and_the_dataset(sphere_dataset):
    ds = load_dataset(sphere_dataset)
    assert footprint(ds.pixel_filter, "centre") is POINT
    assert footprint(ds.pixel_filter, "filter") == ds.pixel_filter and not ds.pixel_filter.is_point
    assert footprint(None, "filter") == DEFAULT  # a Dataset built by hand: Blender's default
    assert load_dataset(sphere_dataset, downscale=2).pixel_filter.downscale == 2  # follows the loaded size
    with pytest.raises(ValueError, match="train_rays"):
        footprint(ds.pixel_filter, "jitter")


def test_a_run_from_before_the_flag_resumes_through_the_centres():
    cli = TrainConfig(dataset="D", out="R", train_rays="filter")
    old = {"config": {"method": "vmgrid", "dataset": "D", "max_steps": 10}}
    with pytest.raises(Exception):  # it differs from the run's own (centre) setting: refused, not switched
        merge_resumed_config(cli, {"config": {**old["config"], "train_rays": "centre"}})
    resumed = merge_resumed_config(TrainConfig(dataset="D", out="R"), old)
    assert resumed.train_rays == "centre"
