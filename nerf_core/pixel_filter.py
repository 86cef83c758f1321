"""The pixel filter: what one pixel of a rendered image averages over, and rendering that average.

A Cycles or EEVEE pixel is not one ray through its centre. Each render sample draws a sub-pixel offset
from the film's pixel filter (Blackman-Harris, 1.5 px wide by default; Render Properties > Film >
Pixel Filter) and the pixel is the plain mean of its samples, so the pixel holds the filter-weighted
average of the scene over a footprint of about 1.5 pixels. Cycles samples the filter one axis at a
time, so the 2D filter is separable: w(x, y) = w(x) w(y).

Where the scene is flat across the footprint a centre ray gives that average; at silhouettes and
texture edges it does not. A model rendered with one centre ray per pixel draws edges sharper than
the capture's, and on the object demo scenes those few pixels carried 70-100 % of the model's error
above the capture's noise (docs/benchmarks/vmgrid200, "Where the remaining error lies").
``render.render_view`` therefore renders each view once through the pixel centres, finds the pixels
whose 3x3 neighbourhood holds an edge (``edge_pixels``), and replaces each of them by the mean of
``samples`` rays drawn from the filter (``offsets``): Cycles' own estimator, at the few pixels where it
differs from the centre ray.

A dataset records its filter as the top-level field ``pixel_filter`` (``{"type": "BLACKMAN_HARRIS" |
"GAUSSIAN" | "BOX", "width": pixels}``, docs/CONTRACTS.md); one without it (other tools' captures, the
original NeRF synthetic scenes, which Blender rendered with its defaults) is taken to have Blender's
default. ``{"type": "NONE"}`` renders one centre ray per pixel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import torch

from .contract.film import DEFAULT_FILTER_KIND, DEFAULT_FILTER_WIDTH, film_filter_field, parse_film_filter

Tensor = torch.Tensor
# Rays per edge pixel. On the multi demo scene (200 px, vmgrid, 5 test views) the mean of 9 filter
# rays gained 0.90 dB over the centre ray, 16 rays 0.95 dB and 4 rays 0.65 dB.
DEFAULT_SAMPLES = 9
# An edge pixel: some channel (colour or opacity) of its 3x3 neighbourhood spans more than this. On the
# same scene 0.05 marked 13 % of the pixels and gained 0.90 dB; 0.02 marked 20 % for no more, 0.1
# marked 9 % and gained 0.87 dB.
EDGE_THRESHOLD = 0.05
_TABLE_SIZE = 1025


@dataclass(frozen=True)
class PixelFilter:
    """A separable pixel filter: ``kind`` (one of ``contract.film.FILTER_KINDS``) over ``width`` pixels, centred on the pixel;
    ``downscale``: the images were box-filtered by this integer factor after rendering (see ``downscaled``)."""

    kind: str = DEFAULT_FILTER_KIND
    width: float = DEFAULT_FILTER_WIDTH
    downscale: int = 1

    @property
    def is_point(self) -> bool:
        """True when a pixel is one ray through its centre (no filter)."""
        return self.kind == "NONE"

    def to_json(self) -> dict:
        """The dataset field (``parse`` reads it back; ``contract.film``)."""
        return film_filter_field(self.kind, self.width, self.downscale)

    def downscaled(self, factor: int) -> "PixelFilter":
        """The filter of images box-filtered by the integer ``factor`` (``data._downscale``), in the new
        pixels: each new pixel is the mean of f x f original pixels, each of those the filter's average
        around its own centre, so an offset is one of the f original centres plus the filter narrowed
        ``factor`` times (``offsets`` draws both)."""
        if factor == 1 or self.is_point:
            return self
        return PixelFilter(self.kind, self.width / factor, self.downscale * int(factor))

    def full_resolution(self) -> "PixelFilter":
        """The filter of the images before ``downscaled``: what the renderer used."""
        return self if self.downscale == 1 else PixelFilter(self.kind, self.width * self.downscale)

    def weight(self, x: Tensor) -> Tensor:
        """Unnormalised filter weight at offsets ``x`` (pixels from the centre), 0 outside the width.
        The formulas are Cycles' (``filter_func_blackman_harris``, ``filter_func_gaussian``)."""
        t = x / self.width + 0.5
        inside = (t >= 0) & (t <= 1)
        if self.kind == "BLACKMAN_HARRIS":
            a = 2 * math.pi * t
            w = 0.35875 - 0.48829 * torch.cos(a) + 0.14128 * torch.cos(2 * a) - 0.01168 * torch.cos(3 * a)
        elif self.kind == "GAUSSIAN":
            v = x * (6.0 / self.width)
            w = torch.exp(-2.0 * v * v)
        else:
            w = torch.ones_like(x)
        return torch.where(inside, w, torch.zeros_like(w))

    def _table(self) -> tuple[Tensor, Tensor]:
        cached = _TABLES.get(self)
        if cached is None:
            x = torch.linspace(-self.width / 2, self.width / 2, _TABLE_SIZE, dtype=torch.float64)
            w = self.weight(x)
            # trapezoid rule: the cdf of a piecewise-linear density
            cdf = torch.cat([x.new_zeros(1), torch.cumsum(0.5 * (w[1:] + w[:-1]) * (x[1:] - x[:-1]), 0)])
            cached = _TABLES[self] = (x, cdf / cdf[-1])
        return cached

    def sample(self, u: Tensor) -> Tensor:
        """Offsets in pixels distributed as the filter, from uniform numbers ``u`` in [0, 1] (any shape):
        the inverse of the filter's cumulative distribution, as Cycles' filter table does it."""
        x, cdf = self._table()
        u = u.double().clamp(0, 1)
        hi = torch.searchsorted(cdf, u).clamp(1, cdf.numel() - 1)
        c0, c1 = cdf[hi - 1], cdf[hi]
        f = ((u - c0) / (c1 - c0).clamp_min(1e-12)).clamp(0, 1)
        return (x[hi - 1] + f * (x[hi] - x[hi - 1])).float()

    def offsets(self, m: int, samples: int, gen: Optional[torch.Generator] = None) -> Tensor:
        """(m, samples, 2) sub-pixel offsets (x right, y down, in pixels) for ``m`` pixels, stratified:
        with ``samples`` = s^2 each pixel gets one offset in each cell of an s x s grid over the
        filter's two cumulative distributions (less noise than independent draws); otherwise the
        draws are independent."""
        s = int(round(math.sqrt(samples)))
        u = torch.rand(m, samples, 2, generator=gen)
        if s * s == samples:
            gy, gx = torch.meshgrid(torch.arange(s), torch.arange(s), indexing="ij")
            cell = torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=-1).to(u)  # (samples, 2)
            u = (cell + u) / s
        off = self.sample(u)
        if self.downscale > 1:  # which of the f x f original pixels, per axis
            f = self.downscale
            k = torch.randint(0, f, off.shape, generator=gen).to(off)
            off = off + (k + 0.5) / f - 0.5
        return off


_TABLES: dict = {}
POINT = PixelFilter("NONE", 0.0)
DEFAULT = PixelFilter()


def parse(value, where: str) -> PixelFilter:
    """The ``pixel_filter`` field of a dataset (``contract.film``; None: Blender's default). Raises
    ValueError naming ``where`` and the field when it is malformed."""
    kind, width, down = parse_film_filter(value, where)
    return POINT if kind == "NONE" else PixelFilter(kind, width, down)


def edge_pixels(image: Tensor, threshold: float = EDGE_THRESHOLD) -> Tensor:
    """(h, w) bool: pixels of ``image`` (h, w, c) whose 3x3 neighbourhood spans more than ``threshold``
    in some channel, where one centre ray and the filter's average differ."""
    t = image.permute(2, 0, 1).unsqueeze(0).float()
    hi = torch.nn.functional.max_pool2d(t, 3, 1, 1)
    lo = -torch.nn.functional.max_pool2d(-t, 3, 1, 1)
    return (hi - lo).amax(dim=1)[0] > threshold


MODES = ("auto", "none")  # the ``--pixel-filter`` choices of ``render`` and ``eval``


def of_run(config: dict, mode: str = "auto", downscale: int = 1) -> PixelFilter:
    """The filter to render a run's views with: the one its dataset recorded (``RUN/config.json``
    ``pixel_filter``, the dataset's at full resolution; runs trained before it was recorded get
    Blender's default), box-filtered by ``downscale`` like ``eval``'s ground truth; ``mode`` "none":
    one ray through each pixel centre."""
    if mode == "none":
        return POINT
    try:
        pf = parse(config.get("pixel_filter"), "config.json")
    except ValueError:
        pf = DEFAULT  # a hand-edited config: render as Blender would by default rather than fail
    return pf.downscaled(int(downscale)) if float(downscale).is_integer() and downscale >= 1 else pf
