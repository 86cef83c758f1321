"""The optimiser's life in a run and the learning-rate schedule of training.

The method chooses its optimiser (``RadianceModel.make_optimizer``, Adam by default: ``nerf_core.optim``)
over its parameter groups, each group with its own ``base_lr``; every step the trainer sets
``lr = base_lr * schedule_factor(...)``: a short linear warm-up, then exponential decay to a tenth at
the end of the training budget.
"""
from __future__ import annotations

from typing import Optional

import torch

from nerf_core.optim import TrainingOptimizer

WARMUP_MAX_FRACTION = 0.02  # warm-up never takes more than this share of the budget


def make_optimizer(model, lr: float) -> TrainingOptimizer:
    """The method's optimiser (``model.make_optimizer(lr)``); each group remembers its rate as
    ``base_lr``, which the schedule scales. Raises TypeError when the method returns something that is
    not a ``nerf_core.optim.TrainingOptimizer`` (the trainer relies on its state check)."""
    opt = model.make_optimizer(lr)
    if not isinstance(opt, TrainingOptimizer):
        raise TypeError(f"method {model.method_name!r}: make_optimizer must return a nerf_core.optim."
                        f"TrainingOptimizer, got a {type(opt).__name__}")
    for g in opt.param_groups:
        g["base_lr"] = g["lr"]  # the schedule scales each group's own base rate
    return opt


def rebuild_optimizer(model, old: TrainingOptimizer, lr: float) -> TrainingOptimizer:
    """A new optimiser for the model's current parameters (after growth); the new optimiser decides
    what of ``old``'s state it keeps (``TrainingOptimizer.carry_state_from``: unchanged parameters keep
    their moments, grown ones start afresh)."""
    new = make_optimizer(model, lr)
    new.carry_state_from(old)
    return new


def clone_state(obj):
    """Deep copy of an optimiser or model state (a rollback snapshot): tensors cloned, dicts and lists
    rebuilt, everything else shared."""
    if torch.is_tensor(obj):
        return obj.detach().clone()
    if isinstance(obj, dict):
        return {k: clone_state(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [clone_state(v) for v in obj]
    return obj


def rescale_base_lrs(opt: torch.optim.Optimizer, model, lr: float) -> None:
    """Set every group's ``base_lr`` to what ``model.optimizer_groups(lr)`` gives it (after loading an
    optimiser state, which brings back the rates it was saved with)."""
    groups = model.optimizer_groups(lr)
    for g, fresh in zip(opt.param_groups, groups):
        g["base_lr"] = fresh["lr"]


def warmup_steps(model, max_steps: Optional[int]) -> int:
    """Warm-up length: the method's ``warmup_steps``, else 5 % of the step budget, at most 100 steps."""
    return int(model.warmup_steps or min(100, (max_steps or 2000) // 20))


def schedule_factor(step: int, frac: float, warmup_steps: int, final_ratio: float = 0.1) -> float:
    """Learning-rate multiplier: linear warm-up over ``warmup_steps`` (cut short once 2 % of the budget
    is spent, so that slow steps under a time budget do not spend the run warming up), then
    exponential decay to ``final_ratio`` at the end of the budget (``frac`` in [0, 1])."""
    warm = 1.0
    if warmup_steps > 0:
        warm = min(1.0, max((step + 1) / warmup_steps, frac / WARMUP_MAX_FRACTION))
    return warm * final_ratio ** frac
