"""Rolling training back: a NaN/inf loss or gradient, or a loss far above its running average,
restores the model and optimiser of the last good in-memory snapshot and halves the learning rate
(a ``rollback`` event); after ``max_rollbacks`` of them training stops with a TrainError.
"""
from __future__ import annotations

import math
from typing import Optional

import torch

from nerf_core.engine.optim import clone_state, make_optimizer, rescale_base_lrs
from nerf_core.errors import TrainError
from nerf_core.runs.checkpoint_checks import nonfinite_weight
from nerf_core.runs.checkpoints import load_state_resizing

SNAPSHOT_EVERY = 100  # steps between snapshots (and after every change of the parameter set)


def take_snapshot(trainer) -> None:
    """Keep a copy of the trainer's model and optimiser state, step and loss average in memory.

    A weight that is NaN or inf here (a finite loss does not prove finite weights: an overflowing
    encoding buffer, an option beyond float32) stops the run with a TrainError naming it, rather than
    a snapshot to roll back to that is itself damaged and a run that ends "done" but cannot be loaded."""
    model = {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}
    bad = nonfinite_weight(model)
    if bad is not None:
        raise TrainError(f"the model's weight {bad!r} is NaN or infinite at step {trainer.step}; training cannot "
                         "continue from it. The method's options (--set) or --lr are beyond what float32 holds: "
                         "lower them and start again")
    trainer.snap = {
        "model": model,
        "opt": clone_state(trainer.opt.state_dict()),
        "step": trainer.step,
        "elapsed_at": trainer.elapsed,
        "loss_ema": trainer.loss_ema,
    }


def loss_problem(loss_value: float, loss_ema: Optional[float], steps_since_rollback: int) -> Optional[str]:
    """Why a step's loss must not be applied (NaN/inf, or a jump far above its running average), or None.

    Args:
        loss_value: the step's loss.
        loss_ema: its running average (None before the first step).
        steps_since_rollback: steps applied since the last rollback (the average needs 200 to settle).
    """
    if not math.isfinite(loss_value):
        return f"loss is {loss_value}"
    if (loss_ema is not None and steps_since_rollback > 200
            and loss_value > 10.0 * loss_ema and loss_value - loss_ema > 0.01):
        return f"loss {loss_value:.4g} jumped above 10x its running average {loss_ema:.4g}"
    return None


def gradient_problem(opt: torch.optim.Optimizer) -> Optional[str]:
    """"gradient is NaN or inf" when the optimiser's gradients are not all finite, else None."""
    params = [p for g in opt.param_groups for p in g["params"] if p.grad is not None]
    gnorm = torch.nn.utils.clip_grad_norm_(params, float("inf")) if params else torch.tensor(0.0)
    return None if torch.isfinite(gnorm) else "gradient is NaN or inf"


def roll_back(trainer, reason: str) -> None:
    """Restore the trainer's last snapshot at half the learning rate; TrainError after too many."""
    trainer.rollbacks += 1
    trainer.lr_scale *= 0.5
    if trainer.rollbacks > trainer.cfg.max_rollbacks:
        raise TrainError(
            f"training diverged: {trainer.rollbacks - 1} rollbacks did not help (last: {reason} at step "
            f"{trainer.step}); try a lower --lr than {trainer.base_lr * trainer.lr_scale * 2:.3g} or another --method"
        )
    snap = trainer.snap
    load_state_resizing(trainer.model, snap["model"])
    trainer.opt = make_optimizer(trainer.model, trainer.base_lr * trainer.lr_scale)
    try:
        trainer.opt.load_state_dict(clone_state(snap["opt"]))
    except (ValueError, KeyError):
        pass  # parameter set changed since the snapshot: fresh Adam moments
    # the state brought the old rates
    rescale_base_lrs(trainer.opt, trainer.model, trainer.base_lr * trainer.lr_scale)
    at = trainer.step
    trainer.step = snap["step"]
    trainer.loss_ema = snap["loss_ema"]
    trainer.steps_since_rollback = 0
    trainer.log.emit("rollback", step=at, reason=f"{reason}; restored step {trainer.step}",
                     lr=trainer.base_lr * trainer.lr_scale, restored_step=trainer.step, rollbacks=trainer.rollbacks)
