"""What the trainer reports besides its loop: ``step`` events, and held-out evaluation while and
after training (``eval`` events, ``RUN/metrics.json``). Only rank 0 of a ``torchrun`` job calls these.
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Optional, Sequence

from nerf_core import contract
from nerf_core.engine.state import RunDecisions
from nerf_core.errors import RunError
from nerf_core.evaluation.evaluate import (
    evaluate_held_out,
    read_metrics_file,
    update_metrics_file,
)
from nerf_core.image.metrics import SSIM_WINDOW
from nerf_core.image.pixel_filter import DEFAULT as DEFAULT_FILTER
from nerf_core.runs.checkpoints import versions
from nerf_core.runs.folder import record_written
from nerf_core.runs.record import check_run_config, trained_with


def emit_step(log, cfg, opt, step: int, elapsed: float, loss: float, psnr: float, interval: dict) -> None:
    """One ``step`` event: the last step's loss and PSNR, the interval's mean loss and samples/s.
    ``interval``: {"t": seconds, "samples": int, "loss": summed loss, "n": steps} since the last event."""
    lr = [g for g in opt.param_groups if g.get("name") != "environment"][-1]["lr"]
    sps = interval["samples"] / interval["t"] if interval["t"] > 0 else 0.0
    log.emit("step", step=step, loss=loss, psnr=psnr, lr=lr, elapsed=elapsed, eta=cfg.eta(step, elapsed),
             frac=cfg.budget_fraction(step, elapsed), samples_per_s=sps,
             loss_avg=interval["loss"] / max(1, interval["n"]),
             lrs={g.get("name", str(k)): g["lr"] for k, g in enumerate(opt.param_groups)})


def failure_line(exc: BaseException, batch_rays: Optional[int], options: Optional[dict] = None) -> str:
    """One line for a RuntimeError or MemoryError inside training (no traceback). Out of memory names
    what to turn down: the allocator's byte count alone does not say which setting asked for it, so
    the options the run set itself (``options``, its ``--set``) come first, then the usual sizes."""
    msg = (str(exc).splitlines() or [type(exc).__name__])[0]
    if isinstance(exc, MemoryError) or "alloc" in msg.lower() or "out of memory" in msg.lower():
        given = " ".join(f"{k}={v}" for k, v in (options or {}).items())
        msg = (f"not enough memory ({msg[:200]}); " + (f"this run sets --set {given}; " if given else "")
               + f"lower --batch-rays (now {batch_rays}) or the method's size options (--set res_final=..., "
               "density_rank=..., width=..., occ_res=...) or sample more coarsely (step_ratio, march_steps)")
    return msg


def emit_start(log, cfg, decisions: RunDecisions, model, dataset, run: Path, device, dist,
               resumed_from: Optional[int]) -> None:
    """The ``start`` event, and on rank 0's stderr what it says that a person should read (sizes,
    background, dataset notes, slow kernels)."""
    train = dataset.split("train")
    kernels = model.kernels(device)  # which implementation each hot loop takes, and why
    log.emit("start", run=str(run), method=decisions.method, max_steps=cfg.max_steps, max_seconds=cfg.max_seconds,
             device=str(device), n_params=model.num_parameters(), model=model.describe(),
             size_reasons=decisions.size_reasons, resumed_from=resumed_from, seed=cfg.seed,
             dataset=str(Path(cfg.dataset).resolve()), n_train_views=len(train), image_size=[train.width, train.height],
             background=decisions.background, background_reason=decisions.background_reason, notes=dataset.notes,
             world_size=dist.world_size, kernels=kernels)
    slow = [f"kernel: {name} runs on {how}" for name, how in kernels.items() if "fallback" in how]
    lines = ([f"size: {r}" for r in decisions.size_reasons]
             + [f"background: {decisions.background} ({decisions.background_reason})"]
             + [f"note: {note}" for note in dataset.notes] + slow)
    for line in lines if dist.is_main else []:
        print(f"train: {line}", file=sys.stderr)


def held_out_eval(log, model, dataset, cfg, background, step: int, at_seconds: float,
                  marks: Optional[Sequence[float]] = None) -> None:
    """Evaluate ``cfg.eval_views`` evenly spaced held-out views (all when unset); an ``eval`` event.

    ``marks``: the ``--eval-at`` times (seconds) this evaluation stands for, recorded in the event as
    ``eval_at`` (several when one slow step crossed more than one)."""
    model.eval()
    try:
        started = time.perf_counter()
        found = evaluate_held_out(model, dataset, cfg.eval_views, background=background, chunk=cfg.chunk)
    finally:
        model.train()
    if found is None:
        return
    split_name, result = found
    log.emit("eval", step=step, split=split_name, psnr=result["psnr"], ssim=result["ssim"],
             n_views=result["n_views"], depth_mae=result.get("depth_mae"), elapsed=at_seconds,
             eval_wall=time.perf_counter() - started, n_params=model.num_parameters(), n_bytes=model.num_bytes(),
             **({"eval_at": [float(t) for t in marks]} if marks else {}))


def evaluation_problem(dataset, cfg) -> Optional[str]:
    """Why the held-out evaluation that training will run cannot score its views, or None: known before
    the first step, so that a run does not train to its end and then fail (SSIM needs 11x11 px)."""
    name = dataset.held_out_split(("test", "val"))
    if name is None or (cfg.eval_views == 0 and not cfg.eval_at):
        return None
    split = dataset.split(name)
    if min(split.width, split.height) >= SSIM_WINDOW:
        return None
    at = f" at --downscale {cfg.downscale}" if cfg.downscale > 1 else ""
    return (f"the {name} images are {split.width}x{split.height} px{at}; evaluating them (SSIM) needs at least "
            f"{SSIM_WINDOW}x{SSIM_WINDOW}. " + ("Use a smaller --downscale, or pass " if cfg.downscale > 1 else "Pass ")
            + "--eval-views 0 (and no --eval-at) to train without evaluating")


def final_eval(log, model, dataset, cfg, background, run: Path, step: int, elapsed: float) -> dict:
    """The end-of-training evaluation within ``cfg.eval_seconds`` (default max(30 s, 25 % of the
    training time)), merged into RUN/metrics.json; returns the metrics ({} when there is nothing to
    evaluate)."""
    if cfg.eval_views == 0 or dataset.held_out_split(("test", "val")) is None:
        return {}
    budget = cfg.eval_seconds if cfg.eval_seconds is not None else max(30.0, 0.25 * elapsed)
    model.eval()
    try:
        split_name, result = evaluate_held_out(model, dataset, cfg.eval_views, seconds=budget,
                                               background=background, chunk=cfg.chunk)
    finally:
        model.train()
    if result["n_views"] < result["n_views_total"]:
        # Say why fewer views were scored: the user's --eval-views, or the time budget (only when no
        # count was given), so that nobody tunes --eval-seconds for a cut it did not make.
        why = (f"as --eval-views {cfg.eval_views} asks" if cfg.eval_views is not None
               else f"at full resolution to stay within {budget:.0f} s")
        result["note"] = (f"evaluated {result['n_views']} of {result['n_views_total']} {split_name} views {why}; "
                          f"`python -m nerf_core eval {run}` evaluates all")
        print(f"train: {result['note']}", file=sys.stderr)
    metrics = Path(contract.metrics_path(run))
    record_written(run, metrics)
    _set_aside_if_damaged(metrics)
    result["trained_with"] = trained_with(asdict(cfg))  # a score with depth is not a colours-only score
    update_metrics_file(metrics, split_name, result, step)
    log.emit("eval", step=step, split=split_name, psnr=result["psnr"], ssim=result["ssim"],
             n_views=result["n_views"], depth_mae=result.get("depth_mae"), trained_with=result["trained_with"])
    return {k: v for k, v in result.items() if k != "per_view"} | {"split": split_name}


def _set_aside_if_damaged(metrics: Path) -> None:
    """Rename a metrics.json that is not the JSON object train writes (edited by hand since the run
    started) to ``metrics.json.damaged`` so that the end of a long training neither fails on it nor
    silently drops what it held."""

    try:
        read_metrics_file(metrics)
    except RunError as exc:
        aside = metrics.with_name(metrics.name + ".damaged")
        os.replace(metrics, aside)
        print(f"train: {exc.args[0].split(';')[0]}; kept it as {aside} and wrote a new one", file=sys.stderr)


def run_config(cfg, decisions: RunDecisions, model, dataset, run: Path, device, world_size: int,
               dataset_hash: Optional[str], dataset_images: Optional[dict] = None) -> dict:
    """What RUN/config.json (and each checkpoint's ``config``) holds: the ``TrainConfig`` plus what the
    trainer decided (``RunDecisions``; docs/CONTRACTS.md).

    Args:
        cfg: the run's ``TrainConfig``; decisions: its ``RunDecisions``; model: the built model;
        dataset: the loaded ``Dataset``; run: the run folder; device: the torch device trained on;
        world_size: processes under torchrun (1 without); dataset_hash: ``runs.folder.dataset_hash``;
        dataset_images: ``runs.dataset_identity.dataset_images`` (what ``eval`` checks the images by).
    """
    ds, tr = dataset, dataset.split("train")
    rec = asdict(cfg)
    rec.update({
        "dataset": str(Path(cfg.dataset).resolve()), "dataset_hash": dataset_hash,
        "dataset_images": dataset_images,
        "out": str(run), "method": decisions.method, "model": model.describe(), "lr": decisions.base_lr,
        "warmup_steps": decisions.warmup, "background_used": decisions.background,
        "background_reason": decisions.background_reason, "eval_background": decisions.eval_background,
        "aabb": model.aabb.detach().cpu().tolist(),
        "aabb_source": ds.aabb_source, "near": ds.near, "far": ds.far, "size_reasons": decisions.size_reasons,
        "dataset_notes": ds.notes, "n_train_views": len(tr), "image_size": [tr.width, tr.height],
        "device_used": str(device), "versions": versions(), "world_size": world_size,
        "rays_per_step": decisions.batch_rays * world_size,
        # the dataset's film filter at its full resolution: render and eval draw edge pixels from it
        "pixel_filter": (ds.pixel_filter.full_resolution() if ds.pixel_filter else DEFAULT_FILTER).to_json(),
    })
    check_run_config(rec, contract.config_path(run))  # what the readers take from it, by their own declaration
    return rec
