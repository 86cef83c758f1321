"""Scoring a rendered view against its ground truth: the one comparison behind ``eval``, training's
held-out evaluation and ``render`` (renders.json).
"""
from __future__ import annotations

from typing import Optional

import torch

from nerf_core.image.metrics import depth_mae, depth_rel, psnr, ssim


def score_view(rgb: torch.Tensor, split, view: int, background, z_depth: Optional[torch.Tensor] = None):
    """Metrics of one rendered view against view ``view`` of a ``data.Split``: the one comparison
    behind ``eval``, training's held-out evaluation and ``render`` (renders.json).

    ``rgb`` (h, w, 3) is the render composited onto ``background`` (3,); the ground truth is
    composited onto the same colour (``Split.image``). PSNR counts only the split's mask pixels.
    Returns ({"psnr", "ssim"[, "depth_mae", "depth_rel"]}, ground truth (h, w, 3)); the depth errors
    (scene units, and relative to the true depth) when ``z_depth`` (h, w) is given and the split has depth.
    """
    gt, alpha = split.image(view, background)
    mask = split.masks[view] if split.masks is not None else None
    scores = {"psnr": psnr(rgb, gt, mask), "ssim": ssim(rgb, gt)}
    if z_depth is not None and split.depth is not None:
        gt_alpha = alpha if split.has_alpha else None
        scores["depth_mae"] = depth_mae(z_depth, split.depth[view], gt_alpha, mask)
        scores["depth_rel"] = depth_rel(z_depth, split.depth[view], gt_alpha, mask)
    return scores, gt
