"""Camera poses in transforms files and requests: the one parser of a camera-to-world matrix, and the
rules a pose must keep (finite, rigid, within float32's reach of the origin). Standard library and numpy.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .errors import PoseError

# Training and rendering work in float32, which keeps about 7 significant digits: at 1e6 units from the
# origin neighbouring positions are 0.06 apart, so a scene placed that far out (or a box that large)
# loses its detail. Coordinates beyond this are refused, with advice to move the scene nearer the origin.
MAX_COORDINATE = 1e6


def short_repr(value, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for messages about values of the wrong kind."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def coordinate_problem(values, what: str) -> Optional[str]:
    """Why the finite coordinates ``values`` (any shape) cannot be trained in float32, or None:
    the message says ``what`` lies how far out, and how to fix it."""
    far_out = float(np.max(np.abs(np.asarray(values, dtype=np.float64))))
    if far_out <= MAX_COORDINATE:
        return None
    return (f"{what} reaches {far_out:.3g} units from the origin, beyond {MAX_COORDINATE:.0e}: training works in "
            "float32 (7 significant digits), which cannot resolve detail that far out; move the scene and its "
            "cameras nearer the origin, or use larger units")


def _first_non_number(value):
    """The first entry of a nested list that is a string or a bool (None when there is none)."""
    if isinstance(value, (list, tuple)):
        for v in value:
            found = _first_non_number(v)
            if found is not None:
                return found
        return None
    return value if isinstance(value, (str, bool)) else None


def check_pose(matrix, where: str = "transform_matrix", scale_tol: float = 1e-3) -> np.ndarray:
    """Validate a camera-to-world matrix and return it as float64 (4, 4) (a (3, 4) gets [0, 0, 0, 1]).

    Raises PoseError naming ``where`` for wrong shape, NaN/inf, a position beyond ``MAX_COORDINATE``, a
    singular or scaled/sheared rotation part, a reflection, or a bottom row other than [0, 0, 0, 1].
    """
    bad = _first_non_number(matrix)
    if bad is not None:
        # numpy would quietly turn "1.0" into 1.0 and True into 1; other loaders refuse them.
        raise PoseError(f"{where}: entries must be JSON numbers, got {bad!r}")
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise PoseError(f"{where}: not a numeric matrix ({exc})") from exc
    if m.shape == (3, 4):
        m = np.vstack([m, [0, 0, 0, 1]])
    if m.shape != (4, 4):
        raise PoseError(f"{where}: expected a 4x4 matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise PoseError(f"{where}: contains NaN or inf (or a number too large for a float)")
    far_out = coordinate_problem(m[:3, 3], "the camera position")
    if far_out:
        raise PoseError(f"{where}: {far_out}")
    rot = m[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # entries near 1e308: inf, then refused as scaled
        det = np.linalg.det(rot)
        gram = rot.T @ rot
    if abs(det) < 1e-8:
        raise PoseError(f"{where}: rotation part is singular (determinant {det:.3g})")
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


def parse_pose(raw, where: str, flat_only: bool = False) -> np.ndarray:
    """The one parser of a camera-to-world matrix written in JSON; returns float64 (4, 4).

    Args:
        raw: the JSON value: a 4x4 (or 3x4) nested list, or 16 numbers row-major (nerfstudio's
            ``camera_to_world``, the render server's ``c2w``).
        where: what the message names, e.g. ``"request 3: field 'c2w'"``.
        flat_only: accept only the 16 numbers (camera_path.json's form).
    Returns:
        (4, 4) float64, checked by ``check_pose``.
    Raises:
        PoseError naming ``where``: strings or booleans among the entries, the wrong count, or a
        matrix ``check_pose`` refuses.
    """
    bad = _first_non_number(raw)
    if bad is not None:
        # numpy would quietly turn "1.0" into 1.0 and True into 1; other loaders refuse them.
        raise PoseError(f"{where}: entries must be JSON numbers, got {bad!r}")
    want = "must hold 16 numbers (a row-major 4x4)" if flat_only else "must be a 4x4 matrix (or 16 numbers, row-major)"
    try:
        m = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise PoseError(f"{where} {want}") from None
    if m.size != 16 or (flat_only and m.ndim != 1):
        raise PoseError(f"{where} {want}, got {m.size} numbers")
    return check_pose(m.reshape(4, 4), where)
