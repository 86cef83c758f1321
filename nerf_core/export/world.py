"""The learned world of a run (``fields.environment.EnvironmentMap``) as an equirectangular PNG that a
Blender World shows as the NeRF does (format: ``contract.world_file``, docs/CONTRACTS.md "World file").

An opaque capture's run learns what lies behind its scene box as light from infinity: the NeRF's render
shows it wherever the box is transparent. A volume or a mesh covers the box only, so without the world a
Cycles render of either shows the scene's own world, or nothing, where the NeRF shows its learned sky,
floor or room (docs/BENCHMARKS.md, "The volume in Cycles": 4 dB on the HDRI scene without it).

Layout: Blender's equirectangular mapping (Cycles' ``direction_to_equirectangular``), which differs from
the environment's own texture (``fields.environment.directions_to_uv``) by a mirror in longitude. Pixel
(row i from the top, column j) of a ``w`` x ``h`` image looks along the direction of

    u = (j + 0.5) / w,  v = (i + 0.5) / h:  longitude atan2(y, x) = pi (1 - 2 u),  polar angle acos(z) = pi v

(+Z up, row 0 straight up; measured in Cycles 5.0: +X at u = 0.5, +Y at u = 0.25, -Y at u = 0.75). Each
pixel is the environment looked up along its centre's direction, so at the environment's own width the
pixel centres are the finest texels' centres, mirrored.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from PIL import Image, PngImagePlugin

from nerf_core.contract import world_file
from nerf_core.contract.eight_bit import to_8bit
from nerf_core.utils.atomic import atomic_file

MAX_WIDTH = 8192  # a Blender image side far past any learned texture (1024 at most): 96 MB of RGB


def blender_directions(width: int) -> torch.Tensor:
    """(h, w, 3) float32 unit directions of the pixel centres of a ``width`` x ``width // 2`` image in
    Blender's equirectangular layout (the module docstring), row 0 at the top."""
    w, h = int(width), max(1, int(width) // 2)
    u = (torch.arange(w, dtype=torch.float64) + 0.5) / w
    v = (torch.arange(h, dtype=torch.float64) + 0.5) / h
    theta = (v * math.pi)[:, None].expand(h, w)
    phi = (math.pi * (1.0 - 2.0 * u))[None, :].expand(h, w)
    dirs = torch.stack([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi), torch.cos(theta)], -1)
    return dirs.float()


@torch.no_grad()
def world_image(environment, width: Optional[int] = None) -> np.ndarray:
    """(h, w, 3) uint8: ``environment`` (an ``EnvironmentMap``, colours in [0, 1]) at each pixel of
    ``blender_directions(width)`` (default: its finest texture's width), as ``contract.eight_bit`` rounds
    every render of a run."""
    w = int(width or environment.options["width"])
    if w < 2 or w > MAX_WIDTH:
        raise ValueError(f"--width {w}: must lie in [2, {MAX_WIDTH}]")
    device = next(environment.parameters()).device
    dirs = blender_directions(w)
    rows = [environment(d.reshape(-1, 3).to(device)).cpu() for d in dirs.split(max(1, (1 << 20) // w))]
    return to_8bit(torch.cat(rows).reshape(dirs.shape).numpy())


def write_world(path: Path | str, image: np.ndarray, colour_management: Optional[dict]) -> None:
    """Write ``image`` (h, w, 3) uint8 as the world PNG at ``path``, atomically, with its text chunks
    (``contract.world_file``): the format, its version and ``colour_management`` ({} when unknown)."""
    info = PngImagePlugin.PngInfo()
    info.add_text(world_file.FORMAT_KEY, world_file.FORMAT)
    info.add_text(world_file.VERSION_KEY, str(world_file.VERSION))
    info.add_text(world_file.COLOUR_KEY, json.dumps(colour_management or {}, sort_keys=True))
    with atomic_file(path) as fh:
        Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), "RGB").save(fh, format="PNG", pnginfo=info)


def read_world(path: Path | str) -> tuple[np.ndarray, dict]:
    """(image (h, w, 3) uint8, info) of a world file (``contract.world_file.read_world_info``'s info);
    ValueError naming the file when it is not one."""
    info = world_file.read_world_info(str(path))
    try:
        with Image.open(path) as im:
            image = np.asarray(im.convert("RGB"))
    except OSError as exc:
        raise ValueError(f"{path}: its image cannot be read ({exc})") from None
    return image, info
