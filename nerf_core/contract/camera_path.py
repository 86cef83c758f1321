"""nerfstudio's ``camera_path.json`` as data (standard library + numpy): reading its cameras and writing one.

The format (nerfstudio ``nerfstudio/cameras/camera_paths.py``, ``get_path_from_json``; its viewer and
its Blender add-on write it)::

    {"camera_type": "perspective", "render_height": H, "render_width": W,
     "camera_path": [{"camera_to_world": [16 floats, row-major 4x4], "fov": DEGREES, "aspect": W/H}, ...],
     "fps": F, "seconds": S, ...keyframes, smoothness_value, is_cycle, crop (ignored when read)}

``fov`` is the *vertical* field of view in degrees (three.js convention): ``fy = fx = (H / 2) / tan(fov / 2)``,
principal point at the image centre. ``camera_to_world`` is OpenGL (+Y up, looking along -Z), the
same convention as our transforms files, and is taken to be in the dataset's world. ``aspect`` is the
viewer's window shape and does not change the intrinsics (nerfstudio ignores it too). Only
``perspective`` cameras are read (a missing ``camera_type`` means perspective, as in nerfstudio);
fisheye, equirectangular and stereo types are refused with an error naming the file and the type.

``path_views`` reads (``nerf_core.cameras.camera_path`` for rendering, the add-on for importing);
``camera_path_document`` writes (the add-on's camera-path export). One rule each way: a camera path
cannot hold a lens shift or non-square pixels, so the writer refuses them, naming the frames.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import List, Sequence

import numpy as np

from .errors import PoseError
from .numbers import is_number
from .poses import parse_pose
from .transforms import MAX_FOCAL_PX, MIN_FOCAL_PX

MAX_SIDE = 16384  # pixels a side: larger is a unit mistake, not a render (as the render server)
# How far a view's principal point may sit from the image centre, and its fx from its fy (relative),
# and still be written as a camera path: float round-off of a centred, square-pixel camera.
CENTRE_TOLERANCE_PX = 1e-6
SQUARE_TOLERANCE = 1e-9


class CameraPathError(ValueError):
    """A camera_path.json that cannot be read or written; the message names the file, camera and field."""


def is_camera_path(data) -> bool:
    """True for a parsed JSON document in nerfstudio's camera-path format."""
    return isinstance(data, dict) and "camera_path" in data


def _positive_int(data: dict, key: str, src: Path) -> int:
    value = data.get(key)
    if not is_number(value) or not 1 <= value <= MAX_SIDE or int(value) != value:
        raise CameraPathError(
            f"{src}: field {key!r} must be a positive whole number of pixels, at most {MAX_SIDE}, got {value!r}"
        )
    return int(value)


def camera_path_intrinsics(fov_degrees: float, width: int, height: int) -> tuple:
    """(fx, fy, cx, cy) in pixels for a vertical field of view, as nerfstudio computes them (fx = inf
    for a field of view too small for a float's tangent)."""
    half = math.tan(math.radians(fov_degrees) / 2.0)
    f = 0.5 * height / half if half > 0 else math.inf
    return f, f, width / 2.0, height / 2.0


def fov_degrees(fy: float, height: float) -> float:
    """The vertical field of view in degrees of a focal length ``fy`` (pixels) over ``height`` pixels:
    the inverse of ``camera_path_intrinsics``."""
    return math.degrees(2.0 * math.atan(0.5 * height / fy))


def exact_fov_degrees(fy: float, height: int) -> float:
    """``fov_degrees(fy, height)``, moved by the few float steps (rarely any) it takes for
    ``camera_path_intrinsics`` to give back ``fy`` at float32 precision, the renderer's
    (``cameras.rays.Cameras``): a written camera path renders with the very focal length it was
    written from, so it draws the same rays as the camera it came from."""
    fov = fov_degrees(fy, height)
    want = np.float32(fy)
    for _ in range(64):
        got = np.float32(camera_path_intrinsics(fov, height, height)[1])
        if got == want:
            break
        fov = math.nextafter(fov, 0.0 if got < want else 180.0)  # a smaller field of view: a longer focal length
    return fov


def path_views(data: dict, src: Path | str) -> List[dict]:
    """The cameras of a parsed camera_path.json: one dict per ``camera_path`` entry with ``c2w``
    ((4, 4) float64), ``fx fy cx cy`` (pixels), ``w h`` (int) and ``fov`` (degrees, as written).

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
    views = []
    for k, cam in enumerate(items):
        where = f"{src}: camera_path[{k}]"
        if not isinstance(cam, dict):
            raise CameraPathError(f"{where}: expected an object with 'camera_to_world' and 'fov'")
        try:
            c2w = parse_pose(cam.get("camera_to_world"), f"{where}: field 'camera_to_world'", flat_only=True)
        except PoseError as exc:
            raise CameraPathError(str(exc)) from None
        fov = cam.get("fov")
        if not is_number(fov) or not 0.0 < fov < 180.0:
            raise CameraPathError(f"{where}: field 'fov' must be the vertical field of view in degrees "
                                  f"(0 < fov < 180), got {fov!r}")
        fx, fy, cx, cy = camera_path_intrinsics(float(fov), w, h)
        if not MIN_FOCAL_PX <= fx <= MAX_FOCAL_PX:  # a fov within a hair of 0 or 180 degrees
            raise CameraPathError(f"{where}: field 'fov' {fov!r} gives a focal length of {fx:.3g} px for "
                                  f"{h} px; rays need one in [{MIN_FOCAL_PX:g}, {MAX_FOCAL_PX:g}]")
        views.append({"c2w": c2w, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "w": w, "h": h, "fov": float(fov)})
    return views


def path_range(data: dict, src: Path | str) -> tuple:
    """(near, far) of a parsed camera_path.json, or (None, None): our additive top-level fields, the
    exporting camera's clip range, which the render engine renders with (nerfstudio ignores them).
    Raises CameraPathError naming ``src`` for values that are not positive numbers with far > near."""
    near, far = data.get("near"), data.get("far")
    if near is None and far is None:
        return None, None
    for key, value in (("near", near), ("far", far)):
        if not is_number(value) or not value > 0:
            raise CameraPathError(f"{src}: field {key!r} must be a positive distance, got {value!r}")
    if far <= near:
        raise CameraPathError(f"{src}: field 'far' ({far!r}) must be greater than 'near' ({near!r})")
    return float(near), float(far)


def camera_path_document(views: Sequence[dict], fps: float, where: str = "camera", clip=None) -> dict:
    """A camera_path.json object for ``views`` (one per frame, in order), each a dict with ``c2w``
    (4x4, OpenGL camera-to-world in the dataset's world), ``fx fy cx cy w h`` (pixels) and an optional
    ``label`` naming it in messages (e.g. "frame 12").

    Every view must share one ``w`` x ``h`` (``render_width``/``render_height``), have square pixels
    (fx = fy) and its principal point at the image centre: the format holds a vertical field of view
    only. Raises CameraPathError naming ``where`` and the frames that break a rule. Each entry gets its
    own ``fov`` (an animated focal length) and ``aspect`` (w / h); ``seconds`` = frames / ``fps``.
    ``clip`` = (near, far) is written as the top-level ``near``/``far`` (``path_range``).
    """
    if not views:
        raise CameraPathError(f"{where}: no frames to write")
    w, h = int(views[0]["w"]), int(views[0]["h"])
    label = [v.get("label", f"view {k}") for k, v in enumerate(views)]
    problems = []
    other = [label[k] for k, v in enumerate(views) if (int(v["w"]), int(v["h"])) != (w, h)]
    if other:
        problems.append(f"{', '.join(other)} render at another size than {w}x{h} (one camera path has one size)")
    shifted = [
        label[k]
        for k, v in enumerate(views)
        if abs(v["cx"] - 0.5 * v["w"]) > CENTRE_TOLERANCE_PX or abs(v["cy"] - 0.5 * v["h"]) > CENTRE_TOLERANCE_PX
    ]
    if shifted:
        problems.append(f"{', '.join(shifted)} have a lens shift (principal point off the image centre), which a "
                        "camera path cannot hold: set Shift X and Y to 0")
    stretched = [label[k] for k, v in enumerate(views) if abs(v["fx"] - v["fy"]) > SQUARE_TOLERANCE * v["fy"]]
    if stretched:
        problems.append(f"{', '.join(stretched)} have non-square pixels (fx != fy), which a camera path cannot hold: "
                        "set the pixel aspect to 1:1")
    if problems:
        raise CameraPathError(f"{where}: " + "; ".join(problems))
    path = []
    for v in views:
        c2w = np.asarray(v["c2w"], dtype=np.float64).reshape(4, 4)
        path.append({"camera_to_world": [float(x) for x in c2w.reshape(-1)],
                     "fov": exact_fov_degrees(float(v["fy"]), h), "aspect": w / h})
    return {"camera_type": "perspective", "render_width": w, "render_height": h, "camera_path": path,
            "fps": float(fps), "seconds": len(views) / float(fps), "smoothness_value": 0.0, "is_cycle": False,
            "crop": None, **({"near": float(clip[0]), "far": float(clip[1])} if clip else {})}
