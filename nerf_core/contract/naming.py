"""Output names of rendered views, and which views "evenly spaced" picks (standard library only).

``python -m nerf_core render`` names its files after the frames it renders; the add-on finds them by
the same rule, so both call ``output_stems``.
"""
from __future__ import annotations

import os
from typing import List, Optional, Sequence

ERRORS_DIR = "errors"  # render's error heat-maps: DIR/errors/<stem>.png


def path_stem(file_path: str) -> str:
    """``./train/r_0`` -> ``r_0``; ``images/a.png`` -> ``a`` (the basename without an image extension)."""
    base = os.path.basename(str(file_path).replace("\\", "/").rstrip("/"))
    stem, ext = os.path.splitext(base)
    return stem if ext else base


# Longest output stem: the longest file made from it ("<stem>_depth.exr", and its temporary name
# while written) stays well inside the 255 bytes most file systems allow for a name. Counted in the
# UTF-8 bytes the file system stores: 200 'é' are 120 characters cut but 240 bytes, and 84 CJK
# characters 252 bytes, which failed on the temporary name after the PNG was written.
MAX_STEM_CHARS = 120
MAX_STEM_BYTES = 120


def file_safe(stem: str) -> str:
    """``stem`` as a file name: control characters (NUL included) become '_', leading dots go (no
    hidden files, no '.' or '..'), and it is cut to ``MAX_STEM_CHARS`` characters and ``MAX_STEM_BYTES``
    bytes of UTF-8; '' when nothing is left."""
    # a lone surrogate (from a JSON "\\ud800") cannot be a file name in any encoding
    cleaned = "".join("_" if ord(c) < 32 or c == "\x7f" or 0xD800 <= ord(c) <= 0xDFFF else c for c in stem).lstrip(".")
    # cut in bytes; a character the cut splits is dropped whole
    return cleaned[:MAX_STEM_CHARS].encode("utf-8")[:MAX_STEM_BYTES].decode("utf-8", "ignore")


def frame_stem(frame, index: int) -> str:
    """A frame's own name before de-duplication: its ``name``, else the basename of ``file_path``
    (``file_safe``), else ``view_XXX`` (``XXX`` = ``index``). ``frame`` is a transforms frame (dict) or
    anything else (a bare matrix), which has no name."""
    if isinstance(frame, dict):
        for key in ("name", "file_path"):
            value = frame.get(key)
            if isinstance(value, str) and file_safe(path_stem(value)):
                return file_safe(path_stem(value))
    return f"view_{index:03d}"


def unique_stems(stems: Sequence[Optional[str]]) -> List[str]:
    """Output names that never collide, whatever the input: ``a, a, a_1`` -> ``a, a_1, a_1_1``.

    Names are compared case-insensitively (macOS and Windows file systems are), and an empty name
    becomes ``view_XXX``.
    """
    used: set = set()
    out = []
    for k, s in enumerate(stems):
        base = str(s or "") or f"view_{k:03d}"
        cand, n = base, 0
        while cand.lower() in used:
            n += 1
            cand = f"{base}_{n}"
        used.add(cand.lower())
        out.append(cand)
    return out


def output_stems(frames: Sequence) -> List[str]:
    """The names ``render`` gives the views of ``frames`` (in order): ``frame_stem`` of each, made unique."""
    return unique_stems([frame_stem(fr, k) for k, fr in enumerate(frames)])


def render_files(stem: str) -> dict:
    """The files ``render`` writes for one view, relative to its output folder: ``image`` (RGBA PNG),
    ``depth`` (EXR, channel Z) and ``error_map`` (heat-map PNG, only when ground truth exists)."""
    return {"image": f"{stem}.png", "depth": f"{stem}_depth.exr", "error_map": f"{ERRORS_DIR}/{stem}.png"}


def evenly_spaced(n_total: int, n_keep: int) -> List[int]:
    """Indices of ``min(n_keep, n_total)`` views spread evenly over ``n_total``, first and last
    included: ``round(k (n_total - 1) / (n_keep - 1))`` for k = 0 .. n_keep - 1."""
    n_total, n_keep = int(n_total), min(int(n_keep), int(n_total))
    if n_keep <= 0:
        return []
    if n_keep == 1:
        return [0]
    return sorted({round(k * (n_total - 1) / (n_keep - 1)) for k in range(n_keep)})
