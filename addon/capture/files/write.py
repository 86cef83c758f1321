"""Writing a capture's dataset files from its plan: transforms files, point cloud, manifest.

One writer for both ways a capture ends: ``CaptureJob`` (one machine: after every frame, and at
the end) and ``run.merge`` (a farm: once, after every shard). Given the same plan and frames
both write the same transforms files and point cloud, byte for byte.
"""
from __future__ import annotations

import os
import time

import numpy as np
import tomllib

from ...bridge.core_contract import contract
from ...bridge.core_path import ADDON_DIR
from ...dataset import aabb, capture_manifest, points, transforms
from ...file_writes import write_png_gray
from ...scene import passes
from ..plan.frame_plan import SHARD_ASSIGNMENT, round6

FORMAT = "nerf_bridge_capture"
SPLITS = ("train", "val", "test")
_ADDON_MANIFEST = os.path.join(ADDON_DIR, "blender_manifest.toml")


def addon_version() -> str | None:
    """The add-on's ``version`` from its blender_manifest.toml; None when it cannot be read."""
    try:
        with open(_ADDON_MANIFEST, "rb") as fh:
            version = tomllib.load(fh).get("version")
    except (OSError, ValueError):
        return None
    return str(version) if version is not None else None


def near_far_of(plan: dict) -> tuple[float, float]:
    """Near/far bracketing the scene box from every planned camera (not only those rendered yet)."""
    cams = [fr["transform_matrix"] for fr in plan["frames"]]
    return aabb.near_far([[m[0][3], m[1][3], m[2][3]] for m in cams], plan["bounds"]["min"], plan["bounds"]["max"])


def write_point_cloud(out: str, frames: list[dict]) -> bool:
    """points3d.ply from the point caches of ``frames`` (plan order); False when none has points."""
    pts, cols, nrms = [], [], []
    for fr in frames:
        if "points_cache" in fr:
            with np.load(os.path.join(out, fr["points_cache"])) as z:
                pts.append(z["points"])
                cols.append(z["colors"])
                nrms.append(z["normals"])
    if not pts:
        return False
    points.write_ply(os.path.join(out, "points3d.ply"), np.concatenate(pts), np.concatenate(cols),
                     np.concatenate(nrms))
    return True


def nerfstudio_depth(out: str, frames: list[dict]) -> None:
    """Give each frame with a depth EXR its 16-bit millimetre PNG under ``nerfstudio/depth/`` (made
    from the EXR when missing or older), as ``nerfstudio_depth_file_path``.

    nerfstudio reads ``depth_file_path`` with OpenCV as integers times its ``depth_unit_scale_factor``
    (a command-line option, 1e-3 unless set, never read from the JSON): an EXR there fails to load,
    or (channel ``Z``) loads as zeros, which turns depth supervision off without a word.
    """
    for fr in frames:
        if not fr.get("depth_file_path"):
            continue
        rel = f"{transforms.NERFSTUDIO_DIR}/depth/{fr['split']}/{fr['name']}.png"
        src, dst = os.path.join(out, fr["depth_file_path"]), os.path.join(out, rel)
        if not os.path.isfile(dst) or os.path.getmtime(dst) < os.path.getmtime(src):
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            write_png_gray(dst, passes.depth_millimetres(passes.read_exr_channels(src)["Z"]))
        fr["nerfstudio_depth_file_path"] = rel


def write_dataset(out: str, plan: dict, done_keys: set, complete: bool, manifest_info: dict) -> tuple[float, float]:
    """Transforms files of the frames in ``done_keys``, the point cloud when ``complete``, the manifest.

    ``manifest_info``: what ``manifest`` needs besides the plan (see there). Returns (near, far).
    """
    done = [fr for fr in plan["frames"] if fr["key"] in done_keys]
    near, far = near_far_of(plan)
    lo, hi = plan["bounds"]["min"], plan["bounds"]["max"]
    beyond = bool(plan["bounds"].get("surroundings")) or not plan["film_transparent"]
    cams = [[m[0][3], m[1][3], m[2][3]] for m in (fr["transform_matrix"] for fr in plan["frames"])]
    common = {"aabb": [list(map(float, lo)), list(map(float, hi))],
              "near": near, "far": far, "aabb_scale": aabb.ngp_aabb_scale(lo, hi, cams, beyond),
              "film_transparent": bool(plan["film_transparent"]), "world": plan["world"],
              # the film's pixel filter: a NeRF renders edge pixels through it to match the images
              "pixel_filter": (plan["render"].get("pixel_filter")
                               or contract.film_filter_field(contract.DEFAULT_FILTER_KIND))}
    if plan["bounds"].get("surroundings"):  # left out of the box, they still render: a NeRF must reach past it
        common["beyond_box"] = list(plan["bounds"]["surroundings"])
    if plan["passes"]["depth"]:
        common["depth_unit_scale_factor"] = 1.0  # EXR depth is already in scene units, not millimetres
    if plan["passes"]["points"] and complete and write_point_cloud(out, done):
        common["ply_file_path"] = "points3d.ply"
    if any(fr["split"] == "train" for fr in done):
        frames = [dict(fr) for fr in done]
        nerfstudio_depth(out, frames)
        transforms.write_transforms(out, frames, common)
        # Captures before nerfstudio/ wrote nerfstudio's file at the root, where instant-ngp loads
        # it beside the split files (every frame twice). It is this capture's own file: drop it.
        legacy = os.path.join(out, "transforms.json")
        if os.path.isfile(legacy):
            os.remove(legacy)
    info = dict(manifest_info, status="complete" if complete else "incomplete", near=near, far=far)
    capture_manifest.write_manifest(out, manifest(plan, done_keys, info))
    return near, far


def manifest(plan: dict, done_keys: set, info: dict) -> dict:
    """The reproducibility manifest (nerf_capture/manifest.json) as a dict.

    ``info``: status, created, blend_file, blend_sha256, blend_unsaved_changes, plan_hash, near, far,
    file_sha256 ({frame key: {file key: sha256}}), shards (N, or None for a one-machine capture).
    """
    sha = info.get("file_sha256") or {}
    frames = {}
    for fr in plan["frames"]:
        key = fr["key"]
        entry = {"hash": fr["hash"], "camera": fr["camera"], "done": key in done_keys, "frame": fr["frame"],
                 "files": {k: fr[k] for k in ("image", "depth_file_path", "normal_file_path", "mask_path") if k in fr}}
        if key in done_keys and sha.get(key):
            entry["sha256"] = sha[key]
        if fr.get("scale_removed"):
            entry["camera_scale_removed"] = fr["scale_removed"]
        frames[key] = entry
    lo, hi = plan["bounds"]["min"], plan["bounds"]["max"]
    shards = info.get("shards")
    return {
        "format": FORMAT, "format_version": 1, "status": info["status"],
        "created": info.get("created"), "updated": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "blender_version": plan["blender_version"], "addon_version": addon_version(),
        "blend_file": info.get("blend_file"), "blend_sha256": info.get("blend_sha256"),
        "blend_unsaved_changes": bool(info.get("blend_unsaved_changes")),
        "scene_signature": info.get("scene_signature"), "appearance_signature": info.get("appearance_signature"),
        "scene": plan["scene"],
        "render": round6(plan["render"]),
        "film_transparent": bool(plan["film_transparent"]), "world": plan["world"],
        "seed": plan["seed"], "layout": plan["layout"],
        "normalization": {"scale": 1.0, "offset": [0.0, 0.0, 0.0], "applied": False,
                          "note": "coordinates are Blender world coordinates, unchanged"},
        "bounds": {"min": list(map(float, lo)), "max": list(map(float, hi))},
        "near": info.get("near"), "far": info.get("far"),
        "conventions": {
            "camera": "OpenGL (+X right, +Y up, looks along -Z); transform_matrix = matrix_world without scale",
            "depth": "planar z-depth along -Z in scene units, float32 EXR channel Z, inf = no surface "
                     "(nerfstudio: set its depth-unit-scale-factor to 1, it assumes millimetres)",
            "normals": "world-space unit normals, float32 EXR channels X, Y, Z; 0 = no surface",
            "mask": "8-bit PNG, 255 = pixel of the target objects, 0 = elsewhere",
            "points": "points3d.ply: x y z, nx ny nz (unit, out of the surface, towards the camera that saw it), "
                      "red green blue",
        },
        "counts": {s: sum(f["split"] == s for f in plan["frames"]) for s in SPLITS},
        "frames": frames,
        "shards": None if not shards else {"count": int(shards), "assignment": SHARD_ASSIGNMENT},
        "plan_hash": info.get("plan_hash"),
        "plan": plan,
    }
