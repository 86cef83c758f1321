"""Cameras in the OpenGL convention, and the rays through their pixels.

Conventions (docs/CONTRACTS.md): +X right, +Y up, looking along -Z; ``c2w`` is camera-to-world
without scale; pixel (i, j) = (column, row from the top) has its centre at (i + 0.5, j + 0.5) and
a pinhole's camera-space ray is ``((i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -1)``. Cameras with a
distorting lens (OPENCV, OPENCV_FISHEYE: ``contract.lens``) carry their coefficients, and their rays
are undistorted per pixel (``nerf_core.cameras.distortion``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import torch

# Pose validation (contract.check_pose) and the focal-length rule (contract.resolve_intrinsics) live
# in nerf_core.contract: the add-on needs them without torch.
from nerf_core.cameras.checks import as_array, check_cameras
from nerf_core.cameras.distortion import distort_direction, pixel_directions
from nerf_core.contract.lens import Lens
from nerf_core.utils import arguments
from nerf_core.volume.sampling import ray_aabb_intersect

_FIELDS = ("c2w", "fx", "fy", "cx", "cy", "width", "height")


@dataclass
class Cameras:
    """A set of n cameras: pinholes, or with a distorting lens (OpenGL convention: +X right, +Y up,
    looking along -Z; pixel (i, j) has its centre at (i + 0.5, j + 0.5)).

    Build one with ``Cameras.create`` (from arrays, one ``contract.Lens`` or None per camera); index
    it (``cams[3]``, ``cams[1:4]``) for a subset, ``to(device)`` to move it.

    Attributes:
        c2w: (n, 4, 4) float32 camera-to-world (rotation without scale, and the camera centre).
        fx, fy, cx, cy: (n,) float32 intrinsics in pixels.
        width, height: (n,) int64 image size in pixels.
        dist: (n, 6) float64 k1, k2, k3, k4, p1, p2 (``contract.lens``), or None when every camera is a pinhole.
        fisheye: (n,) bool, OPENCV_FISHEYE rather than OPENCV; None when ``dist`` is None.
    """

    c2w: torch.Tensor
    fx: torch.Tensor
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    width: torch.Tensor
    height: torch.Tensor
    dist: Optional[torch.Tensor] = None
    fisheye: Optional[torch.Tensor] = None

    def __post_init__(self) -> None:
        check_cameras(self)  # the public boundary (cameras/checks.py); indexing and moving skip it

    @classmethod
    def _trusted(cls, *fields) -> "Cameras":
        """A Cameras made from the fields of checked ones (a subset, a copy on a device): not checked again."""
        cams = object.__new__(cls)
        for name, value in zip(_FIELDS + ("dist", "fisheye"), fields):  # c2w..height, dist, fisheye
            setattr(cams, name, value)
        return cams

    @classmethod
    def create(cls, c2w, fx, fy, cx, cy, width, height, lenses: Optional[Sequence] = None) -> "Cameras":
        """``lenses``: one ``contract.Lens`` or None per camera (None for all: pinholes)."""
        arr = as_array(c2w, "c2w")
        if arr.size % 16 or (arr.size == 0 and arr.ndim != 3):
            raise ValueError(f"Cameras.create: c2w must be (n, 4, 4) or (4, 4) matrices, got shape {arr.shape}")
        c2w = torch.as_tensor(arr, dtype=torch.float32).reshape(-1, 4, 4)
        n = c2w.shape[0]

        def vec(v, dtype=torch.float32):
            t = torch.as_tensor(as_array(v, "an intrinsic"), dtype=dtype).reshape(-1)
            if t.numel() not in (1, n):
                raise ValueError(f"Cameras.create: each intrinsic needs 1 or {n} values, got {t.numel()}")
            return t.expand(n).clone() if t.numel() == 1 else t

        dist = fisheye = None
        if lenses is not None and any(lens is not None for lens in lenses):
            dist = torch.tensor(
                [lens.coeffs if lens is not None else (0.0,) * 6 for lens in lenses], dtype=torch.float64
            )
            fisheye = torch.tensor([lens is not None and lens.fisheye for lens in lenses], dtype=torch.bool)
        return cls(c2w, vec(fx), vec(fy), vec(cx), vec(cy), vec(width, torch.int64), vec(height, torch.int64),
                   dist, fisheye)

    @classmethod
    def cat(cls, parts: Sequence["Cameras"]) -> "Cameras":
        """One set of the cameras of ``parts``, in order."""
        fields = [torch.cat([getattr(c, f) for c in parts]) for f in _FIELDS]
        if all(c.dist is None for c in parts):
            return cls(*fields)
        dist = torch.cat([c.dist if c.dist is not None else torch.zeros(len(c), 6, dtype=torch.float64) for c in parts])
        fish = torch.cat([c.fisheye if c.fisheye is not None else torch.zeros(len(c), dtype=torch.bool) for c in parts])
        return cls(*fields, dist, fish)

    def __len__(self) -> int:
        return self.c2w.shape[0]

    def _map(self, fn) -> "Cameras":
        lens = (None, None) if self.dist is None else (fn(self.dist), fn(self.fisheye))
        return Cameras._trusted(*(fn(getattr(self, f)) for f in _FIELDS), *lens)

    def __getitem__(self, idx) -> "Cameras":
        if isinstance(idx, int):
            idx = slice(idx, idx + 1) if idx != -1 else slice(-1, None)
        return self._map(lambda t: t[idx])

    def to(self, device) -> "Cameras":
        return self._map(lambda t: t.to(device))

    def lens(self, view: int):
        """The ``contract.Lens`` of camera ``view``, or None for a pinhole."""

        if self.dist is None:
            return None
        coeffs = tuple(float(c) for c in self.dist[view])
        if bool(self.fisheye[view]):
            return Lens("OPENCV_FISHEYE", coeffs)
        return Lens("OPENCV", coeffs) if any(coeffs) else None

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
        # Distortion acts on normalised coordinates, so it does not change with the image size.
        lens = (None, None) if self.dist is None else (self.dist.clone(), self.fisheye.clone())
        return Cameras(self.c2w.clone(), self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h, *lens)

    def downscaled(self, factor: int) -> "Cameras":
        """Intrinsics for images downscaled by the integer ``factor`` as the loader does it (cropped to a
        multiple of ``factor``, then box-filtered; ``data.pixels.downscale_image``): sizes floor, and every intrinsic
        divides by ``factor``, so a render matches the ground truth that ``eval`` compares it with."""
        f = int(factor)
        w = torch.clamp(self.width // f, min=1)
        h = torch.clamp(self.height // f, min=1)
        lens = (None, None) if self.dist is None else (self.dist.clone(), self.fisheye.clone())
        return Cameras(self.c2w.clone(), self.fx / f, self.fy / f, self.cx / f, self.cy / f, w, h, *lens)

    def fov_x(self) -> torch.Tensor:
        """(n,) horizontal field of view in radians (``camera_angle_x``)."""
        return 2.0 * torch.atan(self.width.float() / (2.0 * self.fx))


def camera_directions(fx, fy, cx, cy, i, j, offset: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Unnormalised camera-space directions (m, 3) through pixel centres (column i, row j), or through
    the points ``offset`` (m, 2) pixels (x right, y down) from them."""
    u, v = i.float() + 0.5, j.float() + 0.5
    if offset is not None:
        u, v = u + offset[:, 0], v + offset[:, 1]
    x = (u - cx) / fx
    y = -(v - cy) / fy
    return torch.stack([x, y, -torch.ones_like(x)], dim=-1)


def rays_for_pixels(
    cameras: Cameras, view: torch.Tensor, i: torch.Tensor, j: torch.Tensor, offset: Optional[torch.Tensor] = None
) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays through given pixels of given views.

    Args:
        view, i, j: (m,) int64 view index, pixel column, pixel row.
        offset: (m, 2) float sub-pixel offsets from the pixel centres (x right, y down, in pixels), for
            rays drawn from the pixel filter (``nerf_core.image.pixel_filter``); None: the centres.
    Returns:
        rays_o (m, 3), rays_d (m, 3) unit length, z_per_t (m,) planar depth per unit of ray
        distance (multiply a ray distance by it to get z-depth).
    """
    rot = cameras.c2w[view, :3, :3]
    rays_o = cameras.c2w[view, :3, 3]
    if cameras.dist is None:
        d_cam = camera_directions(cameras.fx[view], cameras.fy[view], cameras.cx[view], cameras.cy[view], i, j, offset)
        inv_norm = torch.rsqrt((d_cam * d_cam).sum(-1))
        rays_d = torch.einsum("mij,mj->mi", rot, d_cam) * inv_norm[:, None]
        return rays_o, rays_d, inv_norm  # |d_cam.z| = 1, so z-depth per unit distance is 1/|d_cam|
    tables = _lens_tables(cameras) if offset is None else None  # the tables hold pixel centres only
    if tables is not None:
        table, which = tables
        unit = table[which[view], j, i]
    else:
        u, v = i.double() + 0.5, j.double() + 0.5
        if offset is not None:
            u, v = u + offset[:, 0].double(), v + offset[:, 1].double()
        xd = (u - cameras.cx[view].double()) / cameras.fx[view].double()
        yd = (v - cameras.cy[view].double()) / cameras.fy[view].double()
        unit = pixel_directions(xd, yd, cameras.dist[view], cameras.fisheye[view])[0].float()
    rays_d = torch.einsum("mij,mj->mi", rot, unit)
    return rays_o, rays_d, -unit[:, 2]  # z-depth per unit distance: the cosine to the axis


# Undistorting is Newton's method per pixel (about 1 us a ray), so the directions of each distinct
# lens are worked out once, for every pixel, while they fit in this many pixels in all.
LENS_TABLE_PIXELS = 1 << 24


def _lens_tables(cameras: Cameras) -> Optional[Tuple[torch.Tensor, torch.Tensor]]:
    """(k, h, w, 3) float32 unit camera-space directions of the k distinct lens cameras, and (n,) int64
    the table of each camera; None when the cameras differ in size or the tables would be too large."""
    cached = cameras.__dict__.get("_lens_tables")
    if cached is not None:
        return cached or None
    w, h = int(cameras.width[0]), int(cameras.height[0])
    result = False
    if bool((cameras.width == w).all()) and bool((cameras.height == h).all()):
        keys = torch.cat([torch.stack([cameras.fx, cameras.fy, cameras.cx, cameras.cy], 1).double(),
                          cameras.dist, cameras.fisheye[:, None].double()], 1)
        distinct, which = torch.unique(keys, dim=0, return_inverse=True)
        if distinct.shape[0] * h * w <= LENS_TABLE_PIXELS:
            jj, ii = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                                    indexing="ij")
            tables = []
            for fx, fy, cx, cy, *rest in distinct.tolist():
                coeffs, fish = torch.tensor(rest[:6], dtype=torch.float64), bool(rest[6])
                xd, yd = ((ii + 0.5 - cx) / fx).reshape(-1), ((jj + 0.5 - cy) / fy).reshape(-1)
                dirs, _ = pixel_directions(xd, yd, coeffs.expand(h * w, 6), torch.full((h * w,), fish))
                tables.append(dirs.float().reshape(h, w, 3))
            result = (torch.stack(tables).to(cameras.c2w.device), which.to(cameras.c2w.device))
    cameras.__dict__["_lens_tables"] = result
    return result or None


def rays_for_view(cameras: Cameras, view: int) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """All rays of one view in row-major pixel order (pixel (i, j) is ray j * w + i), through the
    pixel centres; a lens camera's rays are undistorted per pixel.

    Args:
        cameras: the ``Cameras``.
        view: index of the camera, in 0..n-1.

    Returns:
        rays_o: (h*w, 3) float32 origins (the camera centre, repeated).
        rays_d: (h*w, 3) float32 unit directions in world space.
        z_per_t: (h*w,) float32 planar depth per unit of ray distance (multiply a ray distance by it
            to get z-depth along the camera's -Z).
    """
    arguments.instance("rays_for_view", "cameras", cameras, Cameras, "a nerf_core.Cameras")
    view = arguments.integer("rays_for_view", "view", view, low=0, high=len(cameras) - 1)
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
    if cameras.dist is None:
        x, y = pc[:, 0] / depth, -pc[:, 1] / depth
    else:
        m = points.shape[0]
        x, y = distort_direction(pc[:, 0].double(), -pc[:, 1].double(), depth.double(),
                                 cameras.dist[view].expand(m, 6), cameras.fisheye[view].expand(m))
        x, y = x.to(points.dtype), y.to(points.dtype)
    u = cameras.cx[view] + cameras.fx[view] * x
    v = cameras.cy[view] + cameras.fy[view] * y
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
