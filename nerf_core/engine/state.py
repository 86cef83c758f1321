"""The trainer's state as declared types: what changes while a run trains (``TrainState``) and what it
decides once at the start (``RunDecisions``). The helpers of the loop (rollback, the world's prefit,
the run's record) take these, not the trainer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Tuple

from nerf_core import contract


@dataclass
class TrainState:
    """What changes while a run trains. The first five fields are saved in every checkpoint
    (``checkpoint_entries``) and come back on ``--resume`` (``from_checkpoint``).

    Attributes:
        step: optimisation steps applied.
        elapsed: seconds of training (previews, checkpoints and evaluation not counted).
        lr_scale: the learning rate's factor after rollbacks (each halves it).
        rollbacks: rollbacks so far.
        loss_ema: running average of the loss (None before the first step).
        steps_since_rollback: steps applied since the last rollback (the loss check waits for 200).
        last_loss, last_psnr: the last applied step's loss and PSNR, for events and the bar.
        budget_fraction: share of the budget spent at the start of the current step, in [0, 1], or
            None without a budget; computed once per step (``update_budget``).
    """

    step: int = 0
    elapsed: float = 0.0
    lr_scale: float = 1.0
    rollbacks: int = 0
    loss_ema: Optional[float] = None
    steps_since_rollback: int = 0
    last_loss: Optional[float] = None
    last_psnr: Optional[float] = None
    budget_fraction: Optional[float] = None

    def checkpoint_entries(self) -> dict:
        """The entries a checkpoint saves."""
        return {"step": self.step, "elapsed": self.elapsed, "lr_scale": self.lr_scale, "rollbacks": self.rollbacks,
                "loss_ema": self.loss_ema}

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> "TrainState":
        """The state a checkpoint saved (entries from before ``lr_scale`` and ``rollbacks`` existed: 1, 0)."""
        return cls(step=int(ckpt["step"]), elapsed=float(ckpt["elapsed"]), lr_scale=float(ckpt.get("lr_scale", 1.0)),
                   rollbacks=int(ckpt.get("rollbacks", 0)), loss_ema=ckpt.get("loss_ema"))

    def update_budget(self, max_steps: Optional[int], max_seconds: Optional[float]) -> Tuple[Optional[float], float]:
        """Compute the share of the budget spent, once per step (``contract.budget_fraction``).

        Returns (the share or None without a budget, for the method's hook; the share or 0, for the
        schedules)."""
        self.budget_fraction = contract.budget_fraction(self.step, self.elapsed, max_steps, max_seconds)
        return self.budget_fraction, 0.0 if self.budget_fraction is None else self.budget_fraction


@dataclass(frozen=True)
class RunDecisions:
    """What the trainer decides once, at the start of a run; RUN/config.json records each.

    Attributes:
        method: the registered method trained.
        base_lr: the learning rate before the schedule (``--lr`` or the method's ``default_lr``).
        batch_rays: rays per step on this process (``--batch-rays`` or the method's default).
        warmup: learning-rate warm-up steps.
        background: what stands behind the scene while training (``data.backgrounds.for_training``).
        background_reason: why that background.
        eval_background: (3,) RGB the held-out views are scored on.
        size_reasons: one line per size decision (``--size auto``), or the checkpoint's.
    """

    method: str
    base_lr: float
    batch_rays: int
    warmup: int
    background: str
    background_reason: str
    eval_background: List[float]
    size_reasons: List[str] = field(default_factory=list)
