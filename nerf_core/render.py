"""Rendering a trained run: chunked full images, and novel views written to disk.

``python -m nerf_core render RUN --cameras TRANSFORMS.json --out DIR`` writes, per camera,
``DIR/<stem>.png`` (RGBA: straight colour, alpha = accumulated opacity), ``DIR/<stem>_depth.exr``
(planar z-depth in scene units, channel ``Z``, 0 where nothing was hit) and ``DIR/renders.json``.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np
import torch

from .cameras import Cameras, check_pose, PoseError, ray_bounds, rays_for_view
# Checkpoint reading moved to nerf_core.checkpoints; the names stay importable from here for callers
# written against render (scripts/benchmark.py reads model sizes through them).
from .checkpoints import CheckpointRefused, RunError, load_run, model_from_checkpoint, read_checkpoint  # noqa: F401
from .contract import config_path
from .progressbar import ProgressBar


# ----------------------------------------------------------------------------------------------
# rendering


@torch.no_grad()
def render_rays_chunked(model, rays_o, rays_d, near, far, background, chunk: int = 8192,
                        on_chunk: Optional[Callable[[int, int], None]] = None) -> Dict[str, torch.Tensor]:
    """Evaluation rendering of (m, 3) rays in chunks of ``chunk`` rays to bound memory.

    Returns rgb (m, 3), depth (m,) (distance along the ray) and acc (m,) on the rays' device.
    ``on_chunk(done, m)`` is called after each chunk (progress; it may raise to stop early).
    """
    out: Dict[str, List[torch.Tensor]] = {"rgb": [], "depth": [], "acc": []}
    bg = background.expand(rays_o.shape[0], 3) if background.dim() == 1 else background
    for s in range(0, rays_o.shape[0], chunk):
        e = s + chunk
        res = model.render_rays(rays_o[s:e], rays_d[s:e], near[s:e], far[s:e], bg[s:e], training=False)
        for k in out:
            out[k].append(res[k].detach().float().reshape(res[k].shape[0], -1).squeeze(-1) if k != "rgb" else res[k].detach().float())
        if on_chunk is not None:
            on_chunk(min(e, rays_o.shape[0]), rays_o.shape[0])
    return {k: torch.cat(v) for k, v in out.items()}


@torch.no_grad()
def render_view(
    model,
    cameras: Cameras,
    view: int,
    background=(1.0, 1.0, 1.0),
    near: Optional[float] = None,
    far: Optional[float] = None,
    chunk: int = 8192,
    on_chunk: Optional[Callable[[int, int], None]] = None,
) -> Dict[str, torch.Tensor]:
    """Render a whole camera on the model's device (``on_chunk``: see ``render_rays_chunked``).

    Returns CPU tensors: rgb (h, w, 3) composited onto ``background`` (onto the model's learned
    environment instead when it has one), acc (h, w), depth (h, w)
    (distance along the ray, normalised by acc where acc > 0) and z_depth (h, w) planar depth
    along the camera's -Z (0 where acc < 0.5).
    """
    device = model.aabb.device
    h, w = int(cameras.height[view]), int(cameras.width[view])
    check_view_memory(w, h, f"view {view}")
    rays_o, rays_d, z_per_t = rays_for_view(cameras, view)
    rays_o = rays_o.expand_as(rays_d).to(device)
    rays_d = rays_d.to(device)
    t0, t1 = model.ray_interval(rays_o, rays_d, near, far) if hasattr(model, "ray_interval") else \
        ray_bounds(rays_o, rays_d, model.aabb, near, far)
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    if getattr(model, "environment", None) is not None:
        bg = model.background(rays_d, bg)  # the learned world replaces the fixed colour
    res = render_rays_chunked(model, rays_o, rays_d, t0, t1, bg, chunk, on_chunk)
    acc = res["acc"].clamp(0, 1).cpu()
    dist = res["depth"].cpu()
    # Whether a model's depth is already divided by acc is method-specific; dividing again would be
    # wrong, so only use acc to mark empty pixels.
    z = torch.where(acc >= 0.5, dist * z_per_t, torch.zeros_like(dist))
    return {
        "rgb": res["rgb"].cpu().clamp(0, 1).reshape(h, w, 3),
        "acc": acc.reshape(h, w),
        "depth": dist.reshape(h, w),
        "z_depth": z.reshape(h, w),
    }


# Bytes per pixel that rendering a whole view holds at once: ray origins/directions and their pixel
# grid, per-ray bounds, the chunk outputs and their concatenation, the RGBA result and its PNG bytes.
BYTES_PER_PIXEL = 160
MIN_PIXELS_CHECKED = 4096 * 4096  # views up to 16 Mpx (2.7 GB) are never refused


def available_memory() -> int:
    """Bytes of memory this process could still get (MemAvailable on Linux, else physical memory)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return 1 << 62


def check_view_memory(w: int, h: int, where: str) -> None:
    """Refuse (RunError) to render a w x h view that would not fit in memory, before allocating any of it."""
    if w < 1 or h < 1:
        raise RunError(f"{where}: image size {w}x{h} px is empty; use a smaller --downscale")
    need = int(w) * int(h) * BYTES_PER_PIXEL
    have = available_memory()
    if w * h > MIN_PIXELS_CHECKED and need > have:
        raise RunError(f"{where}: {w}x{h} px needs about {need / 1e9:.1f} GB of memory to render, more than the "
                       f"{have / 1e9:.1f} GB available; render at a lower resolution (--downscale "
                       f"{math.ceil(math.sqrt(need / max(have, 1)))} or more)")


def unique_stems(stems: List[str]) -> List[str]:
    """Output names that never collide, whatever the input: ``a, a, a_1`` -> ``a, a_1, a_1_1``.

    Names are compared case-insensitively (macOS and Windows file systems are), and an empty name
    becomes ``view_XXX``.
    """
    used: set = set()
    out = []
    for k, s in enumerate(stems):
        base = str(s) or f"view_{k:03d}"
        cand, n = base, 0
        while cand.lower() in used:
            n += 1
            cand = f"{base}_{n}"
        used.add(cand.lower())
        out.append(cand)
    return out


# ----------------------------------------------------------------------------------------------
# camera files


def _camera_list(data, src: Path):
    """Cameras from a JSON list: each item a 4x4 matrix (intrinsics from the top level) or a dict
    with ``transform_matrix`` plus ``fl_x``/``fl_y``/``cx``/``cy``/``w``/``h`` or ``camera_angle_x``."""
    from .data import INTRINSIC_KEYS, _intrinsics, DatasetError

    items, glob = (data, {}) if isinstance(data, list) else (data.get("cameras"), data)
    if not isinstance(items, list) or not items:
        raise DatasetError(f"{src}: expected a list of cameras (or an object with 'frames' or 'cameras')")
    g = _intrinsics(glob, str(src)) if isinstance(glob, dict) else {}
    mats, params, stems = [], [], []
    for k, item in enumerate(items):
        where = f"{src}: camera {k}"
        m = item.get("transform_matrix") if isinstance(item, dict) else item
        try:
            mats.append(check_pose(m, f"{where}: field 'transform_matrix'"))
        except PoseError as exc:
            raise DatasetError(str(exc)) from exc
        intr = dict(g)
        if isinstance(item, dict):
            intr.update(_intrinsics(item, where))
        if "w" not in intr or "h" not in intr:
            raise DatasetError(f"{where}: fields 'w' and 'h' (image size in pixels) are required")
        W, H = intr["w"], intr["h"]
        if "fl_x" in intr:
            fx = intr["fl_x"]
        elif "camera_angle_x" in intr:
            fx = 0.5 * W / math.tan(0.5 * intr["camera_angle_x"])
        else:
            raise DatasetError(f"{where}: field 'fl_x' or 'camera_angle_x' is required")
        fy = intr.get("fl_y", fx)
        params.append((fx, fy, intr.get("cx", W / 2), intr.get("cy", H / 2), W, H))
        name = item.get("name") or item.get("file_path") if isinstance(item, dict) else None
        stems.append(Path(str(name)).stem if name else f"view_{k:03d}")
    p = np.asarray(params, dtype=np.float64)
    cams = Cameras.create(np.stack(mats), p[:, 0], p[:, 1], p[:, 2], p[:, 3], p[:, 4].astype(int), p[:, 5].astype(int))
    return cams, stems


def _all_frames(path: Path) -> tuple[Cameras, List[str]]:
    """Every frame of one transforms file (image sizes from ``w``/``h`` or the image headers)."""
    from .data import DatasetError, _frames_of, _read_json, cameras_of_frames

    frames = _frames_of(_read_json(path), path, add_png=True)
    if not frames:
        raise DatasetError(f"{path}: field 'frames' has no entries")
    return cameras_of_frames(frames), [f.stem for f in frames]


def cameras_from_file(path: Path | str, split: str = "test") -> tuple[Cameras, List[str]]:
    """Cameras and output stems to render.

    ``path`` may be a dataset folder (the frames of ``split``), a transforms file of either layout
    (all its frames; a nerfstudio file with ``*_filenames`` lists gives the frames of ``split``), a
    nerfstudio ``camera_path.json`` (``nerf_core.camera_path``), or a JSON list of cameras (see ``_camera_list``).
    """
    from .data import DatasetError, load_cameras

    path = Path(path)
    if path.is_dir():
        cams, frames = load_cameras(path, split)
        stems = [f.stem for f in frames]
    else:
        if not path.is_file():
            raise DatasetError(f"{path}: cameras file not found")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as exc:
            raise DatasetError(f"{path}: cannot read ({exc})") from exc
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from exc
        from .camera_path import cameras_from_camera_path, is_camera_path

        if is_camera_path(data):  # nerfstudio's camera_path.json (viewer, Blender add-on)
            cams, stems = cameras_from_camera_path(data, path)
        elif isinstance(data, dict) and "frames" in data:
            if data.get("train_filenames") is not None and not path.name.startswith("transforms_"):
                cams, frames = load_cameras(path, split)
                stems = [f.stem for f in frames]
            else:
                cams, stems = _all_frames(path)
        else:
            cams, stems = _camera_list(data, path)
    # Two frames with one basename (train/r_0 and test/r_0) must not overwrite each other's output.
    return cams, unique_stems(stems)


# ----------------------------------------------------------------------------------------------


def straight_rgba(res: Dict[str, torch.Tensor], opaque: bool) -> np.ndarray:
    """(h, w, 4) float32 RGBA with straight colour from ``render_view(..., background=(0, 0, 0))``.

    ``opaque`` (a run with a learned world): what the camera sees, background included, alpha 1,
    like the opaque capture it was trained on. Otherwise alpha = accumulated opacity.
    """
    acc = res["acc"]
    if opaque:
        return torch.cat([res["rgb"].clamp(0, 1), torch.ones_like(acc)[..., None]], -1).numpy()
    # Rendered onto black, the result is premultiplied: dividing by acc gives straight colour for RGBA.
    rgb = torch.where(acc[..., None] > 1e-6, res["rgb"] / acc[..., None].clamp_min(1e-6), torch.zeros_like(res["rgb"]))
    return torch.cat([rgb.clamp(0, 1), acc[..., None]], -1).numpy()


def render_to_dir(
    model,
    cameras: Cameras,
    stems: List[str],
    out: Path | str,
    overwrite: bool = False,
    near: Optional[float] = None,
    far: Optional[float] = None,
    chunk: int = 8192,
    extra: Optional[dict] = None,
    show_progress: bool = True,
    on_view: Optional[Callable[[int, str], None]] = None,
) -> Path:
    """Render every camera into ``out``; returns the path of ``renders.json``.

    Refuses (RunError listing the files) to replace existing outputs unless ``overwrite``.
    """
    out = Path(out)
    stems = unique_stems(stems)  # colliding names would overwrite each other's images
    for v in range(len(stems)):
        check_view_memory(int(cameras.width[v]), int(cameras.height[v]), f"camera {v} ({stems[v]})")
    targets = [out / "renders.json"]
    for s in stems:
        targets += [out / f"{s}.png", out / f"{s}_depth.exr"]
    existing = [t for t in targets if t.exists()]
    if existing and not overwrite:
        names = ", ".join(t.name for t in existing[:5]) + (f" and {len(existing) - 5} more" if len(existing) > 5 else "")
        raise RunError(f"{out}: would overwrite existing {names}; pass --overwrite or choose another --out")
    from .imageio import write_exr, write_png

    out.mkdir(parents=True, exist_ok=True)
    frames = []
    bar = ProgressBar(total=len(stems), label="render", enabled=show_progress)
    opaque = getattr(model, "environment", None) is not None
    for v, stem in enumerate(stems):
        res = render_view(model, cameras, v, background=(0.0, 0.0, 0.0), near=near, far=far, chunk=chunk)
        rgba = straight_rgba(res, opaque)
        write_png(out / f"{stem}.png", rgba)
        write_exr(out / f"{stem}_depth.exr", {"Z": res["z_depth"].numpy()})
        frames.append({
            "file_path": f"{stem}.png",
            "depth_file_path": f"{stem}_depth.exr",
            "transform_matrix": cameras.c2w[v].tolist(),
            "fl_x": float(cameras.fx[v]), "fl_y": float(cameras.fy[v]),
            "cx": float(cameras.cx[v]), "cy": float(cameras.cy[v]),
            "w": int(cameras.width[v]), "h": int(cameras.height[v]),
            "camera_angle_x": float(cameras.fov_x()[v]),
        })
        bar.update(1, info=stem)
        if on_view:
            on_view(v, stem)
    bar.close()
    meta = {"frames": frames, "depth": "planar z-depth in scene units, EXR channel Z, 0 where nothing was hit",
            "alpha": ("1: opaque, the learned environment is composited behind the scene" if opaque else
                      "accumulated opacity; colour is straight (not premultiplied)"),
            "background": "environment" if opaque else "transparent", "created": time.time()}
    meta.update(extra or {})
    tmp = out / ".renders.json.tmp"
    tmp.write_text(json.dumps(meta, indent=2), encoding="utf-8")
    tmp.replace(out / "renders.json")
    return out / "renders.json"


def render_run(run, cameras_path, out, split="test", overwrite=False, device=None, downscale: float = 1.0,
               chunk: int = 8192, checkpoint=None, show_progress=True) -> Path:
    """The ``render`` subcommand: render a run's latest checkpoint for the cameras of a file."""
    from .device import pick_device

    dev = pick_device(device)
    model, config, ckpt = load_run(run, dev, checkpoint)
    if cameras_path is None:
        cameras_path = config.get("dataset")
        if not cameras_path:
            raise RunError(f"{config_path(run)}: no 'dataset' recorded; pass --cameras")
    cams, stems = cameras_from_file(cameras_path, split)
    if downscale != 1.0:
        cams = cams.scaled(1.0 / downscale)
    return render_to_dir(
        model, cams, stems, out, overwrite=overwrite, near=config.get("near"), far=config.get("far"), chunk=chunk,
        extra={"run": str(Path(run).resolve()), "step": ckpt.get("step"), "method": ckpt.get("method"),
               "cameras": str(Path(cameras_path).resolve())},
        show_progress=show_progress,
    )
