"""A loaded dataset in memory: ``Split`` (one split's cameras, pixels and extras) and ``Dataset``
(the splits, the scene box and the scene's fields).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.transforms import FrameInfo
from nerf_core.image.metrics import composite
from nerf_core.image.pixel_filter import PixelFilter

# An opaque image whose brightest value is at most this (of 1) shows no light: 1 of 255 in an 8-bit PNG.
BLACK_LEVEL = 1.5 / 255


@dataclass
class Split:
    """The images and cameras of one split (n views of one size h x w), as ``load_dataset`` reads them.

    ``image(view, background)`` gives one view's ground truth composited onto a background, and
    ``pixels(...)`` a batch of pixels of it.

    Attributes:
        name: "train", "val" or "test".
        cameras: ``Cameras`` of the n views (``c2w`` (n, 4, 4), intrinsics (n,)).
        images: (n, h, w, c) uint8 (PNG) or float32 (EXR), c = 3 or 4 (straight, not premultiplied, alpha).
        frames: the n parsed frames (``FrameInfo``: file names, (4, 4) float64 ``c2w``), in file order.
        depth: (n, h, w) float32 planar z-depth in scene units, 0 where unknown; or None.
        normals: (n, h, w, 3) float32 or None.
        masks: (n, h, w) bool, False = ignore the pixel; or None.
    """

    name: str
    cameras: Cameras
    images: torch.Tensor
    frames: List[FrameInfo]
    depth: Optional[torch.Tensor] = None
    normals: Optional[torch.Tensor] = None
    masks: Optional[torch.Tensor] = None

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def stems(self) -> List[str]:
        return [f.stem for f in self.frames]

    @property
    def has_alpha(self) -> bool:
        return self.images.shape[-1] == 4

    def shown(self) -> torch.Tensor:
        """(n, h, w) bool: pixels that show something (alpha above 0; every pixel without alpha)."""
        return self.images[..., 3] > 0 if self.has_alpha else torch.ones(self.images.shape[:3], dtype=torch.bool)

    def shows_nothing(self) -> bool:
        """True when every image is transparent everywhere (alpha 0): no pixel shows the scene."""
        return len(self.frames) > 0 and not bool(self.shown().any())

    def is_black(self) -> bool:
        """True when every image is opaque (no alpha, or alpha 1 everywhere) and black everywhere (no
        value above ``BLACK_LEVEL``): the cameras saw no light. Also a cut-out's transparent pixels
        count as showing something (empty space)."""
        if not len(self.frames):
            return False
        full = 255 if self.images.dtype == torch.uint8 else 1.0
        # the colour maximum first: it settles almost every dataset without a mask the size of the split
        if float(self.images[..., :3].max()) / full > BLACK_LEVEL:
            return False
        return not self.has_alpha or bool((self.images[..., 3] >= full).all())

    def masks_select_nothing(self) -> bool:
        """True when there are masks and they mark no pixel that shows something (transparent pixels
        count whatever the masks say, ``load_split``): every loss term would be empty background."""
        if self.masks is None:
            return False
        return not bool((self.masks & self.shown()).any())

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])

    def _to_float(self, px: torch.Tensor) -> torch.Tensor:
        return px.float() / 255.0 if px.dtype == torch.uint8 else px.float()

    def pixels(self, view: torch.Tensor, j: torch.Tensor, i: torch.Tensor, background: torch.Tensor):
        """Ground truth for a batch of pixels.

        Args:
            view, j, i: (m,) int64 view, row, column.
            background: (m, 3) or (3,) colour composited behind the alpha.
        Returns:
            rgb (m, 3) float32 composited, alpha (m,) float32 (ones without an alpha channel).
        """
        px = self._to_float(self.images[view, j, i])
        rgb = px[:, :3]
        if not self.has_alpha:
            return rgb, torch.ones_like(rgb[:, 0])
        alpha = px[:, 3]
        bg = background.to(rgb).expand_as(rgb)
        return rgb * alpha[:, None] + bg * (1.0 - alpha[:, None]), alpha

    def image(self, view: int, background) -> tuple[torch.Tensor, torch.Tensor]:
        """Full image ``view``: rgb (h, w, 3) composited onto ``background`` (3,), alpha (h, w)."""
        px = self._to_float(self.images[view])
        if not self.has_alpha:
            return px[..., :3], torch.ones_like(px[..., 0])
        return composite(px, background), px[..., 3]


@dataclass
class Dataset:
    """A loaded dataset: its splits, the scene box and what the transforms files say about the scene.

    ``split(name)`` returns a non-empty split or raises ``DatasetError`` saying why there is none.

    Attributes:
        root: the dataset folder.
        layout: "synthetic" (``transforms_{train,val,test}.json``), "nerfstudio" (``transforms.json``) or
            "colmap" (``images/`` and ``sparse/0``: ``contract.colmap_dataset``).
        splits: {"train", "val", "test"} -> ``Split`` (empty for splits not loaded).
        aabb: (2, 3) float32 scene box, [min corner, max corner] in scene units.
        aabb_source: "dataset (FILE)" when a transforms file gives ``aabb``, else a sentence saying how
            it was estimated.
        near, far: the dataset's ray bounds in scene units, or None.
        notes: human-readable remarks of the loader (estimated box, held-out frames, ...).
        film_transparent: what the transforms files declare (captured on a transparent film); None
            when they do not say.
        world: the capture's description of the Blender world, when recorded; else None.
        cameras_inside: most train cameras stand inside the scene box (an interior).
        beyond_box: objects the capture says reach beyond ``aabb`` (a floor).
        pixel_filter: what one pixel of the images averages over (``nerf_core.image.pixel_filter``),
            at the loaded resolution; ``load_dataset`` gives Blender's default when the files do not
            say (None only in a ``Dataset`` built by hand).
    """

    root: Path
    layout: str  # "synthetic", "nerfstudio" or "colmap"
    splits: Dict[str, Split]
    aabb: torch.Tensor  # (2, 3)
    aabb_source: str  # "dataset" or a sentence saying how it was estimated
    near: Optional[float] = None
    far: Optional[float] = None
    notes: List[str] = field(default_factory=list)
    film_transparent: Optional[bool] = None  # what the transforms files declare; None when they do not
    world: Optional[dict] = None  # the capture's description of the Blender world, when recorded
    cameras_inside: bool = False  # most train cameras stand inside the scene box: an interior
    beyond_box: List[str] = field(default_factory=list)  # objects the capture says reach beyond ``aabb`` (a floor)
    # What one pixel of the images averages over (``nerf_core.image.pixel_filter``), at the loaded resolution.
    pixel_filter: Optional[PixelFilter] = None

    def split(self, name: str) -> Split:
        if name not in self.splits or len(self.splits[name]) == 0:
            have = ", ".join(k for k, v in self.splits.items() if len(v)) or "none loaded"
            # the loader's note says why a split is empty (cameras only, no held-out list): say it here
            why = [n for n in self.notes if f"_{name}.json" in n or "nothing is evaluated" in n]
            raise DatasetError(f"{self.root}: the dataset has no {name!r} views with images"
                               + (f": {why[0]}" if why else f" (splits with views: {have})"))
        return self.splits[name]

    def held_out_split(self, preferred: Sequence[str] = ("test", "val")) -> Optional[str]:
        """The first non-empty split of ``preferred`` (never train), or None."""
        for name in preferred:
            if name in self.splits and len(self.splits[name]):
                return name
        return None
