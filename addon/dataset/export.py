"""Dataset files: intrinsics from Blender cameras, transforms JSON, point cloud, manifest.

Follows ../shared/CONVENTIONS.md and docs/CONTRACTS.md: ``transforms_{train,val,test}.json`` with
``file_path`` without extension (the only JSON at the root), nerfstudio's ``transforms.json`` with
real file names and split lists in ``nerfstudio/`` (instant-ngp loads every ``*.json`` of the folder
it is given: beside the split files it would load every frame twice), every intrinsic, and the
manifest in ``nerf_capture/manifest.json``.
Only ``camera_intrinsics``, ``camera_to_world`` and ``cameras_transforms`` touch bpy objects.
"""
from __future__ import annotations

import json
import os

import numpy as np

from ..bridge.core_contract import contract

MANIFEST_DIR = "nerf_capture"
MANIFEST_NAME = "manifest.json"
NERFSTUDIO_DIR = "nerfstudio"  # holds nerfstudio's transforms.json; its paths are relative to it ("../train/r_0.png")
SPLITS = ("train", "val", "test")
PER_FRAME_INTRINSICS = ("camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h")  # what a frame may carry


class ExportError(ValueError):
    """A camera or scene cannot be exported; the message names the object or file."""


def intrinsics_from_params(lens, sensor_width, sensor_height, sensor_fit, shift_x, shift_y,
                           res_x, res_y, pixel_aspect_x=1.0, pixel_aspect_y=1.0) -> dict:
    """Pinhole intrinsics in pixels matching Blender's viewplane (BKE_camera_params_compute_viewplane).

    Sensor fit picks which image side the sensor size spans (AUTO: the longer one, in pixel-aspect
    units). Lens shift is in units of that side: shift_x > 0 moves the view right, so the principal
    point moves left (cx = w/2 - shift_x * side); shift_y > 0 moves the view up, so in top-down pixel
    rows the principal point moves down (cy = h/2 + shift_y * side).
    """
    ycor = pixel_aspect_y / pixel_aspect_x
    if sensor_fit == "AUTO":
        sensor = sensor_width
        fit = "HORIZONTAL" if pixel_aspect_x * res_x >= pixel_aspect_y * res_y else "VERTICAL"
    elif sensor_fit == "HORIZONTAL":
        sensor, fit = sensor_width, "HORIZONTAL"
    elif sensor_fit == "VERTICAL":
        sensor, fit = sensor_height, "VERTICAL"
    else:
        raise ExportError(f"unknown sensor fit {sensor_fit!r}")
    viewfac = res_x if fit == "HORIZONTAL" else ycor * res_y
    fx = lens * viewfac / sensor
    fy = fx / ycor
    cx = 0.5 * res_x - shift_x * viewfac
    cy = 0.5 * res_y + shift_y * viewfac / ycor
    return {
        "camera_angle_x": contract.fov_from_focal(fx, res_x),
        "camera_angle_y": contract.fov_from_focal(fy, res_y),
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": int(res_x), "h": int(res_y),
        "camera_model": "OPENCV", "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
    }


def camera_intrinsics(cam_obj, render) -> dict:
    """Intrinsics of a Blender camera object for the scene's render settings (resolution %, aspect)."""
    cam = cam_obj.data
    if cam.type != "PERSP":
        from ..capture.layouts import camera_label

        raise ExportError(f"{camera_label(cam_obj)} is {cam.type.lower()}; only perspective cameras make a NeRF dataset")
    scale = render.resolution_percentage / 100.0
    res_x, res_y = int(render.resolution_x * scale), int(render.resolution_y * scale)
    return intrinsics_from_params(cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit, cam.shift_x,
                                  cam.shift_y, res_x, res_y, render.pixel_aspect_x, render.pixel_aspect_y)


def camera_to_world(cam_obj) -> list[list[float]]:
    """``matrix_world`` with scale removed, as 4 rows (OpenGL axes, never pre-flipped)."""
    from ..capture.layouts import camera_scale_error

    err = camera_scale_error(cam_obj)
    if err:
        raise ExportError(err)
    m = cam_obj.matrix_world.normalized()
    return [[float(v) for v in row] for row in m]


def shared_intrinsics(frames: list[dict]) -> dict | None:
    """The intrinsics all frames share (to write once at the top level), else None."""
    keys = ("fl_x", "fl_y", "cx", "cy", "w", "h")
    first = frames[0]["intrinsics"]
    for fr in frames[1:]:
        if any(abs(fr["intrinsics"][k] - first[k]) > 1e-6 for k in keys):
            return None
    return first


def _atomic_json(path: str, data: dict) -> None:
    tmp = path + ".partial"
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=2)
    os.replace(tmp, path)


def _frame_entry(f: dict, folder: str, per_frame_intrinsics: bool, nerfstudio: bool, path_prefix: str = "") -> dict:
    """One frame of a transforms file: ``./folder/name`` (synthetic) or ``folder/name.png`` (nerfstudio),
    every file path behind ``path_prefix`` (``../`` for nerfstudio's file in its own folder)."""
    path = f"{path_prefix}{folder}/{f['name']}.png" if nerfstudio else f"./{folder}/{f['name']}"
    entry = {"file_path": path, "transform_matrix": f["transform_matrix"]}
    if per_frame_intrinsics:  # instant-ngp and nerfstudio both read these
        for k in PER_FRAME_INTRINSICS:
            entry[k] = f["intrinsics"][k]
    for key in ("depth_file_path", "normal_file_path", "mask_path"):
        if f.get(key):
            entry[key] = path_prefix + f[key]
    if f.get("frame") is not None:
        entry["blender_frame"] = f["frame"]  # not "time": nerfstudio reads that as dynamic-scene time
    if f.get("camera"):
        entry["camera"] = f["camera"]
    return entry


def transforms_document(frames: list[dict], common: dict, folder: str, nerfstudio: bool = False,
                        intrinsics_of: list[dict] | None = None, per_frame: bool = False,
                        path_prefix: str = "") -> dict:
    """The transforms object of ``frames``, all in ``folder``: the one writer of transforms JSON, for
    the capture's files and the Compare panel's camera files alike.

    ``frames``: dicts with name ("r_3"), transform_matrix, intrinsics (``intrinsics_from_params``),
    optional depth/normal/mask relative paths (with extension), ``frame`` (Blender frame) and
    ``camera`` (object name). Intrinsics that all of ``intrinsics_of`` (default ``frames``) share go
    to the top level, else (or with ``per_frame``) they go on every frame. ``nerfstudio``: real file names
    (``folder/name.png``) instead of ``./folder/name``; ``path_prefix`` goes before every file path of a
    frame (nerfstudio's file lives in ``nerfstudio/``, one folder below the images). ``common``: aabb, near, far, ply_file_path...
    """
    basis = frames if intrinsics_of is None else intrinsics_of
    if not basis:
        raise ExportError("no frames to write")
    shared = shared_intrinsics(basis)
    top = {k: v for k, v in (shared or basis[0]["intrinsics"]).items() if k not in ("camera_angle_y",)}
    top.update(common)
    top["frames"] = [_frame_entry(f, folder, per_frame or shared is None, nerfstudio, path_prefix) for f in frames]
    return top


def write_transforms(out_dir: str, frames: list[dict], common: dict) -> list[str]:
    """Write transforms_{train,val,test}.json and nerfstudio's nerfstudio/transforms.json; return the paths.

    ``frames``: as ``transforms_document`` wants them, each with its ``split`` (and, with depth, the
    ``nerfstudio_depth_file_path`` of its millimetre PNG, ``capture_write.nerfstudio_depth``). Every file shares one
    top level, taken from all frames. Paths in the split files are relative to ``out_dir``; in
    nerfstudio's file (which nerfstudio resolves against its own folder) they start with ``../``.
    """
    if not frames:
        raise ExportError(f"{out_dir}: no rendered frames to export")
    written = []
    ns_frames = []
    per_split_files = {s: [] for s in SPLITS}
    for split in SPLITS:
        split_frames = [f for f in frames if f["split"] == split]
        doc = transforms_document(split_frames, common, split, intrinsics_of=frames)
        ns_split = transforms_document(split_frames, common, split, nerfstudio=True, intrinsics_of=frames,
                                       path_prefix="../")["frames"]
        for f, entry in zip(split_frames, ns_split):
            if f.get("nerfstudio_depth_file_path"):  # millimetre PNGs, the depth nerfstudio reads
                entry["depth_file_path"] = "../" + f["nerfstudio_depth_file_path"]
        if common.get("film_transparent"):
            # nerfstudio samples rays only where mask_path is white: with object masks it would never
            # see the transparent background, so free space would go untaught (and a batch larger than
            # the object's pixels fails). The alpha already outlines the objects there.
            for entry in ns_split:
                entry.pop("mask_path", None)
        ns_frames += ns_split
        per_split_files[split] = [e["file_path"] for e in ns_split]
        path = os.path.join(out_dir, f"transforms_{split}.json")
        _atomic_json(path, doc)
        written.append(path)
    ns_doc = transforms_document([], common, "", intrinsics_of=frames)
    if shared_intrinsics(frames) is None:
        # nerfstudio-data reads a top-level intrinsic for every frame, ignoring the frame's own: here
        # the frames alone carry them. (The split files keep the first frame's camera_angle_x, the one
        # field their loaders read; the capture and `check` warn that those loaders misplace the rest.)
        for key in PER_FRAME_INTRINSICS:
            ns_doc.pop(key, None)
    if any(f.get("nerfstudio_depth_file_path") for f in frames):
        ns_doc["depth_unit_scale_factor"] = 1e-3  # nerfstudio's own default: its PNGs hold millimetres
    if "ply_file_path" in ns_doc:
        ns_doc["ply_file_path"] = "../" + ns_doc["ply_file_path"]
    ns_doc.update({f"{s}_filenames": per_split_files[s] for s in SPLITS})
    ns_doc["frames"] = ns_frames
    os.makedirs(os.path.join(out_dir, NERFSTUDIO_DIR), exist_ok=True)
    path = os.path.join(out_dir, NERFSTUDIO_DIR, "transforms.json")
    _atomic_json(path, ns_doc)
    written.append(path)
    return written


def cameras_transforms(cameras, scene, size, frames=None, base: dict | None = None, prefix: str = "view") -> dict:
    """A transforms object (``transforms_document``) for Blender cameras rendered at ``size`` = (w, h),
    for ``nerf_core render`` (the Compare panel's selected cameras or fly-through).

    With ``frames``, ``cameras`` must hold one camera and one view is written per frame (a fly-through
    along its animation). ``base`` supplies near/far/aabb from the run's dataset. Raises ValueError
    (ExportError) when a camera's aspect differs from ``size`` (the run renders the aspect it trained
    on), for a camera that is not perspective, scaled or sheared, and without cameras.
    """
    import bpy  # bpy.path.clean_name: the rule for file names made from object names

    w, h = int(size[0]), int(size[1])
    r = scene.render
    res_x, res_y = r.resolution_x * r.pixel_aspect_x, r.resolution_y * r.pixel_aspect_y
    if abs(res_x / res_y - w / h) > 0.005 * (w / h):
        names = ", ".join(repr(c.name) for c in cameras)
        raise ExportError(
            f"camera {names} renders at {r.resolution_x}x{r.resolution_y} in this scene "
            f"(aspect {res_x / res_y:.3f}) but the run was trained on {w}x{h} (aspect {w / h:.3f}): set "
            f"Output Properties > Resolution to the same aspect, or render the run's own cameras")
    common = {k: v for k, v in (base or {}).items() if k in ("near", "far", "aabb", "aabb_scale")}
    out_frames = []
    saved_frame = scene.frame_current
    try:
        shots = [(cameras[0], f) for f in frames] if frames is not None else [(c, None) for c in cameras]
        for cam, frame in shots:
            if cam.type != "CAMERA":
                raise ExportError(f"object {cam.name!r} is not a camera")
            if frame is not None:
                scene.frame_set(frame)
            data = cam.data
            if data.type != "PERSP":
                raise ExportError(f"camera {cam.name!r} is {data.type.lower()}; only perspective cameras can be rendered")
            intr = intrinsics_from_params(data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                                          data.shift_x, data.shift_y, w, h, r.pixel_aspect_x, r.pixel_aspect_y)
            out_frames.append({"name": f"frame_{frame:04d}" if frame is not None else bpy.path.clean_name(cam.name),
                               "transform_matrix": camera_to_world(cam), "intrinsics": intr, "frame": frame,
                               "camera": cam.name})
    finally:
        scene.frame_set(saved_frame)
    if not out_frames:
        raise ExportError("no cameras to render")
    # Every frame carries its intrinsics, as camera files always have (the top level holds the first's).
    return transforms_document(out_frames, common, prefix, per_frame=True)


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


def write_ply(path: str, points: np.ndarray, colors: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Binary little-endian PLY: float x y z, float nx ny nz (when ``normals`` is given), uchar red green blue.

    points, normals: (n, 3) float32; colors: (n, 3) uint8. The property order is the one 3D Gaussian
    Splatting's ``fetchPly`` reads (it needs the normals).
    """
    n = len(points)
    props = "property float x\nproperty float y\nproperty float z\n"
    fields = [("p", "<f4", 3)]
    if normals is not None:
        props += "property float nx\nproperty float ny\nproperty float nz\n"
        fields.append(("n", "<f4", 3))
    fields.append(("c", "u1", 3))
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n" + props +
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    ).encode("ascii")
    rec = np.empty(n, dtype=fields)
    rec["p"] = points
    if normals is not None:
        rec["n"] = normals
    rec["c"] = colors
    tmp = path + ".partial"
    with open(tmp, "wb") as fh:
        fh.write(header)
        fh.write(rec.tobytes())
    os.replace(tmp, path)


def backproject(depth: np.ndarray, rgb: np.ndarray, intr: dict, c2w, stride: int = 1):
    """World points and colours of the pixels with finite depth.

    depth: (h, w) planar z (inf = none); rgb: (h, w, 3) uint8; c2w: 4x4 rows. Returns (n, 3) float32, (n, 3) uint8.
    """
    h, w = depth.shape
    j, i = np.mgrid[0:h:stride, 0:w:stride]
    z = depth[j, i]
    ok = np.isfinite(z) & (z > 0)
    i, j, z = i[ok], j[ok], z[ok]
    x = (i + 0.5 - intr["cx"]) / intr["fl_x"] * z
    y = -(j + 0.5 - intr["cy"]) / intr["fl_y"] * z
    cam = np.stack([x, y, -z, np.ones_like(z)], axis=1)
    world = cam @ np.asarray(c2w, float).T
    return world[:, :3].astype(np.float32), rgb[j, i]


def manifest_path(out_dir: str) -> str:
    return os.path.join(out_dir, MANIFEST_DIR, MANIFEST_NAME)


def read_manifest(out_dir: str) -> dict | None:
    """The capture manifest of ``out_dir``, None when there is none; ExportError if unreadable."""
    path = manifest_path(out_dir)
    if not os.path.exists(path):
        return None
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError) as exc:
        raise ExportError(f"{path}: unreadable capture manifest ({exc}); move the folder aside or pass --overwrite")


def _json_lines(obj, levels: int, indent: str = "") -> str:
    """JSON with one line per entry for the outer ``levels`` of dicts/lists, compact below.

    ``json.dump(indent=...)`` runs Python's pure-Python encoder; the manifest is rewritten after every
    frame and holds the whole plan, so its inner values go through the C encoder instead.
    """
    if levels <= 0 or not isinstance(obj, (dict, list)) or not obj:
        return json.dumps(obj)
    inner = indent + " "
    if isinstance(obj, dict):
        items = [f"{inner}{json.dumps(str(k))}: {_json_lines(v, levels - 1, inner)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    return "[\n" + ",\n".join(inner + _json_lines(v, levels - 1, inner) for v in obj) + "\n" + indent + "]"


_PLAN_TEXT: dict = {}  # (plan_hash, id(plan)) -> its JSON: a capture's plan is fixed while it rewrites the manifest


def write_manifest(out_dir: str, manifest: dict) -> None:
    """Write the capture manifest atomically (one line per frame entry: quick to rewrite, easy to read).

    The capture rewrites it after every frame; its ``plan`` (fixed for the capture, identified by
    ``plan_hash``) is encoded once, so the per-frame cost does not grow with it.
    """
    os.makedirs(os.path.join(out_dir, MANIFEST_DIR), exist_ok=True)
    plan, key = manifest.get("plan"), (manifest.get("plan_hash"), id(manifest.get("plan")))
    lines = []
    for k, v in manifest.items():
        if k == "plan" and plan is not None and key[0]:
            if key not in _PLAN_TEXT:
                _PLAN_TEXT.clear()
                _PLAN_TEXT[key] = _json_lines(plan, 1, " ")
            text = _PLAN_TEXT[key]
        else:
            text = _json_lines(v, 1, " ")
        lines.append(f" {json.dumps(str(k))}: {text}")
    path = manifest_path(out_dir)
    tmp = path + ".partial"
    with open(tmp, "w") as fh:
        fh.write("{\n" + ",\n".join(lines) + "\n}\n")
    os.replace(tmp, path)
