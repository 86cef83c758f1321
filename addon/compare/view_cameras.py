"""Blender camera objects for rendered views (``renders.json``): the exact inverse of
``dataset/cameras.intrinsics_from_params``, whose home is ``dataset/cameras`` (the capture's camera
import makes the same cameras). Re-exported here for the Compare feature.
"""
from __future__ import annotations

from ..dataset.cameras import (
    LENS_RANGE,
    SENSOR_RANGE,
    SENSOR_WIDTH,
    camera_params,
    make_view_camera,
    use_view_resolution,
)

__all__ = ["LENS_RANGE", "SENSOR_RANGE", "SENSOR_WIDTH", "camera_params", "make_view_camera", "use_view_resolution"]
