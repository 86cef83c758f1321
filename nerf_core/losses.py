"""Losses and regularisers shared by the methods (photometric terms live with the trainer)."""
from __future__ import annotations

import torch

Tensor = torch.Tensor


def mse(pred: Tensor, target: Tensor) -> Tensor:
    """Mean squared error over all elements of (n, 3) colours."""
    return (pred - target).square().mean()


def total_variation_2d(planes: Tensor) -> Tensor:
    """Mean squared difference between neighbouring texels of (..., H, W) planes (smoothness prior)."""
    return (planes[..., 1:, :] - planes[..., :-1, :]).square().mean() + (planes[..., :, 1:] - planes[..., :, :-1]).square().mean()


def l1_sparsity(*tensors: Tensor) -> Tensor:
    """Sum of mean absolute values: pushes factorised density towards zero where nothing needs it."""
    return sum(t.abs().mean() for t in tensors)
