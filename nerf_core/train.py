"""Training a method on a dataset: ``python -m nerf_core train DATASET --out RUN``; this module owns
the loop and the rollback, everything else it uses has its own module.

* Seeded and deterministic for a step budget; the batch generator's state is checkpointed
  (``nerf_core.seeding``), so ``--resume`` continues the same random stream.
* Budgets: ``--max-steps`` and/or ``--max-seconds`` (training time only: previews, checkpoints and
  evaluation are not counted). The learning-rate schedule (``nerf_core.optim``) and the methods'
  own schedules follow whichever budget is nearer (``contract.budget_fraction``).
* Robust: a NaN/inf loss or gradient, or a loss far above its running average, rolls the model
  and optimiser back to the last good in-memory snapshot and halves the learning rate
  (``rollback`` event); after too many rollbacks training stops with an ``error`` event.
* Never destroys data, one writer per run folder (``nerf_core.runfolder``); weights-only
  checkpoints (``nerf_core.checkpoints``). docs/CONTRACTS.md has the files and the events.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable, List, Optional

import torch

from . import backgrounds, contract
from .checkpoints import RunError, load_state_resizing, read_resume_checkpoint, save_checkpoint, versions
from .data import Dataset, DatasetError, RayBatcher, load_dataset
from .evaluate import evaluate_held_out, update_metrics_file
from .interrupts import terminate_as_interrupt
from .losses import masked_mse, psnr_from_mse
from .optim import clone_state, make_optimizer, rebuild_optimizer, rescale_base_lrs, schedule_factor, warmup_steps
from .previews import Previews
from .progress import EventLog
from .progressbar import ProgressBar
from .runfolder import (TrainError, atomic_json, check_run_folder, check_run_vs_dataset, clear_run_folder,
                        dataset_hash, lock_run_folder, os_reason, record_written)
from .seeding import rng_state, seed_everything, set_rng_state
from .train_config import TrainConfig, default_method, merge_resumed_config

__all__ = ["TrainConfig", "TrainError", "Trainer", "train", "default_method"]


DEFAULT_MAX_STEPS = 5000  # used only when neither budget is given
STEP_EVENT_SECONDS = 5.0  # slow steps still produce a step event this often


class Trainer:
    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.run = Path(cfg.out).resolve()

    # The public entry point: never raises for expected problems without first emitting an error event.
    def fit(self) -> dict:
        self._unlock: Optional[Callable[[], None]] = None
        try:
            return self._fit_run_folder()
        finally:
            if self._unlock is not None:
                self._unlock()

    def _fit_run_folder(self) -> dict:
        cfg = self.cfg
        extra_logs = [cfg.progress] if cfg.progress else []
        early_log = EventLog(extra_logs, stdout=cfg.stdout_events)
        self.log = early_log
        try:
            # Before the lock file is made: a run folder that is (or holds, or sits in) the dataset would
            # mix the trainer's files with the user's data, and --overwrite would delete from the dataset.
            check_run_vs_dataset(self.run, cfg.dataset)
            if self.run.is_dir():
                # Before anything else, so that a second trainer into a busy run learns who holds it
                # (rather than that the folder is not empty) and never reads a half-written checkpoint.
                self._unlock = lock_run_folder(self.run)
            check_run_folder(self.run, cfg.resume, cfg.overwrite)
            cfg.check()
            from .device import pick_device

            self.device = pick_device(cfg.device)
            ckpt = None
            if cfg.resume:
                self.resumed_checkpoint, ckpt = read_resume_checkpoint(self.run)
                self.cfg = merge_resumed_config(self.cfg, ckpt)
                check_run_vs_dataset(self.run, self.cfg.dataset)
            self.dataset_hash = dataset_hash(self.cfg.dataset)
            dataset = load_dataset(self.cfg.dataset, downscale=self.cfg.downscale)
            if self._unlock is None:
                # A new folder is made only now, so that a run that never starts leaves nothing behind.
                self.run.mkdir(parents=True, exist_ok=True)
                self._unlock = lock_run_folder(self.run)
                # Another trainer may have made and filled the folder since the first check.
                check_run_folder(self.run, cfg.resume, cfg.overwrite)
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            early_log.emit("error", message=str(exc))
            early_log.close()
            raise
        progress = Path(contract.progress_path(self.run))
        try:
            removed = clear_run_folder(self.run) if cfg.overwrite else []
            self.log = EventLog([progress] + extra_logs, stdout=cfg.stdout_events)
            record_written(self.run, progress)
        except OSError as exc:
            msg = f"{exc.filename or self.run}: {os_reason(exc)}"
            early_log.emit("error", message=msg)
            early_log.close()
            raise TrainError(msg) from None
        early_log.close()
        if removed:
            print(f"train: --overwrite removed {len(removed)} file(s) written by an earlier run: "
                  + ", ".join(removed[:8]) + (" ..." if len(removed) > 8 else ""), file=sys.stderr)
        restore = terminate_as_interrupt()
        try:
            return self._fit(dataset, ckpt)
        except KeyboardInterrupt:
            try:
                path = self._save_checkpoint() if hasattr(self, "opt") else None
            except TrainError as exc:
                self.log.emit("error", message=f"interrupted at step {getattr(self, 'step', 0)}; {exc}")
                raise
            self.log.emit("error", message=f"interrupted at step {getattr(self, 'step', 0)}"
                          + (f"; checkpoint saved, continue with --resume" if path else ""))
            raise
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            self.log.emit("error", message=str(exc))
            raise
        except OSError as exc:  # a full disk while writing config, previews or metrics: name the file
            msg = f"{exc.filename or self.run}: {os_reason(exc)} (at step {getattr(self, 'step', 0)})"
            self.log.emit("error", message=msg)
            raise TrainError(msg) from None
        except RuntimeError as exc:  # e.g. out of memory inside a model: one clear line, no traceback
            msg = str(exc).splitlines()[0]
            self.log.emit("error", message=f"training failed at step {getattr(self, 'step', 0)}: {msg}")
            raise TrainError(f"training failed at step {getattr(self, 'step', 0)}: {msg}") from exc
        finally:
            restore()
            self.log.close()

    # ------------------------------------------------------------------ setup

    def _choose_background(self, dataset: Dataset, ckpt: Optional[dict]) -> None:
        train = dataset.split("train")
        recorded = (ckpt.get("config") or {}).get("background_used") if ckpt is not None else None
        self.bg_mode, self.bg_reason = backgrounds.for_run(self.cfg.background, recorded, dataset)
        if self.bg_mode == "random" and not train.has_alpha:
            raise TrainError(
                f"{train.frames[0].image}: --background {self.bg_mode} needs images with an alpha channel (RGBA); "
                "this dataset's images are RGB (--background environment learns their background)"
            )
        if ckpt is not None and self.bg_mode == "environment" and "environment" not in ckpt["options"]:
            raise TrainError(f"--resume: the run was trained without a learned environment; "
                             f"it cannot continue with --background environment")
        self.eval_bg = [0.0, 0.0, 0.0] if self.bg_mode == "black" else [1.0, 1.0, 1.0]

    def _build(self, dataset: Dataset, ckpt: Optional[dict]):
        from .methods import build_model

        cfg = self.cfg
        train = dataset.split("train")
        self.method = cfg.method or default_method()
        self.size_reasons: List[str] = []
        if ckpt is not None:
            options = dict(ckpt["options"])
            self.size_reasons = list(ckpt.get("size_reasons", []))
            aabb = torch.as_tensor(ckpt["aabb"])
        else:
            options = {}
            if cfg.size == "auto":
                from .sizing import auto_size_dataset

                black = [0.0, 0.0, 0.0] if cfg.background == "black" else [1.0, 1.0, 1.0]
                options, self.size_reasons = auto_size_dataset(self.method, dataset, black)
            elif cfg.size not in (None, "", "default"):
                raise TrainError(f"--size {cfg.size!r}: only 'auto' is supported")
            options.update(cfg.options)
            aabb = dataset.aabb
        if ckpt is None and self.bg_mode == "environment" and "environment" not in options:
            from .environment import size_for_focal

            options["environment"] = {"width": size_for_focal(float(train.cameras.fx.median()))}
        seed_everything(cfg.seed)
        try:
            model = build_model(self.method, aabb, **options)
        except TypeError as exc:
            raise TrainError(f"method {self.method!r} does not accept these options {sorted(options)}: {exc}") from exc
        except ValueError as exc:  # unknown method or option values the method rejects
            raise TrainError(str(exc)) from exc
        if ckpt is not None:
            load_state_resizing(model, ckpt["model"])
        self.model = model.to(self.device).train()
        self.base_lr = float(cfg.lr or getattr(model, "default_lr", 5e-4))
        if cfg.batch_rays is None:
            cfg.batch_rays = int(getattr(model, "default_batch_rays", 0) or (4096 if self.device.type == "cuda" else 1024))
        self.warmup = warmup_steps(model, cfg.max_steps)
        self.train = train

    def _restore(self, ckpt: dict) -> None:
        """Continue from a checkpoint: counters, optimiser (fresh Adam if it does not fit) and RNGs."""
        self.step, self.elapsed = int(ckpt["step"]), float(ckpt["elapsed"])
        self.lr_scale, self.rollbacks = float(ckpt.get("lr_scale", 1.0)), int(ckpt.get("rollbacks", 0))
        self.loss_ema = ckpt.get("loss_ema")
        self.opt = make_optimizer(self.model, self.base_lr * self.lr_scale)
        try:
            self.opt.load_state_dict(ckpt["optimizer"])
        except (ValueError, KeyError) as exc:
            print(f"train: optimiser state in the checkpoint does not fit ({exc}); starting Adam afresh", file=sys.stderr)
        rescale_base_lrs(self.opt, self.model, self.base_lr * self.lr_scale)
        set_rng_state(ckpt["rng"], self.gen)

    # ------------------------------------------------------------------ checkpoints and rollback

    def _save_checkpoint(self) -> Path:
        state = {
            "format": 1, "method": self.method, "options": self.model.options,
            "aabb": self.model.aabb.detach().cpu(),
            "model": {k: v.detach().cpu() for k, v in self.model.state_dict().items()},
            "optimizer": self.opt.state_dict(), "step": self.step, "elapsed": self.elapsed,
            "lr_scale": self.lr_scale, "rollbacks": self.rollbacks, "loss_ema": self.loss_ema,
            "rng": rng_state(self.gen), "config": self.config_record(), "size_reasons": self.size_reasons,
            "versions": versions(),
        }
        latest = save_checkpoint(self.run, state, self.step, self.cfg.keep_checkpoints)
        self.log.emit("checkpoint", step=self.step, path=str(latest))
        self._last_ckpt_wall = time.monotonic()
        self._last_ckpt_step = self.step
        return latest

    def _snapshot(self) -> None:
        self.snap = {
            "model": {k: v.detach().clone() for k, v in self.model.state_dict().items()},
            "opt": clone_state(self.opt.state_dict()),
            "step": self.step,
            "elapsed_at": self.elapsed,
            "loss_ema": self.loss_ema,
        }

    def _rollback(self, reason: str) -> None:
        self.rollbacks += 1
        self.lr_scale *= 0.5
        if self.rollbacks > self.cfg.max_rollbacks:
            raise TrainError(
                f"training diverged: {self.rollbacks - 1} rollbacks did not help (last: {reason} at step {self.step}); "
                f"try a lower --lr than {self.base_lr * self.lr_scale * 2:.3g} or another --method"
            )
        snap = self.snap
        load_state_resizing(self.model, snap["model"])
        self.opt = make_optimizer(self.model, self.base_lr * self.lr_scale)
        try:
            self.opt.load_state_dict(clone_state(snap["opt"]))
        except (ValueError, KeyError):
            pass  # parameter set changed since the snapshot: fresh Adam moments
        rescale_base_lrs(self.opt, self.model, self.base_lr * self.lr_scale)  # the state brought the old rates
        at = self.step
        self.step = snap["step"]
        self.loss_ema = snap["loss_ema"]
        self.steps_since_rollback = 0
        self.log.emit("rollback", step=at, reason=f"{reason}; restored step {self.step}",
                      lr=self.base_lr * self.lr_scale, restored_step=self.step, rollbacks=self.rollbacks)

    # ------------------------------------------------------------------ records

    def config_record(self) -> dict:
        """What RUN/config.json holds: the config plus what the trainer decided (docs/CONTRACTS.md)."""
        ds, tr = self.dataset, self.train
        rec = asdict(self.cfg)
        rec.update({
            "dataset": str(Path(self.cfg.dataset).resolve()), "dataset_hash": getattr(self, "dataset_hash", None),
            "out": str(self.run), "method": self.method, "model": self.model.describe(), "lr": self.base_lr,
            "warmup_steps": self.warmup, "background_used": self.bg_mode, "background_reason": self.bg_reason,
            "eval_background": self.eval_bg, "aabb": self.model.aabb.detach().cpu().tolist(),
            "aabb_source": ds.aabb_source, "near": ds.near, "far": ds.far, "size_reasons": self.size_reasons,
            "dataset_notes": ds.notes, "n_train_views": len(tr), "image_size": [tr.width, tr.height],
            "device_used": str(self.device), "versions": versions(),
        })
        return rec

    # ------------------------------------------------------------------ loop

    def _fit(self, dataset: Dataset, ckpt: Optional[dict]) -> dict:
        cfg = self.cfg
        self.dataset = dataset
        train = dataset.split("train")
        self._choose_background(dataset, ckpt)
        self._build(dataset, ckpt)
        if cfg.max_steps is None and cfg.max_seconds is None:
            cfg.max_steps = int(getattr(self.model, "default_max_steps", DEFAULT_MAX_STEPS))

        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.step, self.elapsed, self.lr_scale, self.rollbacks = 0, 0.0, 1.0, 0
        self.loss_ema: Optional[float] = None
        self.opt = make_optimizer(self.model, self.base_lr)
        resumed_from = None
        if ckpt is not None:
            self._restore(ckpt)
            resumed_from = self.step
        config = Path(contract.config_path(self.run))
        record_written(self.run, config)
        atomic_json(config, self.config_record())
        self.log.emit("start", run=str(self.run), method=self.method, max_steps=cfg.max_steps, max_seconds=cfg.max_seconds,
                      device=str(self.device), n_params=self.model.num_parameters(), model=self.model.describe(),
                      size_reasons=self.size_reasons, resumed_from=resumed_from, seed=cfg.seed,
                      dataset=str(Path(cfg.dataset).resolve()), n_train_views=len(train),
                      image_size=[train.width, train.height], background=self.bg_mode,
                      background_reason=self.bg_reason, notes=dataset.notes)
        for r in self.size_reasons:
            print(f"train: size: {r}", file=sys.stderr)
        print(f"train: background: {self.bg_mode} ({self.bg_reason})", file=sys.stderr)
        for note in dataset.notes:
            print(f"train: note: {note}", file=sys.stderr)

        if ckpt is None and self.model.environment is not None and not getattr(self.model, "contracted", False):
            # (A contracted scene has no ray that misses it: the world beyond the box is geometry too.)
            self._prefit_environment()
        self.previews = Previews(self.run, dataset, cfg.preview_size, cfg.preview_every, cfg.preview_seconds,
                                 self.eval_bg, cfg.chunk)
        self._eval_marks = sorted(t for t in cfg.eval_at if t > self.elapsed)
        batcher = RayBatcher(train, self.bg_mode, self.gen, self.device)
        self._snapshot()
        self.steps_since_rollback = 0
        self._last_ckpt_wall, self._last_ckpt_step = time.monotonic(), self.step
        last_preview_elapsed, last_preview_step = self.elapsed, self.step
        interval = {"t": 0.0, "samples": 0, "loss": 0.0, "n": 0}
        bar_total, bar_unit = cfg.bar_total()
        bar = ProgressBar(total=bar_total, label="train", enabled=cfg.show_bar)
        params_changed = False
        last_loss = last_psnr = None
        first_step = self.step + 1  # always report the first step (also after --resume)
        last_event_wall = time.monotonic()

        while not cfg.finished(self.step, self.elapsed):
            t0 = time.perf_counter()
            frac = cfg.budget_fraction(self.step, self.elapsed)
            hook_frac = contract.budget_fraction(self.step, self.elapsed, cfg.max_steps, cfg.max_seconds)
            if self.model.training_hook(self.step, hook_frac):
                self.opt = rebuild_optimizer(self.model, self.opt, self.base_lr * self.lr_scale)
                params_changed = True
            factor = schedule_factor(self.step, frac, self.warmup)
            for g in self.opt.param_groups:
                g["lr"] = g["base_lr"] * factor
            rays_o, rays_d, bg, gt, weight = batcher.sample(cfg.batch_rays, frac)
            if self.model.environment is not None:
                bg = self.model.background(rays_d, bg)
            near, far = self.model.ray_interval(rays_o, rays_d, dataset.near, dataset.far)
            out = self.model.render_rays(rays_o, rays_d, near, far, bg, training=True)
            mse = masked_mse(out["rgb"], gt, weight)
            loss = mse
            if "rgb_coarse" in out:
                loss = loss + masked_mse(out["rgb_coarse"], gt, weight)
            if out.get("aux_loss") is not None:
                loss = loss + out["aux_loss"]
            loss_value = float(loss.detach())
            bad = None
            if not math.isfinite(loss_value):
                bad = f"loss is {loss_value}"
            elif (self.loss_ema is not None and self.steps_since_rollback > 200
                  and loss_value > 10.0 * self.loss_ema and loss_value - self.loss_ema > 0.01):
                bad = f"loss {loss_value:.4g} jumped above 10x its running average {self.loss_ema:.4g}"
            if bad is None:
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                params = [p for g in self.opt.param_groups for p in g["params"] if p.grad is not None]
                gnorm = torch.nn.utils.clip_grad_norm_(params, float("inf")) if params else torch.tensor(0.0)
                if not torch.isfinite(gnorm):
                    bad = "gradient is NaN or inf"
            self.elapsed += time.perf_counter() - t0
            if bad is not None:
                self.opt.zero_grad(set_to_none=True)
                self._rollback(bad)
                continue
            t1 = time.perf_counter()
            self.opt.step()
            self.step += 1
            self.steps_since_rollback += 1
            self.loss_ema = loss_value if self.loss_ema is None else 0.98 * self.loss_ema + 0.02 * loss_value
            self.elapsed += time.perf_counter() - t1
            interval["t"] += time.perf_counter() - t0
            interval["samples"] += int(out.get("n_samples", cfg.batch_rays))
            interval["loss"] += loss_value
            interval["n"] += 1
            last_loss, last_psnr = loss_value, psnr_from_mse(mse.detach())
            bar.set(cfg.bar_done(bar_unit, self.step, self.elapsed), info=f"step {self.step} loss {loss_value:.4f} psnr {last_psnr:.2f}")

            if params_changed or self.step % 100 == 0:
                self._snapshot()
                params_changed = False
            done = cfg.finished(self.step, self.elapsed)
            while self._eval_marks and self.elapsed >= self._eval_marks[0]:
                # Speed-against-accuracy curves: evaluate at fixed training times inside one run, so the
                # learning-rate and growth schedules are the real ones. Evaluation time is not training time.
                self._eval_marks.pop(0)
                self._held_out_eval(at_seconds=self.elapsed)
            # Slow steps (big models on a CPU) still report at least every few seconds.
            if (self.step == first_step or self.step % cfg.log_every == 0 or done
                    or time.monotonic() - last_event_wall >= STEP_EVENT_SECONDS):
                last_event_wall = time.monotonic()
                self._emit_step(last_loss, last_psnr, interval)
                interval = {"t": 0.0, "samples": 0, "loss": 0.0, "n": 0}
            if not done and self.previews.due(self.step, last_preview_step, self.elapsed, last_preview_elapsed):
                self._preview()
                last_preview_step, last_preview_elapsed = self.step, self.elapsed
            if not done and self._checkpoint_due():
                self._save_checkpoint()
        bar.close(info=f"step {self.step} loss {last_loss if last_loss is not None else float('nan'):.4f}")
        self._preview()
        latest = self._save_checkpoint()
        metrics = self._final_eval()
        self.log.emit("done", step=self.step, elapsed=self.elapsed, checkpoint=str(latest), metrics=metrics)
        return {"step": self.step, "elapsed": self.elapsed, "checkpoint": str(latest), "metrics": metrics,
                "loss": last_loss, "rollbacks": self.rollbacks}

    def _prefit_environment(self) -> None:
        """Fit the learned world to the train rays that miss the scene box; counted as training time."""
        from .environment import prefit_from_split

        started = time.perf_counter()
        msg, share = prefit_from_split(self.model, self.train, self.dataset.near, self.dataset.far, self.gen,
                                       self.device)
        self.elapsed += time.perf_counter() - started
        print(f"train: {msg}", file=sys.stderr)
        self.log.emit("note", message=msg, miss_share=share)

    # ------------------------------------------------------------------ reporting

    def _emit_step(self, loss: float, psnr: float, interval: dict) -> None:
        lr = [g for g in self.opt.param_groups if g.get("name") != "environment"][-1]["lr"]
        sps = interval["samples"] / interval["t"] if interval["t"] > 0 else 0.0
        self.log.emit("step", step=self.step, loss=loss, psnr=psnr, lr=lr, elapsed=self.elapsed, eta=self.cfg.eta(self.step, self.elapsed),
                      frac=self.cfg.budget_fraction(self.step, self.elapsed), samples_per_s=sps,
                      loss_avg=interval["loss"] / max(1, interval["n"]),
                      lrs={g.get("name", str(k)): g["lr"] for k, g in enumerate(self.opt.param_groups)})

    def _checkpoint_due(self) -> bool:
        if self.cfg.checkpoint_every:
            return self.step - self._last_ckpt_step >= self.cfg.checkpoint_every
        return time.monotonic() - self._last_ckpt_wall >= self.cfg.checkpoint_seconds

    def _preview(self) -> None:
        path = self.previews.write(self.model, self.step)
        if path is not None:
            self.log.emit("preview", step=self.step, path=str(path))

    def _held_out_eval(self, at_seconds: float) -> None:
        """Evaluate ``eval_views`` evenly spaced held-out views (all when unset) and emit an ``eval`` event."""
        self.model.eval()
        try:
            started = time.perf_counter()
            found = evaluate_held_out(self.model, self.dataset, self.cfg.eval_views, background=self.eval_bg,
                                      chunk=self.cfg.chunk)
        finally:
            self.model.train()
        if found is None:
            return
        split_name, result = found
        self.log.emit("eval", step=self.step, split=split_name, psnr=result["psnr"], ssim=result["ssim"],
                      n_views=result["n_views"], depth_mae=result.get("depth_mae"), elapsed=at_seconds,
                      eval_wall=time.perf_counter() - started, n_params=self.model.num_parameters(),
                      n_bytes=self.model.num_bytes())

    def _final_eval(self) -> dict:
        cfg = self.cfg
        if cfg.eval_views == 0 or self.dataset.held_out_split(("test", "val")) is None:
            return {}
        budget = cfg.eval_seconds if cfg.eval_seconds is not None else max(30.0, 0.25 * self.elapsed)
        self.model.eval()
        try:
            split_name, result = evaluate_held_out(self.model, self.dataset, cfg.eval_views, seconds=budget,
                                                   background=self.eval_bg, chunk=cfg.chunk)
        finally:
            self.model.train()
        if result["n_views"] < result["n_views_total"]:
            result["note"] = (f"evaluated {result['n_views']} of {result['n_views_total']} {split_name} views at full "
                              f"resolution to stay within {budget:.0f} s; `python -m nerf_core eval {self.run}` "
                              "evaluates all")
            print(f"train: {result['note']}", file=sys.stderr)
        metrics = Path(contract.metrics_path(self.run))
        record_written(self.run, metrics)
        update_metrics_file(metrics, split_name, result, self.step)
        self.log.emit("eval", step=self.step, split=split_name, psnr=result["psnr"], ssim=result["ssim"],
                      n_views=result["n_views"], depth_mae=result.get("depth_mae"))
        return {k: v for k, v in result.items() if k != "per_view"} | {"split": split_name}


def train(cfg: TrainConfig) -> dict:
    """Train according to ``cfg``; returns a summary (step, elapsed, checkpoint, metrics)."""
    return Trainer(cfg).fit()
