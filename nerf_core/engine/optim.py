"""The optimiser and the learning-rate schedule of training.

Adam over the model's parameter groups (``RadianceModel.optimizer_groups``), each group with its own
``base_lr``; every step the trainer sets ``lr = base_lr * schedule_factor(...)``: a short linear
warm-up, then exponential decay to a tenth at the end of the training budget.
"""
from __future__ import annotations

from typing import Optional

import torch

WARMUP_MAX_FRACTION = 0.02  # warm-up never takes more than this share of the budget


def make_optimizer(model, lr: float) -> torch.optim.Optimizer:
    """Adam over ``model.optimizer_groups(lr)``; each group remembers its rate as ``base_lr``."""
    groups = model.optimizer_groups(lr)
    for g in groups:
        g["base_lr"] = g["lr"]  # the schedule scales each group's own base rate
    return torch.optim.Adam(groups, betas=(0.9, 0.99), eps=model.adam_eps, **fused_adam_kwargs(groups))


def fused_adam_kwargs(groups) -> dict:
    """``fused=True`` where every parameter allows it (float tensors on the CPU or CUDA): one kernel per
    step instead of a chain of elementwise ops per tensor, measured 17x faster on a 1.5 M-parameter
    texture on a 2-core CPU (3.5 ms against 59 ms a step)."""
    params = [p for g in groups for p in g["params"]]
    ok = params and all(p.dtype in (torch.float32, torch.float64, torch.float16, torch.bfloat16)
                        and p.device.type in ("cpu", "cuda") for p in params)
    return {"fused": True} if ok else {}


def rebuild_optimizer(model, old: torch.optim.Optimizer, lr: float) -> torch.optim.Optimizer:
    """A new optimiser for the model's current parameters; Adam moments are carried over for
    parameters that are unchanged (same object and shape), grown tensors start fresh."""
    new = make_optimizer(model, lr)
    for g in new.param_groups:
        for p in g["params"]:
            st = old.state.get(p)
            if st and all((not torch.is_tensor(v)) or v.dim() == 0 or v.shape == p.shape for v in st.values()):
                new.state[p] = st
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
