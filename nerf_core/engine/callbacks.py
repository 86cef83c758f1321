"""The trainer's periodic work, one small callback each (in the spirit of nerfstudio's
``TrainingCallback``): held-out evaluation at fixed training times, ``step`` events, previews and
checkpoints.

After every optimisation step the trainer calls each callback's ``after_step`` in the order of
``default_callbacks``; when the budget is spent, each callback's ``end``, which does the run's last
preview, checkpoint and evaluation. A callback reads the trainer's declared attributes (``state``, a
``TrainState``; ``model``, ``opt``, ``gen``, ``log``, ``cfg``, ``decisions``, ``facts``, ``dist``,
``replicas``, ``previews``, ``dataset``) and keeps its own schedule; it calls no method of the trainer.
It may write files; it must not draw random numbers, so that a seeded run trains the same with or
without it. Only rank 0 of a
``torchrun`` job writes; the others keep the same schedule.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import List, Optional, Sequence

from nerf_core.engine.checkpointing import write_checkpoint
from nerf_core.engine.report import emit_step, final_eval, held_out_eval

STEP_EVENT_SECONDS = 5.0  # slow steps still produce a step event this often


class TrainingCallback:
    """Work done between optimisation steps."""

    def start(self, trainer) -> None:
        """Called once, before the first step of this process (also after ``--resume``)."""

    def end(self, trainer) -> dict:
        """Called once, when the budget is spent (not on an interrupt or an error), in the order of
        ``default_callbacks``. Returns entries for the run's summary and ``done`` event (e.g.
        ``checkpoint``, ``metrics``), or {}."""
        return {}

    def after_step(self, trainer, done: bool) -> bool:
        """Called after each optimisation step.

        Args:
            trainer: the ``Trainer`` (``state``, ``model``, ``log``, ``cfg``, ``decisions``, ``dist``).
            done: the budget is spent: this is the last step (each callback's ``end`` follows).
        Returns:
            True when it did side work (an evaluation, a preview, a checkpoint) that the other ranks of a
            ``torchrun`` job waited for.
        """
        return False


class EvalAtTimes(TrainingCallback):
    """``--eval-at``: evaluate held-out views when training time crosses each mark (seconds).

    Speed-against-accuracy curves: evaluating at fixed training times inside one run keeps the
    learning-rate and growth schedules the real ones. Evaluation time is not training time.
    """

    def __init__(self, marks: Sequence[float]):
        self.marks = sorted(marks)

    def start(self, trainer) -> None:
        self.marks = [t for t in self.marks if t > trainer.state.elapsed]

    def after_step(self, trainer, done: bool) -> bool:
        crossed = [t for t in self.marks if trainer.state.elapsed >= t]
        if not crossed:
            return False
        # A slow step can cross several marks; the model is the same for all of them, so it is
        # evaluated once and the event names every mark it stands for.
        del self.marks[:len(crossed)]
        if trainer.dist.is_main:
            held_out_eval(trainer.log, trainer.model, trainer.dataset, trainer.cfg,
                          trainer.decisions.eval_background, trainer.state.step, trainer.state.elapsed, marks=crossed)
        return True

    def end(self, trainer) -> dict:
        if not self.marks or not trainer.dist.is_main:
            return {}
        # --max-steps ran out before these times (a --max-seconds budget refuses marks beyond it)
        marks = ", ".join(f"{t:g}" for t in self.marks)
        msg = (f"--eval-at {marks}: training ended after {trainer.state.elapsed:.1f} s ({trainer.state.step} "
               f"steps), before {'this mark' if len(self.marks) == 1 else 'these marks'}: nothing was evaluated "
               "there")
        print(f"train: note: {msg}", file=sys.stderr)
        trainer.log.emit("note", message=msg)
        return {}


class StepEvents(TrainingCallback):
    """A ``step`` event every ``log_every`` steps, at the first and the last step, and at least every
    ``STEP_EVENT_SECONDS`` of wall time (slow steps: big models on a CPU)."""

    def start(self, trainer) -> None:
        self.first_step = trainer.state.step + 1  # always report the first step (also after --resume)
        self.last_event_wall = time.monotonic()

    def after_step(self, trainer, done: bool) -> bool:
        cfg, state = trainer.cfg, trainer.state
        if (state.step == self.first_step or state.step % cfg.log_every == 0 or done
                or time.monotonic() - self.last_event_wall >= STEP_EVENT_SECONDS):
            self.last_event_wall = time.monotonic()
            emit_step(trainer.log, cfg, trainer.opt, state.step, state.elapsed, state.last_loss,
                      state.last_psnr, trainer.interval.pop())
        return False


class PreviewEvery(TrainingCallback):
    """A preview image every ``--preview-every`` steps, or every ``preview_seconds`` of training, and
    one of the final model."""

    def start(self, trainer) -> None:
        self.last_step, self.last_elapsed = trainer.state.step, trainer.state.elapsed

    def after_step(self, trainer, done: bool) -> bool:
        state = trainer.state
        if done or not trainer.previews.due(state.step, self.last_step, state.elapsed, self.last_elapsed):
            return False
        self.write(trainer)
        self.last_step, self.last_elapsed = state.step, state.elapsed
        return True

    def end(self, trainer) -> dict:
        self.write(trainer)
        return {}

    @staticmethod
    def write(trainer) -> None:
        """One preview of the model as it is now (rank 0 only), and its ``preview`` event."""
        if not trainer.dist.is_main:
            return
        path = trainer.previews.write(trainer.model, trainer.state.step)
        if path is not None:
            trainer.log.emit("preview", step=trainer.state.step, path=str(path))


class CheckpointEvery(TrainingCallback):
    """A checkpoint every ``--checkpoint-every`` steps, or every ``checkpoint_seconds`` of wall time,
    and one of the final model (the summary's ``checkpoint``). It owns the schedule; ``save`` is also
    what an interrupted run calls to keep its work.

    Under ``torchrun`` rank 0's wall clock decides for every rank: the trainer sends
    ``wall_clock_due()`` through the step's reduce and hands the agreed answer back
    (``agree_wall_clock``), so that every rank takes the same (collective) checkpoint steps.

    Args:
        every_steps: ``--checkpoint-every`` (None: by wall time).
        every_seconds: ``checkpoint_seconds``.
    """

    def __init__(self, every_steps: Optional[int], every_seconds: float):
        self.every_steps, self.every_seconds = every_steps, every_seconds
        self.last_step, self.last_wall = 0, time.monotonic()
        self.agreed_due = False

    def start(self, trainer) -> None:
        self.last_step, self.last_wall = trainer.state.step, time.monotonic()
        self.agreed_due = False

    def wall_clock_due(self) -> bool:
        """This process's own clock says a checkpoint is due (never with ``--checkpoint-every``)."""
        return not self.every_steps and time.monotonic() - self.last_wall >= self.every_seconds

    def agree_wall_clock(self, due: bool) -> None:
        """The step's reduce agreed on rank 0's ``wall_clock_due`` (under torchrun)."""
        self.agreed_due = due

    def due(self, step: int, replicated: bool) -> bool:
        if self.every_steps:
            return step - self.last_step >= self.every_steps
        return self.agreed_due if replicated else self.wall_clock_due()

    def after_step(self, trainer, done: bool) -> bool:
        if done or not self.due(trainer.state.step, trainer.replicas is not None):
            return False
        self.save(trainer)
        return True

    def end(self, trainer) -> dict:
        latest = self.save(trainer)
        return {"checkpoint": str(latest)} if latest is not None else {}

    def save(self, trainer) -> Optional[Path]:
        """Write a checkpoint of the run as it is now (rank 0; the other ranks only keep the schedule);
        returns latest.pt, or None on the other ranks."""
        latest = None
        if trainer.dist.is_main:
            latest = write_checkpoint(trainer.facts, trainer.model, trainer.opt, trainer.state, trainer.gen,
                                      trainer.log)
        self.last_wall, self.last_step = time.monotonic(), trainer.state.step
        return latest


class FinalEvaluation(TrainingCallback):
    """The held-out evaluation of the final model into RUN/metrics.json (``report.final_eval``), on
    rank 0; the summary's ``metrics``."""

    def end(self, trainer) -> dict:
        if not trainer.dist.is_main:
            return {}
        return {"metrics": final_eval(trainer.log, trainer.model, trainer.dataset, trainer.cfg,
                                      trainer.decisions.eval_background, trainer.run, trainer.state.step,
                                      trainer.state.elapsed)}


def default_callbacks(cfg, checkpoints: CheckpointEvery) -> List[TrainingCallback]:
    """The trainer's callbacks for ``cfg`` (a ``TrainConfig``), in the order they run after a step and
    at the end (the final preview, then checkpoint, then evaluation); ``checkpoints`` is the trainer's
    own schedule, which an interrupt also saves through."""
    return [EvalAtTimes(cfg.eval_at), StepEvents(), PreviewEvery(), checkpoints, FinalEvaluation()]


class StepInterval:
    """What the steps since the last ``step`` event add up to: seconds, samples, summed loss, steps."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.t, self.samples, self.loss, self.n = 0.0, 0, 0.0, 0

    def add(self, seconds: float, samples: int, loss: float) -> None:
        self.t += seconds
        self.samples += samples
        self.loss += loss
        self.n += 1

    def pop(self) -> dict:
        """``{"t", "samples", "loss", "n"}`` (what ``report.emit_step`` reads), then start again from zero."""
        out = {"t": self.t, "samples": self.samples, "loss": self.loss, "n": self.n}
        self.reset()
        return out
