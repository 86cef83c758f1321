"""Free space from a capture (``train --depth``): the occupancy cells that the train views show empty
at step 0, so that rays skip them from the first step instead of waiting for training to carve them.

A ray from a camera to the surface its depth map records crosses only empty space before it. A ray
through a pixel the film left transparent (alpha 0) crosses nothing at all. Cells that such rays
cross, stopped ``SHELL_CELLS + 0.5`` cells short of their surface, are empty, except cells within
``SHELL_CELLS`` of a surface point that any pixel's depth shows (a grazing ray passes the edge of a
surface another pixel sees, and a field's density rises over a few cells before its surface) or of a
cell that no ray crosses. Cells that no ray crosses stay occupied: unseen is not empty.

Two cells, measured: a trained vmgrid (multi, 5 minutes, 38.5 dB) puts a third of each ray's weight
1-2 occupancy cells in front of the captured depth. Carving its grid with a one-cell shell dropped a
test view from 36.15 to 22.35 dB (and training from the start with it stalled near 23 dB), with two
35.63, with three 36.15; the carved box keeps 18 %, 27 % and 35 % of its cells.

Depth 0 on an opaque pixel says nothing (a sensor's hole, a world at infinity), so those rays carve
nothing.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from nerf_core.cameras.rays import rays_for_pixels
from nerf_core.data.split import Split

Tensor = torch.Tensor

# Cells kept around every surface point (and every cell no ray crossed); a carving ray stops half a
# cell more than that before its surface: the depth of a pixel is that of its centre, a surface is not
# a plane across the pixel's footprint, and a field's density rises over a few cells before its surface.
SHELL_CELLS = 2
# Rays traced for carving (the train views are subsampled evenly to about this many): on a 64^3 grid a
# ray crosses about 100 cells, so this is some 20 M cell lookups, a second or two on one core.
MAX_RAYS = 200_000
_CHUNK = 4096


def _cells(pts: Tensor, lo: Tensor, per_unit: Tensor, r: int) -> tuple[Tensor, Tensor]:
    """Flat cell index (m,) of points (m, 3) and whether each is inside the box (m,)."""
    u = (pts - lo) * per_unit
    inside = (u.amin(-1) >= 0) & (u.amax(-1) < r)
    ijk = u.clamp(0, r - 1).floor().long()
    return (ijk[:, 0] * r + ijk[:, 1]) * r + ijk[:, 2], inside


def free_cells(aabb: Tensor, resolution: int, split: Split, depth: Tensor,
               max_rays: int = MAX_RAYS, shell: int = SHELL_CELLS) -> Tensor:
    """The cells of a ``resolution``^3 grid over ``aabb`` that the split's views show empty.

    Args:
        aabb: (2, 3) the grid's box [min corner, max corner] in world space.
        resolution: cells per axis r (indexed [x, y, z], as ``OccupancyGrid``).
        split: the train split (its cameras, and its alpha where the images have one).
        depth: (v, h, w) float32 planar z-depth of the split's pixels, 0 where unknown (``Split.depth``).
        max_rays: about how many rays to trace (views are subsampled evenly; every pixel's surface
            point still protects its cell).
        shell: cells kept around every surface point and every uncrossed cell (carving rays stop
            ``shell + 0.5`` cells short of their surface).
    Returns:
        (r, r, r) bool, True where a cell is known to be empty.
    """
    r = int(resolution)
    aabb = aabb.float().cpu()
    lo, hi = aabb[0], aabb[1]
    per_unit = r / (hi - lo)
    cell = float((hi - lo).min()) / r
    v, h, w = depth.shape
    shown = split.shown()  # (v, h, w) bool: alpha above 0 (every pixel of an opaque film)
    crossed = torch.zeros(r ** 3, dtype=torch.bool)
    surface = torch.zeros(r ** 3, dtype=torch.bool)
    stride = max(1, math.ceil(math.sqrt(v * h * w / max_rays)))
    for view in range(v):
        z = depth[view]
        # every surface point of the view protects its cell
        jj, ii = torch.nonzero(z > 0, as_tuple=True)
        for s in range(0, jj.numel(), 1 << 16):
            j, i = jj[s:s + (1 << 16)], ii[s:s + (1 << 16)]
            o, d, z_per_t = rays_for_pixels(split.cameras, torch.full_like(j, view), i, j)
            pts = o + d * (z[j, i] / z_per_t)[:, None]
            idx, inside = _cells(pts, lo, per_unit, r)
            surface[idx[inside]] = True
        # the rays that carve: surface pixels up to their surface, transparent pixels all the way
        gj, gi = torch.meshgrid(torch.arange(stride // 2, h, stride), torch.arange(stride // 2, w, stride),
                                indexing="ij")
        j, i = gj.reshape(-1), gi.reshape(-1)
        zz = z[j, i]
        empty = ~shown[view][j, i]
        keep = (zz > 0) | empty
        j, i, zz, empty = j[keep], i[keep], zz[keep], empty[keep]
        for s in range(0, j.numel(), _CHUNK):
            cj, ci = j[s:s + _CHUNK], i[s:s + _CHUNK]
            o, d, z_per_t = rays_for_pixels(split.cameras, torch.full_like(cj, view), ci, cj)
            # the ray's interval inside the box (slabs), ended short of its surface
            inv = 1.0 / torch.where(d.abs() > 1e-12, d, torch.full_like(d, 1e-12))
            t_a, t_b = (lo - o) * inv, (hi - o) * inv
            t0 = torch.minimum(t_a, t_b).amax(-1).clamp_min(0)
            t1 = torch.maximum(t_a, t_b).amin(-1)
            t_surf = zz[s:s + _CHUNK] / z_per_t
            t1 = torch.where(empty[s:s + _CHUNK], t1, torch.minimum(t1, t_surf - (shell + 0.5) * cell))
            n = ((t1 - t0) / (0.5 * cell)).clamp_min(0).ceil().long()
            if int(n.sum()) == 0:
                continue
            ray = torch.repeat_interleave(torch.arange(n.numel()), n)
            first = torch.cumsum(n, 0) - n
            k = torch.arange(ray.numel()) - first[ray]
            t = t0[ray] + (k.float() + 0.5) * (0.5 * cell)
            pts = o[ray] + d[ray] * t[:, None]
            idx, inside = _cells(pts, lo, per_unit, r)
            crossed[idx[inside]] = True
    # A ray that crosses a cell shows only the part it crossed empty. A cell is free when it and all 26
    # cells around it were crossed and none holds a surface point: the one-cell shell that this takes
    # off keeps the edge of what no ray reached (the unseen underside of an object) and the cells that
    # grazing rays pass beside a surface.
    kept = (~crossed | surface).reshape(1, 1, r, r, r).float()
    return F.max_pool3d(kept, 2 * shell + 1, stride=1, padding=shell)[0, 0] == 0
