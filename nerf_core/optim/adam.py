"""``Adam``: the default optimiser, torch's Adam with the betas the grid methods train with, fused
where every parameter allows it."""
from __future__ import annotations

from typing import Sequence

import torch

from nerf_core.optim.base import TrainingOptimizer

BETAS = (0.9, 0.99)  # instant-ngp's and TensoRF's: a shorter second-moment memory than Adam's 0.999


def fused_adam_kwargs(groups: Sequence[dict]) -> dict:
    """``fused=True`` where every parameter allows it (float tensors on the CPU or CUDA): one kernel per
    step instead of a chain of elementwise ops per tensor, measured 17x faster on a 1.5 M-parameter
    texture on a 2-core CPU (3.5 ms against 59 ms a step)."""
    params = [p for g in groups for p in g["params"]]
    ok = params and all(p.dtype in (torch.float32, torch.float64, torch.float16, torch.bfloat16)
                        and p.device.type in ("cpu", "cuda") for p in params)
    return {"fused": True} if ok else {}


class Adam(TrainingOptimizer, torch.optim.Adam):
    """torch's Adam over ``groups`` (each a dict with ``params`` and ``lr``), betas ``BETAS``.

    Args:
        groups: the parameter groups (``RadianceModel.optimizer_groups``).
        eps: Adam's epsilon (``RadianceModel.adam_eps``).
    """

    def __init__(self, groups: Sequence[dict], eps: float):
        super().__init__(list(groups), betas=BETAS, eps=eps, **fused_adam_kwargs(groups))
