"""Writing files whole or not at all, and PNGs with the standard library and numpy (Blender's Python has
no Pillow): the add-on's one home for both. Standard library and numpy only, so every layer may use it
(bridge included).

A file is written under a temporary name beside it and renamed over the target, so a reader (or a
crash, or a full disk) never meets a truncated file; the temporary file is removed when writing fails.
Nothing is written through a link (nerf_core's ``utils.atomic`` holds the same rule for the library):
every temporary is a new file (``O_EXCL | O_NOFOLLOW``, a random part in its name), and a target that
is a symbolic link is refused.
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
import struct
import zlib
from typing import IO, Callable, Iterator, Optional, TextIO, Union

import numpy as np

PARTIAL_SUFFIX = ".partial"  # the temporary name's default suffix: ``<path>.partial``


def refuse_link(path: str) -> None:
    """OSError naming ``path`` when it is a symbolic link (dangling or not) or no regular file."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISLNK(mode):
        raise OSError(f"{path} is a symbolic link (to {os.readlink(path)}); nothing is written through a link")
    if not stat.S_ISREG(mode):
        raise OSError(f"{path} exists and is not a regular file")


def _open_new(tmp: str, binary: bool) -> IO:
    def opener(name: str, flags: int) -> int:  # mode "x": O_CREAT | O_EXCL; never through a link
        return os.open(name, flags | getattr(os, "O_NOFOLLOW", 0), 0o666)

    return open(tmp, "xb", opener=opener) if binary else open(tmp, "x", encoding="utf-8", opener=opener)


@contextlib.contextmanager
def partial_file(path: str, tmp: Optional[str] = None, binary: bool = True) -> Iterator[IO]:
    """Yield a new temporary file beside ``path`` (its name: ``tmp``, default ``path + ".partial"``, and a
    random part), open for writing; on a clean exit it replaces ``path``, else it is removed."""
    refuse_link(path)
    name = f"{tmp or path + PARTIAL_SUFFIX}.{secrets.token_hex(4)}"
    fh = _open_new(name, binary)
    try:
        with fh:
            yield fh
        refuse_link(path)
        os.replace(name, path)
    finally:
        if os.path.lexists(name):
            os.remove(name)


@contextlib.contextmanager
def partial_path(path: str, tmp: Optional[str] = None) -> Iterator[str]:
    """``partial_file`` for writers that take a file name (Blender's ``save_render``, OpenVDB): the name
    is reserved (created empty, exclusively), the writer replaces it, and it is renamed over ``path``."""
    refuse_link(path)
    stem, ext = os.path.splitext(tmp or path + PARTIAL_SUFFIX)
    name = f"{stem}.{secrets.token_hex(4)}{ext}"  # the extension last: writers pick the format by it
    _open_new(name, True).close()
    try:
        yield name
        if os.path.islink(name):
            raise OSError(f"{name} became a symbolic link while it was written")
        refuse_link(path)
        os.replace(name, path)
    finally:
        if os.path.lexists(name):
            os.remove(name)


def write_atomic(path: str, data: Union[bytes, str, Callable[[TextIO], None]], tmp: Optional[str] = None) -> None:
    """Write ``data`` through a new temporary file (``partial_file``; named after ``tmp``, default
    ``path + ".partial"``), then rename it to ``path``: bytes, text (UTF-8), or a function that writes
    text to the open file (``lambda fh: json.dump(obj, fh)``). On OSError the temporary file is removed
    and the error raised again."""
    with partial_file(path, tmp, binary=isinstance(data, bytes)) as fh:
        fh.write(data) if isinstance(data, (bytes, str)) else data(fh)


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
