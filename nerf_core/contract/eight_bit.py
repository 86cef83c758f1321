"""The one rule by which a float value in [0, 1] becomes an 8-bit level, for the render images of both
ways of rendering a run: ``nerf_core render`` (``image.io.write_png``) and the add-on's render engine,
whose colours Blender writes through its own colour management (``addon/bridge/render_client.py``).

``to_8bit``: level k = floor(255 v + 0.5) in float32, v clipped to [0, 1] (NaN -> 0); Blender's
``unit_float_to_uchar_clamp`` rounds the same way. The level changes at the half-level edges
(k + 0.5) / 255.

Blender does not receive our values as they are: the engine hands it scene-linear colour (the
inverse of the sRGB curve), premultiplied, and Blender's Standard view transform (OpenColorIO, with
fast approximate powers) encodes it back before it rounds. Measured with bpy 5.0.1 on 3.1 million
values within 0.005 levels of an edge, at alpha 1 and below: that round trip is off by at most
0.00236 levels, so values closer than that to an edge could round to the neighbouring level (1 or 2
pixels in 1200 of a render). ``clear_of_8bit_edges`` moves such values ``EDGE_MARGIN`` levels to the
side of the edge that ``to_8bit`` rounds them to: both ways then write the same bytes. A value moves
by at most ``EDGE_MARGIN`` / 255 (2e-5), far below what any 8- or 16-bit file holds.
"""
from __future__ import annotations

import numpy as np

# How far (in 8-bit levels) from a half-level edge a value is placed: twice the largest error of
# Blender's colour round trip measured (0.00236 levels), so that Blender's level is ``to_8bit``'s.
EDGE_MARGIN = 0.005


def to_8bit(values) -> np.ndarray:
    """uint8 levels of float ``values`` (any shape) in [0, 1]: floor(255 v + 0.5), clipped, NaN -> 0."""
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float32)), 0.0, 1.0)
    return (v * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)


def clear_of_8bit_edges(values, margin: float = EDGE_MARGIN) -> np.ndarray:
    """float32 ``values`` (any shape, clipped to [0, 1]) with each value that lies within ``margin``
    levels of a half-level edge moved to ``margin`` levels from it, on the side ``to_8bit`` rounds it
    to; every other value is returned unchanged. ``to_8bit`` of the result equals ``to_8bit(values)``,
    and an encoder that agrees with ``to_8bit`` to within ``margin`` levels gives the same levels."""
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float32)), 0.0, 1.0)
    k = to_8bit(v).astype(np.float64)
    x = v.astype(np.float64) * 255.0  # where the value lies, in levels; k - 0.5 <= x < k + 0.5
    low = (k > 0) & (x - (k - 0.5) < margin)  # just above the edge below k
    high = (k < 255) & ((k + 0.5) - x < margin)  # just below the edge above k
    x = np.where(low, k - 0.5 + margin, np.where(high, k + 0.5 - margin, x))
    out = np.where(low | high, (x / 255.0).astype(np.float32), v)
    return out.astype(np.float32)
