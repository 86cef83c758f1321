"""Training a method on a dataset: ``python -m nerf_core train DATASET --out RUN``; this module owns
the loop and the rollback, everything else it uses has its own module.

* Seeded and deterministic for a step budget; the batch generator's state is checkpointed
  (``nerf_core.utils.seeding``), so ``--resume`` continues the same random stream.
* Budgets: ``--max-steps`` and/or ``--max-seconds`` (training time only: previews, checkpoints and
  evaluation are not counted). The learning-rate schedule (``nerf_core.engine.optim``) and the methods'
  own schedules follow whichever budget is nearer (``contract.budget_fraction``).
* Robust: a NaN/inf loss or gradient, or a loss far above its running average, rolls the model
  and optimiser back to the last good in-memory snapshot and halves the learning rate
  (``rollback`` event); after too many rollbacks training stops with an ``error`` event.
* Never destroys data, one writer per run folder (``nerf_core.runs.folder``); weights-only
  checkpoints (``nerf_core.runs.checkpoints``). docs/CONTRACTS.md has the files and the events.
* Data-parallel under ``torchrun`` (``nerf_core.engine.distributed``, ``nerf_core.engine.replicas``): every rank
  trains the same model on its own rays; only rank 0 touches the run folder. Without torchrun's
  environment ``self.replicas`` is None and none of that code runs.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Callable, Optional

import torch

from nerf_core import contract
from nerf_core.contract.errors import DatasetError
from nerf_core.data import backgrounds
from nerf_core.data.batcher import RayBatcher
from nerf_core.data.loading import load_dataset
from nerf_core.data.split import Dataset
from nerf_core.engine import distributed
from nerf_core.engine.callbacks import StepInterval, default_callbacks
from nerf_core.engine.config import TrainConfig, check_field_types, default_method, merge_resumed_config
from nerf_core.engine.model_setup import build_seeded, default_batch_rays, model_options, prefit_environment
from nerf_core.engine.optim import (
    make_optimizer,
    rebuild_optimizer,
    rescale_base_lrs,
    schedule_factor,
    warmup_steps,
)
from nerf_core.engine.previews import Previews
from nerf_core.engine.replicas import Replicas
from nerf_core.engine.report import evaluation_problem, final_eval, run_config
from nerf_core.engine.rollback import (
    SNAPSHOT_EVERY,
    gradient_problem,
    loss_problem,
    roll_back,
    take_snapshot,
)
from nerf_core.errors import RunError, TrainError
from nerf_core.image.losses import backward, masked_mse
from nerf_core.image.metrics import mse_to_psnr as psnr_from_mse
from nerf_core.runs.checkpoint_checks import check_optimizer_state
from nerf_core.runs.checkpoints import (
    read_resume_checkpoint,
    save_checkpoint,
    versions,
)
from nerf_core.runs.dataset_identity import dataset_images
from nerf_core.runs.events import EventLog
from nerf_core.runs.folder import (
    check_progress_file,
    check_run_folder,
    check_run_vs_dataset,
    clear_run_folder,
    dataset_hash,
    lock_run_folder,
    os_reason,
    record_written,
)
from nerf_core.utils.atomic import write_json_atomic
from nerf_core.utils.device import pick_device
from nerf_core.utils.interrupts import DeferredInterrupts, terminate_as_interrupt
from nerf_core.utils.progressbar import ProgressBar
from nerf_core.utils.seeding import rng_state, set_rng_state

__all__ = ["TrainConfig", "TrainError", "Trainer", "train", "default_method"]


DEFAULT_MAX_STEPS = 5000  # used only when neither budget is given


class Trainer:
    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.run = Path(cfg.out).resolve()

    # The public entry point: never raises for expected problems without first emitting an error event.
    def fit(self) -> dict:
        self._unlock: Optional[Callable[[], None]] = None
        self.dist = distributed.init_from_env()  # inactive (no process group) without torchrun
        self.replicas = Replicas(self.dist, self.cfg.seed) if self.dist.active else None
        try:
            return self._fit_run_folder()
        finally:
            if self._unlock is not None:
                self._unlock()
            self.dist.close()

    def _fit_run_folder(self) -> dict:
        """Open the run folder (checks, lock, events), then train with every failure reported as an
        ``error`` event and a TrainError (or the dataset's or run's own error)."""
        cfg = self.cfg  # as given: --resume replaces self.cfg with the run's merged config
        dataset, ckpt, early_log, extra_logs = self._open_run()
        self._start_events(cfg, early_log, extra_logs)
        return self._fit_guarded(dataset, ckpt)

    def _open_run(self):
        """Check the flags, the run folder and the dataset, take the run's lock and load the dataset
        (and the checkpoint to resume). Returns (dataset, checkpoint or None, the early event log,
        the --progress logs); an error is emitted as an event before it is raised."""
        cfg = self.cfg
        main = self.dist.is_main  # only rank 0 writes: events, lock, checkpoints, previews, metrics
        extra_logs = [cfg.progress] if cfg.progress and main else []
        if cfg.progress:
            try:  # before the file is opened for appending; every rank decides alike
                check_progress_file(Path(cfg.progress), cfg.dataset, self.run)
            except TrainError as exc:
                if main:
                    EventLog([], stdout=cfg.stdout_events).emit("error", message=str(exc))
                self.dist.agree(False)
                raise
        early_log = EventLog(extra_logs, stdout=cfg.stdout_events and main)
        self.log = early_log
        try:
            # Before the lock file is made: a run folder that is (or holds, or sits in) the dataset would
            # mix the trainer's files with the user's data, and --overwrite would delete from the dataset.
            check_run_vs_dataset(self.run, cfg.dataset)
            if main and self.run.is_dir():
                # Before anything else, so that a second trainer into a busy run learns who holds it
                # (rather than that the folder is not empty) and never reads a half-written checkpoint.
                self._unlock = lock_run_folder(self.run)
            if main:
                check_run_folder(self.run, cfg.resume, cfg.overwrite)
            cfg.check()

            self.device = self.dist.place(pick_device(cfg.device))
            ckpt = None
            if cfg.resume:
                self.resumed_checkpoint, ckpt = read_resume_checkpoint(self.run)
                self.cfg = merge_resumed_config(self.cfg, ckpt)
                distributed.note_resume(ckpt, self.dist)
                check_run_vs_dataset(self.run, self.cfg.dataset)
            self.dataset_hash, self.dataset_images = dataset_hash(self.cfg.dataset), dataset_images(self.cfg.dataset)
            dataset = load_dataset(self.cfg.dataset, downscale=self.cfg.downscale)
            unscorable = evaluation_problem(dataset, self.cfg)
            if unscorable:
                raise TrainError(unscorable)
            if main and self._unlock is None:
                # A new folder is made only now, so that a run that never starts leaves nothing behind.
                self.run.mkdir(parents=True, exist_ok=True)
                self._unlock = lock_run_folder(self.run)
                # Another trainer may have made and filled the folder since the first check.
                check_run_folder(self.run, cfg.resume, cfg.overwrite)
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            early_log.emit("error", message=str(exc))
            early_log.close()
            self.dist.agree(False)
            raise
        return dataset, ckpt, early_log, extra_logs

    def _start_events(self, cfg: TrainConfig, early_log: EventLog, extra_logs: list) -> None:
        """Clear what --overwrite removes and switch to RUN/progress.jsonl; every rank agrees to start."""
        main = self.dist.is_main
        progress = Path(contract.progress_path(self.run))
        try:
            removed = clear_run_folder(self.run) if cfg.overwrite and main else []
            self.log = EventLog([progress] + extra_logs if main else [], stdout=cfg.stdout_events and main)
            if main:
                record_written(self.run, progress)
        except OSError as exc:
            msg = f"{exc.filename or self.run}: {os_reason(exc)}"
            early_log.emit("error", message=msg)
            early_log.close()
            self.dist.agree(False)
            raise TrainError(msg) from None
        early_log.close()
        if not self.dist.agree(True):  # a rank could not start: every rank stops here, none waits
            msg = f"rank {self.dist.rank}: another rank could not start the run (its error is above)"
            self.log.emit("error", message=msg)
            self.log.close()
            raise TrainError(msg)
        if removed:
            print(f"train: --overwrite removed {len(removed)} file(s) written by an earlier run: "
                  + ", ".join(removed[:8]) + (" ..." if len(removed) > 8 else ""), file=sys.stderr)

    def _fit_guarded(self, dataset: Dataset, ckpt: Optional[dict]) -> dict:
        """``_fit`` with SIGTERM taken as Ctrl-C, a checkpoint saved on an interrupt, and every failure
        one ``error`` event and one line (no traceback)."""
        restore = terminate_as_interrupt()
        try:
            return self._fit(dataset, ckpt)
        except KeyboardInterrupt as exc:  # also distributed.PeerLost: another rank left the job
            try:
                # Shielded: a second Ctrl-C (people press it twice) or torchrun's SIGTERM after a lost
                # rank must not cut the save short and lose every step since the last checkpoint.
                with DeferredInterrupts(True, reraise=False):
                    distributed.report_checksum(getattr(self, "model", None), self.dist, getattr(self, "step", 0))
                    path = self.save_checkpoint() if hasattr(self, "opt") else None
            except TrainError as err:
                self.log.emit("error", message=f"interrupted at step {getattr(self, 'step', 0)}; {err}")
                raise
            self.log.emit("error", message=f"interrupted at step {getattr(self, 'step', 0)}"
                          + (f" ({exc})" if str(exc) else "")
                          + ("; checkpoint saved, continue with --resume" if path else ""))
            raise
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            self.log.emit("error", message=str(exc))
            raise
        except OSError as exc:  # a full disk while writing config, previews or metrics: name the file
            msg = f"{exc.filename or self.run}: {os_reason(exc)} (at step {getattr(self, 'step', 0)})"
            try:
                self.log.emit("error", message=msg)
            except OSError:
                pass  # the failing file may be the --progress log itself; the message still reaches stderr
            raise TrainError(msg) from None
        except (RuntimeError, MemoryError) as exc:  # e.g. out of memory inside a model: one clear line, no traceback
            msg = (str(exc).splitlines() or [type(exc).__name__])[0]
            if isinstance(exc, MemoryError) or "alloc" in msg.lower() or "out of memory" in msg.lower():
                # Name what to turn down: the allocator's byte count alone does not say which setting asked.
                msg = (f"not enough memory ({msg[:200]}); lower --batch-rays (now {self.cfg.batch_rays}) or the "
                       "method's size options (--set res_final=..., density_rank=..., width=..., occ_res=...)")
            self.log.emit("error", message=f"training failed at step {getattr(self, 'step', 0)}: {msg}")
            raise TrainError(f"training failed at step {getattr(self, 'step', 0)}: {msg}") from exc
        finally:
            restore()
            self.log.close()

    # ------------------------------------------------------------------ setup

    def _build(self, dataset: Dataset, ckpt: Optional[dict]) -> None:
        """The model to train (``model_setup``), its learning rate, warm-up and rays per step."""
        cfg = self.cfg
        self.train = dataset.split("train")
        self.method = cfg.method or default_method()
        options, aabb, self.size_reasons = model_options(cfg, self.method, dataset, ckpt, self.bg_mode)
        model = build_seeded(self.method, aabb, options, cfg.seed, ckpt, str(getattr(self, "resumed_checkpoint", "")))
        self.model = model.to(self.device).train()
        self.base_lr = float(cfg.lr or getattr(model, "default_lr", 5e-4))
        if cfg.batch_rays is None:
            cfg.batch_rays = default_batch_rays(model, self.device)
        self.warmup = warmup_steps(model, cfg.max_steps)

    def _restore(self, ckpt: dict) -> None:
        """Continue from a checkpoint: counters, optimiser (fresh Adam if it does not fit) and RNGs."""
        self.step, self.elapsed = int(ckpt["step"]), float(ckpt["elapsed"])
        self.lr_scale, self.rollbacks = float(ckpt.get("lr_scale", 1.0)), int(ckpt.get("rollbacks", 0))
        self.loss_ema = ckpt.get("loss_ema")
        self.opt = make_optimizer(self.model, self.base_lr * self.lr_scale)
        try:
            # checked first: the fused Adam kernel trusts the moments' shapes and would write out of bounds
            _, opt_state = self.model.upgrade_checkpoint(ckpt["model"], ckpt["optimizer"])  # older layouts
            check_optimizer_state(opt_state, self.opt, str(self.resumed_checkpoint))
            self.opt.load_state_dict(opt_state)
        except (ValueError, KeyError, RunError) as exc:
            print(f"train: optimiser state in the checkpoint does not fit ({exc}); starting Adam afresh", file=sys.stderr)
        rescale_base_lrs(self.opt, self.model, self.base_lr * self.lr_scale)
        set_rng_state(ckpt["rng"], self.gen)

    # ------------------------------------------------------------------ checkpoints and rollback

    def save_checkpoint(self) -> Optional[Path]:
        if not self.dist.is_main:  # the other ranks only keep the schedule (checkpoint_every)
            self._last_ckpt_wall, self._last_ckpt_step = time.monotonic(), self.step
            return None
        state = {
            "format": 1, "method": self.method, "options": self.model.options,
            "aabb": self.model.aabb.detach().cpu(),
            "model": {k: v.detach().cpu() for k, v in self.model.state_dict().items()},
            "optimizer": self.opt.state_dict(), "step": self.step, "elapsed": self.elapsed,
            "lr_scale": self.lr_scale, "rollbacks": self.rollbacks, "loss_ema": self.loss_ema,
            "rng": rng_state(self.gen), "config": run_config(self), "size_reasons": self.size_reasons,
            "versions": versions(),
        }
        latest = save_checkpoint(self.run, state, self.step, self.cfg.keep_checkpoints)
        self.log.emit("checkpoint", step=self.step, path=str(latest))
        self._last_ckpt_wall = time.monotonic()
        self._last_ckpt_step = self.step
        return latest

    # ------------------------------------------------------------------ records

    # ------------------------------------------------------------------ loop

    def _fit(self, dataset: Dataset, ckpt: Optional[dict]) -> dict:
        cfg = self.cfg
        self.dataset = dataset
        train = dataset.split("train")
        self.bg_mode, self.bg_reason, self.eval_bg = backgrounds.for_training(cfg.background, ckpt, dataset)
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
            spent = ([f"--max-steps {cfg.max_steps}"] if cfg.max_steps is not None and self.step >= cfg.max_steps else []) \
                + ([f"--max-seconds {cfg.max_seconds:g}"] if cfg.max_seconds is not None and self.elapsed >= cfg.max_seconds else [])
            if spent:  # refused before anything is rewritten: the checkpoints stay as they are
                raise TrainError(f"--resume: the run is already at step {self.step} ({self.elapsed:.0f} s trained), "
                                 f"which meets {' and '.join(spent)}; nothing is left to train. Give a larger budget to "
                                 "continue it")
        if self.dist.is_main:
            config = Path(contract.config_path(self.run))
            record_written(self.run, config)
            write_json_atomic(config, run_config(self), default=str)
        kernels = self.model.kernels(self.device)  # which implementation each hot loop takes, and why
        self.log.emit("start", run=str(self.run), method=self.method, max_steps=cfg.max_steps, max_seconds=cfg.max_seconds,
                      device=str(self.device), n_params=self.model.num_parameters(), model=self.model.describe(),
                      size_reasons=self.size_reasons, resumed_from=resumed_from, seed=cfg.seed,
                      dataset=str(Path(cfg.dataset).resolve()), n_train_views=len(train),
                      image_size=[train.width, train.height], background=self.bg_mode,
                      background_reason=self.bg_reason, notes=dataset.notes, world_size=self.dist.world_size,
                      kernels=kernels)
        slow = [f"kernel: {name} runs on {how}" for name, how in kernels.items() if "fallback" in how]
        for line in ([f"size: {r}" for r in self.size_reasons] + [f"background: {self.bg_mode} ({self.bg_reason})"]
                     + [f"note: {note}" for note in dataset.notes] + slow if self.dist.is_main else []):
            print(f"train: {line}", file=sys.stderr)

        if ckpt is None and self.model.environment is not None and not getattr(self.model, "contracted", False):
            # (A contracted scene has no ray that misses it: the world beyond the box is geometry too.)
            prefit_environment(self)
        if self.replicas is not None:  # every rank starts from rank 0's model and the largest elapsed time
            self.elapsed = self.replicas.start(self.model, self.elapsed)
        self.previews = Previews(self.run, dataset, cfg.preview_size, cfg.preview_every, cfg.preview_seconds,
                                 self.eval_bg, cfg.chunk)
        self.callbacks = default_callbacks(cfg)
        with DeferredInterrupts(self.replicas is not None) as stop:  # torchrun: ranks stop together
            last_loss = self._train_loop(RayBatcher(train, self.bg_mode, self.gen, self.device), stop)
        if self.step == (resumed_from or 0):
            # A budget spent before the first step (fitting the world counts as training time): a
            # checkpoint and metrics of an untrained model must not look like a finished run.
            budget = f"--max-seconds {cfg.max_seconds:g}" if cfg.max_seconds is not None else f"--max-steps {cfg.max_steps}"
            raise TrainError(f"nothing was trained: the budget ({budget}) ran out before the "
                             f"first step, after {self.elapsed:.1f} s" + (" of fitting the world (the background)"
                                                                           if self.model.environment is not None else "")
                             + f"; give a larger {budget.split()[0]}")
        distributed.report_checksum(self.model, self.dist, self.step)
        summary = dict(step=self.step, elapsed=self.elapsed, checkpoint=None, metrics={}, loss=last_loss, rollbacks=self.rollbacks)
        if not self.dist.is_main:
            return summary
        self.preview()
        latest = self.save_checkpoint()
        metrics = final_eval(self.log, self.model, self.dataset, cfg, self.eval_bg, self.run, self.step, self.elapsed)
        self.log.emit("done", step=self.step, elapsed=self.elapsed, checkpoint=str(latest), metrics=metrics)
        return summary | {"checkpoint": str(latest), "metrics": metrics}

    def _train_loop(self, batcher: RayBatcher, stop: DeferredInterrupts) -> Optional[float]:
        """Train until the budget is spent; returns the last step's loss. Under torchrun, ``stop``
        holds a SIGINT/SIGTERM until the step's reduce tells every rank to stop."""
        cfg = self.cfg
        take_snapshot(self)
        self.steps_since_rollback = 0
        self._last_ckpt_wall, self._last_ckpt_step = time.monotonic(), self.step
        self.interval = StepInterval()
        self.last_loss = self.last_psnr = None
        bar_total, bar_unit = cfg.bar_total()
        bar = ProgressBar(total=bar_total, label="train", enabled=cfg.show_bar and self.dist.is_main)
        for callback in self.callbacks:
            callback.start(self)
        self._params_changed = self._ckpt_wall_due = False
        while not cfg.finished(self.step, self.elapsed):
            if not self._step(batcher, stop):
                continue
            bar.set(cfg.bar_done(bar_unit, self.step, self.elapsed),
                    info=f"step {self.step} loss {self.last_loss:.4f} psnr {self.last_psnr:.2f}")
            if self._params_changed or self.step % SNAPSHOT_EVERY == 0:
                take_snapshot(self)
                self._params_changed = False
            done = cfg.finished(self.step, self.elapsed)
            # previews, checkpoints and evaluations: rank 0 writes, the others wait (every callback runs)
            side_work = [callback.after_step(self, done) for callback in self.callbacks]
            if any(side_work) and self.replicas is not None:
                self.previews.cost = self.replicas.after_side_work(self.previews.cost)
        last = self.last_loss
        bar.close(info=f"step {self.step} loss {last if last is not None else float('nan'):.4f}")
        for callback in self.callbacks:
            callback.end(self)
        return last

    def _step(self, batcher: RayBatcher, stop: DeferredInterrupts) -> bool:
        """One optimisation step; False when it was rolled back instead (a bad loss or gradient)."""
        cfg, dataset, rep = self.cfg, self.dataset, self.replicas
        t0 = time.perf_counter()
        frac = cfg.budget_fraction(self.step, self.elapsed)
        hook_frac = contract.budget_fraction(self.step, self.elapsed, cfg.max_steps, cfg.max_seconds)
        if rep is not None:  # the hook's random draws (occupancy jitter) must be equal on every rank
            rep.seed_shared(self.step, self.rollbacks)
        if self.model.training_hook(self.step, hook_frac):
            self.opt = rebuild_optimizer(self.model, self.opt, self.base_lr * self.lr_scale)
            self._params_changed = True
        if rep is not None:
            rep.seed_rank(self.gen, self.step, self.rollbacks)
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
        n_samples = int(out.get("n_samples", cfg.batch_rays))
        if rep is None:
            loss_value = float(loss.detach())
            bad = loss_problem(loss_value, self.loss_ema, self.steps_since_rollback)
            if bad is None:
                self.opt.zero_grad(set_to_none=True)
                backward(loss)
                bad = gradient_problem(self.opt)
            self.elapsed += time.perf_counter() - t0
        else:  # every rank takes the same decisions from the same (reduced) numbers
            self.opt.zero_grad(set_to_none=True)
            backward(loss)
            params = [p for g in self.opt.param_groups for p in g["params"]]
            shared = rep.reduce(params, self.model, loss, mse, n_samples, t0, stop.requested(),
                                self.dist.is_main and self.checkpoint_due(wall_clock=True))
            self.elapsed += shared.seconds
            if shared.stop:
                raise KeyboardInterrupt
            loss_value, mse, n_samples, self._ckpt_wall_due = shared.loss, shared.mse, shared.n_samples, shared.checkpoint_due
            bad = loss_problem(loss_value, self.loss_ema, self.steps_since_rollback) or gradient_problem(self.opt)
        if bad is not None:
            if rep is not None:
                rep.end_step()
            self.opt.zero_grad(set_to_none=True)
            roll_back(self, bad)
            return False
        t1 = time.perf_counter()
        self.opt.step()
        self.step += 1
        self.steps_since_rollback += 1
        self.loss_ema = loss_value if self.loss_ema is None else 0.98 * self.loss_ema + 0.02 * loss_value
        if rep is not None:
            rep.end_step()
        else:
            self.elapsed += time.perf_counter() - t1
        self.interval.add(time.perf_counter() - t0, n_samples, loss_value)
        self.last_loss, self.last_psnr = loss_value, psnr_from_mse(mse.detach() if torch.is_tensor(mse) else mse)
        return True

    # ------------------------------------------------------------------ reporting

    def checkpoint_due(self, wall_clock: bool = False) -> bool:
        """Step-based (``checkpoint_every``) or by rank 0's wall clock, which under torchrun every rank
        learns from the step's reduce (``wall_clock=True``: rank 0 asks its own clock)."""
        if self.cfg.checkpoint_every:
            return not wall_clock and self.step - self._last_ckpt_step >= self.cfg.checkpoint_every
        if self.replicas is not None and not wall_clock:
            return self._ckpt_wall_due
        return time.monotonic() - self._last_ckpt_wall >= self.cfg.checkpoint_seconds

    def preview(self) -> None:
        if not self.dist.is_main:
            return
        path = self.previews.write(self.model, self.step)
        if path is not None:
            self.log.emit("preview", step=self.step, path=str(path))


def train(cfg: TrainConfig) -> dict:
    """Train according to ``cfg``; returns a summary (step, elapsed, checkpoint, metrics).

    Writes RUN = ``cfg.out``: config.json, checkpoints/, progress.jsonl, previews and metrics.json.

    Args:
        cfg: the run's ``TrainConfig``. With neither ``max_steps`` nor ``max_seconds`` set, training
            stops at the method's ``default_max_steps``, which is written into ``cfg.max_steps``.

    Returns:
        dict with ``step`` (steps done), ``elapsed`` (training seconds), ``checkpoint`` (str path of
        checkpoints/latest.pt), ``metrics`` (the final held-out evaluation, {} when skipped), ``loss``
        (the last step's loss, or None) and ``rollbacks``. Under torchrun, ranks other than 0 get
        ``checkpoint`` None and ``metrics`` {}.

    Raises:
        TrainError: bad settings, a run folder in use or not empty, divergence after ``max_rollbacks``,
            a full disk, out of memory, or a budget spent before the first step.
        DatasetError: the dataset cannot be loaded.
        RunError: ``resume`` without a usable checkpoint.
        ValueError: a ``device`` that does not exist.
        KeyboardInterrupt: Ctrl-C, SIGTERM, SIGHUP or a closed stdout, re-raised after a checkpoint is saved.
    """
    check_field_types(cfg)  # before anything reads cfg.out or cfg.dataset (TrainError naming the field)
    return Trainer(cfg).fit()
