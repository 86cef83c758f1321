"""The cameras to render: from a dataset folder, a transforms file of either layout, a JSON list of
cameras or nerfstudio's camera_path.json; their ground truth where the frames have images, and the
dataset files an output must never overwrite.
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import numpy as np

from nerf_core.cameras.camera_path import CameraPathError, cameras_from_camera_path, is_camera_path, path_range
from nerf_core.cameras.rays import Cameras
from nerf_core.contract.errors import DatasetError, PoseError
from nerf_core.contract.intrinsics import resolve_intrinsics
from nerf_core.contract.jsonfile import parse_json_file
from nerf_core.contract.lens import parse_lens
from nerf_core.contract.naming import frame_stem, unique_stems
from nerf_core.contract.outputs import dataset_files  # noqa: F401 (the output rule's; render uses it from here)
from nerf_core.contract.poses import check_pose
from nerf_core.contract.transforms import (
    FrameInfo,
    read_transforms,
)
from nerf_core.data.loading import cameras_of_frames, load_cameras, load_split


def camera_list(data, src: Path) -> tuple[Cameras, List[str]]:
    """Cameras from a JSON list: each item a 4x4 matrix (intrinsics from the top level) or a dict
    with ``transform_matrix`` plus intrinsics (``contract.resolve_intrinsics``; ``w`` and ``h`` required)."""
    if isinstance(data, list):
        items, glob = data, {}
    elif isinstance(data, dict):
        items, glob = data.get("cameras"), data
    else:  # a bare number or string
        items, glob = None, {}
    if not isinstance(items, list) or not items:
        raise DatasetError(f"{src}: expected a list of cameras (or an object with 'frames' or 'cameras')")
    mats, params, lenses = [], [], []
    for k, item in enumerate(items):
        where = f"{src}: camera {k}"
        m = item.get("transform_matrix") if isinstance(item, dict) else item
        try:
            mats.append(check_pose(m, f"{where}: field 'transform_matrix'"))
        except PoseError as exc:
            raise DatasetError(str(exc)) from exc
        own = item if isinstance(item, dict) else None
        params.append(resolve_intrinsics(glob, own, None, where))
        lens, problem = parse_lens(glob, own)
        if problem:
            raise DatasetError(f"{where}: field {problem[0]!r}: {problem[1]}")
        lenses.append(lens)
    p = np.asarray(params, dtype=np.float64)
    cams = Cameras.create(np.stack(mats), p[:, 0], p[:, 1], p[:, 2], p[:, 3], p[:, 4].astype(int), p[:, 5].astype(int),
                          lenses=lenses)
    return cams, [frame_stem(item, k) for k, item in enumerate(items)]


def camera_views(path: Path | str, split: str = "test") -> tuple[Cameras, List[str], List[Optional[FrameInfo]]]:
    """Cameras to render, their output stems (unique, ``contract.output_stems``'s rule) and, per camera,
    the transforms frame it came from (its ``image`` is the ground truth), None for a bare camera.

    ``path`` may be a dataset folder (the frames of ``split``), a transforms file of either layout
    (all its frames; a nerfstudio file with ``*_filenames`` lists gives the frames of ``split``), a
    nerfstudio ``camera_path.json`` (``nerf_core.cameras.camera_path``), or a JSON list of cameras (see
    ``camera_list``).
    """

    path = Path(path)
    frames: List[Optional[FrameInfo]]
    if path.is_dir():
        cams, frames = load_cameras(path, split)
        stems = [f.stem for f in frames]
    else:
        if not path.is_file():
            raise DatasetError(f"{path}: cameras file not found")
        data = parse_json_file(path)

        if is_camera_path(data):  # nerfstudio's camera_path.json (viewer, Blender add-on)
            cams, stems = cameras_from_camera_path(data, path)
            frames = [None] * len(stems)
        elif isinstance(data, dict) and "frames" in data:
            if data.get("train_filenames") is not None and not path.name.startswith("transforms_"):
                cams, frames = load_cameras(path, split)
            else:
                frames = read_transforms(path)
                cams = cameras_of_frames(frames)
            stems = [f.stem for f in frames]
        else:
            cams, stems = camera_list(data, path)
            frames = [None] * len(stems)
    # Two frames with one basename (train/r_0 and test/r_0) must not overwrite each other's output.
    return cams, unique_stems(stems), list(frames)


def camera_file_range(path: Path | str) -> tuple:
    """(near, far) a cameras file asks to render with (a camera_path.json's ``near``/``far``), else (None, None)."""
    path = Path(path)
    if not path.is_file():
        return None, None
    data = parse_json_file(path)
    if not is_camera_path(data):
        return None, None
    try:
        return path_range(data, path)
    except CameraPathError as exc:
        raise DatasetError(str(exc)) from None


def cameras_from_file(path: Path | str, split: str = "test") -> tuple[Cameras, List[str]]:
    """Cameras and output stems to render (``camera_views`` without the frames)."""
    cams, stems, _ = camera_views(path, split)
    return cams, stems


def ground_truth_split(frame: Optional[FrameInfo], cameras: Cameras, view: int, downscale: int):
    """(one-view ``data.Split`` holding the ground truth of ``view``, None) or (None, why not). No
    frame or no image file: (None, None), a camera without ground truth is not a problem."""

    if frame is None or not frame.image.is_file():
        return None, None
    try:
        split = load_split("ground truth", [frame], downscale, extras=("masks",))  # PSNR counts mask pixels
    except DatasetError as exc:
        return None, str(exc)
    size, want = (split.width, split.height), (int(cameras.width[view]), int(cameras.height[view]))
    if size != want:
        return (
            None,
            f"{frame.image} is {size[0]}x{size[1]} px (downscaled by {downscale}), the render {want[0]}x{want[1]}",
        )
    return split, None
