"""The ``pixel_filter`` field of a dataset: the film filter the images were rendered through.

``{"type": "BLACKMAN_HARRIS" | "GAUSSIAN" | "BOX", "width": pixels}``, or ``{"type": "NONE"}`` (one ray a
pixel); ``"downscale": f`` when the images were box-filtered by the integer f after rendering. The
capture writes it (``film_filter_field``, from Cycles' Film > Pixel Filter, or EEVEE's and Workbench's
Filter Size, which are Blackman-Harris); a dataset without it is read as Blender's default, which is
also what the original NeRF synthetic scenes were rendered with. ``nerf_core.image.pixel_filter`` samples it.
Standard library only: the add-on reads these rules without torch.
"""
from __future__ import annotations

from typing import Optional

from .numbers import is_number, is_whole

FILTER_KINDS = ("BLACKMAN_HARRIS", "GAUSSIAN", "BOX", "NONE")
DEFAULT_FILTER_KIND, DEFAULT_FILTER_WIDTH = "BLACKMAN_HARRIS", 1.5  # Blender's defaults, Cycles and EEVEE alike
MIN_FILTER_WIDTH, MAX_FILTER_WIDTH = 0.01, 10.0  # Blender's own range for Cycles' filter width (pixels)


def film_filter_field(kind: str, width: Optional[float] = None, downscale: int = 1) -> dict:
    """The JSON field for a filter (the type upper-case, the width rounded to 6 digits)."""
    kind = kind.upper()
    if kind == "NONE":
        return {"type": kind}
    out = {"type": kind, "width": round(float(DEFAULT_FILTER_WIDTH if width is None else width), 6)}
    if downscale > 1:
        out["downscale"] = int(downscale)
    return out


def parse_film_filter(value, where: str) -> tuple[str, float, int]:
    """(type, width in pixels, downscale) of a ``pixel_filter`` field; None gives Blender's default.
    Raises ValueError naming ``where`` and the field when it is malformed."""
    if value is None:
        return DEFAULT_FILTER_KIND, DEFAULT_FILTER_WIDTH, 1
    if not isinstance(value, dict):
        raise ValueError(f"{where}: field 'pixel_filter' must be an object like "
                         f'{{"type": "BLACKMAN_HARRIS", "width": 1.5}}, got {value!r}')
    kind = value.get("type", DEFAULT_FILTER_KIND)
    if not isinstance(kind, str) or kind.upper() not in FILTER_KINDS:
        raise ValueError(f"{where}: field 'pixel_filter.type' must be one of {', '.join(FILTER_KINDS)}, got {kind!r}")
    kind = kind.upper()
    if kind == "NONE":
        return kind, 0.0, 1
    width = value.get("width", DEFAULT_FILTER_WIDTH)
    if not is_number(width) or not MIN_FILTER_WIDTH <= float(width) <= MAX_FILTER_WIDTH:
        raise ValueError(f"{where}: field 'pixel_filter.width' must be a number of pixels from {MIN_FILTER_WIDTH:g} "
                         f"to {MAX_FILTER_WIDTH:g}, got {width!r}")
    down = value.get("downscale", 1)
    if not is_whole(down) or down < 1:
        raise ValueError(f"{where}: field 'pixel_filter.downscale' must be a whole number >= 1, got {down!r}")
    return kind, float(width), down
