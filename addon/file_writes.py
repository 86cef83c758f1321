"""Writing files whole or not at all, and PNGs with the standard library and numpy (Blender's Python has
no Pillow): the add-on's one home for both. Standard library and numpy only, so every layer may use it
(bridge included).

A file is written under a temporary name beside it and renamed over the target, so a reader (or a
crash, or a full disk) never meets a truncated file; the temporary file is removed when writing fails.
"""
from __future__ import annotations

import errno
import os
import struct
import zlib
from typing import Callable, Optional, TextIO, Union

import numpy as np

PARTIAL_SUFFIX = ".partial"  # the temporary name's default suffix: ``<path>.partial``


def write_atomic(path: str, data: Union[bytes, str, Callable[[TextIO], None]], tmp: Optional[str] = None) -> None:
    """Write ``data`` to ``tmp`` (default ``path + ".partial"``), then rename it to ``path``: bytes, text
    (UTF-8), or a function that writes text to the open file (``lambda fh: json.dump(obj, fh)``). On
    OSError the temporary file is removed and the error raised again."""
    tmp = tmp or path + PARTIAL_SUFFIX
    try:
        if isinstance(data, bytes):
            with open(tmp, "wb") as fh:
                fh.write(data)
        else:
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(data) if isinstance(data, str) else data(fh)
        os.replace(tmp, path)
    except OSError:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def png_bytes(rows: bytes, width: int, height: int, bit_depth: int, colour_type: int) -> bytes:
    """A whole PNG file of filter-prefixed scanlines ``rows`` (each row: a 0 byte, then its pixels)."""

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I",
                                                                             zlib.crc32(tag + payload) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth,
                                                              colour_type, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows, 6)) + chunk(b"IEND", b""))


def write_png(path: str, image: np.ndarray) -> None:
    """Write (h, w, 3|4) floats in [0, 1] (row 0 at the top) as an 8-bit PNG, atomically.

    A full disk never leaves a truncated PNG (OSError with errno ENOSPC names the file).
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"{path}: expected an (h, w, 3) or (h, w, 4) image, got shape {image.shape}")
    h, w, c = image.shape
    data = np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), data.reshape(h, w * c)], axis=1).tobytes()
    png = png_bytes(raw, w, h, 8, 6 if c == 4 else 2)
    try:
        write_atomic(path, png, tmp=f"{path}.tmp{os.getpid()}")
    except OSError as exc:
        if exc.errno == errno.ENOSPC:
            raise OSError(errno.ENOSPC, f"Disk full while writing {path}") from exc
        raise


def write_png_gray(path: str, image: np.ndarray) -> None:
    """Write a (h, w) uint8 or uint16 array as an 8- or 16-bit greyscale PNG, atomically."""
    bits = 16 if image.dtype == np.uint16 else 8
    image = np.ascontiguousarray(image, dtype=">u2" if bits == 16 else np.uint8)  # PNG is big-endian
    h, w = image.shape
    raw = b"".join(b"\0" + image[y].tobytes() for y in range(h))
    write_atomic(path, png_bytes(raw, w, h, bits, 0))
