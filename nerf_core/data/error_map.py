"""Error-weighted ray sampling (``train --ray-sampling error``): training pixels drawn in proportion to a
running estimate of their error, as instant-ngp does, with weights that keep the loss an estimate of
the uniform one.

The split's pixels are grouped into square tiles of ``tile`` px (one tile a pixel on small captures;
larger tiles keep the map at most ``MAX_TILES`` entries). Each tile holds an exponential moving average
of the squared colour error of the rays drawn in it. A pixel is drawn with probability

    p(pixel) = (1 - UNIFORM) * e_k / sum_k(e_k a_k) + UNIFORM / A

where k is its tile, a_k the tile's pixel count, e_k its estimate and A the split's pixel count: the
uniform share keeps every pixel reachable and bounds the weight. A ray's weight is the ratio of the
uniform probability to the one it was drawn with, w = (1 / A) / p(pixel) <= 1 / UNIFORM, and the loss
(``image.losses.masked_mse``; ``depth_loss`` with ``--depth``) is the weighted mean, so that its
expectation is the uniform loss and the pixels that are already right are not fitted less, only
sampled less.

The estimate starts flat (every tile at ``START_ERROR``), so the first draws are uniform. The sampling
table (a cumulative sum over the tiles) is rebuilt every ``REFRESH`` updates: between rebuilds each draw
is a binary search, O(n log N), not a pass over the map.
"""
from __future__ import annotations

import math

import torch

Tensor = torch.Tensor

# share of every draw that is uniform over the pixels: bounds a ray's weight at 1 / UNIFORM
UNIFORM = 0.5
# most tiles the map keeps: 1 M float32 estimates (4 MB); a 100-view 800 px capture gets 8 px tiles
MAX_TILES = 1 << 20
# the moving average's step: a tile's estimate moves this share of the way to each new ray's error
RATE = 0.25
# updates between rebuilds of the sampling table
REFRESH = 16
# the flat estimate every tile starts from (a squared colour error: an untrained field's is ~0.1)
START_ERROR = 0.1


class ErrorMap:
    """A running estimate of the squared colour error over the tiles of a split's pixels, and the draws
    it weights.

    Args:
        views, height, width: the split's size (v, h, w).
        max_tiles: most tiles (the tile side grows until the map fits).
    """

    def __init__(self, views: int, height: int, width: int, max_tiles: int = MAX_TILES):
        self.v, self.h, self.w = int(views), int(height), int(width)
        self.tile = max(1, math.ceil(math.sqrt(self.v * self.h * self.w / max_tiles)))
        t = self.tile
        self.th, self.tw = math.ceil(self.h / t), math.ceil(self.w / t)
        # pixels in each tile row / column (the last ones may be cut by the image's edge)
        rows = torch.full((self.th,), t, dtype=torch.long)
        rows[-1] = self.h - t * (self.th - 1)
        cols = torch.full((self.tw,), t, dtype=torch.long)
        cols[-1] = self.w - t * (self.tw - 1)
        self.rows, self.cols = rows, cols
        area = (rows[:, None] * cols[None, :]).reshape(-1).double()  # (th*tw,)
        self.area = area.repeat(self.v)  # (N,) pixels per tile
        self.total = float(self.v * self.h * self.w)
        self.error = torch.full((self.v * self.th * self.tw,), START_ERROR, dtype=torch.float64)
        self._updates = 0
        self._rebuild()

    @property
    def tiles(self) -> int:
        return self.error.numel()

    def _rebuild(self) -> None:
        mass = self.error.clamp_min(0) * self.area
        s = float(mass.sum())
        spread = mass / s if s > 0 else self.area / self.total
        self.p_tile = (1.0 - UNIFORM) * spread + UNIFORM * self.area / self.total  # (N,) sums to 1
        self.cdf = torch.cumsum(self.p_tile, 0)

    def draw(self, n: int, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """``n`` pixels drawn from the current estimate.

        Returns:
            view, j, i: (n,) long view index, pixel row and column.
            tile: (n,) long tile index of each pixel (what ``update`` is told).
            weight: (n,) float32 uniform over drawn probability of each pixel (in (0, 1 / UNIFORM]).
        """
        u = torch.rand(n, generator=gen, dtype=torch.float64) * float(self.cdf[-1])
        tile = torch.searchsorted(self.cdf, u, right=True).clamp_max(self.tiles - 1)
        view = tile // (self.th * self.tw)
        rest = tile % (self.th * self.tw)
        ty, tx = rest // self.tw, rest % self.tw
        # a uniform pixel inside the tile (edge tiles are smaller)
        dj = (torch.rand(n, generator=gen) * self.rows[ty]).long().clamp_max(self.rows[ty] - 1)
        di = (torch.rand(n, generator=gen) * self.cols[tx]).long().clamp_max(self.cols[tx] - 1)
        j, i = ty * self.tile + dj, tx * self.tile + di
        weight = (self.area[tile] / (self.total * self.p_tile[tile])).float()
        return view, j, i, tile, weight

    def update(self, tile: Tensor, error: Tensor) -> None:
        """Move the estimate of each drawn tile toward the mean squared error (n,) of its rays this step."""
        tile = tile.reshape(-1).cpu()
        error = error.detach().reshape(-1).to("cpu", torch.float64)
        good = torch.isfinite(error)  # a diverged step is rolled back; its errors teach nothing
        tile, error = tile[good], error[good]
        # over the drawn tiles only (O(n log n)), not a pass over the whole map
        hit, where = torch.unique(tile, return_inverse=True)
        sums = torch.zeros(hit.numel(), dtype=torch.float64).index_add_(0, where, error)
        counts = torch.zeros(hit.numel(), dtype=torch.float64).index_add_(0, where, torch.ones_like(error))
        self.error[hit] += RATE * (sums / counts - self.error[hit])
        self._updates += 1
        if self._updates % REFRESH == 0:
            self._rebuild()
