"""Lens distortion: points to distorted image coordinates, and pixels back to rays.

The models and their coefficients are ``contract.lens`` (OPENCV and OPENCV_FISHEYE, nerfstudio's
meanings). Everything here works in OpenCV's normalised image coordinates: x right, y *down*, the
point (x, y, 1) in front of the camera; ``cameras`` turns them into the OpenGL camera's rays.

Undistorting has no closed form, so it is Newton's method per pixel, started at the distorted
point (MultiNeRF and nerfstudio do the same): 2x2 for OPENCV, 1-D in the angle for the fisheye.
It runs in float64, for the whole image at once, and reports the pixels where it did not converge
(a lens whose polynomial folds back inside the image), which ``check_lens_invertible`` refuses.
"""
from __future__ import annotations

import math
from typing import Tuple

import torch
from torch import Tensor

NEWTON_STEPS = 12
# Residual (in normalised coordinates) below which a pixel counts as undistorted: 1e-6 is a
# thousandth of a pixel at a focal length of 1000 px.
CONVERGED = 1e-6


def _radial(coeffs: Tensor, rr: Tensor) -> Tuple[Tensor, Tensor]:
    """1 + k1 rr + k2 rr² + k3 rr³ + k4 rr⁴ and its derivative in rr. coeffs (m, 6), rr (m,)."""
    k1, k2, k3, k4 = coeffs[:, 0], coeffs[:, 1], coeffs[:, 2], coeffs[:, 3]
    d = 1.0 + rr * (k1 + rr * (k2 + rr * (k3 + rr * k4)))
    d_rr = k1 + rr * (2.0 * k2 + rr * (3.0 * k3 + rr * 4.0 * k4))
    return d, d_rr


def _theta_poly(coeffs: Tensor, theta: Tensor) -> Tuple[Tensor, Tensor]:
    """θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸) and its derivative in θ."""
    t2 = theta * theta
    d, d_t2 = _radial(coeffs, t2)
    return theta * d, d + 2.0 * t2 * d_t2


def _distort_opencv(x: Tensor, y: Tensor, coeffs: Tensor) -> Tuple[Tensor, Tensor]:
    """OPENCV's distorted coordinates (m,), (m,) of undistorted ones ``x = X/Z``, ``y = Y/Z`` (m,);
    ``coeffs`` (m, 6) = k1, k2, k3, k4, p1, p2 per point."""
    rr = x * x + y * y
    d, _ = _radial(coeffs, rr)
    p1, p2 = coeffs[:, 4], coeffs[:, 5]
    return (d * x + 2.0 * p1 * x * y + p2 * (rr + 2.0 * x * x),
            d * y + p1 * (rr + 2.0 * y * y) + 2.0 * p2 * x * y)


def distort_direction(X: Tensor, Y: Tensor, Z: Tensor, coeffs: Tensor, fisheye: Tensor) -> Tuple[Tensor, Tensor]:
    """Distorted coordinates (m,), (m,) of camera-space points (OpenCV axes: Z > 0 in front; any Z for a
    fisheye). ``coeffs`` (m, 6) as in ``_distort_opencv``; ``fisheye`` (m,) bool picks the model."""
    rho = torch.sqrt(X * X + Y * Y)
    theta_d, _ = _theta_poly(coeffs, torch.atan2(rho, Z))
    scale = torch.where(rho > 1e-12, theta_d / rho.clamp_min(1e-12), torch.zeros_like(rho))
    px, py = _distort_opencv(X / Z, Y / Z, coeffs)
    return torch.where(fisheye, X * scale, px), torch.where(fisheye, Y * scale, py)


def _undistort_opencv(xd: Tensor, yd: Tensor, coeffs: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
    """Newton on the 2x2 system; (x, y, |residual|)."""
    p1, p2 = coeffs[:, 4], coeffs[:, 5]
    x, y = xd.clone(), yd.clone()
    for _ in range(NEWTON_STEPS):
        rr = x * x + y * y
        d, d_rr = _radial(coeffs, rr)
        fx = d * x + 2.0 * p1 * x * y + p2 * (rr + 2.0 * x * x) - xd
        fy = d * y + p1 * (rr + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        d_x, d_y = 2.0 * x * d_rr, 2.0 * y * d_rr
        fx_x = d + d_x * x + 2.0 * p1 * y + 6.0 * p2 * x
        fx_y = d_y * x + 2.0 * p1 * x + 2.0 * p2 * y
        fy_x = d_x * y + 2.0 * p2 * y + 2.0 * p1 * x
        fy_y = d + d_y * y + 2.0 * p2 * x + 6.0 * p1 * y
        det = fx_x * fy_y - fx_y * fy_x
        det = torch.where(det.abs() < 1e-12, torch.full_like(det, 1e-12), det)
        x = x - (fx * fy_y - fy * fx_y) / det
        y = y - (fy * fx_x - fx * fy_x) / det
    ex, ey = _distort_opencv(x, y, coeffs)
    return x, y, torch.hypot(ex - xd, ey - yd)


def _undistort_fisheye(xd: Tensor, yd: Tensor, coeffs: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
    """Newton in θ; (θ, θ_d, |residual|)."""
    theta_d = torch.hypot(xd, yd)
    theta = theta_d.clone()
    for _ in range(NEWTON_STEPS):
        g, g_t = _theta_poly(coeffs, theta)
        g_t = torch.where(g_t.abs() < 1e-12, torch.full_like(g_t, 1e-12), g_t)
        theta = (theta - (g - theta_d) / g_t).clamp(0.0, math.pi)
    g, _ = _theta_poly(coeffs, theta)
    return theta, theta_d, (g - theta_d).abs()


def pixel_directions(xd: Tensor, yd: Tensor, coeffs: Tensor, fisheye: Tensor) -> Tuple[Tensor, Tensor]:
    """Unit ray directions (m, 3) in the OpenGL camera (+Y up, looking along -Z) through distorted
    normalised coordinates ``xd = (u - cx) / fx``, ``yd = (v - cy) / fy`` (m,), and (m,) bool: converged.

    A fisheye ray may leave at more than 90 degrees from the axis (its z is then positive).
    """
    dtype = xd.dtype
    xd, yd, coeffs = xd.double(), yd.double(), coeffs.double()
    dirs = torch.empty(xd.shape[0], 3, dtype=torch.float64)
    residual = torch.empty_like(xd)
    persp = ~fisheye
    if bool(persp.any()):
        x, y, residual[persp] = _undistort_opencv(xd[persp], yd[persp], coeffs[persp])
        d = torch.stack([x, -y, -torch.ones_like(x)], dim=-1)
        dirs[persp] = d / d.norm(dim=-1, keepdim=True)
    if bool(fisheye.any()):
        fx_, fy_ = xd[fisheye], yd[fisheye]
        theta, theta_d, residual[fisheye] = _undistort_fisheye(fx_, fy_, coeffs[fisheye])
        # (x_d, y_d) / θ_d is the unit direction in the image plane; sin θ of it leaves the axis.
        s = torch.where(theta_d > 1e-12, torch.sin(theta) / theta_d.clamp_min(1e-12), torch.ones_like(theta))
        dirs[fisheye] = torch.stack([fx_ * s, -fy_ * s, -torch.cos(theta)], dim=-1)
    return dirs.to(dtype), residual < CONVERGED


def fold_pixel(fx: float, fy: float, cx: float, cy: float, w: int, h: int, coeffs, fisheye: bool):
    """A pixel (u, v) of a w x h image where the lens cannot be undone, else None.

    Walks from the principal point to every border pixel and the corners: undistortion must
    converge there, and the ray's angle from the axis must grow along the way. A polynomial fitted
    to a smaller image (or typed wrong) turns back inside this one, and then two pixels would see
    the same ray and Newton's method may land on either.
    """
    # A polynomial bends slowly: 257 points an edge (corners included) find a fold in any image.
    eu, ev = torch.linspace(0.0, float(w), 257), torch.linspace(0.0, float(h), 257)
    u = torch.cat([eu, eu, torch.zeros(257), torch.full((257,), float(w))])
    v = torch.cat([torch.zeros(257), torch.full((257,), float(h)), ev, ev])
    t = torch.linspace(0.0, 1.0, 65, dtype=torch.float64)[1:]
    uu = (cx + (u.double()[:, None] - cx) * t).reshape(-1)  # (border, 64) rows walk outwards
    vv = (cy + (v.double()[:, None] - cy) * t).reshape(-1)
    m = uu.shape[0]
    c = torch.as_tensor(coeffs, dtype=torch.float64).reshape(1, 6).expand(m, 6)
    dirs, ok = pixel_directions((uu - cx) / fx, (vv - cy) / fy, c, torch.full((m,), bool(fisheye)))
    angle = torch.acos((-dirs[:, 2]).clamp(-1.0, 1.0)).reshape(-1, 64)
    bad = (~ok).reshape(-1, 64)
    bad[:, 1:] |= angle[:, 1:] <= angle[:, :-1]
    rows, cols = torch.nonzero(bad, as_tuple=True)
    if rows.numel() == 0:
        return None
    k = int(rows[0]) * 64 + int(cols[0])
    return float(uu[k]), float(vv[k])
