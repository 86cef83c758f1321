"""Rendering a trained run: chunked full images, and novel views written to disk.

``python -m nerf_core render RUN --cameras TRANSFORMS.json --out DIR`` writes, per camera,
``DIR/<stem>.png`` (RGBA: straight colour, alpha = accumulated opacity), ``DIR/<stem>_depth.exr``
(planar z-depth in scene units, channel ``Z``, 0 where nothing was hit) and ``DIR/renders.json``;
for cameras whose frame has a ground-truth image also ``DIR/errors/<stem>.png`` (an error heat-map)
and that view's ``psnr``/``ssim`` in renders.json (docs/CONTRACTS.md). File names follow
``nerf_core.contract.naming``.
"""
from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np
import torch

from nerf_core.cameras.camera_path import cameras_from_camera_path, is_camera_path
from nerf_core.cameras.rays import Cameras, ray_bounds, rays_for_pixels, rays_for_view
from nerf_core.contract import config_path
from nerf_core.contract.intrinsics import resolve_intrinsics
from nerf_core.contract.lens import parse_lens
from nerf_core.contract.naming import frame_stem, render_files, unique_stems
from nerf_core.contract.transforms import (
    SPLITS,
    DatasetError,
    FrameInfo,
    PoseError,
    check_pose,
    detect_layout,
    frame_infos,
    parse_json_file,
    read_transforms,
)
from nerf_core.data.loading import cameras_of_frames, load_cameras, load_split

# Checkpoint reading moved to nerf_core.runs.checkpoints; the names stay importable from here for callers
# written against render (scripts/benchmark.py reads model sizes through them).
from nerf_core.errors import RunError
from nerf_core.image import pixel_filter as pf
from nerf_core.image.io import write_exr, write_png
from nerf_core.image.metrics import HEATMAP_VMAX, error_heatmap
from nerf_core.image.pixel_filter import (
    DEFAULT_SAMPLES,
    POINT,
    PixelFilter,
    edge_pixels,
)
from nerf_core.render.scoring import score_view
from nerf_core.runs.checkpoints import load_run
from nerf_core.runs.folder import dataset_changed_note
from nerf_core.utils.atomic import write_json_atomic
from nerf_core.utils.device import pick_device
from nerf_core.utils.progressbar import ProgressBar
from nerf_core.volume.volrend import composite_background

# ----------------------------------------------------------------------------------------------
# rendering


# On the CPU a model call is fastest when its samples' intermediate tensors stay in cache: measured
# at one thread on trained runs, vmgrid renders 1.28x faster in calls of 1024 rays than of 8192 and
# no faster below 512; nerf (128 samples per ray) 1.21x faster at 1024 rays than at 4096, 1.44x again
# at 512, 1.27x at 256, 1.11x at 128: ~16k samples per call. Calls are at most CPU_MAX_CALL_RAYS rays,
# fewer when the previous call reported more than CPU_SAMPLES_PER_CALL samples. A method whose samples
# are cheaper sets its own ray cap as ``cpu_call_rays`` (vmgrid: 2048, see there).
CPU_SAMPLES_PER_CALL = 1 << 14
CPU_MAX_CALL_RAYS = 512
CPU_MIN_CALL_RAYS = 64  # below this the per-call Python overhead dominates


@torch.no_grad()
def render_rays_chunked(model, rays_o, rays_d, near, far, background, chunk: int = 8192,
                        on_chunk: Optional[Callable[[int, int], None]] = None) -> Dict[str, torch.Tensor]:
    """Evaluation rendering of (m, 3) rays in model calls of at most ``chunk`` rays to bound memory.

    On the CPU calls are smaller: at most ``CPU_MAX_CALL_RAYS`` rays (or the model's ``cpu_call_rays``)
    and about ``CPU_SAMPLES_PER_CALL`` samples, from the ``n_samples`` the model returned for the
    previous call (per-ray results do not depend on the call size).
    Returns rgb (m, 3), depth (m,) (distance along the ray) and acc (m,) on the rays' device.
    ``on_chunk(done, m)`` is called after each call (progress; it may raise to stop early).
    """
    out: Dict[str, List[torch.Tensor]] = {"rgb": [], "depth": [], "acc": []}
    m = rays_o.shape[0]
    bg = background.expand(m, 3) if background.dim() == 1 else background
    cpu = rays_o.device.type == "cpu"
    cap = min(chunk, int(getattr(model, "cpu_call_rays", CPU_MAX_CALL_RAYS))) if cpu else chunk
    step = cap
    s = 0
    while s < m:
        e = min(s + step, m)
        res = model.render_rays(rays_o[s:e], rays_d[s:e], near[s:e], far[s:e], bg[s:e], training=False)
        for k in out:
            out[k].append(res[k].detach().float().reshape(res[k].shape[0], -1).squeeze(-1) if k != "rgb" else res[k].detach().float())
        if cpu and "n_samples" in res:
            per_ray = max(1.0, float(res["n_samples"]) / (e - s))
            step = int(min(cap, max(CPU_MIN_CALL_RAYS, CPU_SAMPLES_PER_CALL / per_ray)))
        s = e
        if on_chunk is not None:
            on_chunk(e, m)
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
    pixel_filter: Optional[PixelFilter] = None,
    filter_samples: int = DEFAULT_SAMPLES,
) -> Dict[str, torch.Tensor]:
    """Render a whole camera on the model's device (``on_chunk``: see ``render_rays_chunked``).

    ``pixel_filter``: the film's filter (``nerf_core.image.pixel_filter``): pixels at an edge of the centre-ray
    image become the mean of ``filter_samples`` rays drawn from it, as Cycles renders them; None (or
    the filter "NONE"): one ray through each pixel centre.

    Returns CPU tensors: rgb (h, w, 3) composited onto ``background`` (onto the model's learned
    environment instead when it has one), acc (h, w), depth (h, w)
    (distance along the ray, normalised by acc where acc > 0) and z_depth (h, w) planar depth
    along the camera's -Z (0 where acc < 0.5).
    """
    device = model.aabb.device
    h, w = int(cameras.height[view]), int(cameras.width[view])
    check_view_memory(w, h, f"view {view}")
    rays_o, rays_d, z_per_t = rays_for_view(cameras, view)
    res = _render_rays_of(model, rays_o, rays_d, background, near, far, chunk, on_chunk)
    rgb, acc = res["rgb"].cpu().clamp(0, 1).reshape(h, w, 3), res["acc"].clamp(0, 1).cpu().reshape(h, w)
    # Whether a model's depth is already divided by acc is method-specific; dividing again would be
    # wrong, so only use acc to mark empty pixels.
    dist = res["depth"].cpu().reshape(h, w)
    z = dist * z_per_t.reshape(h, w)
    n_rays = h * w
    if pixel_filter is not None and not pixel_filter.is_point and filter_samples > 1:
        rgb, acc, dist, z, n_rays = _filter_edges(model, cameras, view, rgb, acc, dist, z, pixel_filter, filter_samples,
                                                  background, near, far, chunk, on_chunk)
    return {
        "rgb": rgb,
        "acc": acc,
        "depth": dist,
        "z_depth": torch.where(acc >= 0.5, z, torch.zeros_like(z)),
        "n_rays": n_rays,  # rays rendered: one a pixel, and the filter's at edges
    }


def _render_rays_of(model, rays_o, rays_d, background, near, far, chunk, on_chunk) -> Dict[str, torch.Tensor]:
    """``render_rays_chunked`` of camera rays (origins (m, 3) or (1, 3), unit directions (m, 3)) on the
    model's device, over the model's own ray interval and its learned world when it has one."""
    device = model.aabb.device
    rays_o = rays_o.expand_as(rays_d).to(device)
    rays_d = rays_d.to(device)
    t0, t1 = model.ray_interval(rays_o, rays_d, near, far) if hasattr(model, "ray_interval") else \
        ray_bounds(rays_o, rays_d, model.aabb, near, far)
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    if getattr(model, "environment", None) is not None:
        bg = model.background(rays_d, bg)  # the learned world replaces the fixed colour
    return render_rays_chunked(model, rays_o, rays_d, t0, t1, bg, chunk, on_chunk)


def _filter_edges(model, cameras: Cameras, view: int, rgb: torch.Tensor, acc: torch.Tensor, dist: torch.Tensor,
                  z: torch.Tensor, pixel_filter: PixelFilter, samples: int, background, near, far, chunk,
                  on_chunk) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """rgb (h, w, 3) and acc (h, w) with every pixel at an edge of the centre-ray image (colour or
    opacity, ``pixel_filter.edge_pixels``) replaced by the mean of ``samples`` rays drawn from the
    filter; its distance ``dist`` and z-depth ``z`` (h, w) by those rays' opacity-weighted mean (the
    depth of what covers the pixel, so a pixel the filter makes opaque has one); and the number of
    rays rendered in all.

    A render of part of a frame (a Blender Render Region: the same camera, its principal point moved
    into the crop) gives its pixels what the whole frame gives them: edges are found with the pixels
    one beyond the image rendered too, and each pixel's draws are a hash of its place relative to the
    principal point (``PixelFilter.offsets``), not of its place in the request."""
    h, w = rgb.shape[:2]
    total = h * w
    # the one-pixel ring around the image, through offsets from the nearest pixel inside (a lens
    # camera's per-pixel tables cover only the image)
    ring_i = torch.cat([torch.arange(-1, w + 1), torch.arange(-1, w + 1), torch.full((h,), -1), torch.full((h,), w)])
    ring_j = torch.cat([torch.full((w + 2,), -1), torch.full((w + 2,), h), torch.arange(h), torch.arange(h)])
    inside_i, inside_j = ring_i.clamp(0, w - 1), ring_j.clamp(0, h - 1)
    step = torch.stack([ring_i - inside_i, ring_j - inside_j], dim=-1).float()
    views = torch.full((ring_i.shape[0],), int(view), dtype=torch.long)
    o, d, _ = rays_for_pixels(cameras, views, inside_i, inside_j, step)
    ring = _render_rays_of(model, o, d, background, near, far, chunk, None)
    # Edges of the scene itself, premultiplied, whatever fixed colour lies behind it: render (on black)
    # and eval (on white) refine the same pixels. A learned world is part of the picture.
    behind = None if getattr(model, "environment", None) is not None else torch.as_tensor(background, dtype=torch.float32)

    def scene_layer(c: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        c = c if behind is None else c - (1 - a).unsqueeze(-1) * behind
        return torch.cat([c, a.unsqueeze(-1)], dim=-1)

    padded = torch.zeros(h + 2, w + 2, 4)
    padded[1:-1, 1:-1] = scene_layer(rgb, acc)
    padded[ring_j + 1, ring_i + 1] = scene_layer(ring["rgb"].cpu().clamp(0, 1), ring["acc"].cpu().clamp(0, 1))
    jj, ii = edge_pixels(padded)[1:-1, 1:-1].nonzero(as_tuple=True)
    q = int(jj.shape[0])
    if q == 0:
        return rgb, acc, dist, z, total + ring_i.shape[0]
    keys = torch.stack([torch.round(ii.double() + 0.5 - float(cameras.cx[view])),
                        torch.round(jj.double() + 0.5 - float(cameras.cy[view]))], dim=-1).long()
    off = pixel_filter.offsets(q, samples, keys=keys).reshape(-1, 2)
    views = torch.full((q * samples,), int(view), dtype=torch.long)
    rays_o, rays_d, z_per_t = rays_for_pixels(cameras, views, ii.repeat_interleave(samples), jj.repeat_interleave(samples),
                                              off)
    # The centre pass has reported the whole view; these calls only let ``on_chunk`` stop the render.
    res = _render_rays_of(model, rays_o, rays_d, background, near, far, chunk,
                          None if on_chunk is None else (lambda done, m: on_chunk(total, total)))
    rgb, acc, dist, z = rgb.clone(), acc.clone(), dist.clone(), z.clone()
    rgb[jj, ii] = res["rgb"].cpu().clamp(0, 1).reshape(q, samples, 3).mean(dim=1)
    a = res["acc"].cpu().clamp(0, 1).reshape(q, samples)
    acc[jj, ii] = a.mean(dim=1)
    d = res["depth"].cpu().reshape(q, samples)
    hit = a.sum(dim=1) > 1e-6  # where no filter ray hits anything the centre ray's depth stays
    wsum = a.sum(dim=1).clamp_min(1e-6)
    dist[jj[hit], ii[hit]] = ((a * d).sum(dim=1) / wsum)[hit]
    z[jj[hit], ii[hit]] = ((a * d * z_per_t.cpu().reshape(q, samples)).sum(dim=1) / wsum)[hit]
    return rgb, acc, dist, z, total + ring_i.shape[0] + q * samples


def render_rate(seconds: float, rays: int) -> dict:
    """The timing fields ``render`` and ``eval`` report: ``render_seconds`` (wall time spent in the model
    rendering, without start-up, model loading, image files or metrics), ``rays`` and ``rays_per_s``."""
    return {"render_seconds": seconds, "rays": int(rays), "rays_per_s": rays / seconds if seconds > 0 else None}


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


# ----------------------------------------------------------------------------------------------
# camera files


def _camera_list(data, src: Path) -> tuple[Cameras, List[str]]:
    """Cameras from a JSON list: each item a 4x4 matrix (intrinsics from the top level) or a dict
    with ``transform_matrix`` plus intrinsics (``contract.resolve_intrinsics``; ``w`` and ``h`` required)."""
    if isinstance(data, list):
        items, glob = data, {}
    elif isinstance(data, dict):
        items, glob = data.get("cameras"), data
    else:  # a bare number or string
        items, glob = None, {}
    if not isinstance(items, list) or not items:
        raise DatasetError(f"{src}: expected a list of cameras (or an object with 'frames' or 'cameras')")
    mats, params, lenses = [], [], []
    for k, item in enumerate(items):
        where = f"{src}: camera {k}"
        m = item.get("transform_matrix") if isinstance(item, dict) else item
        try:
            mats.append(check_pose(m, f"{where}: field 'transform_matrix'"))
        except PoseError as exc:
            raise DatasetError(str(exc)) from exc
        own = item if isinstance(item, dict) else None
        params.append(resolve_intrinsics(glob, own, None, where))
        lens, problem = parse_lens(glob, own)
        if problem:
            raise DatasetError(f"{where}: field {problem[0]!r}: {problem[1]}")
        lenses.append(lens)
    p = np.asarray(params, dtype=np.float64)
    cams = Cameras.create(np.stack(mats), p[:, 0], p[:, 1], p[:, 2], p[:, 3], p[:, 4].astype(int), p[:, 5].astype(int),
                          lenses=lenses)
    return cams, [frame_stem(item, k) for k, item in enumerate(items)]


def camera_views(path: Path | str, split: str = "test") -> tuple[Cameras, List[str], List[Optional[FrameInfo]]]:
    """Cameras to render, their output stems (unique, ``contract.output_stems``'s rule) and, per camera,
    the transforms frame it came from (its ``image`` is the ground truth), None for a bare camera.

    ``path`` may be a dataset folder (the frames of ``split``), a transforms file of either layout
    (all its frames; a nerfstudio file with ``*_filenames`` lists gives the frames of ``split``), a
    nerfstudio ``camera_path.json`` (``nerf_core.cameras.camera_path``), or a JSON list of cameras (see ``_camera_list``).
    """

    path = Path(path)
    frames: List[Optional[FrameInfo]]
    if path.is_dir():
        cams, frames = load_cameras(path, split)
        stems = [f.stem for f in frames]
    else:
        if not path.is_file():
            raise DatasetError(f"{path}: cameras file not found")
        data = parse_json_file(path)

        if is_camera_path(data):  # nerfstudio's camera_path.json (viewer, Blender add-on)
            cams, stems = cameras_from_camera_path(data, path)
            frames = [None] * len(stems)
        elif isinstance(data, dict) and "frames" in data:
            if data.get("train_filenames") is not None and not path.name.startswith("transforms_"):
                cams, frames = load_cameras(path, split)
            else:
                frames = read_transforms(path)
                cams = cameras_of_frames(frames)
            stems = [f.stem for f in frames]
        else:
            cams, stems = _camera_list(data, path)
            frames = [None] * len(stems)
    # Two frames with one basename (train/r_0 and test/r_0) must not overwrite each other's output.
    return cams, unique_stems(stems), list(frames)


def cameras_from_file(path: Path | str, split: str = "test") -> tuple[Cameras, List[str]]:
    """Cameras and output stems to render (``camera_views`` without the frames)."""
    cams, stems, _ = camera_views(path, split)
    return cams, stems


def _ground_truth(frame: Optional[FrameInfo], cameras: Cameras, view: int, downscale: int):
    """(one-view ``data.Split`` holding the ground truth of ``view``, None) or (None, why not). No
    frame or no image file: (None, None), a camera without ground truth is not a problem."""

    if frame is None or not frame.image.is_file():
        return None, None
    try:
        split = load_split("ground truth", [frame], downscale, extras=("masks",))  # PSNR counts mask pixels
    except DatasetError as exc:
        return None, str(exc)
    size, want = (split.width, split.height), (int(cameras.width[view]), int(cameras.height[view]))
    if size != want:
        return None, f"{frame.image} is {size[0]}x{size[1]} px (downscaled by {downscale}), the render {want[0]}x{want[1]}"
    return split, None


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


def dataset_files(*paths) -> Dict[Path, str]:
    """{resolved file: 'FILE: frame K (PATH)'} of every image, depth, normal and mask file of the datasets
    (folders or transforms files) at ``paths``, all splits; a path that is not a dataset adds nothing.
    ``render`` never writes over these, even with --overwrite."""

    out: Dict[Path, str] = {}
    for path in paths:
        if not path:
            continue
        try:
            _, _, infos, _ = frame_infos(path, SPLITS)
        except (DatasetError, OSError, ValueError):
            continue
        for frames in infos.values():
            for fr in frames:
                for f in (fr.image, fr.depth, fr.normal, fr.mask):
                    if f is not None:
                        try:
                            out.setdefault(Path(f).resolve(), fr.where)
                        except (OSError, RuntimeError):  # a symlink loop: not a file we could overwrite
                            pass
    return out


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
    ground_truth: Optional[List[Optional[FrameInfo]]] = None,
    metrics_background=(1.0, 1.0, 1.0),
    gt_downscale: int = 1,
    protected: Optional[Dict[Path, str]] = None,
    pixel_filter: Optional[PixelFilter] = None,
) -> Path:
    """Render every camera into ``out``; returns the path of ``renders.json``.

    ``pixel_filter``: the film filter each view is rendered through (``render_view``; None: centre rays).

    ``protected``: files never to write over, even with ``overwrite`` (``dataset_files``: a dataset's
    own images); a target among them is refused (RunError naming it and its frame).

    ``ground_truth``: per camera, the transforms frame whose image is its ground truth (None: none).
    Views with one get ``psnr`` and ``ssim`` in renders.json, computed exactly as ``eval`` does
    (``evaluate.score_view``: render and ground truth composited onto ``metrics_background``, the
    run's ``eval_background``), and an error heat-map ``errors/<stem>.png``. The ground truth is
    box-filtered by ``gt_downscale`` like ``eval --downscale``.
    Refuses (RunError listing the files) to replace existing outputs unless ``overwrite``.
    """
    out = Path(out)
    stems = unique_stems(stems)  # colliding names would overwrite each other's images
    gt_frames = list(ground_truth) if ground_truth is not None else [None] * len(stems)
    for v in range(len(stems)):
        check_view_memory(int(cameras.width[v]), int(cameras.height[v]), f"camera {v} ({stems[v]})")
    targets = [out / "renders.json"]
    for s, fr in zip(stems, gt_frames):
        files = render_files(s)
        targets += [out / files["image"], out / files["depth"]]
        if fr is not None:
            targets.append(out / files["error_map"])
    for t in targets:
        try:
            frame = (protected or {}).get(t.resolve())
        except (OSError, RuntimeError):
            frame = None
        if frame is not None:
            raise RunError(f"--out {out}: would write {t.name} over the dataset's own file ({frame}); "
                           "renders never replace a dataset's images, even with --overwrite. Choose another --out")
    existing = [t for t in targets if t.exists()]
    if existing and not overwrite:
        names = ", ".join(t.name for t in existing[:5]) + (f" and {len(existing) - 5} more" if len(existing) > 5 else "")
        raise RunError(f"{out}: would overwrite existing {names}; pass --overwrite or choose another --out")

    out.mkdir(parents=True, exist_ok=True)
    # The old renders.json describes the images about to be replaced: an interrupted --overwrite left
    # it naming the previous run (and its PSNRs) beside new images. It goes first; the new one is
    # written once every view is.
    (out / "renders.json").unlink(missing_ok=True)
    frames = []
    bar = ProgressBar(total=len(stems), label="render", enabled=show_progress)
    opaque = getattr(model, "environment", None) is not None
    bg = torch.as_tensor(metrics_background, dtype=torch.float32)
    render_seconds, rays = 0.0, 0
    for v, stem in enumerate(stems):
        files = render_files(stem)
        started = time.perf_counter()
        res = render_view(model, cameras, v, background=(0.0, 0.0, 0.0), near=near, far=far, chunk=chunk,
                          pixel_filter=pixel_filter)
        seconds = time.perf_counter() - started
        render_seconds += seconds
        rays += res["n_rays"]
        rgba = straight_rgba(res, opaque)
        write_png(out / files["image"], rgba)
        write_exr(out / files["depth"], {"Z": res["z_depth"].numpy()})
        entry = {
            "file_path": files["image"],
            "depth_file_path": files["depth"],
            "transform_matrix": cameras.c2w[v].tolist(),
            "fl_x": float(cameras.fx[v]), "fl_y": float(cameras.fy[v]),
            "cx": float(cameras.cx[v]), "cy": float(cameras.cy[v]),
            "w": int(cameras.width[v]), "h": int(cameras.height[v]),
            "camera_angle_x": float(cameras.fov_x()[v]),
            "render_seconds": seconds, "rays": res["n_rays"],
        }
        lens = cameras.lens(v)
        if lens is not None:  # the render is as distorted as the camera it was asked for
            entry.update(lens.fields())
        gt_split, why_not = _ground_truth(gt_frames[v], cameras, v, gt_downscale)
        if gt_split is not None:
            # What eval sees: the same pixels as rendering onto the background (model.render_rays puts
            # ``background`` behind the opacity exactly so); a learned world already fills them.
            pred = res["rgb"] if opaque else composite_background(res["rgb"], res["acc"], bg).clamp(0, 1)
            try:
                scores, gt = score_view(pred, gt_split, 0, bg)
            except ValueError as exc:  # e.g. smaller than SSIM's window: the render itself is fine
                why_not = f"{gt_frames[v].image}: {exc}"
            else:
                (out / files["error_map"]).parent.mkdir(exist_ok=True)
                write_png(out / files["error_map"], error_heatmap(pred, gt))
                entry.update(scores, error_map=files["error_map"], ground_truth=str(gt_frames[v].image))
        if why_not:
            entry["metrics_skipped"] = why_not
        frames.append(entry)
        bar.update(1, info=stem)
        if on_view:
            on_view(v, stem)
    bar.close()
    meta = {"frames": frames, "depth": "planar z-depth in scene units, EXR channel Z, 0 where nothing was hit",
            "alpha": ("1: opaque, the learned environment is composited behind the scene" if opaque else
                      "accumulated opacity; colour is straight (not premultiplied)"),
            "background": "environment" if opaque else "transparent", "created": time.time(),
            "pixel_filter": (pixel_filter or POINT).to_json(), **render_rate(render_seconds, rays)}
    if any("psnr" in f for f in frames):
        meta["metrics_background"] = [float(c) for c in bg.tolist()]
        meta["error_map_vmax"] = HEATMAP_VMAX
    meta.update(extra or {})
    write_json_atomic(out / "renders.json", meta)
    return out / "renders.json"


def _inside_dataset(path, dataset) -> bool:
    """Whether ``path`` is the folder ``dataset`` or lies in it."""
    if not isinstance(dataset, str) or not dataset:
        return False
    try:
        path, dataset = Path(path).resolve(), Path(dataset).resolve()
    except (OSError, RuntimeError):
        return False
    return path == dataset or dataset in path.parents


def refuse_dataset_root_out(out) -> None:
    """RunError when ``out`` is a dataset's root folder (it holds transforms_train.json or
    transforms.json). The dataset's own images are safe anyway (``dataset_files``), but renders.json
    and the renders would sit beside its transforms files, and instant-ngp reads every *.json at a
    dataset's root as one: one render would break the dataset for other tools. A subfolder is fine."""

    out = Path(out)
    if not out.is_dir():
        return
    try:
        layout, _ = detect_layout(out)
    except DatasetError:
        return
    found = "transforms_train.json" if layout == "synthetic" else "transforms.json"
    raise RunError(f"--out {out}: this is a dataset folder (it holds {found}); renders.json and the renders would "
                   "sit beside its transforms files, and instant-ngp reads every *.json there as one. "
                   f"Choose another --out, e.g. {out / 'renders'}")


def render_run(run, cameras_path, out, split="test", overwrite=False, device=None, downscale: float = 1.0,
               chunk: int = 8192, checkpoint=None, show_progress=True, pixel_filter: str = "auto") -> Path:
    """The ``render`` subcommand: render a run's latest checkpoint for the cameras of a file, with
    per-view PSNR / SSIM and error heat-maps where the cameras' frames have ground-truth images.
    ``pixel_filter``: "auto", the run's dataset's film filter (``pixel_filter.of_run``), or "none"."""

    refuse_dataset_root_out(out)
    dev = pick_device(device)
    model, config, ckpt = load_run(run, dev, checkpoint)
    if cameras_path is None:
        cameras_path = config.get("dataset")
        if not cameras_path:
            raise RunError(f"{config_path(run)}: no 'dataset' recorded; pass --cameras")
    notes = []
    if _inside_dataset(cameras_path, config.get("dataset")):
        # the run's own dataset, or a file of it (the add-on's Compare passes transforms_test.json):
        # its images are the ground truth of the scores, so say when they are no longer the ones trained on
        changed = dataset_changed_note(config)
        if changed:
            notes.append(changed)
            print(f"render: note: {changed}", file=sys.stderr)
    cams, stems, frames = camera_views(cameras_path, split)
    smallest = int(torch.minimum(cams.width, cams.height).min())
    if not (math.isfinite(downscale) and 0 < downscale <= smallest):
        raise RunError(f"--downscale {downscale:g}: the smallest camera is {smallest} px across, so the factor must "
                       f"lie in (0, {smallest}] to leave at least one pixel")
    if float(downscale).is_integer() and downscale > 1:
        cams = cams.downscaled(int(downscale))  # the sizes and cameras of eval's box-filtered ground truth
    elif downscale != 1.0:
        cams = cams.scaled(1.0 / downscale)
    # Ground truth is box-filtered like eval's; a fractional downscale has no such image: no metrics.
    gt_downscale = int(downscale) if float(downscale).is_integer() and downscale >= 1 else None
    return render_to_dir(
        model, cams, stems, out, overwrite=overwrite, near=config.get("near"), far=config.get("far"), chunk=chunk,
        extra={"run": str(Path(run).resolve()), "step": ckpt.get("step"), "method": ckpt.get("method"),
               "cameras": str(Path(cameras_path).resolve()), **({"notes": notes} if notes else {})},
        show_progress=show_progress,
        ground_truth=frames if gt_downscale else None,
        metrics_background=config.get("eval_background", [1.0, 1.0, 1.0]), gt_downscale=gt_downscale or 1,
        pixel_filter=pf.of_run(config, pixel_filter, downscale),
        # and any dataset that --out is or lies in (dataset_files skips folders that hold none)
        protected=dataset_files(cameras_path, config.get("dataset"), out, *Path(out).resolve().parents),
    )
