"""Rolling training back: a NaN/inf loss or gradient, or a loss far above its running average,
restores the model and optimiser of the last good in-memory snapshot and halves the learning rate
(a ``rollback`` event); after ``max_rollbacks`` of them training stops with a TrainError.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Optional

import torch

from nerf_core.engine.optim import clone_state, make_optimizer, rescale_base_lrs
from nerf_core.engine.state import TrainState
from nerf_core.errors import TrainError
from nerf_core.runs.checkpoint_checks import nonfinite_weight
from nerf_core.runs.weights import load_state_resizing

SNAPSHOT_EVERY = 100  # steps between snapshots (and after every change of the parameter set)


@dataclass(frozen=True)
class Snapshot:
    """The last good in-memory state a rollback restores: model and optimiser state, step, training
    time and loss average then."""

    model: Dict[str, torch.Tensor]
    opt: dict
    step: int
    elapsed_at: float
    loss_ema: Optional[float]


def take_snapshot(model, opt: torch.optim.Optimizer, state: TrainState) -> Snapshot:
    """A copy of the model's and optimiser's state, and of the counters a rollback rewinds.

    A weight that is NaN or inf here (a finite loss does not prove finite weights: an overflowing
    encoding buffer, an option beyond float32) stops the run with a TrainError naming it, rather than
    a snapshot to roll back to that is itself damaged and a run that ends "done" but cannot be loaded."""
    weights = {k: v.detach().clone() for k, v in model.state_dict().items()}
    bad = nonfinite_weight(weights)
    if bad is not None:
        raise TrainError(f"the model's weight {bad!r} is NaN or infinite at step {state.step}; training cannot "
                         "continue from it. The method's options (--set) or --lr are beyond what float32 holds: "
                         "lower them and start again")
    return Snapshot(model=weights, opt=clone_state(opt.state_dict()), step=state.step, elapsed_at=state.elapsed,
                    loss_ema=state.loss_ema)


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


def roll_back(model, snap: Snapshot, state: TrainState, base_lr: float, max_rollbacks: int, reason: str,
              log) -> torch.optim.Optimizer:
    """Restore ``snap`` at half the learning rate: rewinds ``state`` (step, loss average, lr_scale,
    rollbacks), emits a ``rollback`` event on ``log`` and returns the new optimiser; TrainError after
    ``max_rollbacks``."""
    state.rollbacks += 1
    state.lr_scale *= 0.5
    if state.rollbacks > max_rollbacks:
        raise TrainError(
            f"training diverged: {state.rollbacks - 1} rollbacks did not help (last: {reason} at step "
            f"{state.step}); try a lower --lr than {base_lr * state.lr_scale * 2:.3g} or another --method"
        )
    load_state_resizing(model, snap.model)
    opt = make_optimizer(model, base_lr * state.lr_scale)
    try:
        opt.load_state_dict(clone_state(snap.opt))
    except (ValueError, KeyError):
        pass  # parameter set changed since the snapshot: fresh Adam moments
    # the state brought the old rates
    rescale_base_lrs(opt, model, base_lr * state.lr_scale)
    at = state.step
    state.step = snap.step
    state.loss_ema = snap.loss_ema
    state.steps_since_rollback = 0
    log.emit("rollback", step=at, reason=f"{reason}; restored step {state.step}",
             lr=base_lr * state.lr_scale, restored_step=state.step, rollbacks=state.rollbacks)
    return opt
