"""Training batches: what a step trains on (``RayBatch``), the type that draws them (``Batcher``,
which a method chooses with ``RadianceModel.make_batcher``) and the default, ``RayBatcher``: random
rays (and their target colours) from a ``Split``.

Where a training ray goes through its pixel (``train --train-rays``): a Cycles pixel is the mean over
its pixel filter (``nerf_core.image.pixel_filter``), so a ray cast at an offset drawn from that filter
has the pixel's colour as its expected colour, and a model fitted to such rays renders the capture's
soft silhouettes rather than the sharper ones that rays through the centres fit. It costs one ray a
pixel, as the centre ray does (four numbers more per ray from the generator).

Which pixels a step trains on (``train --ray-sampling``): uniformly over every pixel, or in proportion
to a running estimate of their error (``nerf_core.data.error_map``), weighted so that the loss stays an
estimate of the uniform one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Optional

import torch

from nerf_core.cameras.rays import rays_for_pixels
from nerf_core.data.backgrounds import AUTO_WHITE_FRACTION, TRAINING_BACKGROUNDS
from nerf_core.data.error_map import ErrorMap
from nerf_core.data.split import Split
from nerf_core.image.pixel_filter import DEFAULT as DEFAULT_FILTER
from nerf_core.image.pixel_filter import POINT, PixelFilter
from nerf_core.utils import arguments

# ``train --train-rays``: where a training ray goes through its pixel (``footprint``)
TRAIN_RAYS = ("filter", "centre")
DEFAULT_TRAIN_RAYS = "centre"
# what runs recorded before the flag existed trained with
RECORDED_BEFORE_TRAIN_RAYS = "centre"
# ``train --ray-sampling``: which pixels a step draws (uniformly, or by their running error)
RAY_SAMPLING = ("uniform", "error")
DEFAULT_RAY_SAMPLING = "uniform"


def footprint(pixel_filter: Optional[PixelFilter], train_rays: str) -> PixelFilter:
    """What ``RayBatcher`` draws a ray's offset in its pixel from, for ``train --train-rays``: the
    dataset's ``pixel_filter`` at its loaded resolution (``Dataset.pixel_filter``; Blender's default
    where it is None) for "filter", the centre (``POINT``) for "centre"."""
    arguments.choice("footprint", "train_rays", train_rays, TRAIN_RAYS)
    if train_rays == "centre":
        return POINT
    return pixel_filter if pixel_filter is not None else DEFAULT_FILTER


@dataclass(frozen=True, eq=False)
class BatchOptions:
    """What the run's flags ask of its batches, for ``RadianceModel.make_batcher``.

    Attributes:
        footprint: what a ray's sub-pixel offset is drawn from (``train --train-rays``, ``footprint``):
            the split's pixel filter, or ``POINT`` for the pixel centres.
        depth: (v, h, w) float32 planar depth targets of the split's pixels (``train --depth``;
            ``data.depth.depth_targets``, 0 = unknown) that the batches carry as ``RayBatch.depth``, or None.
        sampling: which pixels are drawn (``train --ray-sampling``, one of ``RAY_SAMPLING``).
        alpha: whether the batches carry the pixels' alpha as ``RayBatch.alpha`` (``train --alpha-weight``,
            ``data.alpha``); needs a split with an alpha channel.
    """

    footprint: PixelFilter = POINT
    depth: Optional[torch.Tensor] = None
    sampling: str = DEFAULT_RAY_SAMPLING
    alpha: bool = False


class RayBatch(NamedTuple):
    """One training step's rays and what they should render, all on the training device.

    Attributes:
        rays_o: (n, 3) float32 origins in world space.
        rays_d: (n, 3) float32 unit directions.
        background: (n, 3) float32 colour behind each ray (the ground truth was composited onto it).
        target: (n, 3) float32 ground-truth colour.
        weight: (n,) float32 per-ray weight of the colour error (1 use, 0 ignore), or None (no masks).
        depth: (n,) float32 true distance along each ray to its surface, 0 where it is not known
            (``train --depth``; ``data.depth.depth_targets``), or None (colours only).
        alpha: (n,) float32 alpha of each ray's pixel in [0, 1], what ``target`` was composited with
            (``train --alpha-weight``; ``data.alpha``), or None (colours only).
    """

    rays_o: torch.Tensor
    rays_d: torch.Tensor
    background: torch.Tensor
    target: torch.Tensor
    weight: Optional[torch.Tensor]
    depth: Optional[torch.Tensor] = None
    alpha: Optional[torch.Tensor] = None


class Batcher:
    """What the trainer draws each step's rays from (``RadianceModel.make_batcher`` makes one).

    A batcher draws every random number from the generator it was given, so that a saved generator
    state (checkpoints keep it) replays the same batches on ``--resume``."""

    def sample(self, n: int, frac: float = 1.0) -> RayBatch:
        """The batch of ``n`` rays (a method's own batcher may read ``n`` as its budget) at ``frac``
        (in [0, 1]) of the training budget."""
        raise NotImplementedError

    def observe(self, batch: RayBatch, out: dict) -> None:
        """What the step rendered for ``batch`` (``render_batch``'s dict; the trainer calls this after a
        step that was not rolled back): a batcher that adapts its draws learns from it. By default nothing."""


class RayBatcher(Batcher):
    """Random ray batches over every pixel of a (train) split; images stay uint8 on the CPU.

    ``sample(n, frac)`` returns one ``RayBatch`` of ``n`` rays drawn uniformly over every pixel (or by
    their running error: ``options.sampling``), each through its pixel's centre or at an offset drawn
    from ``options.footprint``.

    Args:
        split: the ``Split`` to draw pixels from (uniformly over all its views' pixels).
        background: a ``train --background`` mode other than ``auto`` (see ``nerf_core.data.backgrounds``):
            "white", "black", "random", "white-then-random" or "environment" (ground truth on white;
            the model's learned world replaces the colour).
        gen: a CPU ``torch.Generator`` that draws every random number (pixels, random colours), so a
            saved generator state replays the same batches.
        device: where the batches go.
        options: the run's ``BatchOptions`` (the footprint, depth targets, sampling and alpha).
    """

    def __init__(self, split: Split, background: str, gen: torch.Generator, device: torch.device,
                 options: BatchOptions = BatchOptions()):
        arguments.instance("RayBatcher", "split", split, Split, "a nerf_core.Split (Dataset.split('train'))")
        arguments.choice("RayBatcher", "background", background, TRAINING_BACKGROUNDS)
        arguments.instance("RayBatcher", "gen", gen, torch.Generator, "a CPU torch.Generator")
        if gen.device.type != "cpu":
            raise ValueError(f"RayBatcher: gen must be a CPU torch.Generator, got one on {gen.device}")
        try:
            device = torch.device(device) if isinstance(device, str) else device
        except RuntimeError:
            raise ValueError(f"RayBatcher: device {device!r} is no device name ('cpu', 'cuda', 'cuda:1')") from None
        arguments.instance("RayBatcher", "device", device, torch.device, "a torch.device (or 'cpu', 'cuda')")
        if len(split) == 0 or split.images is None:
            raise ValueError("RayBatcher: split has no views with images to draw rays from")
        arguments.instance("RayBatcher", "options", options, BatchOptions, "a nerf_core BatchOptions")
        arguments.instance("RayBatcher", "options.footprint", options.footprint, PixelFilter, "a nerf_core PixelFilter")
        arguments.choice("RayBatcher", "options.sampling", options.sampling, RAY_SAMPLING)
        self.split, self.gen, self.device = split, gen, device
        self.footprint, depth = options.footprint, options.depth
        if depth is not None and tuple(depth.shape) != (len(split), split.height, split.width):
            raise ValueError(f"RayBatcher: depth must be ({len(split)}, {split.height}, {split.width}) like the "
                             f"split's images, got {tuple(depth.shape)}")
        self.depth = depth
        if options.alpha and not split.has_alpha:
            raise ValueError("RayBatcher: options.alpha needs a split whose images have an alpha channel (RGBA)")
        self.alpha = options.alpha
        self.errors = ErrorMap(len(split), split.height, split.width) if options.sampling == "error" else None
        self._tiles: Optional[torch.Tensor] = None  # the error map's tiles of the last batch drawn
        self.background = background
        self.hw = split.height * split.width
        self.total = len(split) * self.hw
        # Ground truth is composited onto white in environment mode too (the loaders' convention for the
        # few transparent pixels an opaque capture may have); the model's environment replaces ``bg``.
        self.fixed_bg = torch.tensor([0.0, 0.0, 0.0] if background == "black" else [1.0, 1.0, 1.0])

    def sample(self, n: int, frac: float = 1.0) -> RayBatch:
        """``n`` random rays at ``frac`` (in [0, 1]) of the training budget: a ``RayBatch`` of rays_o
        (n, 3), rays_d (n, 3), background (n, 3), ground-truth colour (n, 3) composited onto that
        background, the mask weight (n,) or None, and the depth and alpha (n,) that ``options`` ask for
        (else None), all on ``device``.
        """

        if self.errors is None:
            flat = torch.randint(0, self.total, (n,), generator=self.gen)
            view = flat // self.hw
            pix = flat % self.hw
            j, i = pix // self.split.width, pix % self.split.width
            importance = None
        else:
            view, j, i, self._tiles, importance = self.errors.draw(n, self.gen)
        random_bg = self.background == "random" or (
            self.background == "white-then-random" and frac >= AUTO_WHITE_FRACTION
        )
        if random_bg:
            bg = torch.rand(n, 3, generator=self.gen)
        else:
            bg = self.fixed_bg.expand(n, 3)
        rgb, alpha = self.split.pixels(view, j, i, bg)
        # drawn after the colours, so that centre rays replay the generator exactly as before
        offset = None if self.footprint.is_point else self.footprint.offsets(n, 1, gen=self.gen)[:, 0]
        rays_o, rays_d, z_per_t = rays_for_pixels(self.split.cameras, view, i, j, offset)
        weight = self.split.masks[view, j, i].float() if self.split.masks is not None else None
        if importance is not None:  # the weighted mean of the loss is then an estimate of the uniform one
            weight = importance if weight is None else weight * importance
        # planar z-depth to distance along the unit ray (0 stays 0: unknown)
        depth = None if self.depth is None else self.depth[view, j, i] / z_per_t
        d = self.device
        return RayBatch(rays_o.to(d), rays_d.to(d), bg.to(d).contiguous(), rgb.to(d),
                        None if weight is None else weight.to(d), None if depth is None else depth.to(d),
                        alpha.to(d) if self.alpha else None)

    def observe(self, batch: RayBatch, out: dict) -> None:
        """Error-weighted sampling: the squared colour error of each ray moves its tile's estimate."""
        if self.errors is None or self._tiles is None:
            return
        self.errors.update(self._tiles, (out["rgb"].detach() - batch.target).square().mean(-1))
