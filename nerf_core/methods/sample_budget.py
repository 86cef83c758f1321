"""``SampleBudget``: the sizes of vmgrid's fixed-shape training step, and the rays per step that fill it.

With ``sample_budget`` set, a training step evaluates a fixed number of samples (instant-ngp's batch
of samples) instead of a fixed number of rays: the rays per step follow how many samples a ray takes,
which falls by an order of magnitude as the occupancy grid prunes empty space and the marching step
refines. Every buffer of the step has a size the host knows before the step (``volume.padded``), so the
step reads nothing back:

- ``samples``: the samples in occupied cells (the budget itself, fixed);
- ``runs``: the marching runs whose probe found occupancy (``padded.occupied_samples_padded``);
- ``visible``: the samples still visible after a first, gradient-free pass (early termination);
- ``coloured``: the samples whose colour is evaluated.

Each step folds what each buffer wanted, per ray, into running maxima on the device (``observe``);
the method's periodic steps read them (one read, ``adapt``) and resize the buffers with a margin and
the rays to fill ``samples``. Between reads the sizes stay fixed. A buffer that overflows anyway cuts
the last rays of the batch, which the loss leaves out (``PaddedSamples.fits``), so an overflow costs
rays, not correctness.
"""
from __future__ import annotations

import math
from typing import Optional

import torch

Tensor = torch.Tensor

MARGIN = 1.25  # the buffers' headroom over the most a ray wanted since the last read
ROUND = 256  # buffer sizes and rays per step are multiples of this: fewer distinct shapes
MIN_RAYS = 64


def _round_up(x: float, to: int = ROUND) -> int:
    return int(max(to, math.ceil(x / to) * to))


class SampleBudget:
    """The buffer sizes and rays per step of a fixed-shape training step.

    Args:
        samples: the samples per step (the budget).
        max_rays: the most rays a step may draw (a sparse grid's steps would otherwise grow without bound).
        steps_per_ray: marching steps per ray at the current step size (``padded.steps_for_box``), the
            most samples a ray can take: the first step assumes every ray takes them all.
        steps_per_run: steps in one probed run (1 when rays are not probed in runs).
    """

    def __init__(self, samples: int, max_rays: int, steps_per_ray: int, steps_per_run: int):
        self.samples = int(samples)
        self.max_rays = max(MIN_RAYS, int(max_rays))
        self._max: Optional[Tensor] = None  # (4,) float64 on the device: most wanted per ray since the last read
        # What the sizes are made from (host floats): the last read maxima, or the start's assumption. A
        # rescale scales these, so a finer step right after a read resizes at once, not at the next read.
        per_ray = float(steps_per_ray)  # at the start, a grid occupied everywhere: every ray takes every step
        self._sized_for = (per_ray, per_ray / max(1, steps_per_run) + 1.0, per_ray, per_ray)
        self._resize(*self._sized_for)

    def _resize(self, samples: float, runs: float, visible: float, coloured: float) -> None:
        """Rays and buffers from what a ray wants of each buffer (samples, runs, visible, coloured)."""
        self._sized_for = (samples, runs, visible, coloured)
        rays = self.samples / max(1.0, MARGIN * samples)
        self.rays = int(min(self.max_rays, max(MIN_RAYS, rays // MIN_RAYS * MIN_RAYS)))
        self.runs = _round_up(MARGIN * runs * self.rays)
        self.visible = min(self.samples, _round_up(MARGIN * visible * self.rays))
        self.coloured = min(self.visible, _round_up(MARGIN * coloured * self.rays))

    def observe(self, n_rays: int, samples: Tensor, runs: Tensor, visible: Tensor, coloured: Tensor) -> None:
        """Fold what a step's ``n_rays`` rays wanted of each buffer (() long tensors each, on the device)
        into the running maxima; no host read."""
        wanted = torch.stack([samples, runs, visible, coloured]).double() / n_rays
        self._max = wanted if self._max is None else torch.maximum(self._max, wanted)

    def rescale(self, factor: float) -> None:
        """The marching step changed by 1 / ``factor`` (a finer step: factor > 1): a ray's samples change
        by about that much at once, before the next read can show it. Both the sizes in use and the
        maxima gathered since the last read (measured at the old step) are scaled; no host read."""
        if self._max is not None:
            self._max = self._max * factor
        self._resize(*(v * factor for v in self._sized_for))

    def adapt(self) -> None:
        """Read the maxima (one host read: call on periodic steps only) and resize; start a new window.
        Without a step observed since the last read the sizes stay."""
        if self._max is not None:
            self._resize(*(float(v) for v in self._max.tolist()))
            self._max = None

    def sizes(self) -> dict:
        return {"rays": self.rays, "samples": self.samples, "runs": self.runs, "visible": self.visible,
                "coloured": self.coloured}
