"""nerfstudio's ``camera_path.json`` as cameras to render (the format and its reading rules:
``nerf_core.contract.camera_path``).
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Tuple

import numpy as np

from nerf_core.cameras.rays import Cameras
from nerf_core.contract.camera_path import (  # noqa: F401  (re-exported: the renderer's names)
    MAX_SIDE,
    CameraPathError,
    camera_path_intrinsics,
    is_camera_path,
    path_range,
    path_views,
)


def cameras_from_camera_path(data: dict, src: Path | str) -> Tuple[Cameras, List[str]]:
    """Cameras (n views) and output stems ``frame_00000``... of a parsed camera_path.json.

    Raises CameraPathError naming ``src`` (and the camera index and field) for anything unusable.
    """
    views = path_views(data, src)
    cams = Cameras.create(
        np.stack([v["c2w"] for v in views]),
        *([v[k] for v in views] for k in ("fx", "fy", "cx", "cy")),
        views[0]["w"],
        views[0]["h"],
    )
    return cams, [f"frame_{k:05d}" for k in range(len(views))]
