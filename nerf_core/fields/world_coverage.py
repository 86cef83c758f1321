"""Which parts of the world (the background at infinity) the train views show, and how much of a
held-out view looks where none of them did.

Why it matters: a world is a colour per *direction* (``environment.py``). A held-out pixel whose ray
leaves the scene box in a direction that no train ray took shows a part of the world that no
training image contains, so no model can get it right; it can only guess from the neighbours.
Low cameras of a dome capture are the usual case: their upper rows see the sky above the horizon,
which the other (higher, downward-looking) train cameras never do, and a low test camera between
them looks at sky that nobody photographed. On the benchmark's ``hdri`` scene, 21 % of test view 0
is such sky; it scores 12.9 dB there and 31.8 dB on the rest of the view.
The capture now keeps the lowest tenth of a generated layout in training
(``addon/layouts.LOWEST_TRAIN_SHARE``), which removes the case from its own datasets.

``unseen_world_share`` measures that share per held-out view from the cameras alone (no pixels are
read), so ``python -m nerf_core check`` can say which views will score low and why.

Binning: directions go into a lat-long grid (``environment.directions_to_uv``) whose cells span about
two train pixels, so that adjacent train pixels leave no gaps between their cells. A covered cell also
covers its neighbours (one cell in latitude; in longitude as many cells as make up the same angle at
that latitude, because the cells narrow towards the poles). Coverage therefore errs on the side of
"seen": the check should warn about real holes, not about the gaps between pixels.
"""
from __future__ import annotations

import math
from typing import Optional

import torch

from nerf_core.cameras.rays import Cameras, rays_for_pixels
from nerf_core.fields.environment import directions_to_uv
from nerf_core.volume.sampling import ray_aabb_intersect

Tensor = torch.Tensor

MIN_BINS = 64  # longitude cells of the coarsest grid (a 5.6 degree cell)
MAX_BINS = 2048  # and of the finest (0.18 degree): finer costs memory and says nothing more


TRAIN_RAYS_PER_VIEW = 40_000  # rays per train view that ``covered_directions`` traces at most
HELD_OUT_RAYS_PER_VIEW = 10_000  # and ``unseen_world_share`` per held-out view


def bins_for_cameras(cameras: Cameras, stride: int = 1) -> int:
    """Longitude cells of a grid whose cell spans about two traced pixels (every ``stride``-th pixel)
    of the median train camera, so that neighbouring traced rays leave no empty cell between them."""
    focal = float(torch.median(torch.minimum(cameras.fx, cameras.fy)))
    return int(min(MAX_BINS, max(MIN_BINS, round(2.0 * math.pi * focal / (2.0 * stride)))))


def auto_stride(cameras: Cameras, rays_per_view: int) -> int:
    """The pixel stride that traces at most about ``rays_per_view`` rays of the largest view."""
    pixels = float((cameras.width * cameras.height).max())
    return max(1, math.ceil(math.sqrt(pixels / rays_per_view)))


def _pixel_grid(cameras: Cameras, view: int, stride: int) -> tuple[Tensor, Tensor, Tensor]:
    w, h = int(cameras.width[view]), int(cameras.height[view])
    jj, ii = torch.meshgrid(torch.arange(0, h, stride), torch.arange(0, w, stride), indexing="ij")
    v = torch.full((ii.numel(),), view, dtype=torch.long)
    return v, ii.reshape(-1), jj.reshape(-1)


def _cells(dirs: Tensor, n_u: int) -> Tensor:
    """(m, 3) directions -> (m,) flat cell index of an (n_u / 2, n_u) lat-long grid."""
    n_v = n_u // 2
    uv = directions_to_uv(dirs)
    cu = (uv[:, 0] * n_u).long().clamp_(0, n_u - 1)
    cv = (uv[:, 1] * n_v).long().clamp_(0, n_v - 1)
    return cv * n_u + cu


def _dilate(mask: Tensor) -> Tensor:
    """Grow a (n_v, n_u) lat-long mask by one cell's angle in every direction.

    Longitude wraps around. A row at polar angle theta has cells sin(theta) times narrower, so it is
    grown by about 1 / sin(theta) cells in longitude (rounded up; at most half the row).
    """
    n_v, n_u = mask.shape
    theta = (torch.arange(n_v, dtype=torch.float64) + 0.5) / n_v * math.pi
    # The 0.05 keeps rows near the equator (sin(theta) > 0.95) at one cell: coverage is approximate anyway.
    radius = torch.ceil(1.0 / torch.sin(theta).clamp_min(1e-6) - 0.05).long().clamp_(1, n_u // 2)
    r_max = int(radius.max())
    m = mask.to(torch.int32)
    padded = torch.cat([m[:, -r_max:], m, m[:, :r_max]], dim=1)  # (n_v, n_u + 2 r_max), wrapped
    cs = torch.nn.functional.pad(padded.cumsum(1), (1, 0))  # cs[:, k] = sum of padded[:, :k]
    u = torch.arange(n_u)[None, :] + r_max  # column of u in the padded row
    lo = (u - radius[:, None]).clamp_min(0)
    hi = (u + radius[:, None] + 1).clamp_max(padded.shape[1])
    grown = (cs.gather(1, hi) - cs.gather(1, lo)) > 0
    # One cell in latitude (no wrap over the poles: a pole cell touches every longitude anyway).
    out = grown.clone()
    out[1:] |= grown[:-1]
    out[:-1] |= grown[1:]
    return out


def covered_directions(train: Cameras, n_u: Optional[int] = None, stride: Optional[int] = None) -> Tensor:
    """(n_u / 2, n_u) bool lat-long grid: the directions some train ray takes (grown by one cell).

    Every train ray counts, including those that hit the scene, so the grid errs towards "seen"
    (a ray blocked by an object did not see the world; we do not know that from cameras alone).
    ``stride``: trace every stride-th pixel in each direction (default: at most about
    ``TRAIN_RAYS_PER_VIEW`` rays a view); the default ``n_u`` makes the cells match it.
    """
    stride = int(stride or auto_stride(train, TRAIN_RAYS_PER_VIEW))
    n_u = int(n_u or bins_for_cameras(train, stride))
    seen = torch.zeros((n_u // 2) * n_u, dtype=torch.bool)
    for view in range(len(train)):
        v, i, j = _pixel_grid(train, view, stride)
        _, rays_d, _ = rays_for_pixels(train, v, i, j)
        seen[_cells(rays_d.float(), n_u)] = True
    return _dilate(seen.view(n_u // 2, n_u))


def unseen_world_share(held_out: Cameras, view: int, covered: Tensor, aabb: Optional[Tensor] = None,
                       stride: Optional[int] = None) -> float:
    """Share in [0, 1] of ``view``'s pixels that see the world in a direction no train ray took.

    Args:
        held_out: cameras of a held-out split; ``view`` indexes them.
        covered: ``covered_directions`` of the train cameras, (n_v, n_u) bool.
        aabb: (2, 3) scene box; a pixel whose ray passes through it may see the scene instead of the
            world, so only rays that miss it count. ``None``: every ray counts.
        stride: every stride-th pixel in each direction is tested (default: at most about
            ``HELD_OUT_RAYS_PER_VIEW`` of them).
    """
    stride = int(stride or auto_stride(held_out[view], HELD_OUT_RAYS_PER_VIEW))
    v, i, j = _pixel_grid(held_out, view, stride)
    rays_o, rays_d, _ = rays_for_pixels(held_out, v, i, j)
    rays_o, rays_d = rays_o.float(), rays_d.float()
    if aabb is not None:
        misses = ~ray_aabb_intersect(rays_o, rays_d, aabb.to(rays_o))[2]
    else:
        misses = torch.ones(len(rays_d), dtype=torch.bool)
    n_u = covered.shape[1]
    unseen = misses & ~covered.reshape(-1)[_cells(rays_d, n_u)]
    return float(unseen.float().mean()) if len(unseen) else 0.0
