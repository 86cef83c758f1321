"""Rays and projection against hand-computed values for an off-centre, non-square camera."""

import numpy as np
import pytest
import torch

from nerf_core.cameras.rays import (
    Cameras,
    camera_directions,
    project_points,
    ray_bounds,
    rays_for_pixels,
    rays_for_view,
)
from nerf_core.contract.errors import PoseError
from nerf_core.contract.poses import check_pose
from nerf_core.volume.sampling import ray_aabb_intersect as intersect_aabb

# Camera rotated 90 degrees about world Z, sitting at (1, 2, 3):
# its +X (right) is world +Y, its +Y (up) is world -X, it looks along world -Z.
C2W = np.array([[0.0, -1.0, 0.0, 1.0],
                [1.0, 0.0, 0.0, 2.0],
                [0.0, 0.0, 1.0, 3.0],
                [0.0, 0.0, 0.0, 1.0]])
FX, FY, CX, CY, W, H = 50.0, 40.0, 13.3, 7.1, 30, 17


@pytest.fixture
def cam():
    return Cameras.create(C2W[None], FX, FY, CX, CY, W, H)


def test_ray_through_pixel_matches_hand_computation(cam):
    # Pixel (i=18, j=9): camera direction ((18.5-13.3)/50, -(9.5-7.1)/40, -1) = (0.104, -0.06, -1).
    o, d, z_per_t = rays_for_pixels(cam, torch.tensor([0]), torch.tensor([18]), torch.tensor([9]))
    dc = np.array([0.104, -0.06, -1.0])
    world = np.array([0.06, 0.104, -1.0])  # rotate: x_w = -y_c, y_w = x_c, z_w = z_c
    np.testing.assert_allclose(o[0].numpy(), [1.0, 2.0, 3.0])
    np.testing.assert_allclose(d[0].numpy(), world / np.linalg.norm(world), atol=1e-6)
    np.testing.assert_allclose(float(z_per_t[0]), 1.0 / np.linalg.norm(dc), atol=1e-6)


def test_projection_matches_hand_computation(cam):
    # Camera-space point (0.2, -0.1, -2) -> world (1 + 0.1, 2 + 0.2, 3 - 2).
    uv, z = project_points(cam, 0, torch.tensor([[1.1, 2.2, 1.0]]))
    np.testing.assert_allclose(uv[0].numpy(), [CX + FX * 0.2 / 2, CY + FY * 0.1 / 2], atol=1e-5)  # (18.3, 9.1)
    assert float(z[0]) == pytest.approx(2.0)


def test_project_then_ray_passes_through_point(cam):
    g = torch.Generator().manual_seed(1)
    pc = torch.rand(50, 3, generator=g) * torch.tensor([1.0, 0.6, 3.0]) - torch.tensor([0.5, 0.3, 4.0])  # in front
    pw = pc @ torch.tensor(C2W[:3, :3], dtype=torch.float32).T + torch.tensor(C2W[:3, 3], dtype=torch.float32)
    uv, z = project_points(cam, 0, pw)
    # A fractional pixel position u is "pixel i" with i = u - 0.5 (centres sit at i + 0.5).
    dc = camera_directions(cam.fx[0], cam.fy[0], cam.cx[0], cam.cy[0], uv[:, 0] - 0.5, uv[:, 1] - 0.5)
    d = torch.nn.functional.normalize(dc @ torch.tensor(C2W[:3, :3], dtype=torch.float32).T, dim=-1)
    o = cam.origins[0]
    v = pw - o
    off_line = v - (v * d).sum(-1, keepdim=True) * d
    assert off_line.norm(dim=-1).max() < 1e-4
    np.testing.assert_allclose(z.numpy(), -pc[:, 2].numpy(), atol=1e-5)


def test_full_view_rays_are_row_major_and_unit(cam):
    o, d, _ = rays_for_view(cam, 0)
    assert d.shape == (H * W, 3)
    np.testing.assert_allclose(d.norm(dim=-1).numpy(), 1.0, atol=1e-6)
    o1, d1, _ = rays_for_pixels(cam, torch.tensor([0]), torch.tensor([7]), torch.tensor([4]))
    np.testing.assert_allclose(d[4 * W + 7].numpy(), d1[0].numpy(), atol=1e-7)
    # Top-left pixel looks up and left: world up of this camera is -X, its right is +Y.
    assert d[0, 0] < 0 and d[0, 1] < 0


def test_scaled_intrinsics_keep_the_field_of_view(cam):
    half = cam.scaled(0.5)
    assert (int(half.width[0]), int(half.height[0])) == (15, 8)  # 17 * 0.5 rounds to 8
    assert float(half.fx[0]) == pytest.approx(25.0)
    assert float(half.cx[0]) == pytest.approx(CX / 2)
    assert float(half.fy[0]) == pytest.approx(FY * 8 / 17)
    assert float(half.fov_x()[0]) == pytest.approx(float(cam.fov_x()[0]))


def test_bad_poses_are_rejected_with_the_field_name():
    m = np.eye(4)
    with pytest.raises(PoseError, match="frame 3.*NaN"):
        check_pose(np.where(np.eye(4) > 0, np.nan, 0), "frame 3")
    scaled = m.copy()
    scaled[:3, :3] *= 2
    with pytest.raises(PoseError, match="scaled"):
        check_pose(scaled, "frame 0")
    singular = m.copy()
    singular[:3, 2] = 0
    with pytest.raises(PoseError, match="singular"):
        check_pose(singular, "frame 1")
    with pytest.raises(PoseError, match="4x4"):
        check_pose([[1, 0], [0, 1]], "frame 2")
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(PoseError, match="reflection"):
        check_pose(mirror, "f")


def test_aabb_intersection_hand_values():
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    o = torch.tensor([[-3.0, 0.0, 0.0], [-3.0, 5.0, 0.0], [0.0, 0.0, 0.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    t0, t1, hit = intersect_aabb(o, d, aabb)
    assert hit.tolist() == [True, False, True]
    assert t0[0] == pytest.approx(2.0) and t1[0] == pytest.approx(4.0)
    assert t0[2] == 0.0 and t1[2] == pytest.approx(1.0)  # origin inside the box starts at 0
    n, f = ray_bounds(o, d, aabb, near=2.5, far=3.5)
    assert n[0] == pytest.approx(2.5) and f[0] == pytest.approx(3.5)
    assert bool((f >= n).all())
