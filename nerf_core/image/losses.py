"""Losses and regularisers: the photometric terms the trainer optimises. (The PSNR formula lives in
``metrics``; ``psnr_from_mse`` is the trainer's name for it.)"""
from __future__ import annotations

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


def depth_loss(depth: Tensor, acc: Tensor, target: Tensor, weight: Optional[Tensor] = None) -> Tensor:
    """The depth supervision of ``train --depth``: the mean over rays with a known surface of the
    relative error of the rendered depth, |acc depth - acc target| / target, plus the transparency left
    on those rays, 1 - acc; with ``weight``, the mean over those rays weighted by the colour loss's weights.

    ``acc depth`` is the weights' sum of the sample distances, linear in the weights: the normalised
    depth alone has gradients that grow as 1 / acc, without bound on the transparent rays of a field
    at initialisation. Once a ray is opaque the term is the relative error of its expected depth.
    Relative, so that the term means the same in any scene's units (1 % too far is 0.01 whether the
    scene is a room in metres or a toy in millimetres). Rays whose target is 0 (no surface, or a
    depth edge where one pixel's depth does not describe the pixel: ``depth_targets``) do not count.

    Args:
        depth: (n,) the rendered expected distance along each unit ray (normalised by the opacity).
        acc: (n,) the rendered opacity.
        target: (n,) the true distance along each ray, 0 where it is not known.
        weight: (n,) the batch's per-ray weights (``RayBatch.weight``: a mask, times the importance
            weight of ``--ray-sampling error``), or None (uniform). The error-weighted sampler draws
            some rays more often than others; weighing each by its uniform over its drawn probability
            keeps this loss an estimate of the uniform one, as the colour loss is.
    Returns:
        () the loss, 0 when no ray has a surface (or every such ray has weight 0).
    """
    has = target > 0
    t = torch.where(has, target, torch.ones_like(target))
    err = torch.where(has, (acc * (depth - t)).abs() / t + (1.0 - acc), torch.zeros_like(depth))
    if weight is None:  # the count of rays with a surface (kept apart: bit-identical --depth runs)
        return err.sum() / has.sum().clamp_min(1)
    w = torch.where(has, weight, torch.zeros_like(weight))
    # Normalised by the weights of the rays that count, not by clamp_min(1.0) as ``masked_mse``: a
    # batch with few surface rays may weigh less than 1 in all, and the mean must not shrink with it.
    return (err * w).sum() / w.sum().clamp_min(torch.finfo(w.dtype).tiny)


def alpha_loss(acc: Tensor, alpha: Tensor, weight: Optional[Tensor]) -> Tensor:
    """The opacity supervision of ``train --alpha-weight``: the squared error between the rendered
    opacity and the pixel's alpha on a transparent film, averaged over rays like the colour loss
    (``masked_mse``: the same weights, the same normalisation).

    Args:
        acc: (n,) the rendered opacity (``out["acc"]``).
        alpha: (n,) the pixels' alpha in [0, 1] (``RayBatch.alpha``).
        weight: (n,) the batch's per-ray weights (``RayBatch.weight``), or None (uniform).
    Returns:
        () the loss.
    """
    return masked_mse(acc.unsqueeze(-1), alpha.unsqueeze(-1), weight)


def total_variation_2d(planes: Tensor) -> Tensor:
    """Mean squared difference between neighbouring texels of (..., H, W) planes (smoothness prior)."""
    return (planes[..., 1:, :] - planes[..., :-1, :]).square().mean() + (
        planes[..., :, 1:] - planes[..., :, :-1]
    ).square().mean()


def l1_sparsity(*tensors: Tensor) -> Tensor:
    """Sum of mean absolute values: pushes factorised density towards zero where nothing needs it."""
    return sum(t.abs().mean() for t in tensors)


def backward(loss: Tensor) -> None:
    """``loss.backward()``, or nothing when no parameter took part in the loss.

    A batch whose rays all miss the scene box (or every occupied cell) is rendered as pure background:
    its loss is a constant, and autograd would raise "element 0 of tensors does not require grad".
    Such a batch teaches nothing; the optimiser step that follows skips parameters without a gradient.
    """
    if loss.requires_grad:
        loss.backward()
