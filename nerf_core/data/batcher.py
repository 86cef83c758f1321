"""Training batches: what a step trains on (``RayBatch``), the type that draws them (``Batcher``,
which a method chooses with ``RadianceModel.make_batcher``) and the default, ``RayBatcher``: random
rays (and their target colours) from a ``Split``.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import torch

from nerf_core.cameras.rays import rays_for_pixels
from nerf_core.data.backgrounds import AUTO_WHITE_FRACTION, TRAINING_BACKGROUNDS
from nerf_core.data.split import Split
from nerf_core.utils import arguments


class RayBatch(NamedTuple):
    """One training step's rays and what they should render, all on the training device.

    Attributes:
        rays_o: (n, 3) float32 origins in world space.
        rays_d: (n, 3) float32 unit directions.
        background: (n, 3) float32 colour behind each ray (the ground truth was composited onto it).
        target: (n, 3) float32 ground-truth colour.
        weight: (n,) float32 per-ray weight of the colour error (1 use, 0 ignore), or None (no masks).
    """

    rays_o: torch.Tensor
    rays_d: torch.Tensor
    background: torch.Tensor
    target: torch.Tensor
    weight: Optional[torch.Tensor]


class Batcher:
    """What the trainer draws each step's rays from (``RadianceModel.make_batcher`` makes one).

    A batcher draws every random number from the generator it was given, so that a saved generator
    state (checkpoints keep it) replays the same batches on ``--resume``."""

    def sample(self, n: int, frac: float = 1.0) -> RayBatch:
        """The batch of ``n`` rays (a method's own batcher may read ``n`` as its budget) at ``frac``
        (in [0, 1]) of the training budget."""
        raise NotImplementedError


class RayBatcher(Batcher):
    """Random ray batches over every pixel of a (train) split; images stay uint8 on the CPU.

    ``sample(n, frac)`` returns one ``RayBatch`` of ``n`` rays drawn uniformly over every pixel, each
    through its pixel's centre.

    Args:
        split: the ``Split`` to draw pixels from (uniformly over all its views' pixels).
        background: a ``train --background`` mode other than ``auto`` (see ``nerf_core.data.backgrounds``):
            "white", "black", "random", "white-then-random" or "environment" (ground truth on white;
            the model's learned world replaces the colour).
        gen: a CPU ``torch.Generator`` that draws every random number (pixels, random colours), so a
            saved generator state replays the same batches.
        device: where the batches go.
    """

    def __init__(self, split: Split, background: str, gen: torch.Generator, device: torch.device):
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
        self.split, self.gen, self.device = split, gen, device
        self.background = background
        self.hw = split.height * split.width
        self.total = len(split) * self.hw
        # Ground truth is composited onto white in environment mode too (the loaders' convention for the
        # few transparent pixels an opaque capture may have); the model's environment replaces ``bg``.
        self.fixed_bg = torch.tensor([0.0, 0.0, 0.0] if background == "black" else [1.0, 1.0, 1.0])

    def sample(self, n: int, frac: float = 1.0) -> RayBatch:
        """``n`` random rays at ``frac`` (in [0, 1]) of the training budget: a ``RayBatch`` of rays_o
        (n, 3), rays_d (n, 3), background (n, 3), ground-truth colour (n, 3) composited onto that
        background, and the mask weight (n,) or None, all on ``device``.
        """

        flat = torch.randint(0, self.total, (n,), generator=self.gen)
        view = flat // self.hw
        pix = flat % self.hw
        j, i = pix // self.split.width, pix % self.split.width
        random_bg = self.background == "random" or (
            self.background == "white-then-random" and frac >= AUTO_WHITE_FRACTION
        )
        if random_bg:
            bg = torch.rand(n, 3, generator=self.gen)
        else:
            bg = self.fixed_bg.expand(n, 3)
        rgb, _ = self.split.pixels(view, j, i, bg)
        rays_o, rays_d, _ = rays_for_pixels(self.split.cameras, view, i, j)
        weight = self.split.masks[view, j, i].float() if self.split.masks is not None else None
        d = self.device
        return RayBatch(rays_o.to(d), rays_d.to(d), bg.to(d).contiguous(), rgb.to(d),
                        None if weight is None else weight.to(d))
