"""COLMAP's pose convention against ours (standard library + numpy; docs/CONTRACTS.md, "COLMAP folder").

``qvec``/``tvec`` map world to camera, ``X_cam = R(q) X + t``, in OpenCV camera axes (x right, y down,
z forward). Our ``c2w`` is OpenGL (y up, looking along -z), so ``w2c = inverse(c2w @ diag(1, -1, -1, 1))``
(``pose_to_colmap``) and back (``pose_from_colmap``).
"""
from __future__ import annotations

import math
from typing import Tuple

import numpy as np

# OpenGL camera axes -> OpenCV's (and back): flip y and z
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> (4,) unit quaternion (w, x, y, z) with w >= 0 (Shepperd's method: stable for
    every rotation, unlike the trace formula near 180 degrees)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    cands = np.array([t, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(cands))
    if k == 0:
        w = math.sqrt(1.0 + t) / 2
        q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(max(0.0, 1.0 + R[i, i] - R[j, j] - R[m, m])) * 2
        q = np.zeros(4)
        q[0] = (R[m, j] - R[j, m]) / s
        q[1 + i] = s / 4
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + m] = (R[m, i] + R[i, m]) / s
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(4,) quaternion (w, x, y, z), normalised first -> (3, 3) rotation."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def pose_to_colmap(c2w: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Our (4, 4) OpenGL camera-to-world -> COLMAP's world-to-camera (qvec (4,), tvec (3,)), OpenCV axes."""
    c2w_cv = np.asarray(c2w, dtype=np.float64) @ GL_TO_CV
    R = c2w_cv[:3, :3].T
    t = -R @ c2w_cv[:3, 3]
    return rotmat_to_qvec(R), t


def pose_from_colmap(qvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """COLMAP's world-to-camera (qvec, tvec) -> our (4, 4) OpenGL camera-to-world."""
    R = qvec_to_rotmat(qvec)
    c2w_cv = np.eye(4)
    c2w_cv[:3, :3] = R.T
    c2w_cv[:3, 3] = -R.T @ np.asarray(tvec, dtype=np.float64)
    return c2w_cv @ GL_TO_CV
