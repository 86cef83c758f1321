"""Display colours (what a NeRF learnt from a capture's images) back to Blender's scene-linear light,
through the inverse of the view transform the capture was rendered with, by Blender's own OpenColorIO.

Why: a capture rendered under AgX (Blender's default) stores AgX's display values, and a NeRF learns
those. Undoing them with the sRGB curve (right only for the Standard view transform) and showing the
result through AgX again darkens and desaturates it: on the multi demo scene the imported volume agreed
with the NeRF's render at 22.8 dB that way.

How: Blender has no call that converts an array of colours, but it converts a float image to scene
linear as it loads it, from the colour space the image is tagged with. Each view transform has a
display colour space that is its inverse (``INVERSE_SPACE``): the colours are written to a temporary
OpenEXR file untouched ("Non-Color"), loaded back tagged with that space, and read out.
Blender's view: ``display = view(linear * 2^exposure) ^ (1 / gamma)``, so the inverse is
``linear = view^-1(display ^ gamma) / 2^exposure``. A look is not undone (a note says so).
"""
from __future__ import annotations

import os
import tempfile
from typing import Callable, Optional

import bpy
import numpy as np

from . import volume_files

# view transform (sRGB display) -> the colour space whose conversion to scene linear undoes it
INVERSE_SPACE = {"Standard": "sRGB", "AgX": "AgX Base sRGB", "Filmic": "Filmic sRGB",
                 "Khronos PBR Neutral": "Khronos PBR Neutral sRGB", "ACES 1.3": "ACES 1.3 sRGB",
                 "ACES 2.0": "ACES 2.0 sRGB", "Raw": "Non-Color"}
ROW = 4096  # pixels per row of the temporary image


def _through_space(display: np.ndarray, space: str) -> np.ndarray:
    """(m, 3) float32 display values -> (m, 3) float32, as Blender loads them from colour space ``space``."""
    m = len(display)
    w, h = min(ROW, max(1, m)), max(1, -(-m // ROW))
    px = np.ones((w * h, 4), dtype=np.float32)
    px[:m, :3] = display
    with tempfile.TemporaryDirectory(prefix="nerf_colours_") as tmp:
        path = os.path.join(tmp, "display.exr")
        img = bpy.data.images.new("nerf display colours", w, h, alpha=True, float_buffer=True)
        try:
            img.colorspace_settings.name = "Non-Color"
            img.pixels.foreach_set(px.ravel())
            img.filepath_raw, img.file_format = path, "OPEN_EXR"
            img.save()
        finally:
            bpy.data.images.remove(img)
        img = bpy.data.images.load(path, check_existing=False)
        try:
            img.colorspace_settings.name = space
            out = np.empty(w * h * 4, dtype=np.float32)
            img.pixels.foreach_get(out)
        finally:
            bpy.data.images.remove(img)
    return out.reshape(-1, 4)[:m, :3]


def describe(cm: dict) -> str:
    return f"view transform {cm.get('view_transform')!r} (look {cm.get('look')}, " \
           f"exposure {cm.get('exposure', 0.0):g}, gamma {cm.get('gamma', 1.0):g})"


def to_linear_for(recorded: Optional[dict], scene,
                  what: str = "volume") -> tuple[Callable[[np.ndarray], np.ndarray], list]:
    """The conversion of the capture's display colours (m, 3) float32 in [0, 1] to scene-linear
    (m, 3) float32, undoing ``recorded`` (the ``what`` file's ``color_management``; None or {}: unknown,
    taken as Standard), and the notes a user should read: what could not be undone, and when the
    scene's own view settings differ from the capture's (its render then shows the captured light as
    the scene shows any object, not the NeRF's images)."""
    notes = []
    cm = dict(recorded or {})
    if not cm:
        notes.append(f"the {what} file records no colour management: its colours are taken as sRGB (Standard)")
        cm = {"display_device": "sRGB", "view_transform": "Standard", "look": "None", "exposure": 0.0, "gamma": 1.0}
    view = cm.get("view_transform", "Standard")
    space = INVERSE_SPACE.get(view)
    if space is None or cm.get("display_device", "sRGB") != "sRGB":
        notes.append(f"the capture's {describe(cm)} on display {cm.get('display_device')!r} cannot be undone here; "
                     "its colours are taken as sRGB (Standard)")
        space = "sRGB"
    if cm.get("look", "None") not in ("None", ""):
        notes.append(f"the capture's look {cm['look']!r} is not undone: the {what} keeps it in its colours")
    exposure, gamma = float(cm.get("exposure", 0.0)), float(cm.get("gamma", 1.0))
    vs = scene.view_settings
    here = {"view_transform": vs.view_transform, "look": vs.look, "exposure": vs.exposure, "gamma": vs.gamma}
    if any(here[k] != cm.get(k, here[k]) for k in ("view_transform", "look")) or \
            abs(here["exposure"] - exposure) > 1e-6 or abs(here["gamma"] - gamma) > 1e-6:
        notes.append(f"the capture was rendered with {describe(cm)}, the scene shows {describe(here)}: the {what} "
                     "holds the captured light, so the scene shows it as it shows its own objects, not as the "
                     "NeRF's images; set the scene's colour management to the capture's to compare them")

    # Standard's inverse is the sRGB curve itself, exactly (OpenColorIO's is within 3e-5 of it)
    undo = (lambda d: volume_files.srgb_to_linear(d)) if space == "sRGB" else (lambda d: _through_space(d, space))

    def to_linear(display: np.ndarray) -> np.ndarray:
        d = np.clip(np.asarray(display, dtype=np.float32), 0.0, 1.0) ** np.float32(gamma)
        return (undo(d) / np.float32(2.0 ** exposure)).astype(np.float32)

    return to_linear, notes
