"""The capture plan: every frame to render, decided once, and how ``--shard K/N`` divides it.

The plan is plain JSON (no bpy objects): the render signature, the world, the pass settings, the
scene bounds and, per frame, its key, split, camera, pose, intrinsics and file paths. It follows
from the scene, the layout settings and the seed alone, so every shard of a render farm computes
the same plan; ``plan_hash`` tells plans apart (a shard started with other settings is refused).

Shards count from 1: shard K of N renders the frames whose index ``i`` in ``plan["frames"]``
(train, then val, then test, each in camera order) has ``i % N == K - 1``. Round-robin spreads each
split over every shard, so shards take about equally long.
"""
from __future__ import annotations

import hashlib
import json
import re

PLAN_VERSION = 1
# Files a frame may own, as keys of its plan entry; all but the point cache are images.
FRAME_FILE_KEYS = ("image", "depth_file_path", "normal_file_path", "mask_path", "points_cache")
# What a frame entry of the plan carries besides its files (FRAME_FILE_KEYS).
FRAME_KEYS = ("index", "key", "split", "name", "camera", "transform_matrix", "intrinsics", "frame",
              "scale_removed", "hash")
SHARD_ASSIGNMENT = "frame i of plan.frames (counting from 0) belongs to shard (i mod N) + 1"


class CaptureError(RuntimeError):
    """A capture cannot start or continue; the message names the file, camera or setting."""


def round6(obj):
    """``obj`` with every float rounded to 6 decimals (hashes ignore float noise below that)."""
    if isinstance(obj, float):
        return round(obj, 6)
    if isinstance(obj, (list, tuple)):
        return [round6(v) for v in obj]
    if isinstance(obj, dict):
        return {k: round6(v) for k, v in obj.items()}
    return obj


def stable_hash(data) -> str:
    """16 hex digits identifying ``data`` (JSON, floats to 6 decimals); a frame's settings hash."""
    return hashlib.sha256(json.dumps(round6(data), sort_keys=True).encode()).hexdigest()[:16]


def plan_hash(plan: dict) -> str:
    """sha256 (hex) of the whole plan; equal plans, and only those, render the same dataset."""
    return hashlib.sha256(json.dumps(round6(plan), sort_keys=True).encode()).hexdigest()


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` -> (K, N) with 1 <= K <= N; ValueError naming the flag and the allowed range."""
    m = re.fullmatch(r"\s*(-?\d+)\s*/\s*(-?\d+)\s*", str(text))
    if not m:
        raise ValueError(f"--shard {text!r}: expected K/N, e.g. 1/4 (shard K of N, K counts from 1)")
    k, n = int(m.group(1)), int(m.group(2))
    if n < 1:
        raise ValueError(f"--shard {text!r}: N (the number of shards) must be at least 1")
    if not 1 <= k <= n:
        raise ValueError(f"--shard {text!r}: K must lie in 1..{n} (shards count from 1, "
                         f"like SLURM's --array=1-{n})")
    return k, n


def shard_frames(frames: list[dict], k: int, n: int) -> list[dict]:
    """The frames shard ``k`` of ``n`` renders (see SHARD_ASSIGNMENT)."""
    return [fr for i, fr in enumerate(frames) if i % n == k - 1]


def frame_files(split: str, name: str, depth: bool, normals: bool, masks: bool, points: bool,
                cache_dir: str) -> dict:
    """{file key: path relative to the dataset} of one frame; ``cache_dir`` holds point caches."""
    files = {"image": f"{split}/{name}.png"}
    if depth:
        files["depth_file_path"] = f"depth/{split}/{name}.exr"
    if normals:
        files["normal_file_path"] = f"normals/{split}/{name}.exr"
    if masks:
        files["mask_path"] = f"masks/{split}/{name}.png"
    if points and split == "train":
        files["points_cache"] = f"{cache_dir}/points/{split}_{name}.npz"
    return files


def make_plan(frames: list[dict], *, settings, render_sig: dict, world: dict, bounds, scene_name: str,
              blender_version: str, surroundings=()) -> dict:
    """The JSON plan of a capture; ``frames`` in plan order, ``settings`` a CaptureSettings.
    ``surroundings``: objects the scene box leaves out (``plan.planning.scene_box``), recorded when any."""
    keep = FRAME_KEYS + FRAME_FILE_KEYS
    lo, hi = bounds
    plan = {
        "version": PLAN_VERSION, "scene": scene_name, "blender_version": blender_version,
        "render": round6(render_sig), "world": world, "film_transparent": bool(settings.film_transparent),
        "resolution": [int(settings.res_x), int(settings.res_y)],
        "passes": {"depth": bool(settings.depth), "normals": bool(settings.normals),
                   "masks": bool(settings.masks), "points": bool(settings.points)},
        "n_points": int(settings.n_points), "seed": int(settings.seed), "layout": settings.layout,
        "bounds": {"min": [float(v) for v in lo], "max": [float(v) for v in hi]},
        "frames": [{k: fr[k] for k in keep if k in fr} for fr in frames],
    }
    if surroundings:
        plan["bounds"]["surroundings"] = sorted(surroundings)
    return plan


def shard_settings_error(plan: dict, plan_hash_value: str, other: dict, source: str) -> str | None:
    """Why a shard with ``plan`` cannot join a folder whose ``other`` plan record came from ``source``.

    ``other``: {"hash", "plan"} (a shard's state or a manifest's plan). None when they agree.
    """
    if other.get("hash") == plan_hash_value:
        return None
    theirs = other.get("plan") or {}
    diffs = [k for k in sorted(set(plan) | set(theirs)) if round6(plan.get(k)) != round6(theirs.get(k))]
    what = ", ".join(diffs[:4]) + (", ..." if len(diffs) > 4 else "") if diffs else "unknown"
    return (f"{source} was planned with other settings (differing: {what}); every shard must run the same "
            "scene, layout, seed and render settings. Use another --out, or delete that capture first")
