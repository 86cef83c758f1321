"""Pinhole cameras in the OpenGL convention, and the rays through their pixels.

Conventions (docs/CONTRACTS.md): +X right, +Y up, looking along -Z; ``c2w`` is camera-to-world
without scale; pixel (i, j) = (column, row from the top) has its centre at (i + 0.5, j + 0.5) and
its camera-space ray is ``((i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -1)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np
import torch

# Pose validation (contract.check_pose) and the focal-length rule (contract.resolve_intrinsics) live
# in nerf_core.contract: the add-on needs them without torch.
from .sampling import ray_aabb_intersect


@dataclass
class Cameras:
    """A set of pinhole cameras.

    Attributes:
        c2w: (n, 4, 4) float32 camera-to-world.
        fx, fy, cx, cy: (n,) float32 intrinsics in pixels.
        width, height: (n,) int64 image size in pixels.
    """

    c2w: torch.Tensor
    fx: torch.Tensor
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    width: torch.Tensor
    height: torch.Tensor

    @classmethod
    def create(cls, c2w, fx, fy, cx, cy, width, height) -> "Cameras":
        c2w = torch.as_tensor(np.asarray(c2w), dtype=torch.float32).reshape(-1, 4, 4)
        n = c2w.shape[0]

        def vec(v, dtype=torch.float32):
            t = torch.as_tensor(np.asarray(v), dtype=dtype).reshape(-1)
            return t.expand(n).clone() if t.numel() == 1 else t

        return cls(c2w, vec(fx), vec(fy), vec(cx), vec(cy), vec(width, torch.int64), vec(height, torch.int64))

    def __len__(self) -> int:
        return self.c2w.shape[0]

    def __getitem__(self, idx) -> "Cameras":
        if isinstance(idx, int):
            idx = slice(idx, idx + 1) if idx != -1 else slice(-1, None)
        return Cameras(*(getattr(self, f)[idx] for f in ("c2w", "fx", "fy", "cx", "cy", "width", "height")))

    def to(self, device) -> "Cameras":
        return Cameras(*(getattr(self, f).to(device) for f in ("c2w", "fx", "fy", "cx", "cy", "width", "height")))

    @property
    def origins(self) -> torch.Tensor:
        """(n, 3) camera centres in world space."""
        return self.c2w[:, :3, 3]

    @property
    def forward(self) -> torch.Tensor:
        """(n, 3) viewing directions (the camera's -Z axis) in world space."""
        return -self.c2w[:, :3, 2]

    def scaled(self, factor: float) -> "Cameras":
        """Intrinsics for images resized by ``factor`` (0.5 = half resolution).

        Sizes are rounded; focal lengths and principal points are scaled by the actual size ratio per
        axis so that the field of view and the principal point stay at the same place in the image.
        """
        w = torch.clamp(torch.round(self.width.double() * factor), min=1).long()
        h = torch.clamp(torch.round(self.height.double() * factor), min=1).long()
        sx = (w.double() / self.width.double()).float()
        sy = (h.double() / self.height.double()).float()
        return Cameras(self.c2w.clone(), self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h)

    def fov_x(self) -> torch.Tensor:
        """(n,) horizontal field of view in radians (``camera_angle_x``)."""
        return 2.0 * torch.atan(self.width.float() / (2.0 * self.fx))


def camera_directions(fx, fy, cx, cy, i, j) -> torch.Tensor:
    """Unnormalised camera-space directions (m, 3) through pixel centres (column i, row j)."""
    x = (i.float() + 0.5 - cx) / fx
    y = -(j.float() + 0.5 - cy) / fy
    return torch.stack([x, y, -torch.ones_like(x)], dim=-1)


def rays_for_pixels(
    cameras: Cameras, view: torch.Tensor, i: torch.Tensor, j: torch.Tensor
) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays through given pixels of given views.

    Args:
        view, i, j: (m,) int64 view index, pixel column, pixel row.
    Returns:
        rays_o (m, 3), rays_d (m, 3) unit length, z_per_t (m,) planar depth per unit of ray
        distance (multiply a ray distance by it to get z-depth).
    """
    d_cam = camera_directions(cameras.fx[view], cameras.fy[view], cameras.cx[view], cameras.cy[view], i, j)
    inv_norm = torch.rsqrt((d_cam * d_cam).sum(-1))
    rot = cameras.c2w[view, :3, :3]
    rays_d = torch.einsum("mij,mj->mi", rot, d_cam) * inv_norm[:, None]
    rays_o = cameras.c2w[view, :3, 3]
    return rays_o, rays_d, inv_norm  # |d_cam.z| = 1, so z-depth per unit distance is 1/|d_cam|


def rays_for_view(cameras: Cameras, view: int) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """All rays of one view in row-major pixel order: rays_o, rays_d (h*w, 3) and z_per_t (h*w,)."""
    w, h = int(cameras.width[view]), int(cameras.height[view])
    jj, ii = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    v = torch.full((h * w,), view, dtype=torch.long)
    return rays_for_pixels(cameras, v, ii.reshape(-1), jj.reshape(-1))


def project_points(cameras: Cameras, view: int, points: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
    """Project world points (m, 3) into ``view``: pixel coordinates (m, 2) as (u, v) and z-depth (m,).

    ``u`` grows to the right and ``v`` downwards; the centre of pixel (i, j) is (i + 0.5, j + 0.5).
    The z-depth is positive in front of the camera.
    """
    c2w = cameras.c2w[view]
    rot, t = c2w[:3, :3], c2w[:3, 3]
    pc = (points - t) @ rot  # = R^T (X - t), the world-to-camera transform without inverting a 4x4
    depth = -pc[:, 2]
    u = cameras.cx[view] + cameras.fx[view] * pc[:, 0] / depth
    v = cameras.cy[view] - cameras.fy[view] * pc[:, 1] / depth
    return torch.stack([u, v], dim=-1), depth


def ray_bounds(
    rays_o: torch.Tensor,
    rays_d: torch.Tensor,
    aabb: torch.Tensor,
    near: Optional[float] = None,
    far: Optional[float] = None,
) -> Tuple[torch.Tensor, torch.Tensor]:
    """The interval (m,), (m,) handed to a model: the box intersection, tightened by the dataset's near/far."""
    t_near, t_far, _ = ray_aabb_intersect(rays_o, rays_d, aabb.to(rays_o))
    if near is not None:
        t_near = t_near.clamp_min(float(near))
    if far is not None:
        t_far = t_far.clamp_max(float(far))
    t_far = torch.maximum(t_far, t_near)
    return t_near, t_far
