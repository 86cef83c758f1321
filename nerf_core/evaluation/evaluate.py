"""Evaluation of a run on a held-out split (the metrics themselves live in ``nerf_core.image.metrics``)."""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Callable, List, Optional, Sequence

import numpy as np
import torch

from nerf_core import contract
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.naming import evenly_spaced
from nerf_core.data.loading import load_cameras, load_dataset
from nerf_core.data.split import Split
from nerf_core.errors import RunError
from nerf_core.fields.world_coverage import covered_directions, unseen_world_share
from nerf_core.image.pixel_filter import POINT
from nerf_core.render.frame import check_render_arguments, render_view
from nerf_core.render.memory import DEFAULT_CHUNK, render_rate

# Re-exported: callers and tests have always found the metrics here.
from nerf_core.render.scoring import score_view
from nerf_core.runs.checkpoints import load_trained
from nerf_core.runs.events import EventLog
from nerf_core.runs.folder import dataset_changed_note
from nerf_core.runs.record import trained_with
from nerf_core.utils import arguments
from nerf_core.utils.atomic import write_json_atomic
from nerf_core.utils.device import pick_device
from nerf_core.utils.memory import named_out_of_memory
from nerf_core.utils.progressbar import ProgressBar


def mean_finite(values: Sequence[Optional[float]]) -> Optional[float]:
    """Mean of the finite values (None and inf/NaN skipped); None when there are none."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return sum(vals) / len(vals) if vals else None


def evaluate_split(
    model,
    split,
    views: Optional[Sequence[int]] = None,
    background=(1.0, 1.0, 1.0),
    near: Optional[float] = None,
    far: Optional[float] = None,
    chunk: int = DEFAULT_CHUNK,
    on_view: Optional[Callable[[dict], None]] = None,
    pixel_filter=None,
) -> dict:
    """Render ``views`` of a ``data.Split`` and compare with its images.

    Ground truth is composited onto ``background`` (white, like the original NeRF evaluation) and
    the model renders onto the same colour, through the images' ``pixel_filter`` (``render_view``;
    None: one ray through each pixel centre). PSNR counts only the split's mask pixels when it has masks.

    Args:
        model: a ``RadianceModel`` in eval mode.
        split: a ``Split`` with images (n, h, w, c).
        views: view indices to evaluate; None: all n.
        background: (3,) colour in [0, 1] behind both render and ground truth.
        near, far: the dataset's ray bounds (``Dataset.near``/``far``), or None.
        chunk: most rays per model call.
        on_view: called with each view's entry (see ``per_view``) as soon as it is scored.
        pixel_filter: the images' film filter (``Dataset.pixel_filter``), or None.

    Returns:
        dict with ``psnr`` and ``ssim`` (means over the views with finite values; None when none),
        ``n_views``, ``n_views_total`` (len(split)), ``width``, ``height``, ``per_view`` (a list of
        {``view``, ``name``, ``psnr``, ``ssim``[, ``depth_mae``, ``depth_rel``]}), the rendering time
        (``render.render_rate``: ``render_seconds``, ``rays``, ``rays_per_s``) and ``depth_mae``, ``depth_rel`` when
        the split has depth.

    Raises:
        ValueError: images smaller than SSIM's 11 x 11 window.
    """
    check_render_arguments("evaluate_split", model, None, None, background, near, far, chunk)
    arguments.instance("evaluate_split", "split", split, Split, "a nerf_core.Split (Dataset.split(name))")
    if views is not None and not isinstance(views, (list, tuple, range, np.ndarray, torch.Tensor)):
        raise TypeError(f"evaluate_split: views must be a list of view indices or None, got {views!r:.60}")
    if views is not None:
        views = [arguments.integer("evaluate_split", "views[]", v, low=0, high=len(split) - 1) for v in views]
    views = list(range(len(split))) if views is None else list(views)
    per_view: List[dict] = []
    render_seconds, rays = 0.0, 0
    for v in views:
        started = time.perf_counter()
        res = render_view(model, split.cameras, v, background=background, near=near, far=far, chunk=chunk,
                          pixel_filter=pixel_filter)
        render_seconds += time.perf_counter() - started
        rays += res["n_rays"]
        scores, _ = score_view(res["rgb"], split, v, background, res["z_depth"])
        entry = {"view": v, "name": split.frames[v].stem, **scores}
        per_view.append(entry)
        if on_view:
            on_view(entry)
    out = {
        "psnr": mean_finite([e["psnr"] for e in per_view]),
        "ssim": mean_finite([e["ssim"] for e in per_view]),
        "n_views": len(per_view),
        "n_views_total": len(split),
        "width": split.width,
        "height": split.height,
        "per_view": per_view,
        **render_rate(render_seconds, rays),
    }
    if split.depth is not None:
        out["depth_mae"] = mean_finite([e.get("depth_mae") for e in per_view])
        out["depth_rel"] = mean_finite([e.get("depth_rel") for e in per_view])
    return out


def spread_views(n: int, k: int) -> List[int]:
    """``k`` view indices evenly spread over ``0 .. n-1``, first and last included (``[0]`` for k <= 1):
    the contract's ``evenly_spaced`` rule."""
    return evenly_spaced(n, max(1, k)) if n > 0 else [0]


def evaluate_in_budget(model, split, seconds: float, max_views: Optional[int] = None, background=(1.0, 1.0, 1.0),
                       near: Optional[float] = None, far: Optional[float] = None, chunk: int = DEFAULT_CHUNK,
                       pixel_filter=None) -> dict:
    """``evaluate_split`` on evenly spread views of ``split``: ``max_views`` of them when given, else
    as many as fit in ``seconds`` at the time view 0 took (at least one). The end-of-training
    evaluation, which must not take longer than a share of the training itself.
    """

    n = len(split)
    t0 = time.perf_counter()
    kw = dict(background=background, near=near, far=far, chunk=chunk, pixel_filter=pixel_filter)
    first = evaluate_split(model, split, [0], **kw)
    per_view_s = time.perf_counter() - t0
    if max_views is not None:
        k = min(n, max_views)
    else:
        k = int(min(n, max(1, seconds // max(per_view_s, 1e-3))))
    rest = [v for v in spread_views(n, k) if v != 0]
    if not rest:
        return first
    more = evaluate_split(model, split, rest, **kw)
    per_view = first["per_view"] + more["per_view"]
    result = dict(first, per_view=per_view, n_views=len(per_view),
                  **render_rate(first["render_seconds"] + more["render_seconds"], first["rays"] + more["rays"]))
    for key in ("psnr", "ssim", "depth_mae", "depth_rel"):
        if key in first:
            result[key] = mean_finite([e.get(key) for e in per_view])
    return result


def evaluate_held_out(model, dataset, max_views: Optional[int] = None, seconds: Optional[float] = None,
                      background=(1.0, 1.0, 1.0), chunk: int = DEFAULT_CHUNK) -> Optional[tuple[str, dict]]:
    """(split name, ``evaluate_split`` result) on the held-out split of a ``data.Dataset`` (test, else
    val), None when it has neither. Views are evenly spread: ``max_views`` of them (all when None or
    0) or, when ``seconds`` is given and ``max_views`` is None, as many as fit in that time
    (``evaluate_in_budget``). Views render through the dataset's pixel filter."""
    split_name = dataset.held_out_split(("test", "val"))
    if split_name is None:
        return None
    split = dataset.splits[split_name]
    kw = dict(background=background, near=dataset.near, far=dataset.far, chunk=chunk, pixel_filter=dataset.pixel_filter)
    if seconds is not None:
        return split_name, evaluate_in_budget(model, split, seconds, max_views, **kw)
    n = len(split)
    return split_name, evaluate_split(model, split, spread_views(n, min(n, max_views or n)), **kw)


def read_metrics_file(path: Path) -> dict:
    """RUN/metrics.json as a dict ({} when there is none yet). A file that is not the JSON object
    ``train`` and ``eval`` write (hand-edited, or another tool's) raises RunError naming it: merging
    into it would throw away the scores it holds for other splits."""

    path = Path(path)
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise RunError(f"{path}: not readable as JSON ({type(exc).__name__}); eval merges its scores into this "
                       "file, so move it aside (or delete it) and run eval again") from None
    except OSError as exc:
        raise RunError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not isinstance(data, dict):
        raise RunError(f"{path}: expected the JSON object that train and eval write, got a {type(data).__name__}; "
                       "move it aside (or delete it) and run eval again")
    return data


def update_metrics_file(path: Path, split: str, result: dict, step: Optional[int]) -> dict:
    """Merge ``result`` into RUN/metrics.json: top-level keys describe the latest evaluation,
    ``splits`` keeps the latest result per split. Written atomically."""
    path = Path(path)
    data = read_metrics_file(path)
    summary = {k: v for k, v in result.items() if k != "per_view"}
    summary.update({"split": split, "step": step, "time": time.time()})
    data.update(summary)
    data.setdefault("splits", {})[split] = dict(summary, per_view=result.get("per_view", []))
    write_json_atomic(path, data, allow_nan=False, default=lambda o: None)
    return data


UNSEEN_WORLD_NOTE = 0.02  # share of a view on unseen world that the per-view line mentions


def unseen_world_shares(model, dataset_path, split, views: Sequence[int]) -> dict:
    """{view: share of its pixels that look at world directions no train view shows}
    (``nerf_core.fields.world_coverage``), for a model with a learned world; {} otherwise or when the
    train cameras cannot be read."""
    if not model.models_world:
        return {}

    try:
        train, _ = load_cameras(dataset_path, "train")
    except (DatasetError, OSError, ValueError):
        return {}
    covered = covered_directions(train)
    aabb = model.aabb.detach().cpu().float()
    return {v: unseen_world_share(split.cameras, v, covered, aabb) for v in views}


def evaluate_run(
    run,
    split: str = "test",
    device=None,
    max_views: Optional[int] = None,
    downscale: Optional[int] = None,
    chunk: int = DEFAULT_CHUNK,
    checkpoint=None,
    print_fn=print,
    show_progress: bool = True,
    pixel_filter: str = "auto",
) -> dict:
    """The ``eval`` subcommand: evaluate a run's latest checkpoint on ``split``; prints a line per
    view and returns the summary (also merged into RUN/metrics.json and RUN/progress.jsonl).

    The dataset is the one recorded in the run's config.json, loaded at the run's ``downscale`` unless
    ``downscale`` says otherwise; render and ground truth are composited onto the run's
    ``eval_background``.

    Args:
        run: a run folder written by ``train``.
        split: "train", "val" or "test".
        device: "cpu", "cuda"...; None: CUDA when there is one.
        max_views: evaluate this many views, evenly spread (first and last included); None or 0: all.
        downscale: integer image downscale; None: the one the run trained at.
        chunk: most rays per model call.
        checkpoint: a checkpoint file of the run to evaluate instead of ``latest.pt``.
        print_fn: called with each view's line of text.
        show_progress: show a progress bar on stderr.
        pixel_filter: "auto" renders through the dataset's film filter (``nerf_core.image.pixel_filter``),
            "none" one ray through each pixel centre.

    Returns:
        dict with ``psnr``, ``ssim``, ``split``, ``n_views``, ``n_views_total``, ``step`` (of the
        checkpoint), ``method``, ``pixel_filter``, ``render_seconds``, ``rays``, ``rays_per_s``, and
        ``depth_mae`` when the split has depth, ``unseen_world`` ({view name: share}) when some views
        look at world no train view shows.

    Raises:
        RunError: an unusable run folder, checkpoint or metrics.json, or no dataset recorded.
        CheckpointRefused: a checkpoint that would need code to load.
        DatasetError: the run's dataset cannot be loaded, or has no views with images in ``split``.
    """

    f = "evaluate_run"
    run = Path(arguments.path(f, "run", run))
    arguments.choice(f, "split", split, contract.SPLITS)
    if max_views is not None:
        arguments.integer(f, "max_views", max_views, low=1)  # 0 is no request for "all": that is None
    if downscale is not None:
        arguments.integer(f, "downscale", downscale, low=1)
    arguments.integer(f, "chunk", chunk, low=1)
    arguments.choice(f, "pixel_filter", pixel_filter, ("auto", "none"))
    if checkpoint is not None:
        arguments.path(f, "checkpoint", checkpoint)
    if device is not None and not isinstance(device, (str, torch.device)):
        raise TypeError(f"{f}: device must be 'cpu', 'cuda', ... or a torch.device, got {device!r}")
    dev = pick_device(device)
    model, record, ckpt = load_trained(run, dev, checkpoint)
    dataset_path = record.dataset
    if not dataset_path:
        raise RunError(f"{contract.config_path(run)}: no 'dataset' recorded")
    metrics_path = Path(contract.metrics_path(run))
    read_metrics_file(metrics_path)  # a damaged file is refused before the evaluation, not after it
    if Path(contract.progress_path(run)).is_dir():
        raise RunError(f"{contract.progress_path(run)}: is a folder; eval appends its event to this file")
    changed = dataset_changed_note(record.raw)
    if changed:
        print(f"eval: note: {changed}", file=sys.stderr)
    trained_at = record.downscale
    if downscale is None:
        downscale = trained_at  # score at the resolution the model learnt, as papers report downscaled scenes
    elif int(downscale) != trained_at:
        # said, since a score at another resolution is not comparable with the run's own evaluations
        finer = "finer than" if int(downscale) < trained_at else "coarser than"
        print(f"eval: note: evaluating at --downscale {int(downscale)}, {finer} the --downscale {trained_at} the run "
              "trained at; its logged PSNR is not comparable with this one", file=sys.stderr)
    ds = load_dataset(dataset_path, splits=(split,), downscale=int(downscale))
    sp = ds.split(split)
    unreached = record.reach_problem(sp.cameras.c2w[:, :3, 3].numpy())  # else every score is of an empty render
    if unreached:
        raise RunError(unreached)
    n = len(sp) if not max_views else min(len(sp), int(max_views))
    views = evenly_spaced(len(sp), n)
    bg = list(record.eval_background)
    unseen = unseen_world_shares(model, dataset_path, sp, views)
    bar = ProgressBar(total=len(views), label=f"eval {split}", enabled=show_progress)

    def show(entry):
        line = f"view {entry['view']:3d} {entry['name']}: psnr {entry['psnr']:.2f} ssim {entry['ssim']:.4f}"
        if entry.get("depth_mae") is not None:
            line += f" depth_mae {entry['depth_mae']:.4f}"
        if entry.get("depth_rel") is not None:
            line += f" depth_rel {entry['depth_rel']:.4f}"
        share = unseen.get(entry["view"], 0.0)
        if share >= UNSEEN_WORLD_NOTE:
            # Say why a view scores low when the reason is the capture, not the model.
            line += f" ({100 * share:.0f} % looks at world no train view shows)"
        print_fn(line)
        bar.update(1, info=entry["name"])

    film_filter = POINT if pixel_filter == "none" else ds.pixel_filter
    with named_out_of_memory(f"--chunk {chunk}", "lower --chunk, or evaluate at a larger --downscale"):
        result = evaluate_split(model, sp, views, background=bg, near=record.near, far=record.far, chunk=chunk,
                                on_view=show, pixel_filter=film_filter)
    bar.close()
    step = ckpt.get("step")
    result["trained_with"] = trained_with(record.raw)  # a score with depth is not a colours-only score
    update_metrics_file(metrics_path, split, result, step)
    with EventLog([contract.progress_path(run)], stdout=False) as log:
        log.emit("eval", step=step, split=split, psnr=result["psnr"], ssim=result["ssim"])
    summary = {"psnr": result["psnr"], "ssim": result["ssim"], "split": split, "n_views": result["n_views"],
               "n_views_total": result["n_views_total"], "step": step, "method": ckpt.get("method"),
               "pixel_filter": film_filter.to_json(), "trained_with": result["trained_with"]}
    for key in ("depth_mae", "depth_rel"):
        if key in result:
            summary[key] = result[key]
    low = {sp.stems[v]: round(share, 4) for v, share in unseen.items() if share >= UNSEEN_WORLD_NOTE}
    if low:
        summary["unseen_world"] = low  # view name -> share of its pixels on world no train view shows
    summary.update({k: result[k] for k in ("render_seconds", "rays", "rays_per_s")})
    return summary
