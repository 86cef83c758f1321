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
from nerf_core.runs.checkpoints import load_state_resizing

SNAPSHOT_EVERY = 100  # steps between snapshots (and after every change of the parameter set)


def take_snapshot(trainer) -> None:
    """Keep a copy of the trainer's model and optimiser state, step and loss average in memory."""
    trainer.snap = {
        "model": {k: v.detach().clone() for k, v in trainer.model.state_dict().items()},
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


def step_values(loss: torch.Tensor, mse: torch.Tensor,
                opt: torch.optim.Optimizer) -> tuple[float, float, Optional[str]]:
    """What the trainer must know after a step's backward pass, read from the device in one transfer
    (each read makes the host wait for a GPU): (loss, mse, ``gradient_problem``'s answer).

    The gradients are finite when the sum of their norms is (a NaN or inf in any of them makes it NaN
    or inf); unlike ``gradient_problem`` nothing is written back to them.
    """
    grads = [p.grad for g in opt.param_groups for p in g["params"] if p.grad is not None]
    parts = [loss.detach().float().reshape(1), mse.detach().float().reshape(1)]
    if grads:
        parts.append(torch.stack(torch._foreach_norm(grads)).sum().float().reshape(1).to(parts[0].device))
    values = torch.cat(parts).tolist()
    grad_ok = len(values) < 3 or math.isfinite(values[2])
    return values[0], values[1], None if grad_ok else "gradient is NaN or inf"


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
