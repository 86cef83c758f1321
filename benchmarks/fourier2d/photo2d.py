"""One real photograph as a 2D fitting target: a crop of one of Blender's studio-light HDRIs.

Blender ships eight equirectangular HDR photographs (1024 x 512, linear radiance) under
``<datafiles>/studiolights/world/*.exr``. This module finds them *without importing bpy*
(nerf_core never imports bpy: it locates the installed ``bpy`` package on disk instead; callers
that run inside Blender pass ``bpy.utils.system_resource('DATAFILES')``), reads one with OpenEXR,
box-downscales a crop in linear radiance and tone-maps it to display values in [0, 1].

:func:`synthetic_photo` is the deterministic stand-in for machines without bpy (edges, texture and
smooth shading); anything that uses it must say so.
"""
from __future__ import annotations

import glob
import importlib.util
import math
import os
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

STUDIOLIGHTS_SUBDIR = os.path.join("studiolights", "world")
# forest.exr, rows 250-378 and columns 700-828: a wooden fence, rocks and leaves, detail at every
# scale (picked by eye among all eight HDRIs; the sky-heavy crops are mostly smooth). 128 px at
# full resolution: downscaling a larger crop packs in detail finer than half the training grid's
# rate, which no interpolator can recover, and 4x the pixels costs 4x the CPU time.
DEFAULT_HDRI = "forest.exr"
DEFAULT_CROP = (250, 700, 128)  # (top row, left column, side) in the HDRI's pixels


class PhotoError(Exception):
    """No HDRI where one was looked for, or a crop that does not fit; the message names the path."""


@dataclass
class Photo:
    """A tone-mapped image (h, w, 3) float32 in [0, 1] and where it came from (for reports)."""

    image: np.ndarray
    source: str  # the EXR's path, or "synthetic"
    crop: Optional[tuple]  # (top, left, side) in the source's pixels; None for synthetic
    downscale: int
    tonemap: str

    @property
    def synthetic(self) -> bool:
        return self.source == "synthetic"


def bpy_datafiles_candidates() -> List[str]:
    """``datafiles`` folders inside the installed ``bpy`` package (found on disk, bpy is not imported)."""
    try:
        spec = importlib.util.find_spec("bpy")
    except (ImportError, ValueError):
        return []
    roots = list(spec.submodule_search_locations or []) if spec else []
    if spec and spec.origin and not roots:
        roots = [os.path.dirname(spec.origin)]
    found = []
    for root in roots:
        # The PyPI wheel keeps them at bpy/<major.minor>/datafiles; newest version folder first.
        found += sorted(glob.glob(os.path.join(root, "*", "datafiles")), reverse=True)
    return found


def find_hdri(name: str = DEFAULT_HDRI, datafiles: Optional[str] = None) -> str:
    """Path of studio-light HDRI ``name``; PhotoError naming every folder searched when absent.

    ``datafiles``: Blender's DATAFILES folder when the caller has bpy (``bpy.utils.system_resource``);
    otherwise the installed bpy package is searched.
    """
    folders = [datafiles] if datafiles else bpy_datafiles_candidates()
    searched = []
    for folder in folders:
        world = os.path.join(folder, STUDIOLIGHTS_SUBDIR)
        path = os.path.join(world, name)
        if os.path.isfile(path):
            return path
        searched.append(world)
    where = ", ".join(searched) if searched else "no bpy package is installed for this Python"
    raise PhotoError(f"studio-light HDRI {name!r} not found (searched: {where}); install bpy==5.0.1 "
                     "(pip install 'nerf-blender[blender]') or pass --hdri PATH to an EXR")


def tonemap(radiance: np.ndarray) -> np.ndarray:
    """Linear radiance (..., 3) -> display values in [0, 1]: Reinhard x/(1+x), then gamma 1/2.2.

    Reinhard keeps the bright sky from clipping flat; the gamma spreads the shadows the way a display
    expects, so PSNR weighs dark and bright detail about as the eye does.
    """
    x = np.maximum(np.nan_to_num(radiance, nan=0.0, posinf=0.0), 0.0)
    return np.clip(x / (1.0 + x), 0.0, 1.0) ** (1.0 / 2.2)


def box_downscale(img: np.ndarray, factor: int) -> np.ndarray:
    """(h, w, c) -> (h // factor, w // factor, c), the mean of each factor x factor block."""
    if factor == 1:
        return img
    h, w = img.shape[0] // factor * factor, img.shape[1] // factor * factor
    blocks = img[:h, :w].reshape(h // factor, factor, w // factor, factor, -1)
    return blocks.mean(axis=(1, 3))


def load_photo(path: str, crop: Sequence[int] = DEFAULT_CROP, downscale: int = 1) -> Photo:
    """Crop ``(top, left, side)`` of the EXR at ``path``, box-downscaled by ``downscale`` in linear
    radiance (averaging light, as a larger sensor pixel would), then tone-mapped.

    Returns a Photo whose image is (side // downscale, side // downscale, 3) float32 in [0, 1].
    """
    from nerf_core.errors import ImageReadError
    from nerf_core.image.io import read_exr_rgba

    try:
        rgb = read_exr_rgba(path)[..., :3]
    except ImageReadError as exc:
        raise PhotoError(str(exc)) from exc
    top, left, side = (int(v) for v in crop)
    h, w = rgb.shape[:2]
    if top < 0 or left < 0 or side < 1 or top + side > h or left + side > w:
        raise PhotoError(f"{path}: crop (top {top}, left {left}, side {side}) does not fit the {w} x {h} image")
    if downscale < 1 or side % downscale:
        raise PhotoError(f"{path}: crop side {side} is not a multiple of downscale {downscale}")
    img = tonemap(box_downscale(rgb[top:top + side, left:left + side], downscale)).astype(np.float32)
    return Photo(img, source=str(path), crop=(top, left, side), downscale=downscale, tonemap="reinhard+gamma2.2")


def synthetic_photo(n: int = 64) -> Photo:
    """Deterministic stand-in (n, n, 3) in [0, 1] with hard edges, fine texture and smooth shading.

    A disc and a rotated bar (edges at all angles), value noise at two scales (texture, seeded),
    over a smooth colour gradient: the same kinds of content as the forest crop.
    """
    ys, xs = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")
    rng = np.random.default_rng(0)

    def value_noise(cells: int) -> np.ndarray:
        grid = rng.random((cells + 1, cells + 1, 3))
        gy, gx = ys * cells, xs * cells
        i, j = np.minimum(gy.astype(int), cells - 1), np.minimum(gx.astype(int), cells - 1)
        fy, fx = (gy - i)[..., None], (gx - j)[..., None]
        top = grid[i, j] * (1 - fx) + grid[i, j + 1] * fx
        bottom = grid[i + 1, j] * (1 - fx) + grid[i + 1, j + 1] * fx
        return top * (1 - fy) + bottom * fy

    img = 0.35 + 0.3 * np.stack([xs, ys, 1 - xs], -1)
    img += 0.25 * (value_noise(max(2, n // 3)) - 0.5) + 0.15 * (value_noise(max(2, n // 8)) - 0.5)
    disc = np.hypot(xs - 0.35, ys - 0.4) < 0.22
    img[disc] = 0.85 * img[disc] + 0.15 * np.array([1.0, 0.9, 0.2])
    ang = math.radians(30)
    u = (xs - 0.65) * math.cos(ang) + (ys - 0.6) * math.sin(ang)
    v = -(xs - 0.65) * math.sin(ang) + (ys - 0.6) * math.cos(ang)
    bar = (abs(u) < 0.3) & (abs(v) < 0.06)
    img[bar] = 0.1 + 0.2 * img[bar]
    return Photo(np.clip(img, 0, 1).astype(np.float32), source="synthetic", crop=None, downscale=1, tonemap="none")
