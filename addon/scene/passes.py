"""Read Blender's multilayer EXR render output and write the per-pass files of a dataset.

Blender's Python has numpy but not OpenEXR, so this module carries a small EXR reader for the one
kind of file we ask Blender to write (scanline, uncompressed, half or float channels) and an EXR
writer for single-part float files. PNG masks are written by ``file_writes.write_png_gray``. Nothing here imports bpy.

Arrays are row 0 = top of the image, like the PNGs, so a pixel (column i, row j) lines up with the
ray convention in docs/CONTRACTS.md.
"""
from __future__ import annotations

import struct

import numpy as np

from ..file_writes import write_atomic

EXR_MAGIC = 20000630
_PIXEL_DTYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}
# Blender writes "no surface" as this huge depth; CONTRACTS says inf.
BACKGROUND_DEPTH = 1e9


class PassError(RuntimeError):
    """A render pass could not be read or written; the message names the file."""


def _read_attr_value(kind: str, data: bytes):
    if kind == "chlist":
        channels = []
        pos = 0
        while data[pos] != 0:
            end = data.index(b"\0", pos)
            name = data[pos:end].decode("utf-8")
            pixel_type, _plinear, xs, ys = struct.unpack_from("<iB3xii", data, end + 1)
            channels.append((name, pixel_type, xs, ys))
            pos = end + 1 + 16
        return channels
    if kind == "compression":
        return data[0]
    if kind == "box2i":
        return struct.unpack("<4i", data)
    return data


def read_exr_channels(path: str) -> dict[str, np.ndarray]:
    """All channels of an uncompressed scanline EXR as float32 arrays (h, w), keyed by full name.

    Multilayer names look like ``ViewLayer.Depth.Z``. Raises PassError naming ``path`` for anything
    this reader does not handle (compression, tiles, multi-part, subsampling).
    """
    try:
        with open(path, "rb") as fh:
            blob = fh.read()
    except OSError as exc:
        raise PassError(f"{path}: cannot read render pass file: {exc}") from exc
    if len(blob) < 8 or struct.unpack_from("<i", blob, 0)[0] != EXR_MAGIC:
        raise PassError(f"{path}: not an OpenEXR file")
    flags = struct.unpack_from("<I", blob, 4)[0]
    if flags & (0x200 | 0x800 | 0x1000):
        raise PassError(f"{path}: tiled, deep or multi-part EXR is not supported here")
    pos = 8
    header = {}
    while blob[pos] != 0:
        end = blob.index(b"\0", pos)
        name = blob[pos:end].decode("utf-8")
        end2 = blob.index(b"\0", end + 1)
        kind = blob[end + 1:end2].decode("utf-8")
        size = struct.unpack_from("<i", blob, end2 + 1)[0]
        start = end2 + 5
        header[name] = _read_attr_value(kind, blob[start:start + size])
        pos = start + size
    pos += 1
    if header.get("compression", 0) != 0:
        raise PassError(f"{path}: compressed EXR (codec {header['compression']}); expected uncompressed")
    xmin, ymin, xmax, ymax = header["dataWindow"]
    w, h = xmax - xmin + 1, ymax - ymin + 1
    channels = sorted(header["channels"], key=lambda c: c[0].encode("utf-8"))
    if any(c[2] != 1 or c[3] != 1 for c in channels):
        raise PassError(f"{path}: subsampled channels are not supported")
    offsets = np.frombuffer(blob, dtype="<u8", count=h, offset=pos)
    out = {name: np.empty((h, w), np.float32) for name, *_ in channels}
    for row, off in enumerate(offsets):
        off = int(off)
        y, _size = struct.unpack_from("<ii", blob, off)
        cursor = off + 8
        for name, pixel_type, _xs, _ys in channels:
            dtype = _PIXEL_DTYPES[pixel_type]
            out[name][y - ymin] = np.frombuffer(blob, dtype=dtype, count=w, offset=cursor)
            cursor += w * dtype.itemsize
    return out


def find_pass(channels: dict[str, np.ndarray], pass_name: str, components: str) -> np.ndarray | None:
    """Stack the channels of one pass, e.g. ``("Depth", "Z")`` -> (h, w, 1); None when absent.

    Matches ``<layer>.<pass>.<component>`` for any view layer name, so renamed layers still work.
    """
    found = []
    for comp in components:
        suffix = f".{pass_name}.{comp}"
        match = [k for k in channels if k.endswith(suffix)]
        if not match:
            return None
        found.append(channels[match[0]])
    return np.stack(found, axis=-1)


def write_exr(path: str, channels: dict[str, np.ndarray]) -> None:
    """Write float32 (h, w) arrays as one uncompressed scanline EXR, atomically (``{"Z": depth}``)."""
    names = sorted(channels, key=lambda n: n.encode("utf-8"))
    h, w = channels[names[0]].shape

    def attr(name: str, kind: str, value: bytes) -> bytes:
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in names) + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = (
        struct.pack("<iI", EXR_MAGIC, 2)
        + attr("channels", "chlist", chlist)
        + attr("compression", "compression", b"\0")
        + attr("dataWindow", "box2i", box)
        + attr("displayWindow", "box2i", box)
        + attr("lineOrder", "lineOrder", b"\0")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    line_bytes = 4 * w * len(names)
    first = len(header) + 8 * h
    offsets = np.arange(h, dtype="<u8") * (8 + line_bytes) + first
    rows = np.stack([np.ascontiguousarray(channels[n], dtype="<f4") for n in names], axis=1)  # (h, c, w)
    body = bytearray()
    for y in range(h):
        body += struct.pack("<ii", y, line_bytes)
        body += rows[y].tobytes()
    write_atomic(path, header + offsets.tobytes() + bytes(body))


# The most a 16-bit depth PNG holds, in millimetres: nerfstudio reads them as integers times its
# depth_unit_scale_factor, a command-line option that is 1e-3 unless the user sets it.
MAX_DEPTH_MM = 65535


def depth_millimetres(depth: np.ndarray) -> np.ndarray:
    """(h, w) float depth in scene units -> uint16 millimetres, 0 where there is no depth or it is
    beyond 65.535 units (what 16 bits hold): nerfstudio's depth PNG, read as ``depth > 0`` valid."""
    mm = np.where(np.isfinite(depth), np.round(depth.astype(np.float64) * 1000.0), 0.0)
    return np.where((mm > 0) & (mm <= MAX_DEPTH_MM), mm, 0).astype(np.uint16)


def planar_depth(depth: np.ndarray, clip_end: float | None = None) -> np.ndarray:
    """(h, w) Blender Z pass -> float32 planar depth with inf where no surface was hit.

    Cycles writes 1e10 where a ray hits nothing; EEVEE writes the far clipping plane there (about
    ``clip_end``, a little more off the axis), so with the camera's ``clip_end`` depths from 99.9 % of
    it on count as background too: nothing beyond the clipping plane renders anyway.
    """
    depth = depth.astype(np.float32)
    far = BACKGROUND_DEPTH if clip_end is None else min(BACKGROUND_DEPTH, 0.999 * float(clip_end))
    return np.where((depth > 0) & (depth < far), depth, np.float32(np.inf)).astype(np.float32)
