"""``--size auto``: pick a model size from the capture geometry and two cheap probes of the images.

Three questions decide the size:
1. *How fine can detail be?* A pixel seen from distance ``d`` covers about ``d / fx`` scene units.
   The finest footprint anywhere in the box is the one at the box's nearest point to the cameras,
   so a grid finer than ``extent / footprint`` cells (or encoding frequencies above that Nyquist
   limit) cannot be supervised by these images and only adds cost and floaters.
2. *How much texture is there?* The high-frequency energy of the images (what a 3x3 box blur
   removes) inside the objects' silhouettes separates flat-coloured objects, whose only detail is
   their outline, from textured ones. It scales the appearance rank (VM grids) or MLP width.
3. *How fine is the texture?* The share of the images' detail at the pixel scale rather than one
   octave coarser (a Laplacian pyramid) scales the grid between half and all of question 1's limit.

Calibration (``docs/benchmarks/full``, 100 px captures, 5 minutes of one CPU core): on the
fine-checker scene an appearance rank of 16 at 72 cells scored as well as rank 32 or 48 and within
0.2 dB of the 160-cell default, so a full texture budget is rank 16, not more: a bigger model makes
fewer steps in the same time. A density rank above 8 bought nothing even on thin rods (see
``VMGrid.size_options``). Empty space is not a sizing concern: the occupancy grid skips it at run time.
Known blind spot: geometric detail at the pixel scale on untextured objects (several small objects
seen from afar) reads as coarse, so such scenes get a grid a step too coarse (0.4 dB on ``multi``).
"""
from __future__ import annotations

from typing import Optional, Tuple

import torch
import torch.nn.functional as F

from nerf_core.contract.naming import evenly_spaced
from nerf_core.methods.registry import method_class

Tensor = torch.Tensor

# Detail score at which the full texture budget is used: about a third of the object's interior
# pixels carrying texture. A flat-shaded cube scores a few percent (its face edges only).
_FULL_DETAIL = 0.3
# Share of the detail at the pixel scale (``fine_detail_share``) below which a grid at half the
# footprint resolution suffices, and above which it needs the full footprint resolution. Calibrated
# on 100 px captures: the fine checker (share 0.65) kept gaining up to 72 cells (30.9 dB at 48,
# 31.4 at 72); the glossy scene (0.36) lost from 48 cells up (37.6 dB at 48, 36.8 at 72).
_COARSE_SHARE, _FINE_SHARE = 0.3, 0.6


def _foreground(rgb: Tensor, alpha: Optional[Tensor]) -> Tensor:
    """(k, 1, h, w) float mask of object pixels for (k, h, w, 3) images and optional (k, h, w) alpha.

    With alpha, the object is alpha > 0.5. Without, it is whatever differs from the background (the
    median of the image border) by more than 0.02 in some channel.
    """
    if alpha is not None:
        return (alpha > 0.5).float().unsqueeze(1)
    border = torch.cat([rgb[:, 0], rgb[:, -1], rgb[:, :, 0], rgb[:, :, -1]], dim=1)  # (k, 2h+2w, 3)
    bg = border.median(dim=1).values  # (k, 3)
    return ((rgb - bg[:, None, None]).abs().amax(-1) > 0.02).float().unsqueeze(1)


def _probe_views(images: Tensor, alphas: Optional[Tensor], max_images: int) -> Tuple[Tensor, Tensor]:
    """Grey levels (k, 1, h, w) and object masks (k, 1, h, w) of up to ``max_images`` evenly spaced views."""
    if images.ndim != 4 or images.shape[-1] < 3:
        raise ValueError(f"images must be (n, h, w, 3), got {tuple(images.shape)}")
    n = images.shape[0]
    pick = torch.tensor(evenly_spaced(n, max_images), dtype=torch.long)
    rgb = images[pick, ..., :3].float()
    gray = rgb.mean(-1, keepdim=True).permute(0, 3, 1, 2)
    return gray, _foreground(rgb, None if alphas is None else alphas[pick].float())


def _interior(mask: Tensor) -> Tensor:
    """Erosion by 2 pixels: object pixels whose 5x5 neighbourhood is all object (no silhouette edge)."""
    return -F.max_pool2d(-mask, 5, stride=1, padding=2)


def detail_score(images: Tensor, max_images: int = 8, threshold: float = 0.01,
                 alphas: Optional[Tensor] = None) -> float:
    """Fraction of object-interior pixels with high-frequency content, for (n, h, w, 3) images in [0, 1].

    Residual = grey level minus its 3x3 box blur. Only object pixels (see ``_foreground``) that stay
    so after a 2-pixel erosion count, so silhouettes against the background do not pass for texture.
    Averaged over up to ``max_images`` evenly spaced images; 0 when no image shows any object.
    ``alphas``: optional (n, h, w) opacity in [0, 1], a better object mask than the background test.
    """
    gray, fg = _probe_views(images, alphas, max_images)
    blur = F.avg_pool2d(F.pad(gray, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    resid = (gray - blur).abs()
    interior = _interior(fg)
    n_int = interior.sum()
    if n_int < 1:
        return 0.0
    return float(((resid > threshold).float() * interior).sum() / n_int)


def fine_detail_share(images: Tensor, max_images: int = 8, alphas: Optional[Tensor] = None) -> float:
    """How much of the texture sits at the pixel scale rather than one octave coarser, in [0, 1].

    Two Laplacian-pyramid levels of the grey image: L0 = image - upsampled 2x2 average (detail of
    1-2 pixels) and L1, the same one level down (2-4 pixels). Returns mean |L0| / (mean |L0| + mean
    |L1|) over object-interior pixels: ~0.65 for a checker finer than the pixels, ~0.4 for texture
    spots several pixels wide, 0.36 for smooth glossy shading, 0 without texture (flat colours), and
    1 for objects too thin to have an interior two levels down (rods, wires).
    A grid only needs the pixel footprint's resolution where the detail is at the pixel scale.
    """
    gray, fg = _probe_views(images, alphas, max_images)
    h, w = gray.shape[-2:]
    gray, fg = gray[..., : h // 4 * 4, : w // 4 * 4], fg[..., : h // 4 * 4, : w // 4 * 4]
    energy = []
    for _ in range(2):
        down = F.avg_pool2d(gray, 2)
        lap = (gray - F.interpolate(down, scale_factor=2.0, mode="bilinear", align_corners=False)).abs()
        inner = _interior(fg)
        if inner.sum() < 1:
            # Objects without an interior at this scale are structures a few pixels wide: their
            # geometry is at the pixel scale (thin rods, wires). No objects at all: nothing to resolve.
            return 1.0 if fg.sum() > 0 else 0.0
        energy.append(float((lap * inner).sum() / inner.sum()))
        gray, fg = down, (F.avg_pool2d(fg, 2) > 0.99).float()
    total = energy[0] + energy[1]
    return energy[0] / total if total > 1e-4 else 0.0


def auto_size(method: str, aabb: Tensor, fx: float, width: int, height: int, cam_dist: float,
              images: Tensor | int | None, alphas: Optional[Tensor] = None) -> Tuple[dict, list[str]]:
    """Choose build options for ``method``.

    The three questions of the module docstring are answered here, for every method alike; turning
    the answers into options is the method's own ``size_options`` (``RadianceModel.size_options``).

    Args:
        method: a registered method name (unknown names, and methods without a rule, get no options).
        aabb: (2, 3) scene box. fx: focal length in pixels. width, height: image size in pixels.
        cam_dist: typical distance from a camera to the *nearest point of the box* (scene units):
            where the images resolve the finest detail (see ``nearest_box_distance``).
        images: (n, h, w, 3) float images in [0, 1] for the content probe. An int (image count) or None
            skips the probe and assumes full detail (a reason says so).
        alphas: optional (n, h, w) opacity of ``images``: the object mask of the probe.

    Returns:
        (options for ``build_model``, human-readable reasons, one per decision).
    """
    aabb = torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3)
    extent = float((aabb[1] - aabb[0]).max())
    if not (fx > 0 and cam_dist > 0 and extent > 0):
        raise ValueError(
            f"auto_size needs fx > 0, cam_dist > 0 and a non-empty aabb (fx={fx}, cam_dist={cam_dist}, extent={extent})"
        )
    footprint = cam_dist / fx
    nyquist = extent / footprint  # cells per axis that one pixel per cell would resolve
    reasons = [f"a pixel covers ~{footprint:.4g} scene units at the box's nearest point ({cam_dist:.3g} units "
               f"from the cameras, fx {fx:.1f} px); the box spans {extent:.3g} units = {nyquist:.0f} pixel footprints"]
    if torch.is_tensor(images) and images.ndim == 4 and images.shape[0] > 0:
        score = detail_score(images, alphas=alphas)
        s = min(1.0, score / _FULL_DETAIL)
        reasons.append(f"texture amount: image detail score {score:.3f} (share of object pixels with "
                       f"high-frequency content; full budget at {_FULL_DETAIL}): {100 * s:.0f}% of the full rank")
        share = fine_detail_share(images, alphas=alphas)
        f = min(1.0, max(0.0, (share - _COARSE_SHARE) / (_FINE_SHARE - _COARSE_SHARE)))
        reasons.append(f"texture scale: {100 * share:.0f}% of the detail at the pixel scale (coarse at "
                       f"{100 * _COARSE_SHARE:.0f}%, pixel-fine at {100 * _FINE_SHARE:.0f}%)")
    else:
        s = f = 1.0
        reasons.append("no images given for the content probes: assuming full, pixel-fine texture")
    # Cells per axis: the footprint's resolution for pixel-fine texture, half of it for coarse or none.
    fine_res = nyquist * (0.5 + 0.5 * f)

    cls = method_class(method)
    if cls is None:
        reasons.append(f"no sizing rule for method {method!r}: using its defaults")
        return {}, reasons
    opts, why = cls.size_options(fine_res, s, f)
    return dict(opts), reasons + list(why)


def auto_size_dataset(method: str, dataset, background=(1.0, 1.0, 1.0)) -> Tuple[dict, list[str]]:
    """``auto_size`` for the train split of a loaded ``data.Dataset``.

    The probes look at a few images only: they get 8 evenly spaced views as float, composited onto
    ``background`` (the evaluation background) with their alpha, instead of a float copy of the
    whole split.
    """
    tr = dataset.split("train")
    near = nearest_box_distance(tr.cameras.origins, dataset.aabb)
    pick = torch.linspace(0, len(tr) - 1, min(len(tr), 8)).round().long().tolist()
    views = [tr.image(v, list(background)) for v in pick]
    probe = torch.stack([rgb for rgb, _ in views])
    alphas = torch.stack([a for _, a in views]) if tr.has_alpha else None
    options, reasons = auto_size(method, dataset.aabb, float(tr.cameras.fx[0]), tr.width, tr.height, near,
                                 probe, alphas=alphas)
    return dict(options), list(reasons)


def nearest_box_distance(origins: Tensor, aabb: Tensor) -> float:
    """Median distance from camera ``origins`` (n, 3) to the nearest point of ``aabb`` (2, 3).

    A camera inside the box counts as 5% of the box's extent away, so the footprint stays finite
    (the resolution cap in ``auto_size`` then applies).
    """
    aabb = torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3)
    o = torch.as_tensor(origins, dtype=torch.float32).reshape(-1, 3)
    gap = torch.maximum(aabb[0] - o, o - aabb[1]).clamp_min(0.0)  # (n, 3), 0 along axes inside the slab
    floor = 0.05 * float((aabb[1] - aabb[0]).max())
    return float(gap.norm(dim=-1).clamp_min(floor).median())
