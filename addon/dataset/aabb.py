"""The box a dataset declares: instant-ngp's ``aabb_scale``, the box corners and near/far."""
from __future__ import annotations

import numpy as np


def ngp_aabb_scale(lo, hi, camera_positions=(), beyond_box: bool = False) -> int:
    """instant-ngp's ``aabb_scale`` (a power of two, 1..128) for a file that also carries ``aabb``.

    With ``aabb`` instant-ngp scales and centres that box onto its unit cube (``nerf_loader.cu``), and
    ``aabb_scale`` is the side of the cube it samples, in units of the box's longest side. A scene
    that is all inside the box (a transparent film, nothing left out) needs 1. One that renders
    beyond it (``beyond_box``: an opaque world, a floor to the horizon) gets the smallest cube that
    reaches twice as far as the farthest camera: what lies beyond the cameras is what they see.
    """
    if not beyond_box:
        return 1
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    length = max(float((hi - lo).max()), 1e-6)
    centre = 0.5 * (lo + hi)
    reach = max([float(np.abs(np.asarray(p, float) - centre).max()) for p in camera_positions] or [length])
    need = 4.0 * reach / length  # a cube of side aabb_scale * length, centred, holding 2 x reach
    scale = 1
    while scale < need and scale < 128:
        scale *= 2
    return scale


def box_corners(lo, hi) -> np.ndarray:
    """(8, 3) float64: the corners of the axis-aligned box (lo, hi)."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)


def near_far(camera_positions, lo, hi) -> tuple[float, float]:
    """Near/far that bracket the box (lo, hi) from every camera: nearest box point, farthest corner."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = box_corners(lo, hi)
    near, far = float("inf"), 0.0
    for p in camera_positions:
        p = np.asarray(p, float)
        nearest = np.linalg.norm(p - np.clip(p, lo, hi))
        near = min(near, nearest)
        far = max(far, float(np.linalg.norm(corners - p, axis=1).max()))
    near = max(0.9 * near, 0.01 * far, 1e-3)
    return float(near), float(1.05 * far)
