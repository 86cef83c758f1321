"""Scene contraction (mip-NeRF 360 style) for geometry beyond the scene box: a ground plane running
to the horizon, distant buildings or hills.

The box keeps its coordinates; everything outside it is squeezed into a shell of the same
thickness around it, with infinity on the shell's outer face. In the box's normalised coordinates
``x_n = (x - centre) / half`` (the box is [-1, 1]^3) and with the max-norm ``r = |x_n|_inf``:

    squeeze(x_n) = x_n                       for r <= 1
                 = (2 - 1 / r) * x_n / r     for r > 1      (in [-2, 2]^3, -> the face at 2 as r -> inf)

The max-norm (rather than mip-NeRF 360's L2 norm) keeps the whole box, corners included, unwarped,
so a contracted model sees the box exactly as an uncontracted one would. A grid over [-2, 2]^3
spends half its cells per axis on the box and half on the rest of the world, whose detail shrinks
with distance the way a camera sees it.
"""
from __future__ import annotations

import torch

Tensor = torch.Tensor


def outer_box(aabb: Tensor) -> Tensor:
    """(2, 3) box that the contracted world fills: the scene box grown to twice its size about its centre."""
    centre, half = 0.5 * (aabb[0] + aabb[1]), 0.5 * (aabb[1] - aabb[0])
    return torch.stack([centre - 2.0 * half, centre + 2.0 * half])


def squeeze_into_outer_box(pts: Tensor, aabb: Tensor) -> Tensor:
    """World points (m, 3) -> contracted points (m, 3) inside ``outer_box(aabb)``; unchanged in the box.

    Args:
        pts: (m, 3) world points (any leading shape (..., 3) works).
        aabb: (2, 3) scene box [min corner, max corner]; the box kept as it is.

    Returns:
        (m, 3) contracted points: in the box unchanged, outside it squeezed into the shell between the
        box and ``outer_box(aabb)`` (the box grown to twice its size about its centre) by the max-norm.
    """
    centre, half = 0.5 * (aabb[0] + aabb[1]), 0.5 * (aabb[1] - aabb[0])
    offset = pts - centre
    # (2 - 1/r) / r = (2r - 1) / r^2 scales the offset, and is 1 at r = 1: clamping r to 1 leaves the box
    # as it is without a second branch (every sample of a contracted scene passes through here).
    r = (offset / half).abs().amax(dim=-1, keepdim=True).clamp_min(1.0)
    return torch.addcmul(centre, offset, (2.0 * r - 1.0) / (r * r))
