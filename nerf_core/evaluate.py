"""Image metrics (PSNR, SSIM, depth error) and evaluation of a run on a held-out split.

SSIM follows Wang et al. 2004 as used by the NeRF papers: an 11x11 Gaussian window with sigma 1.5,
K1 = 0.01, K2 = 0.03, dynamic range 1, computed per RGB channel over the valid (unpadded) region
and averaged.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import torch
import torch.nn.functional as F

from . import contract
from .losses import psnr_from_mse

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def psnr(pred: torch.Tensor, gt: torch.Tensor, mask: Optional[torch.Tensor] = None) -> float:
    """PSNR of (..., 3) images in [0, 1], over the pixels where ``mask`` (...,) is True."""
    err = (pred.float() - gt.float()) ** 2
    if mask is not None:
        err = err[mask.bool()]
    return psnr_from_mse(err.mean())


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """(size,) normalised 1D Gaussian centred on the middle tap."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    g = torch.exp(-(x * x) / (2.0 * sigma * sigma))
    return g / g.sum()


def ssim_map(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM (3, h - 10, w - 10) of two (h, w, 3) images in [0, 1]."""
    if pred.shape != gt.shape or pred.dim() != 3:
        raise ValueError(f"ssim needs two (h, w, c) images of one shape, got {tuple(pred.shape)} and {tuple(gt.shape)}")
    if min(pred.shape[:2]) < SSIM_WINDOW:
        raise ValueError(f"ssim needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {pred.shape[1]}x{pred.shape[0]}")
    x = pred.double().permute(2, 0, 1)[None]  # (1, c, h, w); float64 so E[x^2]-E[x]^2 does not cancel badly
    y = gt.double().permute(2, 0, 1)[None]
    c = x.shape[1]
    g = gaussian_window()
    kx = g.view(1, 1, 1, -1).repeat(c, 1, 1, 1)
    ky = g.view(1, 1, -1, 1).repeat(c, 1, 1, 1)

    def blur(t):
        return F.conv2d(F.conv2d(t, kx, groups=c), ky, groups=c)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x * mu_x
    syy = blur(y * y) - mu_y * mu_y
    sxy = blur(x * y) - mu_x * mu_y
    c1, c2 = SSIM_K1 ** 2, SSIM_K2 ** 2
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (sxx + syy + c2)
    return (num / den)[0]


def ssim(pred: torch.Tensor, gt: torch.Tensor) -> float:
    """Mean SSIM of two (h, w, 3) images in [0, 1]."""
    return float(ssim_map(pred, gt).mean())


def depth_mae(pred_z: torch.Tensor, gt_z: torch.Tensor, gt_alpha: Optional[torch.Tensor] = None,
              mask: Optional[torch.Tensor] = None) -> Optional[float]:
    """Mean absolute error of planar depths (h, w) over pixels with ground truth (finite, > 0),
    ground-truth alpha > 0.5 and ``mask``; None when no pixel qualifies."""
    valid = torch.isfinite(gt_z) & (gt_z > 0)
    if gt_alpha is not None:
        valid &= gt_alpha > 0.5
    if mask is not None:
        valid &= mask.bool()
    if not bool(valid.any()):
        return None
    return float((pred_z[valid] - gt_z[valid]).abs().mean())


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
    chunk: int = 8192,
    on_view: Optional[Callable[[dict], None]] = None,
) -> dict:
    """Render ``views`` of a ``data.Split`` and compare with its images.

    Ground truth is composited onto ``background`` (white, like the original NeRF evaluation) and
    the model renders onto the same colour. Returns ``psnr``, ``ssim``, ``n_views``, ``per_view``
    and ``depth_mae`` when the split has depth.
    """
    from .render import render_view

    views = list(range(len(split))) if views is None else list(views)
    per_view: List[dict] = []
    for v in views:
        res = render_view(model, split.cameras, v, background=background, near=near, far=far, chunk=chunk)
        gt, alpha = split.image(v, background)
        mask = split.masks[v] if split.masks is not None else None
        entry = {"view": v, "name": split.frames[v].stem, "psnr": psnr(res["rgb"], gt, mask), "ssim": ssim(res["rgb"], gt)}
        if split.depth is not None:
            entry["depth_mae"] = depth_mae(res["z_depth"], split.depth[v], alpha if split.has_alpha else None, mask)
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
    }
    if split.depth is not None:
        out["depth_mae"] = mean_finite([e.get("depth_mae") for e in per_view])
    return out


def spread_views(n: int, k: int) -> List[int]:
    """``k`` view indices evenly spread over ``0 .. n-1``, first and last included (``[0]`` for k <= 1)."""
    return sorted({round(x * (n - 1) / max(1, k - 1)) for x in range(k)}) if k > 1 else [0]


def evaluate_in_budget(model, split, seconds: float, max_views: Optional[int] = None, background=(1.0, 1.0, 1.0),
                       near: Optional[float] = None, far: Optional[float] = None, chunk: int = 8192) -> dict:
    """``evaluate_split`` on evenly spread views of ``split``: ``max_views`` of them when given, else
    as many as fit in ``seconds`` at the time view 0 took (at least one). The end-of-training
    evaluation, which must not take longer than a share of the training itself.
    """
    n = len(split)
    t0 = time.perf_counter()
    first = evaluate_split(model, split, [0], background=background, near=near, far=far, chunk=chunk)
    per_view_s = time.perf_counter() - t0
    if max_views is not None:
        k = min(n, max_views)
    else:
        k = int(min(n, max(1, seconds // max(per_view_s, 1e-3))))
    rest = [v for v in spread_views(n, k) if v != 0]
    if not rest:
        return first
    more = evaluate_split(model, split, rest, background=background, near=near, far=far, chunk=chunk)
    per_view = first["per_view"] + more["per_view"]
    result = dict(first, per_view=per_view, n_views=len(per_view))
    for key in ("psnr", "ssim", "depth_mae"):
        if key in first:
            result[key] = mean_finite([e.get(key) for e in per_view])
    return result


def evaluate_held_out(model, dataset, max_views: Optional[int] = None, seconds: Optional[float] = None,
                      background=(1.0, 1.0, 1.0), chunk: int = 8192) -> Optional[tuple[str, dict]]:
    """(split name, ``evaluate_split`` result) on the held-out split of a ``data.Dataset`` (test, else
    val), None when it has neither. Views are evenly spread: ``max_views`` of them (all when None or
    0) or, when ``seconds`` is given and ``max_views`` is None, as many as fit in that time
    (``evaluate_in_budget``)."""
    split_name = dataset.held_out_split(("test", "val"))
    if split_name is None:
        return None
    split = dataset.splits[split_name]
    kw = dict(background=background, near=dataset.near, far=dataset.far, chunk=chunk)
    if seconds is not None:
        return split_name, evaluate_in_budget(model, split, seconds, max_views, **kw)
    n = len(split)
    return split_name, evaluate_split(model, split, spread_views(n, min(n, max_views or n)), **kw)


def update_metrics_file(path: Path, split: str, result: dict, step: Optional[int]) -> dict:
    """Merge ``result`` into RUN/metrics.json: top-level keys describe the latest evaluation,
    ``splits`` keeps the latest result per split. Written atomically."""
    path = Path(path)
    data: dict = {}
    if path.is_file():
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError:
            data = {}
    summary = {k: v for k, v in result.items() if k != "per_view"}
    summary.update({"split": split, "step": step, "time": time.time()})
    data.update(summary)
    data.setdefault("splits", {})[split] = dict(summary, per_view=result.get("per_view", []))
    tmp = path.with_name("." + path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, allow_nan=False, default=lambda o: None), encoding="utf-8")
    tmp.replace(path)
    return data


def evaluate_run(run, split: str = "test", device=None, max_views: Optional[int] = None, downscale: int = 1,
                 chunk: int = 8192, checkpoint=None, print_fn=print, show_progress: bool = True) -> dict:
    """The ``eval`` subcommand: evaluate a run's latest checkpoint on ``split``; prints a line per
    view and returns the summary (also merged into RUN/metrics.json and RUN/progress.jsonl)."""
    from .data import load_dataset
    from .device import pick_device
    from .progress import EventLog
    from .progressbar import ProgressBar
    from .checkpoints import RunError, load_run

    dev = pick_device(device)
    run = Path(run)
    model, config, ckpt = load_run(run, dev, checkpoint)
    dataset_path = config.get("dataset")
    if not dataset_path:
        raise RunError(f"{contract.config_path(run)}: no 'dataset' recorded")
    ds = load_dataset(dataset_path, splits=(split,), downscale=max(int(downscale), int(config.get("downscale", 1))))
    sp = ds.split(split)
    n = len(sp) if not max_views else min(len(sp), int(max_views))
    views = spread_views(len(sp), n)
    bg = config.get("eval_background", [1.0, 1.0, 1.0])
    bar = ProgressBar(total=len(views), label=f"eval {split}", enabled=show_progress)

    def show(entry):
        line = f"view {entry['view']:3d} {entry['name']}: psnr {entry['psnr']:.2f} ssim {entry['ssim']:.4f}"
        if entry.get("depth_mae") is not None:
            line += f" depth_mae {entry['depth_mae']:.4f}"
        print_fn(line)
        bar.update(1, info=entry["name"])

    result = evaluate_split(model, sp, views, background=bg, near=config.get("near"), far=config.get("far"), chunk=chunk, on_view=show)
    bar.close()
    step = ckpt.get("step")
    update_metrics_file(Path(contract.metrics_path(run)), split, result, step)
    with EventLog([contract.progress_path(run)], stdout=False) as log:
        log.emit("eval", step=step, split=split, psnr=result["psnr"], ssim=result["ssim"])
    summary = {"psnr": result["psnr"], "ssim": result["ssim"], "split": split, "n_views": result["n_views"],
               "n_views_total": result["n_views_total"], "step": step, "method": ckpt.get("method")}
    if "depth_mae" in result:
        summary["depth_mae"] = result["depth_mae"]
    return summary
