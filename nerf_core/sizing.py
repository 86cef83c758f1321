"""``--size auto``: pick a model size from the capture geometry and a cheap probe of image content.

Two questions decide the size:
1. *How fine can detail be?* A pixel seen from ``cam_dist`` covers about ``cam_dist / fx`` scene units,
   so a grid finer than ``extent / footprint`` cells (or encoding frequencies above that Nyquist
   limit) cannot be supervised by these images and only adds cost and floaters.
2. *How much detail is there?* The high-frequency energy of the images (what a 3x3 box blur removes,
   relative to the image's own variance) separates flat-coloured objects, whose only detail is their
   silhouette, from textured ones. It scales feature ranks / widths between a small and a full model.

Empty space is not a sizing concern: the occupancy grid of the grid methods skips it at run time.
"""
from __future__ import annotations

import math
from typing import Tuple

import torch
import torch.nn.functional as F

Tensor = torch.Tensor

# Detail score at which the full-size model is used: about a third of the object's interior pixels
# carrying texture. A flat-shaded cube scores a few percent (its face edges only).
_FULL_DETAIL = 0.3


def detail_score(images: Tensor, max_images: int = 8, threshold: float = 0.01) -> float:
    """Fraction of object-interior pixels with high-frequency content, for (n, h, w, 3) images in [0, 1].

    Residual = grey level minus its 3x3 box blur. Only pixels that differ from the background (the
    median of the image border) by more than 0.02, and that stay so after a 2-pixel erosion, count,
    so silhouettes against the background do not pass for texture. Averaged over up to
    ``max_images`` evenly spaced images; 0 when no image shows any object.
    """
    if images.ndim != 4 or images.shape[-1] < 3:
        raise ValueError(f"images must be (n, h, w, 3), got {tuple(images.shape)}")
    n = images.shape[0]
    pick = torch.linspace(0, n - 1, min(n, max_images)).round().long()
    rgb = images[pick, ..., :3].float()
    gray = rgb.mean(-1, keepdim=True).permute(0, 3, 1, 2)  # (k, 1, h, w)
    blur = F.avg_pool2d(F.pad(gray, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    resid = (gray - blur).abs()
    border = torch.cat([rgb[:, 0], rgb[:, -1], rgb[:, :, 0], rgb[:, :, -1]], dim=1)  # (k, 2h+2w, 3)
    bg = border.median(dim=1).values  # (k, 3)
    fg = ((rgb - bg[:, None, None]).abs().amax(-1) > 0.02).float().unsqueeze(1)
    interior = -F.max_pool2d(-fg, 5, stride=1, padding=2)  # erosion by 2 pixels
    n_int = interior.sum()
    if n_int < 1:
        return 0.0
    return float(((resid > threshold).float() * interior).sum() / n_int)


def auto_size(method: str, aabb: Tensor, fx: float, width: int, height: int, cam_dist: float,
              images: Tensor | int | None) -> Tuple[dict, list[str]]:
    """Choose build options for ``method``.

    Args:
        method: method name ("vmgrid", "nerf", "nerf-nope"; others get no options).
        aabb: (2, 3) scene box. fx: focal length in pixels. width, height: image size in pixels.
        cam_dist: typical camera distance to the box centre (scene units).
        images: (n, h, w, 3) float images in [0, 1] for the content probe. An int (image count) or None
            skips the probe and assumes full detail (a reason says so).

    Returns:
        (options for ``build_model``, human-readable reasons, one per decision).
    """
    aabb = torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3)
    extent = float((aabb[1] - aabb[0]).max())
    if not (fx > 0 and cam_dist > 0 and extent > 0):
        raise ValueError(f"auto_size needs fx > 0, cam_dist > 0 and a non-empty aabb (fx={fx}, cam_dist={cam_dist}, extent={extent})")
    footprint = cam_dist / fx
    nyquist = extent / footprint  # cells per axis that one pixel per cell would resolve
    reasons = [f"a pixel covers ~{footprint:.4g} scene units at distance {cam_dist:.3g} (fx {fx:.1f} px); "
               f"the box spans {extent:.3g} units = {nyquist:.0f} pixel footprints"]
    if torch.is_tensor(images) and images.ndim == 4 and images.shape[0] > 0:
        score = detail_score(images)
        s = min(1.0, score / _FULL_DETAIL)
        reasons.append(f"image detail score {score:.3f} (high-frequency energy / variance; full model at "
                       f"{_FULL_DETAIL}): using {100 * s:.0f}% of the full feature budget")
    else:
        s = 1.0
        reasons.append("no images given for the content probe: assuming full detail")

    if method == "vmgrid":
        res_final = int(max(32, min(320, round(nyquist * (0.5 + 0.5 * s) / 8) * 8)))
        res_init = int(max(16, min(48, res_final // 3)))
        app_rank = int(max(8, min(48, round((8 + 40 * s) / 4) * 4)))
        density_rank = 8 if s < 0.35 else 16
        opts = dict(res_final=res_final, res_init=res_init, app_rank=app_rank, density_rank=density_rank)
        reasons.append(f"grid grows {res_init} -> {res_final} cells per axis (no finer than the pixel footprint"
                       + (", halved towards flat content" if s < 1 else "") + ")")
        reasons.append(f"appearance rank {app_rank}, density rank {density_rank} from the detail score")
        return opts, reasons
    if method in ("nerf", "nerf-nope"):
        # Highest frequency 2^(L-1) pi on [-1, 1]: period 2^(2-L) of the box half-size; stop at ~2 cells.
        pos_freqs = int(max(4, min(12, math.ceil(math.log2(max(2.0, nyquist * (0.5 + 0.5 * s)))))))
        width = 64 if s < 0.35 else 128
        opts = dict(width=width)
        if method == "nerf":
            opts["pos_freqs"] = pos_freqs
            reasons.append(f"{pos_freqs} positional-encoding frequencies: the finest period matches ~2 pixel footprints")
        reasons.append(f"MLP width {width} from the detail score")
        return opts, reasons
    reasons.append(f"no sizing rule for method {method!r}: using its defaults")
    return {}, reasons
