"""Lens models of a transforms file: which are read, and what their coefficients mean (standard library only).

nerfstudio, instant-ngp and COLMAP's converters write a camera's distortion next to its intrinsics:
``camera_model`` and ``k1 k2 k3 k4 p1 p2``, at the top level or per frame (a frame's field overrides
the file's, field by field, as for the intrinsics). Two models are read, with nerfstudio's meanings,
in OpenCV's normalised image coordinates (x right, y down, z = 1 in front of the camera):

- ``OPENCV`` (Brown-Conrady; also assumed when ``camera_model`` is absent, and for the pinhole names
  when their distortion is non-zero):
  ``x_d = x r + 2 p1 x y + p2 (rr + 2 x²)``, ``y_d = y r + p1 (rr + 2 y²) + 2 p2 x y`` with
  ``rr = x² + y²`` and ``r = 1 + k1 rr + k2 rr² + k3 rr³ + k4 rr⁴``;
- ``OPENCV_FISHEYE`` (equidistant, Kannala-Brandt; also what instant-ngp's ``"is_fisheye": true``
  means, which its colmap2nerf writes instead of a ``camera_model``): with ``θ`` the angle from the optical axis,
  ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` and ``(x_d, y_d) = θ_d (x, y) / |(x, y)|``; it has no
  tangential terms, so ``p1``/``p2`` must be zero.

Pixels are ``u = cx + fl_x x_d``, ``v = cy + fl_y y_d``. The maths (distorting points, undistorting
pixels into rays) lives in ``nerf_core.cameras.distortion``; this module only reads and validates the fields.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "PERSPECTIVE")
LENS_MODELS = ("OPENCV", "OPENCV_FISHEYE")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
# FULL_OPENCV's rational terms and the thin-prism ones: no model here reads them, so a non-zero value
# is refused rather than dropped.
UNREAD_KEYS = ("k5", "k6", "s1", "s2", "s3", "s4")


@dataclass(frozen=True)
class Lens:
    """A distorting lens: ``model`` in ``LENS_MODELS`` and ``coeffs`` = (k1, k2, k3, k4, p1, p2)."""

    model: str
    coeffs: Tuple[float, float, float, float, float, float]

    @property
    def fisheye(self) -> bool:
        return self.model == "OPENCV_FISHEYE"

    def fields(self) -> dict:
        """The JSON fields that write this lens back (``camera_model`` and the coefficients)."""
        return {"camera_model": self.model, **dict(zip(DISTORTION_KEYS, self.coeffs))}


def _model_name(value) -> Tuple[Optional[str], Optional[str]]:
    """(upper-case model name, problem)."""
    if value is None:
        return None, None
    if not isinstance(value, str) or value.upper() not in PINHOLE_MODELS + LENS_MODELS:
        return None, (
            f"{value!r} is not supported: the camera models read are {', '.join(PINHOLE_MODELS + LENS_MODELS)}. "
            "Reproject the images to one of them first (e.g. COLMAP's image_undistorter)"
        )
    return value.upper(), None


def _number(value) -> Tuple[float, Optional[str]]:
    if value is None:
        return 0.0, None
    if isinstance(value, bool):
        return 0.0, f"is not a number ({value!r})"
    try:
        number = float(value)
    except (TypeError, ValueError):
        return 0.0, f"is not a number ({value!r})"
    if not math.isfinite(number):
        return 0.0, f"must be a finite number, got {value!r}"
    return number, None


def lens_problem(src: dict) -> Optional[Tuple[str, str]]:
    """(field, what is wrong) for the lens fields of ``src`` (a transforms file or one frame) on their
    own, else None."""
    model, problem = _model_name(src.get("camera_model"))
    if problem:
        return "camera_model", problem
    fisheye = src.get("is_fisheye")
    if fisheye is not None and not isinstance(fisheye, bool):
        return "is_fisheye", f"must be true or false, got {fisheye!r}"
    if fisheye and model is not None and model != "OPENCV_FISHEYE":
        return "is_fisheye", f"says the camera is a fisheye, but camera_model is {src['camera_model']!r}"
    for key in DISTORTION_KEYS + UNREAD_KEYS:
        number, problem = _number(src.get(key))
        if problem:
            return key, problem
        if key in UNREAD_KEYS and number != 0.0:
            return key, (f"is a coefficient of a lens model that is not read here ({src[key]!r}); "
                         "only OPENCV (k1-k4, p1, p2) and OPENCV_FISHEYE (k1-k4) are")
    return None


def parse_lens(meta: Optional[dict], frame: Optional[dict]) -> Tuple[Optional[Lens], Optional[Tuple[str, str]]]:
    """(the frame's lens, or None for a pinhole; problem) with ``frame``'s fields over ``meta``'s.

    The problem is (field, message) for fields that cannot be read, or a fisheye with tangential terms.
    """
    for src in (meta or {}, frame or {}):
        problem = lens_problem(src)
        if problem:
            return None, problem
    merged = dict(meta or {})
    merged.update({k: v for k, v in (frame or {}).items() if k in ("camera_model", "is_fisheye") + DISTORTION_KEYS})
    model, _ = _model_name(merged.get("camera_model"))
    if model is None and merged.get("is_fisheye") is True:
        model = "OPENCV_FISHEYE"  # instant-ngp: read as OPENCV, a fisheye ray was off by up to 24 degrees
    coeffs = tuple(_number(merged.get(k))[0] for k in DISTORTION_KEYS)
    if model == "OPENCV_FISHEYE":
        for key, value in zip(DISTORTION_KEYS[4:], coeffs[4:]):
            if value != 0.0:
                return None, (
                    key,
                    f"is a tangential coefficient ({value!r}), which the OPENCV_FISHEYE model does not have",
                )
        return Lens("OPENCV_FISHEYE", coeffs), None  # a fisheye bends rays even with zero coefficients
    if all(c == 0.0 for c in coeffs):
        return None, None
    return Lens("OPENCV", coeffs), None
