"""Training a method on a dataset: ``python -m nerf_core train DATASET --out RUN``; this module owns
the loop and the rollback, everything else it uses has its own module.

* Seeded and deterministic for a step budget; the batch generator's state is checkpointed
  (``nerf_core.utils.seeding``), so ``--resume`` continues the same random stream.
* Budgets: ``--max-steps`` and/or ``--max-seconds`` (training time only: previews, checkpoints and
  evaluation are not counted). The learning-rate schedule (``nerf_core.engine.optim``) and the methods'
  own schedules follow whichever budget is nearer (``contract.budget_fraction``).
* Robust: a NaN/inf loss or gradient, or a loss far above its running average, rolls the model and optimiser
  back to the last good in-memory snapshot and halves the learning rate (``rollback`` event); after too many
  rollbacks training stops with an ``error`` event.
* Never destroys data, one writer per run folder (``nerf_core.runs.folder``); weights-only
  checkpoints (``nerf_core.runs.checkpoints``). docs/CONTRACTS.md has the files and the events.
* Data-parallel under ``torchrun`` (``nerf_core.engine.distributed``, ``nerf_core.engine.replicas``): every rank
  trains the same model on its own rays; only rank 0 touches the run folder. Without torchrun's
  environment ``self.replicas`` is None and none of that code runs.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import torch

from nerf_core import contract
from nerf_core.contract.errors import DatasetError
from nerf_core.data import backgrounds
from nerf_core.data.batcher import Batcher
from nerf_core.data.loading import load_dataset
from nerf_core.data.split import Dataset
from nerf_core.engine import distributed
from nerf_core.engine.batches import check_supervision, training_batcher, with_supervision
from nerf_core.engine.callbacks import CheckpointEvery, StepInterval, default_callbacks
from nerf_core.engine.checkpointing import RunFacts
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
from nerf_core.engine.report import emit_start, evaluation_problem, failure_line
from nerf_core.engine.rollback import (
    SNAPSHOT_EVERY,
    gradient_problem,
    loss_problem,
    roll_back,
    step_values,
    take_snapshot,
)
from nerf_core.engine.state import RunDecisions, TrainState
from nerf_core.errors import RunError, TrainError
from nerf_core.image.losses import backward
from nerf_core.image.metrics import mse_to_psnr as psnr_from_mse
from nerf_core.methods.base import RadianceModel
from nerf_core.optim import TrainingOptimizer
from nerf_core.runs.checkpoints import read_resume_checkpoint
from nerf_core.runs.dataset_identity import dataset_images
from nerf_core.runs.events import EventLog
from nerf_core.runs.folder import (
    check_progress_file,
    check_run_folder,
    check_run_layout,
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
from nerf_core.utils.seeding import set_rng_state

__all__ = ["TrainConfig", "TrainError", "Trainer", "train", "default_method"]


class Trainer:
    """One training run. ``fit()`` opens the run folder, builds the model and trains it.

    What it holds while training: ``cfg`` (the ``TrainConfig``), ``decisions`` (``RunDecisions``, made
    once at the start), ``facts`` (``RunFacts``: what config.json records), ``state`` (``TrainState``:
    step, elapsed, learning-rate scale, rollbacks, loss average), ``model``, ``opt`` (the method's
    ``TrainingOptimizer``), ``gen`` (the batches' generator), ``dataset``, ``log`` (events), ``dist``
    and ``replicas`` (torchrun), ``checkpoints`` (the checkpoint schedule)."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.run = Path(cfg.out).resolve()
        self.state = TrainState()
        self.model: Optional[RadianceModel] = None
        self.opt: Optional[TrainingOptimizer] = None
        self.facts: Optional[RunFacts] = None  # set once the run's decisions are made (``_fit``)
        # The checkpoint schedule, also what an interrupt saves through (so it exists from the start).
        self.checkpoints = CheckpointEvery(cfg.checkpoint_every, cfg.checkpoint_seconds)
        self.resumed_checkpoint = ""
        self.dataset_hash: Optional[str] = None
        self.dataset_images: Optional[dict] = None

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
                check_run_layout(self.run)  # before the lock is opened: a link in the run is refused untouched
                # Before anything else, so that a second trainer into a busy run learns who holds it
                # (rather than that the folder is not empty) and never reads a half-written checkpoint.
                self._unlock = lock_run_folder(self.run)
            if main:
                check_run_folder(self.run, cfg.resume, cfg.overwrite)
            cfg.check()

            self.device = self.dist.place(pick_device(cfg.device))
            ckpt = None
            if cfg.resume:
                path, ckpt = read_resume_checkpoint(self.run)
                self.resumed_checkpoint = str(path)
                self.cfg = merge_resumed_config(self.cfg, ckpt)
                distributed.note_resume(ckpt, self.dist)
                check_run_vs_dataset(self.run, self.cfg.dataset)
            self.dataset_hash, self.dataset_images = dataset_hash(self.cfg.dataset), dataset_images(self.cfg.dataset)
            dataset = load_dataset(self.cfg.dataset, downscale=self.cfg.downscale)
            check_supervision(dataset, self.cfg)  # before the run folder: --depth's maps, --alpha-weight's film
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
                    distributed.report_checksum(self.model, self.dist, self.state.step)
                    path = self.checkpoints.save(self) if self.opt is not None else None
            except TrainError as err:
                self.log.emit("error", message=f"interrupted at step {self.state.step}; {err}")
                raise
            self.log.emit("error", message=f"interrupted at step {self.state.step}"
                          + (f" ({exc})" if str(exc) else "")
                          + ("; checkpoint saved, continue with --resume" if path else ""))
            raise
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            self.log.emit("error", message=str(exc))
            raise
        except OSError as exc:  # a full disk while writing config, previews or metrics: name the file
            msg = f"{exc.filename or self.run}: {os_reason(exc)} (at step {self.state.step})"
            try:
                self.log.emit("error", message=msg)
            except OSError:
                pass  # the failing file may be the --progress log itself; the message still reaches stderr
            raise TrainError(msg) from None
        except (RuntimeError, MemoryError) as exc:  # e.g. out of memory inside a model: one clear line, no traceback
            msg = failure_line(exc, self.cfg.batch_rays, self.cfg.options)
            self.log.emit("error", message=f"training failed at step {self.state.step}: {msg}")
            raise TrainError(f"training failed at step {self.state.step}: {msg}") from exc
        finally:
            restore()
            self.log.close()

    # ------------------------------------------------------------------ setup

    def _build(self, dataset: Dataset, ckpt: Optional[dict]) -> Optional[dict]:
        """The model to train (``model_setup``) and the decisions made once: learning rate, rays per
        step, warm-up, background. Returns the resumed checkpoint's optimiser state (or None)."""
        cfg = self.cfg
        background, reason, eval_bg = backgrounds.for_training(cfg.background, ckpt, dataset)
        method = cfg.method or default_method()
        options, aabb, size_reasons = model_options(cfg, method, dataset, ckpt, background)
        model, opt_state = build_seeded(method, aabb, options, cfg.seed, ckpt, self.resumed_checkpoint or "checkpoint")
        self.model = model.to(self.device).train()
        if cfg.batch_rays is None:  # recorded in config.json as the run's own
            cfg.batch_rays = default_batch_rays(model, self.device)
        warmup = warmup_steps(model, cfg.max_steps)  # from the budget as given (a default budget: 2000 steps)
        if cfg.max_steps is None and cfg.max_seconds is None:
            cfg.max_steps = int(model.default_max_steps)
        self.decisions = RunDecisions(method=method, base_lr=float(cfg.lr or model.default_lr),
                                      batch_rays=cfg.batch_rays, warmup=warmup, background=background,
                                      background_reason=reason, eval_background=eval_bg, size_reasons=size_reasons)
        return opt_state

    def _restore(self, ckpt: dict, opt_state: Optional[dict]) -> None:
        """Continue from a checkpoint: counters, optimiser (a fresh one if its state does not fit) and RNGs."""
        self.state = TrainState.from_checkpoint(ckpt)
        lr = self.decisions.base_lr * self.state.lr_scale
        self.opt = make_optimizer(self.model, lr)
        try:
            # checked first, by the optimiser itself: a fused kernel trusts the shapes and would write out of bounds
            self.opt.check_state(opt_state, self.resumed_checkpoint)
            self.opt.load_state_dict(opt_state)
        except (ValueError, KeyError, RunError) as exc:
            print(f"train: optimiser state in the checkpoint does not fit ({exc}); starting "
                  f"{type(self.opt).__name__} afresh", file=sys.stderr)
        rescale_base_lrs(self.opt, self.model, lr)
        set_rng_state(ckpt["rng"], self.gen)

    # ------------------------------------------------------------------ loop

    def _fit(self, dataset: Dataset, ckpt: Optional[dict]) -> dict:
        cfg = self.cfg
        self.dataset = dataset
        train = dataset.split("train")
        opt_state = self._build(dataset, ckpt)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.facts = RunFacts(self.cfg, self.decisions, dataset, self.run, self.device, self.dist.world_size,
                              self.dataset_hash, self.dataset_images)
        self.opt = make_optimizer(self.model, self.decisions.base_lr)
        resumed_from = None
        if ckpt is not None:
            self._restore(ckpt, opt_state)
            resumed_from = self.state.step
            self._refuse_spent_budget()
        if self.dist.is_main:
            config = Path(contract.config_path(self.run))
            record_written(self.run, config)
            write_json_atomic(config, self.facts.config(self.model), default=str)
        emit_start(self.log, cfg, self.decisions, self.model, dataset, self.run, self.device, self.dist,
                   resumed_from)
        if ckpt is None and self.model.models_world and not self.model.contracted:
            # (A contracted scene has no ray that misses it: the world beyond the box is geometry too.)
            msg, share, seconds = prefit_environment(self.model, train, dataset.near, dataset.far, self.gen,
                                                     self.device)
            self.state.elapsed += seconds
            if self.dist.is_main:
                print(f"train: {msg}", file=sys.stderr)
            self.log.emit("note", message=msg, miss_share=share)
        if self.replicas is not None:  # every rank starts from rank 0's model and the largest elapsed time
            self.state.elapsed = self.replicas.start(self.model, self.state.elapsed)
        self.previews = Previews(self.run, dataset, cfg.preview_size, cfg.preview_every, cfg.preview_seconds,
                                 self.decisions.eval_background, cfg.chunk)
        self.callbacks = default_callbacks(cfg, self.checkpoints)
        batcher = training_batcher(self.model, dataset, cfg, self.decisions.background, self.gen, self.device,
                                   self.log, self.dist.is_main, self.decisions.method)  # --depth carves here
        with DeferredInterrupts(self.replicas is not None) as stop:  # torchrun: ranks stop together
            self._train_loop(batcher, stop)
        if self.state.step == (resumed_from or 0):
            # A budget spent before the first step (fitting the world counts as training time): a
            # checkpoint and metrics of an untrained model must not look like a finished run.
            budget = (f"--max-seconds {cfg.max_seconds:g}" if cfg.max_seconds is not None
                      else f"--max-steps {cfg.max_steps}")
            raise TrainError(f"nothing was trained: the budget ({budget}) ran out before the "
                             f"first step, after {self.state.elapsed:.1f} s"
                             + (" of fitting the world (the background)" if self.model.models_world else "")
                             + f"; give a larger {budget.split()[0]}")
        distributed.report_checksum(self.model, self.dist, self.state.step)
        summary = dict(step=self.state.step, elapsed=self.state.elapsed, checkpoint=None, metrics={},
                       loss=self.state.last_loss, rollbacks=self.state.rollbacks)
        for callback in self.callbacks:  # the final preview, checkpoint and evaluation
            summary.update(callback.end(self))
        if self.dist.is_main:
            self.log.emit("done", step=self.state.step, elapsed=self.state.elapsed, checkpoint=summary["checkpoint"],
                          metrics=summary["metrics"])
        return summary

    def _refuse_spent_budget(self) -> None:
        """--resume of a run whose budget is met: refused before anything is rewritten."""
        state, spent = self.state, self.cfg.spent_budgets(self.state.step, self.state.elapsed)
        if spent:
            raise TrainError(f"--resume: the run is already at step {state.step} ({state.elapsed:.0f} s trained), "
                             f"which meets {' and '.join(spent)}; nothing is left to train. Give a larger budget "
                             "to continue it")

    def _train_loop(self, batcher: Batcher, stop: DeferredInterrupts) -> None:
        """Train until the budget is spent. Under torchrun, ``stop`` holds a SIGINT/SIGTERM until the
        step's reduce tells every rank to stop."""
        cfg, state = self.cfg, self.state
        self.snap = take_snapshot(self.model, self.opt, state)
        state.steps_since_rollback = 0
        self.interval = StepInterval()
        state.last_loss = state.last_psnr = None
        bar_total, bar_unit = cfg.bar_total()
        bar = ProgressBar(total=bar_total, label="train", enabled=cfg.show_bar and self.dist.is_main)
        for callback in self.callbacks:
            callback.start(self)
        self._params_changed = False
        while not cfg.finished(state.step, state.elapsed):
            if not self.step(batcher, stop):
                continue
            bar.set(cfg.bar_done(bar_unit, state.step, state.elapsed),
                    info=f"step {state.step} loss {state.last_loss:.4f} psnr {state.last_psnr:.2f}")
            if self._params_changed or state.step % SNAPSHOT_EVERY == 0:
                self.snap = take_snapshot(self.model, self.opt, state)
                self._params_changed = False
            done = cfg.finished(state.step, state.elapsed)
            # previews, checkpoints and evaluations: rank 0 writes, the others wait (every callback runs)
            side_work = [callback.after_step(self, done) for callback in self.callbacks]
            if any(side_work) and self.replicas is not None:
                self.previews.cost = self.replicas.after_side_work(self.previews.cost)
        last = state.last_loss
        bar.close(info=f"step {state.step} loss {last if last is not None else float('nan'):.4f}")

    def step(self, batcher: Batcher, stop: DeferredInterrupts) -> bool:
        """One optimisation step; False when it was rolled back instead (a bad loss or gradient)."""
        state, model = self.state, self.model
        t0 = time.perf_counter()
        hook_frac, frac = state.update_budget(self.cfg.max_steps, self.cfg.max_seconds)  # once per step
        self._hook(hook_frac, frac)
        batch = batcher.sample(model.rays_per_step(self.decisions.batch_rays), frac)
        out = model.render_batch(batch.rays_o, batch.rays_d, batch.background, self.dataset.near, self.dataset.far,
                                 training=True)
        loss, mse = model.loss(out, batch.target, batch.weight)
        loss = with_supervision(loss, out, batch, self.cfg)  # --depth, --alpha-weight; colours only: loss itself
        self.opt.zero_grad(set_to_none=True)
        backward(loss)  # even for a bad loss (rolled back below): one read of what to check
        checked = self._checked(loss, mse, out, t0, stop)
        if checked.problem is not None:
            self._roll_back(checked.problem)
            return False
        t1 = time.perf_counter()
        model.optimizer_step(self.opt, out)
        batcher.observe(batch, out)  # an error-weighted sampler learns where the error is
        self._advance(checked, t0, t1)
        return True

    def _hook(self, hook_frac: Optional[float], frac: float) -> None:
        """The method's hook (occupancy, growth: a new optimiser when the parameters changed), then
        this step's learning rates; under torchrun each with its random streams seeded."""
        state, rep = self.state, self.replicas
        if rep is not None:  # the hook's random draws (occupancy jitter) must be equal on every rank
            rep.seed_shared(state.step, state.rollbacks)
        if self.model.training_hook(state.step, hook_frac):
            self.opt = rebuild_optimizer(self.model, self.opt, self.decisions.base_lr * state.lr_scale)
            self._params_changed = True
        if rep is not None:
            rep.seed_rank(self.gen, state.step, state.rollbacks)
        factor = schedule_factor(state.step, frac, self.decisions.warmup)
        for g in self.opt.param_groups:
            g["lr"] = g["base_lr"] * factor

    def _checked(self, loss: torch.Tensor, mse: torch.Tensor, out: dict, t0: float,
                 stop: DeferredInterrupts) -> StepCheck:
        """The step's numbers read once from the device (under torchrun: reduced over the ranks, with
        the gradients) and whether it may be applied."""
        state, rep = self.state, self.replicas
        n_samples = int(out.get("n_samples", self.decisions.batch_rays))
        if rep is None:
            loss_value, mse_value, grad_bad = step_values(loss, mse, self.opt)
            state.elapsed += time.perf_counter() - t0
            problem = loss_problem(loss_value, state.loss_ema, state.steps_since_rollback) or grad_bad
            return StepCheck(loss_value, mse_value, n_samples, problem)
        # every rank takes the same decisions from the same (reduced) numbers
        params = [p for g in self.opt.param_groups for p in g["params"]]
        shared = rep.reduce(params, self.model, loss, mse, n_samples, t0, stop.requested(),
                            self.dist.is_main and self.checkpoints.wall_clock_due())
        state.elapsed += shared.seconds
        if shared.stop:
            raise KeyboardInterrupt
        self.checkpoints.agree_wall_clock(shared.checkpoint_due)
        problem = loss_problem(shared.loss, state.loss_ema, state.steps_since_rollback) or gradient_problem(self.opt)
        return StepCheck(shared.loss, shared.mse, shared.n_samples, problem)

    def _roll_back(self, problem: str) -> None:
        if self.replicas is not None:
            self.replicas.end_step()
        self.opt.zero_grad(set_to_none=True)
        self.opt = roll_back(self.model, self.snap, self.state, self.decisions.base_lr, self.cfg.max_rollbacks,
                             problem, self.log)

    def _advance(self, checked: StepCheck, t0: float, t1: float) -> None:
        """Count the applied step: counters, the loss average, the step's time and its report."""
        state = self.state
        state.step += 1
        state.steps_since_rollback += 1
        loss_value = checked.loss
        state.loss_ema = loss_value if state.loss_ema is None else 0.98 * state.loss_ema + 0.02 * loss_value
        if self.replicas is not None:
            self.replicas.end_step()
        else:
            state.elapsed += time.perf_counter() - t1
        self.interval.add(time.perf_counter() - t0, checked.n_samples, loss_value)
        state.last_loss, state.last_psnr = loss_value, psnr_from_mse(checked.mse)


@dataclass(frozen=True)
class StepCheck:
    """What a step's checks read from the device: loss, photometric MSE (floats), samples evaluated,
    and why the step must not be applied (None when it may)."""

    loss: float
    mse: float
    n_samples: int
    problem: Optional[str]


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
