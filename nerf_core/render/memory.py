"""How fast and how large a render may be: rays per second, and the memory a view needs against what
the machine has (a view too large is refused before it starts, naming its size).
"""
from __future__ import annotations

import math

from nerf_core.errors import RunError
from nerf_core.utils.memory import available_memory

# Bytes per pixel that rendering a whole view holds at once: ray origins/directions and their pixel
# grid, per-ray bounds, the chunk outputs and their concatenation, the RGBA result and its PNG bytes.
BYTES_PER_PIXEL = 160
MIN_PIXELS_CHECKED = 4096 * 4096  # views up to 16 Mpx (2.7 GB) are never refused
# The most rays a model call renders without grad (``--chunk``; fewer on a CPU, see render.frame): the
# one default of every renderer, evaluator and command.
DEFAULT_CHUNK = 8192


def render_rate(seconds: float, rays: int) -> dict:
    """The timing fields ``render`` and ``eval`` report: ``render_seconds`` (wall time spent in the model
    rendering, without start-up, model loading, image files or metrics), ``rays`` and ``rays_per_s``."""
    return {"render_seconds": seconds, "rays": int(rays), "rays_per_s": rays / seconds if seconds > 0 else None}


def check_view_memory(w: int, h: int, where: str) -> None:
    """Refuse (RunError) to render a w x h view that would not fit in memory (``utils.memory.available_memory``:
    free memory, ``ulimit -v``, a container's limit), before allocating any of it."""
    if w < 1 or h < 1:
        raise RunError(f"{where}: image size {w}x{h} px is empty; use a smaller --downscale")
    need = int(w) * int(h) * BYTES_PER_PIXEL
    have = available_memory()
    if w * h > MIN_PIXELS_CHECKED and have is not None and need > have:
        raise RunError(f"{where}: {w}x{h} px needs about {need / 1e9:.1f} GB of memory to render, more than the "
                       f"{have / 1e9:.1f} GB available; render at a lower resolution (--downscale "
                       f"{math.ceil(math.sqrt(need / max(have, 1)))} or more)")
