"""Losses, regularisers and the PSNR of an MSE: the one home of the photometric terms the trainer
optimises and of the PSNR formula every report uses."""
from __future__ import annotations

import math
from typing import Optional

import torch

Tensor = torch.Tensor


def mse(pred: Tensor, target: Tensor) -> Tensor:
    """Mean squared error over all elements of (n, 3) colours."""
    return (pred - target).square().mean()


def masked_mse(pred: Tensor, gt: Tensor, weight: Optional[Tensor]) -> Tensor:
    """Mean over rays of the per-ray squared error of (n, 3) colours, each ray weighted by ``weight``
    (n,) (a mask: 0 = ignore); plain mean when ``weight`` is None."""
    err = ((pred - gt) ** 2).mean(-1)
    if weight is None:
        return err.mean()
    return (err * weight).sum() / weight.sum().clamp_min(1.0)


def psnr_from_mse(value: float | Tensor) -> float:
    """PSNR in dB for colours in [0, 1]; inf for a perfect match."""
    v = float(value)
    return math.inf if v <= 0 else -10.0 * math.log10(v)


def total_variation_2d(planes: Tensor) -> Tensor:
    """Mean squared difference between neighbouring texels of (..., H, W) planes (smoothness prior)."""
    return (planes[..., 1:, :] - planes[..., :-1, :]).square().mean() + (planes[..., :, 1:] - planes[..., :, :-1]).square().mean()


def l1_sparsity(*tensors: Tensor) -> Tensor:
    """Sum of mean absolute values: pushes factorised density towards zero where nothing needs it."""
    return sum(t.abs().mean() for t in tensors)
