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
at an edge, those that differ from the mean of their neighbours (``edge_pixels``), and replaces each
of them by the mean of ``samples`` rays drawn from the filter (``offsets``): Cycles' own estimator,
at the few pixels where it differs from the centre ray. On the 200 px benchmark's 5-minute vmgrid
runs that gained 0.0-1.0 dB a scene (multi +1.0) for 1.3-4.4 rays a pixel. Training is unchanged:
training on the footprint (4 filter rays per edge pixel of a batch) lost 0.5 dB at a fixed time,
since those grazing rays cost the most samples (docs/benchmarks/vmgrid200/summary.md).

A dataset records its filter as the top-level field ``pixel_filter`` (``{"type": "BLACKMAN_HARRIS" |
"GAUSSIAN" | "BOX", "width": pixels}``, docs/CONTRACTS.md); one without it (other tools' captures, the
original NeRF synthetic scenes, which Blender rendered with its defaults) is taken to have Blender's
default. ``{"type": "NONE"}`` renders one centre ray per pixel.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Optional, Union

import torch

from nerf_core.contract.film import (
    DEFAULT_FILTER_KIND,
    DEFAULT_FILTER_WIDTH,
    film_filter_field,
    parse_film_filter,
)

Tensor = torch.Tensor
# Rays per edge pixel. On the multi demo scene (200 px, vmgrid, 5 test views) the mean of 9 filter
# rays gained 0.90 dB over the centre ray, 16 rays 0.95 dB and 4 rays 0.65 dB.
DEFAULT_SAMPLES = 9
# An edge pixel: some channel (colour or opacity) of the centre-ray image differs from the mean of its 8
# neighbours by more than this. The filter is symmetric, so where the image is linear across a pixel
# (a smooth gradient) its mean is the centre ray; only curvature and steps change a pixel. On the
# vmgrid runs of the 200 px benchmark (5 min, 5 test views, 9 rays an edge pixel), against the 3x3
# range above 0.05: multi 38.41 against 38.34 dB at 1.77 against 2.15 rays a pixel, the HDRI scene
# 33.23 against 33.25 dB at 4.4 against 8.5 rays a pixel (its photographed world is busy everywhere).
EDGE_THRESHOLD = 0.02
_TABLE_SIZE = 1025


@dataclass(frozen=True)
class PixelFilter:
    """A separable pixel filter: ``kind`` (one of ``contract.film.FILTER_KINDS``) over ``width`` pixels,
    centred on the pixel; ``downscale``: the images were box-filtered by this integer factor after
    rendering (see ``downscaled``)."""

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
        """The filter of images box-filtered by the integer ``factor`` (``data.pixels.downscale_image``), in the new
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

    def offsets(self, m: int, samples: int, gen: Optional[torch.Generator] = None,
                keys: Optional[Tensor] = None) -> Tensor:
        """(m, samples, 2) sub-pixel offsets (x right, y down, in pixels) for ``m`` pixels, stratified:
        with ``samples`` = s^2 each pixel gets one offset in each cell of an s x s grid over the
        filter's two cumulative distributions (less noise than independent draws); otherwise the
        draws are independent. The uniform numbers come from ``gen``, or, given ``keys`` (m, 2) int64,
        from a hash of each pixel's key (``render_view`` keys a pixel by its place relative to the
        principal point, so a Render Region draws the rays its pixels get in the whole frame)."""
        s = int(round(math.sqrt(samples)))
        u = torch.rand(m, samples, 4, generator=gen) if keys is None else hashed_uniform(keys, samples, 4)
        off_u, pick = u[..., :2], u[..., 2:]  # the offset's cdf values; which original pixel (downscale)
        if s * s == samples:
            gy, gx = torch.meshgrid(torch.arange(s), torch.arange(s), indexing="ij")
            cell = torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=-1).to(u)  # (samples, 2)
            off_u = (cell + off_u) / s
        off = self.sample(off_u)
        if self.downscale > 1:  # which of the f x f original pixels, per axis
            f = self.downscale
            k = torch.floor(pick * f).clamp(max=f - 1)
            off = off + (k + 0.5) / f - 0.5
        return off


def hashed_uniform(keys: Tensor, samples: int, dims: int) -> Tensor:
    """(m, samples, dims) numbers in [0, 1) that depend only on each row of ``keys`` (m, 2) int64 and
    the sample and dimension index: a 32-bit integer hash (the "lowbias32" mixer, in int64 so that
    nothing overflows)."""
    mask = 0xFFFFFFFF
    k = keys.long() & mask
    idx = torch.arange(samples * dims, dtype=torch.long).reshape(1, samples, dims)
    x = (k[:, 0, None, None] * 0x9E3779B1 + k[:, 1, None, None] * 0x85EBCA77 + idx * 0xC2B2AE3D) & mask
    for mul in (0x7FEB352D, 0x846CA68B):
        x = ((x ^ (x >> 16)) * mul) & mask
    x = x ^ (x >> 16)
    return (x >> 8).to(torch.float32) / float(1 << 24)


_TABLES: dict = {}
POINT = PixelFilter("NONE", 0.0)
DEFAULT = PixelFilter()


def parse(value, where: str) -> PixelFilter:
    """The ``pixel_filter`` field of a dataset (``contract.film``; None: Blender's default). Raises
    ValueError naming ``where`` and the field when it is malformed."""
    kind, width, down = parse_film_filter(value, where)
    return POINT if kind == "NONE" else PixelFilter(kind, width, down)


def edge_pixels(image: Tensor, threshold: float = EDGE_THRESHOLD) -> Tensor:
    """(h, w) bool: pixels of ``image`` (h, w, c) where some channel differs from the mean of its 8
    neighbours by more than ``threshold`` (a discrete Laplacian; the border repeats the edge pixels):
    where the filter's mean and one centre ray differ."""
    x = image.permute(2, 0, 1).unsqueeze(1).float()  # (c, 1, h, w)
    kernel = torch.full((1, 1, 3, 3), 1.0 / 8)
    kernel[0, 0, 1, 1] = -1.0
    lap = torch.nn.functional.conv2d(torch.nn.functional.pad(x, (1, 1, 1, 1), mode="replicate"), kernel)
    return lap.abs().amax(dim=0)[0] > threshold


MODES = ("none", "auto")  # the two names every renderer takes; None means "none" everywhere (``render_view``'s)


def of_run(config: dict, mode: Union[str, PixelFilter, None] = "auto", downscale: float = 1,
           where: str = "pixel_filter") -> PixelFilter:
    """The filter to render a run's views with: the one its dataset recorded (``RUN/config.json``
    ``pixel_filter``, the dataset's at full resolution; runs trained before it was recorded get
    Blender's default), box-filtered by an integer ``downscale`` like ``eval``'s ground truth.

    ``mode``: "auto" that filter; "none" or None one ray through each pixel centre (None means this in
    ``render_view`` too); a ``PixelFilter`` itself. Anything else is refused (ValueError naming
    ``where``): an unknown name was once taken as "auto"."""
    if isinstance(mode, PixelFilter):
        return mode
    if mode is None or mode == "none":
        return POINT
    if mode != "auto":
        raise ValueError(f"{where}: must be 'none', 'auto', None or a PixelFilter, got {mode!r}")
    try:
        film = parse(config.get("pixel_filter"), "config.json")
    except ValueError as exc:
        # a hand-edited config: render as Blender would by default rather than fail, and say so
        print(f"note: {exc}; rendering through Blender's default filter ({DEFAULT.kind} {DEFAULT.width:g} px)",
              file=sys.stderr)
        film = DEFAULT
    return film.downscaled(int(downscale)) if float(downscale).is_integer() and downscale >= 1 else film
