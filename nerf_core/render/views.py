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

import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.contract import config_path
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.naming import render_files, unique_stems
from nerf_core.contract.numbers import is_real
from nerf_core.contract.outputs import OutputError, check_not_a_dataset_file, link_problem
from nerf_core.contract.transforms import FrameInfo, detect_layout

# Checkpoint reading moved to nerf_core.runs.checkpoints; the names stay importable from here for callers
# written against render (benchmarks/benchmark.py reads model sizes through them).
from nerf_core.errors import RunError
from nerf_core.image import pixel_filter as pf
from nerf_core.image.io import write_exr, write_png
from nerf_core.image.metrics import HEATMAP_VMAX, error_heatmap
from nerf_core.image.pixel_filter import POINT, PixelFilter
from nerf_core.render.cameras import camera_file_range, camera_views, dataset_files, ground_truth_split
from nerf_core.render.frame import render_view, straight_rgba
from nerf_core.render.memory import DEFAULT_CHUNK, check_view_memory, render_rate
from nerf_core.render.scoring import score_view
from nerf_core.runs.checkpoints import load_trained
from nerf_core.runs.folder import dataset_changed_note
from nerf_core.utils import arguments
from nerf_core.utils.atomic import write_json_atomic
from nerf_core.utils.device import pick_device
from nerf_core.utils.memory import named_out_of_memory
from nerf_core.utils.progressbar import ProgressBar
from nerf_core.volume.volrend import composite_background

# ----------------------------------------------------------------------------------------------
# rendering


# ----------------------------------------------------------------------------------------------
# camera files


def render_to_dir(
    model,
    cameras: Cameras,
    stems: List[str],
    out: Path | str,
    overwrite: bool = False,
    near: Optional[float] = None,
    far: Optional[float] = None,
    chunk: int = DEFAULT_CHUNK,
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
    _refuse_targets(out, stems, gt_frames, overwrite, protected)

    out.mkdir(parents=True, exist_ok=True)
    # The old renders.json describes the images about to be replaced: an interrupted --overwrite left
    # it naming the previous run (and its PSNRs) beside new images. It goes first; the new one is
    # written once every view is.
    (out / "renders.json").unlink(missing_ok=True)
    frames = []
    bar = ProgressBar(total=len(stems), label="render", enabled=show_progress)
    opaque = model.models_world
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
        entry = _view_entry(files, cameras, v, seconds, res["n_rays"])
        _score_into(entry, out, files, res, opaque, bg, gt_frames[v], cameras, v, gt_downscale)
        frames.append(entry)
        bar.update(1, info=stem)
        if on_view:
            on_view(v, stem)
    bar.close()
    meta = _renders_meta(frames, opaque, bg, pixel_filter, render_seconds, rays, extra)
    write_json_atomic(out / "renders.json", meta)
    return out / "renders.json"


def _refuse_targets(out: Path, stems: List[str], gt_frames: list, overwrite: bool,
                    protected: Optional[Dict[Path, str]]) -> None:
    """RunError when a file ``render_to_dir`` would write is a dataset's own (``protected``), a link,
    or exists and ``overwrite`` is off (the output rule, ``contract.outputs``); nothing is written
    before this passes."""
    targets = [out / "renders.json"]
    for s, fr in zip(stems, gt_frames):
        files = render_files(s)
        targets += [out / files["image"], out / files["depth"]]
        if fr is not None:
            targets.append(out / files["error_map"])
    for t in targets:
        try:
            check_not_a_dataset_file(t, t.name, protected or {}, f"--out {out}: would write")
        except OutputError as exc:
            raise RunError(str(exc)) from None
        problem = link_problem(t)
        if problem:
            raise RunError(f"--out {out}: {t.name} {problem}")
    existing = [t for t in targets if os.path.lexists(t)]
    if existing and not overwrite:
        names = ", ".join(t.name for t in existing[:5]) + (
            f" and {len(existing) - 5} more" if len(existing) > 5 else ""
        )
        raise RunError(f"{out}: would overwrite existing {names}; pass --overwrite or choose another --out")


def _view_entry(files: dict, cameras: Cameras, v: int, seconds: float, rays: int) -> dict:
    """renders.json's frame of view ``v``: its files, pose, intrinsics (and lens), and render time."""
    entry = {
        "file_path": files["image"],
        "depth_file_path": files["depth"],
        "transform_matrix": cameras.c2w[v].tolist(),
        "fl_x": float(cameras.fx[v]), "fl_y": float(cameras.fy[v]),
        "cx": float(cameras.cx[v]), "cy": float(cameras.cy[v]),
        "w": int(cameras.width[v]), "h": int(cameras.height[v]),
        "camera_angle_x": float(cameras.fov_x()[v]),
        "render_seconds": seconds, "rays": rays,
    }
    lens = cameras.lens(v)
    if lens is not None:  # the render is as distorted as the camera it was asked for
        entry.update(lens.fields())
    return entry


def _score_into(entry: dict, out: Path, files: dict, res: dict, opaque: bool, bg: torch.Tensor,
                frame: Optional[FrameInfo], cameras: Cameras, v: int, gt_downscale: int) -> None:
    """Add view ``v``'s scores against its ground truth ``frame`` to ``entry`` and write its error
    heat-map; or say in ``metrics_skipped`` why it has none. ``bg``: (3,) the metrics background."""
    gt_split, why_not = ground_truth_split(frame, cameras, v, gt_downscale)
    if gt_split is not None:
        # What eval sees: the same pixels as rendering onto the background (model.render_rays puts
        # ``background`` behind the opacity exactly so); a learned world already fills them.
        pred = res["rgb"] if opaque else composite_background(res["rgb"], res["acc"], bg).clamp(0, 1)
        try:
            scores, gt = score_view(pred, gt_split, 0, bg)
        except ValueError as exc:  # e.g. smaller than SSIM's window: the render itself is fine
            why_not = f"{frame.image}: {exc}"
        else:
            (out / files["error_map"]).parent.mkdir(exist_ok=True)
            write_png(out / files["error_map"], error_heatmap(pred, gt))
            entry.update(scores, error_map=files["error_map"], ground_truth=str(frame.image))
    if why_not:
        entry["metrics_skipped"] = why_not


def _renders_meta(frames: list, opaque: bool, bg: torch.Tensor, pixel_filter: Optional[PixelFilter],
                  render_seconds: float, rays: int, extra: Optional[dict]) -> dict:
    """renders.json's content: the frames, what depth and alpha mean, the pixel filter, the render rate."""
    meta = {"frames": frames, "depth": "planar z-depth in scene units, EXR channel Z, 0 where nothing was hit",
            "alpha": ("1: opaque, the learned environment is composited behind the scene" if opaque else
                      "accumulated opacity; colour is straight (not premultiplied)"),
            "background": "environment" if opaque else "transparent", "created": time.time(),
            "pixel_filter": (pixel_filter or POINT).to_json(), **render_rate(render_seconds, rays)}
    if any("psnr" in f for f in frames):
        meta["metrics_background"] = [float(c) for c in bg.tolist()]
        meta["error_map_vmax"] = HEATMAP_VMAX
    meta.update(extra or {})
    return meta


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
    found = {"synthetic": "transforms_train.json", "colmap": "a COLMAP model, images/ and sparse/"}.get(
        layout, "transforms.json")
    raise RunError(f"--out {out}: this is a dataset folder (it holds {found}); renders.json and the renders would "
                   "sit beside its transforms files, and instant-ngp reads every *.json there as one. "
                   f"Choose another --out, e.g. {out / 'renders'}")


def render_run(run, cameras_path, out, split="test", overwrite=False, device=None, downscale: float = 1.0,
               chunk: int = DEFAULT_CHUNK, checkpoint=None, show_progress=True, pixel_filter: str = "auto") -> Path:
    """The ``render`` subcommand: render a run's latest checkpoint for the cameras of a file, with
    per-view PSNR / SSIM and error heat-maps where the cameras' frames have ground-truth images.

    Writes, per camera, ``OUT/<stem>.png`` (RGBA: straight colour, alpha = accumulated opacity),
    ``OUT/<stem>_depth.exr`` (planar z-depth, channel ``Z``) and ``OUT/renders.json``; for cameras with a
    ground-truth image also ``OUT/errors/<stem>.png`` and that view's ``psnr``/``ssim`` in renders.json.

    Args:
        run: a run folder written by ``train``.
        cameras_path: what to render: a dataset folder (the frames of ``split``), a transforms file,
            a nerfstudio ``camera_path.json`` or a JSON list of cameras; None: the run's own dataset.
        out: the folder to write into (created; never a dataset's root folder).
        split: the split to render when ``cameras_path`` is a dataset folder (or a nerfstudio file with
            split lists): "train", "val" or "test".
        overwrite: replace existing outputs in ``out`` (a dataset's own images are never replaced).
        device: "cpu", "cuda"...; None: CUDA when there is one.
        downscale: factor > 0 to shrink the cameras by (an integer matches ``eval --downscale``'s
            box-filtered ground truth; a fractional one renders without metrics).
        chunk: most rays per model call.
        checkpoint: a checkpoint file of the run to render instead of ``latest.pt``.
        show_progress: show a progress bar on stderr.
        pixel_filter: "auto", the run's dataset's film filter (``pixel_filter.of_run``), or "none".

    Returns:
        The path of ``OUT/renders.json``.

    Raises:
        RunError: an unusable run or checkpoint, a bad ``downscale``, outputs that exist without
            ``overwrite``, or an ``out`` that is a dataset folder.
        DatasetError: a cameras file that cannot be read.
    """

    f = "render_run"
    run, out = arguments.path(f, "run", run), arguments.path(f, "out", out)
    if cameras_path is not None:
        arguments.path(f, "cameras_path", cameras_path)
    arguments.choice(f, "split", split, ("train", "val", "test"))
    if not is_real(downscale):
        raise TypeError(f"{f}: downscale must be a number, got {downscale!r:.60}")
    # Its range is checked once the cameras are read: the message says how small they are.
    arguments.integer(f, "chunk", chunk, low=1)
    arguments.choice(f, "pixel_filter", pixel_filter, ("auto", "none"))
    if not isinstance(overwrite, bool):
        raise TypeError(f"{f}: overwrite must be True or False, got {overwrite!r}")
    refuse_dataset_root_out(out)
    dev = pick_device(device)
    model, record, ckpt = load_trained(run, dev, checkpoint)
    if cameras_path is None:
        cameras_path = record.dataset
        if not cameras_path:
            raise RunError(f"{config_path(run)}: no 'dataset' recorded; pass --cameras")
    notes = []
    if _inside_dataset(cameras_path, record.dataset):
        # the run's own dataset, or a file of it (the add-on's Compare passes transforms_test.json):
        # its images are the ground truth of the scores, so say when they are no longer the ones trained on
        changed = dataset_changed_note(record.raw)
        if changed:
            notes.append(changed)
            print(f"render: note: {changed}", file=sys.stderr)
    cams, stems, frames = camera_views(cameras_path, split)
    near, far = camera_file_range(cameras_path)  # a camera path exported from Blender: its camera's clip
    if near is None:
        near, far = record.near, record.far
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
    with named_out_of_memory(f"--chunk {chunk}", "lower --chunk, or render smaller views with a larger --downscale"):
        return render_to_dir(
            model, cams, stems, out, overwrite=overwrite, near=near, far=far, chunk=chunk,
            extra={"run": str(Path(run).resolve()), "step": ckpt.get("step"), "method": ckpt.get("method"),
                   "cameras": str(Path(cameras_path).resolve()), **({"notes": notes} if notes else {})},
            show_progress=show_progress,
            ground_truth=frames if gt_downscale else None,
            metrics_background=list(record.eval_background), gt_downscale=gt_downscale or 1,
            pixel_filter=pf.of_run(record.raw, pixel_filter, downscale),
            # and any dataset that --out is or lies in (dataset_files skips folders that hold none)
            protected=dataset_files(cameras_path, record.dataset, out, *Path(out).resolve().parents),
        )
