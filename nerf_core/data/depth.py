"""Depth as supervision (``train --depth``): the checks a capture's depth maps must pass, and the
per-pixel targets a batcher draws.

A capture's depth files hold planar z-depth in scene units, 0 (or inf) where there is no surface
(docs/CONTRACTS.md). Training with them is refused, naming the file and the frame, when a train frame
has none, when a map holds NaN or negative values, or when its distances cannot be in the scene's
units (``check_depth``). ``depth_targets`` leaves out the pixels at a depth edge: a pixel there mixes
two surfaces in its colour, and one depth does not describe it.
"""
from __future__ import annotations

import math
from typing import Optional

import torch
import torch.nn.functional as F

from nerf_core.cameras.rays import rays_for_pixels
from nerf_core.data.split import Dataset, Split
from nerf_core.errors import DatasetError
from nerf_core.image.io import ImageReadError, read_depth
from nerf_core.image.losses import depth_loss

# ``train --depth-weight``'s default: the depth loss (a relative error, ``image.losses.depth_loss``)
# against the colour MSE. Measured in docs/BENCHMARKS.md, "Depth as supervision".
DEFAULT_DEPTH_WEIGHT = 0.002
# A pixel is at a depth edge when the depths of its 3x3 neighbourhood differ by more than this share,
# or some neighbour has no surface.
EDGE_RATIO = 1.05
# How far a median surface distance may be from the camera's distance to the scene box (plus the
# box's size) before the depth is taken to be in other units: millimetres for metres is 1000x, inches
# 39x; a close-up of a surface in a large box is far below 1x, but never 1000x below.
UNITS_RANGE = (1e-3, 10.0)


def check_depth(dataset: Dataset, split: Split) -> None:
    """Refuse depth supervision on ``split`` (the train split of ``dataset``) that cannot be right.

    Raises:
        DatasetError: naming ``--depth`` and the dataset when no frame has depth; naming the frame
            when one has none while others do, when its map holds NaN or negative values (read
            again, strictly), or when its distances are not in the scene's units.
    """
    frames = split.frames
    with_depth = [f for f in frames if f.depth is not None]
    if not with_depth or split.depth is None:
        raise DatasetError(f"--depth: {dataset.root}: no train frame has a depth map (field 'depth_file_path'); "
                           "capture with depth (scripts/capture.py --depth) or train without --depth")
    if len(with_depth) < len(frames):
        first = next(f for f in frames if f.depth is None)
        raise DatasetError(f"{first.where}: --depth: this frame has no depth map (field 'depth_file_path'), "
                           f"while {len(with_depth)} of the {len(frames)} train frames have one; every train "
                           "frame needs one, or train without --depth")
    for fr in frames:
        try:
            read_depth(fr.depth, png_scale=1.0, refuse_invalid=True)  # the sign and NaN need no scale
        except ImageReadError as exc:
            raise DatasetError(f"{fr.where}: field 'depth_file_path': {exc}") from None
    centre = dataset.aabb.mean(0).double()
    size = float((dataset.aabb[1] - dataset.aabb[0]).norm())
    for v, fr in enumerate(frames):
        z = split.depth[v]
        surface = z[z > 0]
        if surface.numel() == 0:
            continue
        median = float(surface.median())
        reach = float((split.cameras.c2w[v, :3, 3].double() - centre).norm()) + size
        ratio = median / reach
        if not UNITS_RANGE[0] <= ratio <= UNITS_RANGE[1]:
            raise DatasetError(
                f"{fr.where}: field 'depth_file_path': the median surface is {median:.4g} units from the camera, "
                f"but the camera is {reach - size:.4g} units from the scene box's centre and the box is {size:.4g} "
                "across, so the depth is not in the units the dataset says (scene units for EXR; "
                "'depth_unit_scale_factor' or 'integer_depth_scale' for 16-bit PNG and .npy maps)")


def surface_in_box(split: Split, z: torch.Tensor, box: torch.Tensor) -> torch.Tensor:
    """(v, h, w) bool: the pixels whose surface point (planar depth ``z`` (v, h, w) along the pixel's
    centre ray) lies inside ``box`` (2, 3)."""
    v, h, w = z.shape
    lo, hi = box[0].float().cpu(), box[1].float().cpu()
    out = torch.zeros(v, h, w, dtype=torch.bool)
    jj, ii = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    j, i = jj.reshape(-1), ii.reshape(-1)
    for view in range(v):
        o, d, z_per_t = rays_for_pixels(split.cameras, torch.full_like(j, view), i, j)
        pts = o + d * (z[view].reshape(-1) / z_per_t)[:, None]
        out[view] = (((pts >= lo) & (pts <= hi)).all(-1) & (z[view].reshape(-1) > 0)).reshape(h, w)
    return out


def depth_targets(split: Split, box: Optional[torch.Tensor] = None) -> torch.Tensor:
    """(v, h, w) float32 planar depths the depth loss may use: the split's depth, 0 where there is no
    surface, at depth edges (``EDGE_RATIO``) and, with ``box`` (2, 3, the run's scene box), where the
    surface lies outside it. Why the box: the loss also asks a ray to turn opaque, and a surface past the
    box is the learned world's (light from infinity) or a contracted shell's, not the grid's. On the
    ground demo scene (an unbounded floor) depth on every pixel cost 4.2 dB at 60 s at a third of the
    steps."""
    z = split.depth.float()
    x = z.unsqueeze(1)  # (v, 1, h, w)
    big = F.max_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    hole = F.max_pool2d(F.pad((x <= 0).float(), (1, 1, 1, 1), mode="replicate"), 3, stride=1) > 0
    small = -F.max_pool2d(F.pad(-torch.where(x > 0, x, torch.full_like(x, math.inf)), (1, 1, 1, 1),
                                mode="replicate"), 3, stride=1)
    edge = hole | (big > small * EDGE_RATIO)
    target = torch.where(edge, torch.zeros_like(x), x).squeeze(1)
    if box is not None:  # after the edges: a pixel beside the box's edge is no depth edge
        target = torch.where(surface_in_box(split, z, box), target, torch.zeros_like(target))
    return target


def depth_weight(weight: Optional[float]) -> float:
    """The depth loss's weight: ``--depth-weight`` when given, else ``DEFAULT_DEPTH_WEIGHT``."""
    return DEFAULT_DEPTH_WEIGHT if weight is None else float(weight)


def with_depth_term(loss: torch.Tensor, out: dict, target: Optional[torch.Tensor],
                    ray_weight: Optional[torch.Tensor], weight: Optional[float]) -> torch.Tensor:
    """A step's ``loss`` () with what ``train --depth`` adds: ``depth_weight(weight)`` times ``depth_loss``
    of the rendered ``out["depth"]`` and ``out["acc"]`` (n,) against ``target`` (n,) (``RayBatch.depth``),
    each ray weighted by ``ray_weight`` (n,) (``RayBatch.weight``: masks and the error-weighted sampler's
    importance; None = uniform). ``loss`` itself when the batch carries no depth (colours only): no
    ``+ 0`` that a colours-only step would run for nothing."""
    if target is None:
        return loss
    return loss + depth_weight(weight) * depth_loss(out["depth"], out["acc"], target, ray_weight)
