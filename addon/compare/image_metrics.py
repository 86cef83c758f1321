"""Writing PNGs from inside Blender with the standard library and numpy (Blender's Python has no Pillow).

The comparison metrics (PSNR, SSIM) and error heat-maps are not computed here any more:
``nerf_core render`` computes them with ``nerf_core.metrics`` (the functions behind ``eval``) and
lists them in ``renders.json``, which the Compare gallery reads.
"""
from __future__ import annotations

import errno
import os
import struct
import zlib

import numpy as np


def write_png(path: str, image: np.ndarray) -> None:
    """Write (h, w, 3|4) floats in [0, 1] (row 0 at the top) as an 8-bit PNG, standard library only.

    Written to a temporary file first, so a full disk never leaves a truncated PNG (OSError with
    errno ENOSPC names the file).
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"{path}: expected an (h, w, 3) or (h, w, 4) image, got shape {image.shape}")
    h, w, c = image.shape
    data = np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), data.reshape(h, w * c)], axis=1).tobytes()

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload))

    colour_type = 6 if c == 4 else 2
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, "wb") as fh:
            fh.write(png)
        os.replace(tmp, path)
    except OSError as exc:
        if os.path.exists(tmp):
            os.remove(tmp)
        if exc.errno == errno.ENOSPC:
            raise OSError(errno.ENOSPC, f"Disk full while writing {path}") from exc
        raise
