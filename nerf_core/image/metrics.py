"""Image metrics, computed in one place for ``eval``, training's held-out evaluation and ``render``.

PSNR over [0, 1] colours; SSIM after Wang et al. 2004 as the NeRF papers use it: an 11x11 Gaussian
window with sigma 1.5, K1 = 0.01, K2 = 0.03, dynamic range 1, per RGB channel over the valid
(unpadded) region, averaged; the error heat-map that ``render`` writes beside each view with ground
truth (the Compare gallery in Blender shows it). Functions take torch tensors or numpy arrays.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
import torch
import torch.nn.functional as F

from nerf_core.utils import arguments

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _tensor(x) -> torch.Tensor:
    return x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))


_EIGHT_BIT = " (colours in [0, 1] are floats: divide 8-bit images by 255)"


def _images(func: str, pred, gt, last_dim: Optional[int] = 3) -> tuple:
    """``pred`` and ``gt`` checked at the public boundary: float, finite, the same shape (no broadcasting)."""
    a = arguments.tensor(func, "pred", pred, last_dim=last_dim, dtype_hint=_EIGHT_BIT)
    b = arguments.tensor(func, "gt", gt, last_dim=last_dim, dtype_hint=_EIGHT_BIT)
    arguments.same_shape(func, "pred", a, "gt", b)
    if not a.numel():
        raise ValueError(f"{func}: pred and gt are empty (shape {tuple(a.shape)})")
    return a, b


def _mask(func: str, mask, shape: tuple, name: str = "mask") -> Optional[torch.Tensor]:
    """A bool mask of ``shape`` (None stays None)."""
    if mask is None:
        return None
    m = arguments.tensor(func, name, mask, floating=False, finite=False)
    if tuple(m.shape) != tuple(shape):
        raise ValueError(f"{func}: {name} must have shape {tuple(shape)}, got {tuple(m.shape)}")
    return m.bool()


def mse_to_psnr(mse: float | torch.Tensor) -> float:
    """PSNR in dB for images in [0, 1]; ``inf`` for a perfect match."""
    mse = float(mse)
    return float("inf") if mse <= 0 else -10.0 * math.log10(mse)


def psnr(pred: torch.Tensor, gt: torch.Tensor, mask: Optional[torch.Tensor] = None) -> float:
    """PSNR of (..., 3) images in [0, 1], over the pixels where ``mask`` (...,) is True.

    Args:
        pred: (..., 3) rendered colours in [0, 1] (e.g. (h, w, 3)); a tensor or numpy array.
        gt: (..., 3) ground truth of the same shape.
        mask: (...,) bool, the pixels to count; None: all.

    Returns:
        PSNR in dB, -10 log10(MSE); ``inf`` for a perfect match (NaN when ``mask`` selects nothing).
    """
    pred, gt = _images("psnr", pred, gt)
    mask = _mask("psnr", mask, pred.shape[:-1])
    err = (pred.float() - gt.float()) ** 2
    if mask is not None:
        err = err[mask]
    return mse_to_psnr(err.mean())


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """(size,) normalised 1D Gaussian centred on the middle tap."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    g = torch.exp(-(x * x) / (2.0 * sigma * sigma))
    return g / g.sum()


def ssim_map(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM (3, h - 10, w - 10) of two (h, w, 3) images in [0, 1]."""
    pred, gt = _tensor(pred), _tensor(gt)
    if pred.shape != gt.shape or pred.dim() != 3:
        raise ValueError(f"ssim needs two (h, w, c) images of one shape, got {tuple(pred.shape)} and {tuple(gt.shape)}")
    if min(pred.shape[:2]) < SSIM_WINDOW:
        raise ValueError(
            f"ssim needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {pred.shape[1]}x{pred.shape[0]}"
        )
    x = pred.double().permute(2, 0, 1)[None]  # (1, c, h, w); float64 so E[x^2]-E[x]^2 does not cancel badly
    y = gt.double().permute(2, 0, 1)[None]
    c = x.shape[1]
    g = gaussian_window()
    kx = g.view(1, 1, 1, -1).repeat(c, 1, 1, 1)
    ky = g.view(1, 1, -1, 1).repeat(c, 1, 1, 1)

    def blur(t):
        return F.conv2d(F.conv2d(t, kx, groups=c), ky, groups=c)

    mu_x, mu_y = blur(x), blur(y)
    sxx = blur(x * x) - mu_x * mu_x
    syy = blur(y * y) - mu_y * mu_y
    sxy = blur(x * y) - mu_x * mu_y
    c1, c2 = SSIM_K1 ** 2, SSIM_K2 ** 2
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (sxx + syy + c2)
    return (num / den)[0]


def ssim(pred: torch.Tensor, gt: torch.Tensor) -> float:
    """Mean SSIM of two (h, w, 3) images in [0, 1].

    Wang et al. 2004 as the NeRF papers use it: 11 x 11 Gaussian window, sigma 1.5, over the valid
    (unpadded) region, per channel, averaged.

    Args:
        pred: (h, w, 3) rendered colours in [0, 1]; a tensor or numpy array.
        gt: (h, w, 3) ground truth of the same shape.

    Returns:
        The mean SSIM, at most 1.

    Raises:
        ValueError: images of different shapes, not (h, w, c), or smaller than 11 x 11 pixels.
    """
    pred, gt = _images("ssim", pred, gt, last_dim=None)
    return float(ssim_map(pred, gt).mean())


def _depth_pixels(name: str, pred_z, gt_z, gt_alpha, mask) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The depth metrics' one rule for which pixels count: ground truth there (finite, > 0), a finite
    prediction, ground-truth alpha > 0.5 and ``mask``. Returns (pred_z, gt_z, valid (h, w) bool), the
    inputs checked with ``name`` in their errors."""
    pred_z = arguments.tensor(name, "pred_z", pred_z, ndim=2, finite=False)
    gt_z = arguments.tensor(name, "gt_z", gt_z, ndim=2, finite=False)  # non-finite: no ground truth there
    arguments.same_shape(name, "pred_z", pred_z, "gt_z", gt_z)
    if gt_alpha is not None:
        gt_alpha = arguments.tensor(name, "gt_alpha", gt_alpha)
        arguments.same_shape(name, "gt_alpha", gt_alpha, "gt_z", gt_z)
    mask = _mask(name, mask, gt_z.shape)
    valid = torch.isfinite(gt_z) & (gt_z > 0) & torch.isfinite(pred_z)
    if gt_alpha is not None:
        valid &= gt_alpha > 0.5
    if mask is not None:
        valid &= mask.bool()
    return pred_z, gt_z, valid


def depth_mae(pred_z: torch.Tensor, gt_z: torch.Tensor, gt_alpha: Optional[torch.Tensor] = None,
              mask: Optional[torch.Tensor] = None) -> Optional[float]:
    """Mean absolute error of planar depths (h, w) over pixels with ground truth (finite, > 0), a
    finite prediction, ground-truth alpha > 0.5 and ``mask``; None when no pixel qualifies.

    Args:
        pred_z: (h, w) rendered planar z-depth (``render_view``'s ``z_depth``), in scene units.
        gt_z: (h, w) ground-truth planar depth; 0, negative or non-finite where unknown.
        gt_alpha: (h, w) ground-truth alpha in [0, 1], or None.
        mask: (h, w) bool, the pixels to count, or None.

    Returns:
        The mean absolute difference in scene units, or None.
    """
    pred_z, gt_z, valid = _depth_pixels("depth_mae", pred_z, gt_z, gt_alpha, mask)
    if not bool(valid.any()):
        return None
    return float((pred_z[valid] - gt_z[valid]).abs().mean())


def depth_rel(pred_z: torch.Tensor, gt_z: torch.Tensor, gt_alpha: Optional[torch.Tensor] = None,
              mask: Optional[torch.Tensor] = None) -> Optional[float]:
    """Mean relative error of planar depths, ``|pred - gt| / gt`` (depth benchmarks' AbsRel), over the
    pixels ``depth_mae`` counts; None when no pixel qualifies. Unlike ``depth_mae`` it does not grow
    with the scene's scale or the camera's distance, so scenes can be compared.

    Args: as ``depth_mae``. Returns: a share (0.01 = 1 % of the true depth), or None.
    """
    pred_z, gt_z, valid = _depth_pixels("depth_rel", pred_z, gt_z, gt_alpha, mask)
    if not bool(valid.any()):
        return None
    return float(((pred_z[valid] - gt_z[valid]).abs() / gt_z[valid]).mean())


def composite(image, background=(1.0, 1.0, 1.0)):
    """(h, w, 3|4) -> (h, w, 3): straight-alpha RGBA over ``background`` (3,); RGB is returned as it is.

    The compositing that ground truth gets before any metric (``data.Split.image``); numpy in, numpy out.
    """
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise ValueError(f"expected an (h, w, 3) or (h, w, 4) image, got shape {tuple(image.shape)}")
    if image.shape[-1] == 3:
        return image
    rgb, alpha = image[..., :3], image[..., 3:4]
    if isinstance(image, torch.Tensor):
        bg = torch.as_tensor(background, dtype=rgb.dtype, device=rgb.device)
    else:
        bg = np.asarray(background, dtype=rgb.dtype)
    return rgb * alpha + bg[:3] * (1.0 - alpha)


HEATMAP_VMAX = 0.25  # mean absolute error drawn at full brightness; fixed so that views are comparable
# A perceptually ordered dark-to-bright map (stops sampled from matplotlib's "inferno"), so that
# larger errors read as brighter in any viewer, including for colour-blind users.
INFERNO = np.array([
    [0.001, 0.000, 0.014], [0.133, 0.047, 0.329], [0.341, 0.062, 0.429], [0.550, 0.161, 0.506],
    [0.735, 0.216, 0.330], [0.894, 0.366, 0.176], [0.978, 0.557, 0.035], [0.973, 0.804, 0.188],
    [0.988, 0.998, 0.645],
], dtype=np.float32)


def error_heatmap(pred, gt, vmax: float = HEATMAP_VMAX) -> np.ndarray:
    """(h, w, 3) float32 colour image of the per-pixel mean absolute error of two (h, w, 3) images,
    ``vmax`` and above at full scale (a fixed scale keeps heat-maps of different views comparable)."""
    a = np.asarray(pred.detach().cpu() if isinstance(pred, torch.Tensor) else pred, dtype=np.float64)
    b = np.asarray(gt.detach().cpu() if isinstance(gt, torch.Tensor) else gt, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape} vs {b.shape}")
    err = np.mean(np.abs(a - b), axis=-1) if a.ndim == 3 else np.abs(a - b)
    t = np.clip(err / vmax, 0.0, 1.0) * (len(INFERNO) - 1)
    lo = np.floor(t).astype(np.int64)
    hi = np.minimum(lo + 1, len(INFERNO) - 1)
    frac = (t - lo)[..., None].astype(np.float32)
    return INFERNO[lo] * (1.0 - frac) + INFERNO[hi] * frac
