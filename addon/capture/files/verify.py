"""Whether a captured frame's files are the ones written: sha256 as recorded, images decode at size.

Resume (keep a frame instead of rendering it again) and ``--merge`` (accept a shard's frame) use
the same test, so a truncated PNG, an empty EXR or a file swapped for another is never taken.
A frame is a plan entry (``plan.frame_plan``): its file keys map to paths relative to the dataset.
"""
from __future__ import annotations

import hashlib
import os

import bpy
import numpy as np

from ..plan.frame_plan import FRAME_FILE_KEYS


def sha256_file(path: str) -> str | None:
    """Hex sha256 of the file at ``path``; None when there is no such file."""
    if not path or not os.path.isfile(path):
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def decodes_at(path: str, width: int, height: int) -> bool:
    """Whether Blender decodes the image at ``path`` (PNG or EXR) to ``width`` x ``height`` pixels."""
    try:
        img = bpy.data.images.load(path, check_existing=False)
    except RuntimeError:
        return False
    try:
        if tuple(img.size) != (width, height):
            return False
        return len(img.pixels) == width * height * img.channels
    except RuntimeError:
        return False
    finally:
        bpy.data.images.remove(img)


def frame_paths(fr: dict) -> dict:
    """{file key: relative path} of the files frame ``fr`` owns."""
    return {k: fr[k] for k in FRAME_FILE_KEYS if k in fr}


def files_exist(out: str, fr: dict) -> bool:
    return all(os.path.isfile(os.path.join(out, rel)) for rel in frame_paths(fr).values())


def file_hashes(out: str, fr: dict) -> dict:
    """{file key: sha256} of frame ``fr``'s files as they are now (recorded right after writing)."""
    return {k: sha256_file(os.path.join(out, rel)) for k, rel in frame_paths(fr).items()}


def frame_problem(out: str, fr: dict, recorded: dict | None, width: int, height: int) -> str | None:
    """Why frame ``fr`` cannot be kept (naming the file), or None when it is intact.

    ``recorded``: {file key: sha256} written with the frame; None for manifests from before that
    record (then only existence and decoding are checked). Images must decode at width x height.
    """
    for k, rel in frame_paths(fr).items():
        path = os.path.join(out, rel)
        if not os.path.isfile(path):
            return f"{rel} is missing"
        if recorded is not None and recorded.get(k) != sha256_file(path):
            return f"{rel} differs from the file written (sha256)"
        if k == "points_cache":
            if not _points_cache_ok(path):
                return f"{rel} is not a point cache with points, colours and normals"
        elif not decodes_at(path, width, height):
            return f"{rel} does not decode as a {width}x{height} image"
    return None


def _points_cache_ok(path: str) -> bool:
    """Caches from before point normals lack them; such a frame renders again."""
    try:
        with np.load(path) as z:
            return {"points", "colors", "normals"} <= set(z.files)
    except (OSError, ValueError, EOFError):
        return False
