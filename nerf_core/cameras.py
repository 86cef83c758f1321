"""Pinhole cameras in the OpenGL convention, and the rays through their pixels.

Conventions (docs/CONTRACTS.md): +X right, +Y up, looking along -Z; ``c2w`` is camera-to-world
without scale; pixel (i, j) = (column, row from the top) has its centre at (i + 0.5, j + 0.5) and
its camera-space ray is ``((i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -1)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np
import torch


class PoseError(ValueError):
    """A camera matrix that is not a finite rigid transform."""


def check_pose(matrix, where: str = "transform_matrix", scale_tol: float = 1e-3) -> np.ndarray:
    """Validate a camera-to-world matrix and return it as float64 (4, 4).

    Raises PoseError naming ``where`` for wrong shape, NaN/inf, a singular or scaled/sheared
    rotation part, or a bottom row other than [0, 0, 0, 1].
    """
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PoseError(f"{where}: not a numeric matrix ({exc})") from exc
    if m.shape == (3, 4):
        m = np.vstack([m, [0, 0, 0, 1]])
    if m.shape != (4, 4):
        raise PoseError(f"{where}: expected a 4x4 matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise PoseError(f"{where}: contains NaN or inf")
    rot = m[:3, :3]
    det = np.linalg.det(rot)
    if abs(det) < 1e-8:
        raise PoseError(f"{where}: rotation part is singular (determinant {det:.3g})")
    gram = rot.T @ rot
    if not np.allclose(gram, np.eye(3), atol=scale_tol):
        scales = np.sqrt(np.diag(gram))
        raise PoseError(
            f"{where}: rotation part is scaled or sheared (column lengths {np.round(scales, 4).tolist()}); "
            "transform_matrix must be matrix_world with the scale removed"
        )
    if det < 0:
        raise PoseError(f"{where}: rotation part is a reflection (determinant {det:.3g})")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise PoseError(f"{where}: bottom row must be [0, 0, 0, 1], got {m[3].tolist()}")
    return m


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


def intersect_aabb(rays_o: torch.Tensor, rays_d: torch.Tensor, aabb: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Slab test of rays against a box.

    Args:
        rays_o, rays_d: (m, 3); aabb: (2, 3) [[min], [max]].
    Returns:
        t_near (m,) clamped at 0, t_far (m,), hit (m,) bool. Missed rays get t_near = t_far.
    """
    inv = 1.0 / torch.where(rays_d.abs() < 1e-12, torch.full_like(rays_d, 1e-12), rays_d)
    t0 = (aabb[0] - rays_o) * inv
    t1 = (aabb[1] - rays_o) * inv
    t_near = torch.minimum(t0, t1).amax(-1).clamp_min(0.0)
    t_far = torch.maximum(t0, t1).amin(-1)
    hit = t_far > t_near
    t_far = torch.where(hit, t_far, t_near)
    return t_near, t_far, hit


def ray_bounds(
    rays_o: torch.Tensor,
    rays_d: torch.Tensor,
    aabb: torch.Tensor,
    near: Optional[float] = None,
    far: Optional[float] = None,
) -> Tuple[torch.Tensor, torch.Tensor]:
    """The interval (m,), (m,) handed to a model: the box intersection, tightened by the dataset's near/far."""
    try:  # one box test for the whole library: the models' own sampler when it is there
        from .sampling import ray_aabb_intersect as _intersect
    except ImportError:
        _intersect = intersect_aabb
    t_near, t_far, _ = _intersect(rays_o, rays_d, aabb.to(rays_o))
    if near is not None:
        t_near = t_near.clamp_min(float(near))
    if far is not None:
        t_far = t_far.clamp_max(float(far))
    t_far = torch.maximum(t_far, t_near)
    return t_near, t_far


def focal_from_fov(fov: float, size: float) -> float:
    """Focal length in pixels for a field of view (radians) spanning ``size`` pixels."""
    return 0.5 * size / math.tan(0.5 * fov)
