"""Datasets for the studies: demo scenes captured once and reused, and datasets derived from them.

``ensure_dataset`` builds a demo scene and captures it (through ``scripts/make_demo_scene.py`` and
``scripts/capture.py``) unless a capture with the same settings is cached; ``subset_views`` and
``perturb_poses`` derive stress-test copies (fewer train views, noisy train poses) whose images are
links, never touching the source. Only the standard library at module level (numpy on use).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import time
from typing import Callable, Optional, Sequence

from .runner import REPO_ROOT, BenchError, run_cli, script_cmd


def _demo_capture():
    """``addon/capture/demo/capture_flags.py`` as a module (None when the file is missing), loaded by path:
    importing the ``addon`` package would import bpy."""
    import importlib.util

    path = os.path.join(REPO_ROOT, "addon", "capture", "demo", "capture_flags.py")
    if not os.path.isfile(path):
        return None
    spec = importlib.util.spec_from_file_location("_nerf_bridge_demo_capture", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def demo_capture_defaults(scene: str) -> dict:
    """Capture settings demo scene ``scene`` needs (``addon/capture/demo/capture_flags.py``: e.g. opaque,
    layout inside)."""
    module = _demo_capture()
    return module.capture_defaults(scene) if module else {}


def demo_scene_names() -> list[str]:
    """The demo scenes ``make_demo_scene.py`` builds (``addon/capture/demo/capture_flags.SCENES``; [] when unknown)."""
    module = _demo_capture()
    return list(getattr(module, "SCENES", {})) if module else []


def settings_key(settings: dict) -> str:
    """Stable short hash of capture settings: the cache key of a captured dataset."""
    blob = json.dumps(settings, sort_keys=True, separators=(",", ":"))
    return hashlib.sha1(blob.encode()).hexdigest()[:10]


def dataset_is_complete(path: str) -> bool:
    return all(os.path.isfile(os.path.join(path, f"transforms_{s}.json")) for s in ("train", "test"))


def ensure_dataset(
    scene: str,
    root: str,
    settings: dict,
    log_path: Optional[str] = None,
    capture_args: Callable[[str, str, dict], list[str]] | None = None,
) -> tuple[str, bool]:
    """Capture demo scene ``scene`` into ``root/<scene>-<key>`` unless a matching capture is there.

    ``settings`` (resolution, view counts, ...) are written to ``<dataset>.settings.json`` beside the
    dataset folder (outside it, so instant-ngp-style loaders never read it). A cached dataset is reused only
    when that file matches exactly; a half-written one (no transforms) is captured again into a fresh
    folder, never over the user's data. Returns (dataset path, reused?).

    Scenes that need their own capture flags (``demo_capture_defaults``: hdri and interior are opaque,
    interior uses the inside layout) get them merged under ``settings`` (``settings`` wins), so they
    are part of the cache key and of the capture's flags; object scenes' keys are unchanged.
    """
    os.makedirs(root, exist_ok=True)
    settings = {**demo_capture_defaults(scene), **settings}
    key = settings_key({"scene": scene, **settings})
    ds = os.path.join(root, f"{scene}-{key}")
    stamp = ds + ".settings.json"
    if dataset_is_complete(ds) and os.path.isfile(stamp):
        with open(stamp, encoding="utf-8") as fh:
            if json.load(fh) == {"scene": scene, **settings}:
                return ds, True
    if os.path.exists(ds):
        # An interrupted capture: move it aside instead of deleting, then capture afresh.
        shutil.move(ds, ds + f".incomplete-{int(time.time())}")
    blend = os.path.join(root, f"{scene}.blend")
    res = run_cli(script_cmd("make_demo_scene.py", scene, "--out", blend, "--overwrite"), log_path=log_path)
    if not res.ok or not os.path.isfile(blend):
        # Older make_demo_scene.py without --overwrite: retry plainly into a fresh file name.
        blend = os.path.join(root, f"{scene}-{key}.blend")
        if os.path.exists(blend):
            os.remove(blend)
        res = run_cli(script_cmd("make_demo_scene.py", scene, "--out", blend), log_path=log_path)
        if not res.ok or not os.path.isfile(blend):
            raise BenchError(f"demo scene {scene!r}: make_demo_scene.py failed: {res.error_message()}")
    args = (capture_args or default_capture_args)(blend, ds, settings)
    res = run_cli(script_cmd("capture.py", *args), log_path=log_path)
    if not res.ok or not dataset_is_complete(ds):
        raise BenchError(f"demo scene {scene!r}: capture.py failed: {res.error_message()}")
    with open(stamp, "w", encoding="utf-8") as fh:
        json.dump({"scene": scene, **settings}, fh, indent=1, sort_keys=True)
    return ds, False


def default_capture_args(blend: str, out: str, settings: dict) -> list[str]:
    """Flags of scripts/capture.py for ``settings`` (keys are the flag names without dashes)."""
    args = ["--blend", blend, "--out", out]
    for key, value in settings.items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        args += [flag] if value is True else [flag, str(value)]
    return args


def load_json(path: str) -> dict:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _write_json_file(path: str, obj) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=1)


def derive_dataset(src: str, dst: str, edit_train: Callable[[dict], dict], note: dict) -> str:
    """Copy dataset ``src`` to ``dst`` with the train split's JSON rewritten by ``edit_train``.

    Images are linked (copied where links are not allowed), so the original is never touched. The
    nerfstudio ``transforms.json`` (``nerfstudio/``, or the root in older captures) is not carried over: it
    would still list the unedited cameras.
    The edit is recorded in ``dst/nerf_capture/derived.json`` so a derived dataset is never mistaken
    for a capture.
    """
    if os.path.exists(dst):
        shutil.rmtree(dst)
    os.makedirs(dst)
    for name in os.listdir(src):
        s, d = os.path.join(src, name), os.path.join(dst, name)
        if name in ("transforms.json", "nerfstudio", "nerf_capture"):  # nerfstudio's file: root (old) or nerfstudio/
            continue
        if name.startswith("transforms_") and name.endswith(".json"):
            meta = load_json(s)
            if name == "transforms_train.json":
                meta = edit_train(meta)
            _write_json_file(d, meta)
            continue
        try:
            os.symlink(os.path.abspath(s), d)
        except OSError:
            (shutil.copytree if os.path.isdir(s) else shutil.copy2)(s, d)
    os.makedirs(os.path.join(dst, "nerf_capture"), exist_ok=True)
    _write_json_file(os.path.join(dst, "nerf_capture", "derived.json"), {"source": os.path.abspath(src), **note})
    return dst


def evenly_spaced(n_total: int, n_keep: int) -> list[int]:
    """Indices of ``n_keep`` frames spread over ``n_total`` (cameras on an orbit stay well spread)."""
    if n_keep >= n_total:
        return list(range(n_total))
    if n_keep <= 0:
        return []
    return sorted({int(math.floor(i * n_total / n_keep)) for i in range(n_keep)})


def subset_views(src: str, dst: str, n_views: int) -> str:
    """A copy of ``src`` whose train split keeps ``n_views`` evenly spread frames."""

    def edit(meta: dict) -> dict:
        frames = meta["frames"]
        if n_views > len(frames):
            raise BenchError(f"{src}: asked for {n_views} train views but transforms_train.json has {len(frames)}")
        meta = dict(meta)
        meta["frames"] = [frames[i] for i in evenly_spaced(len(frames), n_views)]
        return meta

    return derive_dataset(src, dst, edit, {"train_views": n_views})


def rotation_matrix(axis: Sequence[float], angle: float):
    import numpy as np

    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    c, s, C = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return np.array(
        [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
         [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
         [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]
    )


def perturb_pose(c2w, rot_deg: float, trans: float, rng):
    """Rotate ``c2w`` (4, 4) by ``rot_deg`` degrees about a random axis (about the camera centre) and
    move its centre by a random vector of length ``trans`` (scene units)."""
    import numpy as np

    c2w = np.asarray(c2w, dtype=np.float64).copy()
    axis = rng.normal(size=3)
    R = rotation_matrix(axis, math.radians(rot_deg))
    c2w[:3, :3] = R @ c2w[:3, :3]
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    c2w[:3, 3] = c2w[:3, 3] + trans * direction
    return c2w


def perturb_poses(src: str, dst: str, rot_deg: float, trans_frac: float, seed: int = 0) -> str:
    """A copy of ``src`` whose train poses are noisy: each camera is rotated by ``rot_deg`` degrees
    and shifted by ``trans_frac`` times the mean camera distance from the scene-box centre.

    Test and val poses stay exact, so held-out PSNR measures what pose error costs.
    """
    import numpy as np

    rng = np.random.default_rng(seed)

    def edit(meta: dict) -> dict:
        meta = dict(meta)
        poses = [np.asarray(f["transform_matrix"], dtype=np.float64) for f in meta["frames"]]
        aabb = meta.get("aabb")
        centre = np.mean(np.asarray(aabb, dtype=np.float64), axis=0) if aabb else np.zeros(3)
        radius = float(np.mean([np.linalg.norm(p[:3, 3] - centre) for p in poses])) if poses else 1.0
        frames = []
        for f, p in zip(meta["frames"], poses):
            f = dict(f)
            f["transform_matrix"] = perturb_pose(p, rot_deg, trans_frac * radius, rng).tolist()
            frames.append(f)
        meta["frames"] = frames
        return meta

    return derive_dataset(src, dst, edit, {"pose_noise_deg": rot_deg, "pose_noise_trans_frac": trans_frac,
                                           "seed": seed})


def count_frames(dataset: str, split: str) -> int:
    path = os.path.join(dataset, f"transforms_{split}.json")
    return len(load_json(path)["frames"]) if os.path.isfile(path) else 0

