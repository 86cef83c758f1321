"""The scene box of a dataset that gives no ``aabb``, and the margin an interior's box needs.

``estimate_aabb`` builds a box from the cameras (and the surface points their depth maps show,
``depth_points``); ``pad_box_for_interior`` grows a box the cameras stand inside, so that walls on its
faces lie inside it, and ``pad_box_for_faces`` every other box a little, so that the floor a scene
stands on does too. ``data.load_dataset`` applies them. ``box_length_unit`` is the length that the
methods measure density against, so that a scene trains the same at any scale.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import numpy as np
import torch

from nerf_core.cameras.rays import Cameras, rays_for_pixels
from nerf_core.volume.sampling import ray_aabb_intersect

if TYPE_CHECKING:  # data imports this module; the type is only named in a signature
    from nerf_core.data.split import Split


def estimate_aabb(cameras: Cameras, far: Optional[float] = None,
                  seen: Optional[torch.Tensor] = None) -> tuple[torch.Tensor, str]:
    """A scene box from the cameras alone, for datasets that give no ``aabb``.

    Inward-facing captures: the box is centred on the point closest (least squares) to all optical
    axes, with half-size 0.5 x the median camera distance to that point (the synthetic scenes fit
    in +-1.5 with cameras at radius 4 -> +-2). Cameras that look outward or the same way (an
    interior, a street; the least squares is ill-posed or behind them): a box holding every camera
    and what they see, from ``seen`` (m, 3) surface points back-projected from depth maps when the
    dataset has them (``depth_points``), else ``far`` (or twice the camera spread) ahead of each camera.
    """
    o = cameras.origins.double().numpy()
    d = cameras.forward.double().numpy()
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = proj.sum(0)
    b = np.einsum("nij,nj->i", proj, o)
    if np.linalg.cond(A) < 1e3:
        centre = np.linalg.solve(A, b)
        in_front = np.einsum("ni,ni->n", centre[None] - o, d)
        if np.all(in_front > 0):
            radius = float(np.median(np.linalg.norm(o - centre, axis=1)))
            half = 0.5 * radius
            box = np.stack([centre - half, centre + half])
            note = (f"no 'aabb' in the dataset: estimated a box centred at {np.round(centre, 3).tolist()} "
                    f"(where the cameras look) of half-size {half:.3g} (0.5 x median camera distance)")
            return torch.tensor(box, dtype=torch.float32), note
    if seen is not None and len(seen) >= 16:
        pts = seen.double().numpy()
        # Robust extent of what the cameras see (a few stray depth pixels must not blow the box up).
        lo, hi = np.percentile(pts, 0.5, axis=0), np.percentile(pts, 99.5, axis=0)
        lo, hi = np.minimum(lo, o.min(0)), np.maximum(hi, o.max(0))
        pad = 0.05 * (hi - lo)
        box = np.stack([lo - pad, hi + pad])
        note = ("no 'aabb' in the dataset and the cameras do not look at a common centre: estimated a box holding "
                f"every camera and the {len(pts)} surface points their depth maps show")
        return torch.tensor(box, dtype=torch.float32), note
    spread = float(np.linalg.norm(o.max(0) - o.min(0))) or 1.0
    depth = float(far) if far else 2.0 * spread
    ahead = o + d * depth
    pts = np.concatenate([o, ahead])
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.05 * (hi - lo).max()
    box = np.stack([lo - pad, hi + pad])
    note = ("no 'aabb' in the dataset and the cameras do not look at a common centre: using a box spanning the "
            f"cameras and {depth:.3g} units in front of them; add 'aabb' to the transforms file for better results")
    return torch.tensor(box, dtype=torch.float32), note


def depth_points(split: "Split", max_points: int = 100_000, seed: int = 0) -> Optional[torch.Tensor]:
    """Up to ``max_points`` (m, 3) world points back-projected from a split's depth maps (planar
    z-depth; 0 or inf = no surface), or None without depth."""
    if split.depth is None or len(split) == 0:
        return None
    z = split.depth.reshape(-1)
    valid = torch.nonzero(torch.isfinite(z) & (z > 0)).squeeze(-1)
    if valid.numel() == 0:
        return None
    gen = torch.Generator().manual_seed(seed)
    pick = valid[torch.randperm(valid.numel(), generator=gen)[:max_points]]
    hw = split.height * split.width
    view, pix = pick // hw, pick % hw
    rays_o, rays_d, z_per_t = rays_for_pixels(split.cameras, view, pix % split.width, pix // split.width)
    return rays_o + rays_d * (z[pick] / z_per_t)[:, None]


def box_length_unit(aabb: torch.Tensor) -> float:
    """Scene units per unit of the box rescaled to the cube [-1, 1]^3: the box's diagonal / (2 sqrt 3).

    A method whose field yields density per this unit (sigma_scene = sigma_box / unit) trains the same
    whatever units the scene was modelled in. Measured per scene unit, density had to reach ~1e5 for
    a surface of a 3 mm object (a ring modelled in metres), where a grid's softplus is linear and its
    raw values climb by the learning rate per step: the probe's object at 0.001 x scored 18.3 dB
    against 26.7 dB at 1 x after 30 s of vmgrid (25.0 at 0.01 x). The demo scenes' boxes (diagonals
    3.2 to 4.4 units) make the unit 0.9 to 1.3, so their densities barely change.
    """
    box = torch.as_tensor(aabb, dtype=torch.float64).reshape(2, 3)
    return float((box[1] - box[0]).norm()) / (2.0 * 3.0 ** 0.5)


INSIDE_PAD = 0.05  # share of the box's extent added on each side when the cameras stand inside it


def pad_box_for_interior(aabb: torch.Tensor, origins: torch.Tensor) -> tuple[torch.Tensor, Optional[str]]:
    """Grow ``aabb`` (2, 3) by ``INSIDE_PAD`` per side when most camera ``origins`` (n, 3) are inside it.

    Cameras inside the box mean an interior: the box is the room's bounds, so its walls, floor and
    ceiling lie exactly on the box's faces, where a grid has half a cell of support and rays end. The
    surfaces the images show most then sit where the model is weakest, and the transmittance that the
    walls fail to stop leaks into the background. A margin puts them inside. Returns the box and a
    note (None when unchanged).
    """
    if origins.numel() == 0:
        return aabb, None
    inside = ((origins >= aabb[0]) & (origins <= aabb[1])).all(dim=-1)
    if float(inside.float().mean()) < 0.5:
        return aabb, None
    pad = INSIDE_PAD * (aabb[1] - aabb[0])
    note = (f"{int(inside.sum())} of {len(origins)} train cameras stand inside the scene box (an interior): "
            f"grew the box by {100 * INSIDE_PAD:.0f} % of its size on each side so that walls, floor and ceiling "
            "on its faces lie inside it")
    return torch.stack([aabb[0] - pad, aabb[1] + pad]), note


# Every other box grows by this share of its extent on each side (2 cells of the default 160-cell grid),
# because a capture's box is the union of its objects' bounds, so the floor a scene stands on lies on
# its bottom face. A grid cannot put density beyond its last node: the field's density ramped up over
# the two cells above the face, and the surface sat half a percent of the diagonal too high. On the
# multi demo capture, 5 minutes, one thread, side by side (docs/BENCHMARKS.md, "Surfaces on the box's
# faces"): mesh F-score at 0.5 % of the diagonal 0.592 -> 0.887, PSNR 38.13 -> 39.18 dB.
FACE_PAD = 0.0125


def pad_box_for_faces(aabb: torch.Tensor) -> torch.Tensor:
    """``aabb`` (2, 3) grown by ``FACE_PAD`` of its extent on each side, so that surfaces on its faces
    (a floor, a back wall) lie inside it, where the grid holds them on both sides."""
    pad = FACE_PAD * (aabb[1] - aabb[0])
    return torch.stack([aabb[0] - pad, aabb[1] + pad])


# A cut-out whose opaque pixels look past the box in at least this share of all its pixels shows
# geometry beyond the box (a floor or backdrop reaching to the horizon): the box alone cannot hold
# it, and a model paints it as fog on the box's faces. The capture's floor scene (a 2.7 m figure on
# a 100 m floor, boxed around the figure) has 11 %; the demo object scenes have 0.01 % at most.
BEYOND_BOX_SHARE = 0.02


def beyond_box_share(split: "Split", aabb: torch.Tensor, max_pixels: int = 200_000, seed: int = 0) -> float:
    """Share of ``split``'s pixels that are opaque (alpha >= 0.5) while their ray misses ``aabb``
    (2, 3); 0 for images without alpha, where the world and far geometry cannot be told apart.
    At most ``max_pixels`` pixels are drawn, evenly at random over the views."""

    if not len(split) or not split.has_alpha:
        return 0.0
    n, h, w = len(split), split.height, split.width
    gen = torch.Generator().manual_seed(seed)
    flat = torch.randint(0, n * h * w, (min(max_pixels, n * h * w),), generator=gen)
    view, pix = flat // (h * w), flat % (h * w)
    j, i = pix // w, pix % w
    alpha = split.images[view, j, i, 3]
    opaque = alpha >= (0.5 if alpha.is_floating_point() else 128)
    rays_o, rays_d, _ = rays_for_pixels(split.cameras, view, i, j)
    misses = ~ray_aabb_intersect(rays_o.float(), rays_d.float(), aabb.to(torch.float32))[2]
    return float((opaque & misses).float().mean())


def beyond_box_reason(dataset, background: str) -> Optional[str]:
    """Why a model that can (``unbounded``) should also model the world beyond ``dataset``'s box, or
    None: the dataset says objects reach past it (``beyond_box``, written by the capture), or, for a
    model trained on a cut-out (``background`` other than ``environment``), its opaque pixels look
    past the box (``beyond_box_share``). The one rule behind ``train`` and the plan ``check`` prints."""
    if dataset.beyond_box:
        names = ", ".join(dataset.beyond_box[:3]) + (" ..." if len(dataset.beyond_box) > 3 else "")
        return f"the dataset's 'beyond_box' says {names} reach(es) beyond the scene box"
    if background != "environment":
        share = beyond_box_share(dataset.split("train"), dataset.aabb)
        if share >= BEYOND_BOX_SHARE:
            return (f"{100 * share:.0f} % of the train pixels are opaque where their ray misses the scene box "
                    "(geometry beyond it, such as a floor reaching the horizon)")
    return None
