"""The colour management a capture's images were rendered with, as the add-on's capture manifest
records it (``DATASET/nerf_capture/manifest.json``, ``render.color_management``).

A NeRF learns the images' display values: under AgX (Blender's default view transform) a display value
of 0.5 is not the scene-linear 0.214 that the sRGB curve would give. Whatever turns the NeRF's colours
back into light for Blender (the volume import) must undo the capture's own view transform, so the
export carries this record along (``export.volume``). Standard library only: the add-on reads it too.
"""
from __future__ import annotations

import json
import os
from typing import Optional

from .numbers import is_number

CAPTURE_MANIFEST = os.path.join("nerf_capture", "manifest.json")
TEXT_FIELDS = ("display_device", "view_transform", "look")
NUMBER_FIELDS = ("exposure", "gamma")
STANDARD = {"display_device": "sRGB", "view_transform": "Standard", "look": "None", "exposure": 0.0, "gamma": 1.0}


def recorded(dataset_dir: str) -> Optional[dict]:
    """The capture's colour management {display_device, view_transform, look: str; exposure, gamma:
    float}, or None when the dataset has no capture manifest or the manifest records none usable (a
    dataset not captured by the add-on; the images are then taken as sRGB, ``STANDARD``)."""
    path = os.path.join(dataset_dir, CAPTURE_MANIFEST)
    try:
        with open(path, encoding="utf-8") as fh:
            manifest = json.load(fh)
    except (OSError, ValueError):
        return None
    render = manifest.get("render") if isinstance(manifest, dict) else None
    cm = render.get("color_management") if isinstance(render, dict) else None
    if not isinstance(cm, dict):
        return None
    out = dict(STANDARD)
    for key in TEXT_FIELDS:
        if key in cm:
            if not isinstance(cm[key], str):
                return None
            out[key] = cm[key]
    for key in NUMBER_FIELDS:
        if key in cm:
            value = cm[key]
            if not is_number(value):
                return None
            out[key] = float(value)
    return out if out["gamma"] > 0 else None
