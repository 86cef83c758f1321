"""The world file (``export world``'s PNG): what its text chunks say, read with the standard library.

nerf_core writes it (``nerf_core.export.world``, with Pillow); the add-on reads it inside Blender, whose
Python has no Pillow, so the reader of its ``tEXt`` chunks lives here. The pixels are an 8-bit RGB
equirectangular image in Blender's own layout (``docs/CONTRACTS.md``, "World file"), display-referred:
the colours the NeRF renders, under the capture's view transform. Its chunks:

- ``nerf_bridge.format`` = "nerf_bridge.world", ``nerf_bridge.version`` = "1";
- ``nerf_bridge.color_management``: the capture's colour management as JSON text ("{}" when unknown:
  the colours are then taken as sRGB), which the import undoes to turn them back into light.
"""
from __future__ import annotations

import json
import struct
import zlib
from typing import Dict

FORMAT, VERSION = "nerf_bridge.world", 1
FORMAT_KEY, VERSION_KEY, COLOUR_KEY = "nerf_bridge.format", "nerf_bridge.version", "nerf_bridge.color_management"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_TEXT = 1 << 20  # a text chunk longer than this is no metadata of ours


def png_text(path: str) -> Dict[str, str]:
    """The ``tEXt`` and ``zTXt`` chunks of the PNG at ``path`` as {keyword: text} (Latin-1, as the PNG
    spec has it). ValueError naming the file when it is no PNG or its chunks are cut short."""
    out: Dict[str, str] = {}
    try:
        with open(path, "rb") as fh:
            if fh.read(8) != PNG_SIGNATURE:
                raise ValueError(f"{path}: not a PNG file")
            while True:
                head = fh.read(8)
                if len(head) < 8:
                    raise ValueError(f"{path}: the PNG ends before its IEND chunk (a truncated file)")
                length, kind = struct.unpack(">I4s", head)
                if kind in (b"tEXt", b"zTXt") and length <= MAX_TEXT:
                    body = fh.read(length)
                    if len(body) < length:
                        raise ValueError(f"{path}: the PNG's {kind.decode()} chunk is cut short (a truncated file)")
                    key, _, text = body.partition(b"\0")
                    if kind == b"zTXt":
                        try:
                            text = zlib.decompress(text[1:])  # a compression-method byte, then the zlib stream
                        except zlib.error as exc:
                            raise ValueError(f"{path}: the PNG's zTXt chunk {key!r} does not decompress "
                                             f"({exc})") from None
                    out[key.decode("latin-1")] = text.decode("latin-1")
                    fh.seek(4, 1)  # its CRC
                elif kind == b"IEND":
                    return out
                else:
                    fh.seek(length + 4, 1)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror or exc})") from None


def read_world_info(path: str) -> dict:
    """{"version": int, "color_management": dict} of a world file; ValueError naming the file when it is
    not one written by ``export world`` (another PNG, a newer version, colour management that is no
    JSON object)."""
    text = png_text(path)
    if text.get(FORMAT_KEY) != FORMAT:
        raise ValueError(f"{path}: not a world file written by `export world` (no {FORMAT_KEY} = {FORMAT!r} "
                         "in its PNG text)")
    try:
        version = int(text.get(VERSION_KEY, ""))
    except ValueError:
        raise ValueError(f"{path}: its {VERSION_KEY} {text.get(VERSION_KEY)!r} is not a number") from None
    if version > VERSION:
        raise ValueError(f"{path}: world file version {version}, newer than this reader's {VERSION}; "
                         "update the add-on")
    try:
        cm = json.loads(text.get(COLOUR_KEY, "{}"))
    except ValueError:
        cm = None
    if not isinstance(cm, dict):
        raise ValueError(f"{path}: its {COLOUR_KEY} is not a JSON object")
    return {"version": version, "color_management": cm}
