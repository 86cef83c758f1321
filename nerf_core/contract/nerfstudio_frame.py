"""nerfstudio's world and ours: ``dataparser_transforms.json`` read, applied and undone (standard library + numpy).

nerfstudio's dataparsers re-orient, re-centre and re-scale the poses they read before training
(``auto_orient_and_center_poses``, then the scale that fits the cameras into [-1, 1]), and write what
they did to ``OUTPUT/dataparser_transforms.json``: ``{"transform": 3x4 [R | t], "scale": s}``. A point
``p`` of the dataset's world lands at ``p' = s (R p + t)`` in nerfstudio's; a camera-to-world matrix
``C`` becomes ``[R C_R | s (R C_t + t)]`` (rotation ``R C_R``, the camera's axes and so the OpenGL
convention untouched). Everything nerfstudio exports (``ns-export`` point clouds and meshes, the viewer's
``camera_path.json``) lives in its world; ``to_dataset_*`` bring it back exactly.

Our captures write the scene's own world into the dataset (the manifest records the only change a
capture makes, dropping a camera's scale), so undoing nerfstudio's transform puts results in the
Blender scene's frame.
"""
from __future__ import annotations

from pathlib import Path
from typing import Tuple

import numpy as np

from .errors import DatasetError
from .jsonfile import read_json
from .numbers import is_number

DATAPARSER_FILE = "dataparser_transforms.json"
ROTATION_TOLERANCE = 1e-5  # |R^T R - I|: a transform that is not a rotation is refused, not guessed at


# The scales a dataparser writes fit a scene into about a unit box; beyond these, poses leave float range.
MIN_SCALE, MAX_SCALE = 1e-6, 1e6


def read_dataparser_transform(path: Path | str) -> Tuple[np.ndarray, float]:
    """(R|t as (3, 4) float64, scale) of a ``dataparser_transforms.json`` (or of an output folder holding one).

    Raises DatasetError naming the file and field: a missing file, a transform that is not 3x4 (or
    4x4 with a last row 0 0 0 1) or whose 3x3 part is not a rotation, a scale that is not positive.
    """
    path = Path(path)
    if path.is_dir():
        path = path / DATAPARSER_FILE
    if not path.is_file():
        raise DatasetError(f"{path}: file not found (nerfstudio writes {DATAPARSER_FILE} into its output folder)")
    data = read_json(path)
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected an object with 'transform' and 'scale'")
    raw = data.get("transform")
    try:
        m = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape == (4, 4) and np.allclose(m[3], (0, 0, 0, 1)):
        m = m[:3]
    if m.shape != (3, 4) or not np.all(np.isfinite(m)):
        raise DatasetError(f"{path}: field 'transform' must be a 3x4 matrix [R | t] of finite numbers")
    if np.abs(m[:, :3].T @ m[:, :3] - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(m[:, :3]) < 0:
        raise DatasetError(f"{path}: field 'transform': its 3x3 part is not a rotation")
    scale = data.get("scale", 1.0)
    if not is_number(scale) or not scale > 0:
        raise DatasetError(f"{path}: field 'scale' must be a positive number, got {scale!r}")
    if not MIN_SCALE <= scale <= MAX_SCALE:  # 1e-300 would put every camera at infinity, and exit 0
        raise DatasetError(f"{path}: field 'scale' is {scale!r}, outside {MIN_SCALE:g}..{MAX_SCALE:g}: nerfstudio "
                           "scales a scene to about a unit box, so this is not a file it wrote")
    return m, float(scale)


def dataset_to_nerfstudio_matrix(transform: np.ndarray, scale: float) -> np.ndarray:
    """(4, 4) M with ``p' = M p`` (homogeneous) taking points of the dataset's world into nerfstudio's."""
    m = np.eye(4)
    m[:3] = scale * np.asarray(transform, dtype=np.float64)
    return m


def nerfstudio_to_dataset_matrix(transform: np.ndarray, scale: float) -> np.ndarray:
    """(4, 4) inverse of ``dataset_to_nerfstudio_matrix``: ``p = R^T (p' / s - t)``. As a Blender
    object's ``matrix_world`` it puts geometry exported by nerfstudio into the dataset's world."""
    r, t = np.asarray(transform, dtype=np.float64)[:, :3], np.asarray(transform, dtype=np.float64)[:, 3]
    m = np.eye(4)
    m[:3, :3] = r.T / scale
    m[:3, 3] = -r.T @ t
    return m


def to_dataset_points(points: np.ndarray, transform: np.ndarray, scale: float) -> np.ndarray:
    """(n, 3) points of nerfstudio's world in the dataset's world."""
    r, t = np.asarray(transform, dtype=np.float64)[:, :3], np.asarray(transform, dtype=np.float64)[:, 3]
    return (np.asarray(points, dtype=np.float64) / scale - t) @ r


def to_dataset_pose(c2w: np.ndarray, transform: np.ndarray, scale: float) -> np.ndarray:
    """A (4, 4) camera-to-world matrix of nerfstudio's world in the dataset's world (no scale in the result)."""
    r, t = np.asarray(transform, dtype=np.float64)[:, :3], np.asarray(transform, dtype=np.float64)[:, 3]
    c2w = np.asarray(c2w, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = r.T @ c2w[:3, :3]
    out[:3, 3] = r.T @ (c2w[:3, 3] / scale - t)
    return out


def to_nerfstudio_pose(c2w: np.ndarray, transform: np.ndarray, scale: float) -> np.ndarray:
    """A (4, 4) camera-to-world matrix of the dataset's world in nerfstudio's (the inverse of ``to_dataset_pose``)."""
    r, t = np.asarray(transform, dtype=np.float64)[:, :3], np.asarray(transform, dtype=np.float64)[:, 3]
    c2w = np.asarray(c2w, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = r @ c2w[:3, :3]
    out[:3, 3] = scale * (r @ c2w[:3, 3] + t)
    return out
