"""The trainer's periodic work, one small callback each (in the spirit of nerfstudio's
``TrainingCallback``): held-out evaluation at fixed training times, ``step`` events, previews and
checkpoints.

After every optimisation step the trainer calls each callback's ``after_step`` in the order of
``default_callbacks``. A callback reads the trainer's state (step, elapsed training time, model, log)
and may write files; it must not draw random numbers, so that a seeded run trains the same with or
without it. Only rank 0 of a ``torchrun`` job writes; the others keep the same schedule.
"""
from __future__ import annotations

import sys
import time
from typing import List, Sequence

from nerf_core.engine.report import emit_step, held_out_eval

STEP_EVENT_SECONDS = 5.0  # slow steps still produce a step event this often


class TrainingCallback:
    """Work done between optimisation steps."""

    def start(self, trainer) -> None:
        """Called once, before the first step of this process (also after ``--resume``)."""

    def end(self, trainer) -> None:
        """Called once, when the budget is spent (not on an interrupt or an error)."""

    def after_step(self, trainer, done: bool) -> bool:
        """Called after each optimisation step.

        Args:
            trainer: the ``Trainer`` (``step``, ``elapsed``, ``model``, ``log``, ``cfg``, ``dist``).
            done: the budget is spent: this is the last step (the trainer then previews, checkpoints
                and evaluates once more itself).
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
        self.marks = [t for t in self.marks if t > trainer.elapsed]

    def after_step(self, trainer, done: bool) -> bool:
        crossed = [t for t in self.marks if trainer.elapsed >= t]
        if not crossed:
            return False
        # A slow step can cross several marks; the model is the same for all of them, so it is
        # evaluated once and the event names every mark it stands for.
        del self.marks[:len(crossed)]
        if trainer.dist.is_main:
            held_out_eval(trainer.log, trainer.model, trainer.dataset, trainer.cfg, trainer.eval_bg, trainer.step,
                          trainer.elapsed, marks=crossed)
        return True

    def end(self, trainer) -> None:
        if not self.marks or not trainer.dist.is_main:
            return
        # --max-steps ran out before these times (a --max-seconds budget refuses marks beyond it)
        marks = ", ".join(f"{t:g}" for t in self.marks)
        msg = (f"--eval-at {marks}: training ended after {trainer.elapsed:.1f} s ({trainer.step} steps), before "
               f"{'this mark' if len(self.marks) == 1 else 'these marks'}: nothing was evaluated there")
        print(f"train: note: {msg}", file=sys.stderr)
        trainer.log.emit("note", message=msg)


class StepEvents(TrainingCallback):
    """A ``step`` event every ``log_every`` steps, at the first and the last step, and at least every
    ``STEP_EVENT_SECONDS`` of wall time (slow steps: big models on a CPU)."""

    def start(self, trainer) -> None:
        self.first_step = trainer.step + 1  # always report the first step (also after --resume)
        self.last_event_wall = time.monotonic()

    def after_step(self, trainer, done: bool) -> bool:
        cfg = trainer.cfg
        if (trainer.step == self.first_step or trainer.step % cfg.log_every == 0 or done
                or time.monotonic() - self.last_event_wall >= STEP_EVENT_SECONDS):
            self.last_event_wall = time.monotonic()
            emit_step(trainer.log, cfg, trainer.opt, trainer.step, trainer.elapsed, trainer.last_loss,
                      trainer.last_psnr, trainer.interval.pop())
        return False


class PreviewEvery(TrainingCallback):
    """A preview image every ``--preview-every`` steps, or every ``preview_seconds`` of training."""

    def start(self, trainer) -> None:
        self.last_step, self.last_elapsed = trainer.step, trainer.elapsed

    def after_step(self, trainer, done: bool) -> bool:
        if done or not trainer.previews.due(trainer.step, self.last_step, trainer.elapsed, self.last_elapsed):
            return False
        trainer.preview()
        self.last_step, self.last_elapsed = trainer.step, trainer.elapsed
        return True


class CheckpointEvery(TrainingCallback):
    """A checkpoint every ``--checkpoint-every`` steps, or every ``checkpoint_seconds`` of wall time."""

    def after_step(self, trainer, done: bool) -> bool:
        if done or not trainer.checkpoint_due():
            return False
        trainer.save_checkpoint()
        return True


def default_callbacks(cfg) -> List[TrainingCallback]:
    """The trainer's callbacks for ``cfg`` (a ``TrainConfig``), in the order they run after a step."""
    return [EvalAtTimes(cfg.eval_at), StepEvents(), PreviewEvery(), CheckpointEvery()]


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
