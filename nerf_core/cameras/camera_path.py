"""nerfstudio's ``camera_path.json``: the camera paths its viewer and its Blender add-on write.

The format (nerfstudio ``nerfstudio/cameras/camera_paths.py``, ``get_path_from_json``)::

    {"camera_type": "perspective", "render_height": H, "render_width": W,
     "camera_path": [{"camera_to_world": [16 floats, row-major 4x4], "fov": DEGREES, "aspect": W/H}, ...],
     ...keyframes, seconds, fps... (ignored here)}

``fov`` is the *vertical* field of view in degrees (three.js convention): ``fy = fx = (H / 2) / tan(fov / 2)``,
principal point at the image centre. ``camera_to_world`` is OpenGL (+Y up, looking along -Z), the
same convention as our transforms files, and is taken to be in the dataset's world (what the
nerfstudio Blender add-on writes for a scene's camera). ``aspect`` is the viewer's window shape and
does not change the intrinsics (nerfstudio ignores it too). Only ``perspective`` cameras are
rendered (a missing ``camera_type`` means perspective, as in nerfstudio); fisheye, equirectangular
and stereo types are refused with an error naming the file and the type.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import List, Tuple

import numpy as np

from nerf_core.cameras.rays import Cameras
from nerf_core.contract.errors import PoseError
from nerf_core.contract.poses import parse_pose
from nerf_core.contract.transforms import MAX_FOCAL_PX, MIN_FOCAL_PX

MAX_SIDE = 16384  # pixels a side: larger is a unit mistake, not a render (as the render server)


class CameraPathError(ValueError):
    """A camera_path.json that cannot be rendered; the message names the file, camera and field."""


def is_camera_path(data) -> bool:
    """True for a parsed JSON document in nerfstudio's camera-path format."""
    return isinstance(data, dict) and "camera_path" in data


def _positive_int(data: dict, key: str, src: Path) -> int:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not 1 <= value <= MAX_SIDE or int(value) != value:
        raise CameraPathError(f"{src}: field {key!r} must be a positive whole number of pixels, at most {MAX_SIDE}, got {value!r}")
    return int(value)


def camera_path_intrinsics(fov_degrees: float, width: int, height: int) -> Tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels for a vertical field of view, as nerfstudio computes them (fx = inf
    for a field of view too small for a float's tangent)."""
    half = math.tan(math.radians(fov_degrees) / 2.0)
    f = 0.5 * height / half if half > 0 else math.inf
    return f, f, width / 2.0, height / 2.0


def cameras_from_camera_path(data: dict, src: Path | str) -> Tuple[Cameras, List[str]]:
    """Cameras (n views) and output stems ``frame_00000``... of a parsed camera_path.json.

    Raises CameraPathError naming ``src`` (and the camera index and field) for anything unusable.
    """
    src = Path(src)
    kind = data.get("camera_type", "perspective")
    if not isinstance(kind, str) or kind.lower() != "perspective":
        raise CameraPathError(f"{src}: field 'camera_type' is {kind!r}; only 'perspective' camera paths can be "
                              "rendered (fisheye, equirectangular and stereo cameras are not supported)")
    w = _positive_int(data, "render_width", src)
    h = _positive_int(data, "render_height", src)
    items = data.get("camera_path")
    if not isinstance(items, list) or not items:
        raise CameraPathError(f"{src}: field 'camera_path' must be a non-empty list of cameras")
    mats, fx, fy, cx, cy = [], [], [], [], []
    for k, cam in enumerate(items):
        where = f"{src}: camera_path[{k}]"
        if not isinstance(cam, dict):
            raise CameraPathError(f"{where}: expected an object with 'camera_to_world' and 'fov'")
        try:
            mats.append(parse_pose(cam.get("camera_to_world"), f"{where}: field 'camera_to_world'", flat_only=True))
        except PoseError as exc:
            raise CameraPathError(str(exc)) from None
        fov = cam.get("fov")
        if isinstance(fov, bool) or not isinstance(fov, (int, float)) or not 0.0 < fov < 180.0:
            raise CameraPathError(f"{where}: field 'fov' must be the vertical field of view in degrees "
                                  f"(0 < fov < 180), got {fov!r}")
        intr = camera_path_intrinsics(float(fov), w, h)
        if not MIN_FOCAL_PX <= intr[0] <= MAX_FOCAL_PX:  # a fov within a hair of 0 or 180 degrees
            raise CameraPathError(f"{where}: field 'fov' {fov!r} gives a focal length of {intr[0]:.3g} px for "
                                  f"{h} px; rays need one in [{MIN_FOCAL_PX:g}, {MAX_FOCAL_PX:g}]")
        for lst, v in zip((fx, fy, cx, cy), intr):
            lst.append(v)
    cams = Cameras.create(np.stack(mats), fx, fy, cx, cy, w, h)
    return cams, [f"frame_{k:05d}" for k in range(len(items))]
