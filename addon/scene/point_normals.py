"""Unit normals for the capture's point cloud, out of the surface (3D Gaussian Splatting needs them).

3DGS reads ``points3d.ply`` with ``nx ny nz`` and fails without them. A pixel's normal comes from
the render's Normal pass (world space; Cycles and EEVEE) when there is one, else from the depth
map: the cross product of the neighbouring back-projected points, taking on each axis the side
whose depth changes less, so silhouettes do not tilt the normals of the pixels along them. Either
way the normal is turned to face the camera that saw the pixel: a visible surface faces its viewer,
so that side is the outside (for closed objects seen from outside).
"""
from __future__ import annotations

import numpy as np


def camera_points(depth: np.ndarray, intr: dict) -> np.ndarray:
    """(h, w, 3) camera-space points (OpenGL: looking along -Z) of planar ``depth`` (h, w); NaN where none."""
    h, w = depth.shape
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    j, i = np.mgrid[0:h, 0:w]
    return np.stack([(i + 0.5 - intr["cx"]) / intr["fl_x"] * z, -(j + 0.5 - intr["cy"]) / intr["fl_y"] * z, -z], -1)


def _tangent(p: np.ndarray, axis: int) -> np.ndarray:
    """Difference to the neighbour along ``axis`` (h, w, 3): the side with the smaller depth step."""
    fwd = np.full_like(p, np.nan)
    bwd = np.full_like(p, np.nan)
    if axis == 1:
        fwd[:, :-1] = p[:, 1:] - p[:, :-1]
        bwd[:, 1:] = p[:, 1:] - p[:, :-1]
    else:
        fwd[:-1] = p[1:] - p[:-1]
        bwd[1:] = p[1:] - p[:-1]
    fwd_ok, bwd_ok = np.isfinite(fwd).all(-1), np.isfinite(bwd).all(-1)
    use_fwd = fwd_ok & (~bwd_ok | (np.abs(np.nan_to_num(fwd[..., 2])) <= np.abs(np.nan_to_num(bwd[..., 2]))))
    return np.where(use_fwd[..., None], fwd, bwd)


def depth_normals(depth: np.ndarray, intr: dict) -> np.ndarray:
    """(h, w, 3) camera-space unit normals from planar ``depth`` (h, w), facing the camera; NaN where unknown."""
    p = camera_points(depth, intr)
    n = np.cross(_tangent(p, 1), _tangent(p, 0))
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(length > 0, n / length, np.nan)
    flip = np.einsum("hwc,hwc->hw", n, p) > 0  # p points from the camera to the surface
    return np.where(flip[..., None], -n, n)


def point_normals(depth: np.ndarray, intr: dict, c2w, normal_pass: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) float32 world-space unit normals, one per point of ``points.backproject(depth, ...)``.

    depth: (h, w) planar z (inf = none); c2w: 4x4 rows; normal_pass: (h, w, 3) world-space normals
    from the render (0 where no surface) or None. Points without a usable normal get the direction
    to the camera.
    """
    c2w = np.asarray(c2w, float)
    rot, cam_pos = c2w[:3, :3], c2w[:3, 3]
    ok = np.isfinite(depth) & (depth > 0)
    p_cam = camera_points(depth, intr)[ok]
    p_world = p_cam @ rot.T + cam_pos
    n = depth_normals(depth, intr)[ok] @ rot.T
    if normal_pass is not None:
        rendered = np.asarray(normal_pass, float)[ok]
        length = np.linalg.norm(rendered, axis=-1, keepdims=True)
        usable = (length[:, 0] > 0.5) & np.isfinite(length[:, 0])
        n = np.where(usable[:, None], rendered / np.where(usable[:, None], length, 1.0), n)
    to_cam = cam_pos - p_world
    to_cam /= np.maximum(np.linalg.norm(to_cam, axis=-1, keepdims=True), 1e-12)
    n = np.where(np.isfinite(n).all(-1, keepdims=True), n, to_cam)
    n = np.where((np.einsum("nc,nc->n", n, to_cam) < 0)[:, None], -n, n)
    return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
