"""Validation of a dataset's top-level fields and the one pass that lists every problem
(``dataset_problems``), shared by ``nerf_core.data.loading.load_dataset`` (stops at the first) and
``python -m nerf_core check`` (lists them all). Messages name the file, frame and field.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
import torch

from nerf_core.contract.errors import DatasetError
from nerf_core.contract.poses import coordinate_problem
from nerf_core.contract.transforms import FrameInfo
from nerf_core.image.pixel_filter import parse

# A box thinner than this along an axis holds no scene: its grid cells would be below float32's reach.
MIN_BOX_EXTENT = 1e-6


def parse_aabb(value, where: str) -> torch.Tensor:
    try:
        box = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: field 'aabb' is not a numeric [[xmin,ymin,zmin],[xmax,ymax,zmax]]") from exc
    if box.shape != (2, 3) or not np.all(np.isfinite(box)) or not np.all(box[1] > box[0]):
        raise DatasetError(
            f"{where}: field 'aabb' must be [[xmin,ymin,zmin],[xmax,ymax,zmax]] with min < max, got {value!r}"
        )
    far_out = coordinate_problem(box, "the box")
    if far_out:
        raise DatasetError(f"{where}: field 'aabb': {far_out}")
    thin = box[1] - box[0]
    if thin.min() < MIN_BOX_EXTENT * max(1.0, float(np.abs(box).max())):
        axis = "xyz"[int(thin.argmin())]
        raise DatasetError(f"{where}: field 'aabb' is {thin.min():.3g} units thick along {axis}; a scene box must "
                           "have a real extent on every axis")
    return torch.tensor(box, dtype=torch.float32)


def checked_box(func: str, aabb) -> torch.Tensor:
    """``aabb`` as a (2, 3) float32 tensor by ``parse_aabb``'s rule, for a public function's argument
    (ValueError/TypeError naming ``func`` and ``aabb``)."""
    if isinstance(aabb, (str, bytes, dict)) or aabb is None:
        raise TypeError(f"{func}: aabb must be a (2, 3) array [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {aabb!r}")
    if isinstance(aabb, torch.Tensor):
        aabb = aabb.detach().cpu().double().numpy()
    try:
        return parse_aabb(aabb, f"{func}: argument aabb")
    except DatasetError as exc:
        raise ValueError(str(exc).replace("field 'aabb'", "aabb")) from None


def check_train_count(root: Path, infos: Dict[str, List[FrameInfo]], min_train_views: int) -> None:
    # Views, not frames: one image listed twice (with one pose; two poses are check_duplicate_images's)
    # is still one view.
    n_train = len({str(f.image) for f in infos["train"]})
    if n_train < min_train_views:
        jf = infos["train"][0].json_file if infos["train"] else root
        raise DatasetError(
            f"{jf}: field 'frames': the train split has {n_train} view{'s' if n_train != 1 else ''}; a NeRF needs "
            f"many views of the scene (at least {min_train_views}, typically 50-200)"
        )


def empty_masks_problem(frames: List[FrameInfo]) -> str:
    """The message for a train split whose masks (``mask_path``) all select no pixel: every loss term
    would be weighted by zero, so training would learn nothing and report no PSNR."""
    with_mask = [f for f in frames if f.mask is not None]
    return (f"{with_mask[0].json_file}: field 'mask_path': the masks of all {len(with_mask)} train frames that "
            "have one are empty (every pixel 0 = ignored), so no pixel is left to train on; white (255) marks "
            "the pixels to learn")


def transparent_train_problem(frames: List[FrameInfo]) -> str:
    """The message for a train split whose every image is transparent everywhere: no pixel shows the
    scene, so a model would learn empty space and training would exit having learnt nothing."""
    return (f"{frames[0].json_file}: field 'file_path': all {len(frames)} train images are fully transparent "
            "(alpha 0 everywhere), so no pixel shows the scene; the cameras look past it, or the film hid it "
            "(a holdout, a camera inside an object)")


def black_train_problem(frames: List[FrameInfo]) -> str:
    """The message for a train split whose every image is opaque and black everywhere
    (``Split.is_black``): no camera saw any light, so a model would learn a black fog."""
    return (f"{frames[0].json_file}: field 'file_path': all {len(frames)} train images are opaque and black "
            "everywhere, so no camera saw any light: the cameras stand inside a closed object (the 'inside' "
            "layout on a single object), the lights are off, or the exposure is far too low")


def check_duplicate_images(infos: Dict[str, List[FrameInfo]]) -> None:
    """Refuse two frames of one split that name the same image with different poses (DatasetError
    naming both): one photograph cannot have been taken from two places, so one pose is wrong and
    training would average two contradictory views into fog."""
    for name, frames in infos.items():
        seen: Dict[str, FrameInfo] = {}
        for fr in frames:
            key = str(fr.image)
            first = seen.setdefault(key, fr)
            if first is not fr and not np.allclose(first.c2w, fr.c2w, atol=1e-6):
                raise DatasetError(f"{fr.where}: field 'file_path': names the same image as frame {first.index} "
                                   f"({first.file_path}) with another transform_matrix; one image has one camera")


def repeated_frames_note(frames: List[FrameInfo]) -> Optional[str]:
    """A note when train frames repeat another frame's image (``check_duplicate_images`` has refused
    repeats with another pose): each repeat weighs that view again, and the split has fewer views
    than frames. None when every frame is its own view."""
    distinct = len({str(f.image) for f in frames})
    if distinct == len(frames):
        return None
    seen: set = set()
    first = None
    for f in frames:
        if str(f.image) in seen:
            first = first or f
        seen.add(str(f.image))
    return (f"{first.where}: the {len(frames)} train frames show {distinct} distinct view{'s' if distinct != 1 else ''}"
            f" ({len(frames) - distinct} repeat another frame's image and pose); each repeat weighs its view "
            "again in training, and adds no viewpoint")


def hdr_note(images, frames: List[FrameInfo]) -> Optional[str]:
    """A note when float (EXR) train images hold colours above 1: the methods' colour heads end in a
    sigmoid and reach at most 1, so those pixels are learned as 1 (their light above it is lost).

    Args:
        images: (n, h, w, c) uint8 or float32 pixels of the train split (only float ones can exceed 1).
        frames: the split's frames, to name the first image.
    """
    if not images.is_floating_point() or not len(frames):
        return None
    counts = [int((view[..., :3] > 1.0).sum()) for view in images]  # view by view: no full-size mask
    if not any(counts):
        return None
    first = next(k for k, c in enumerate(counts) if c)
    share = sum(counts) / (images[..., :3].numel())
    peak = max(float(view[..., :3].max()) for view in images)
    return (f"{frames[first].image.name}: {100 * share:.2g} % of the train pixels' colours exceed 1.0 (HDR, peak "
            f"{peak:.3g}); the methods' colours reach at most 1, so they are learned as 1. "
            "Tone-map the images (or render them with Filmic/AgX and 8-bit PNG) to keep that light")


def scene_fields(scene: dict) -> tuple:
    """(near, far, film_transparent, world, beyond_box) of a dataset's top-level fields, validated (raises
    DatasetError). ``beyond_box``: names of objects that reach beyond the scene box ([] when not given).
    ``pixel_filter`` is validated here too; ``scene_pixel_filter`` reads it."""
    near = far = None
    for key in ("near", "far"):
        if key in scene:
            try:
                if isinstance(scene[key], (bool, str)):  # "2.5" or true: a writer's bug
                    raise TypeError
                v = float(scene[key])
            except (TypeError, ValueError, OverflowError):
                raise DatasetError(f"{scene[key + '_file']}: field {key!r} is not a number ({scene[key]!r})") from None
            if not math.isfinite(v) or v < 0:
                raise DatasetError(f"{scene[key + '_file']}: field {key!r} must be a finite number >= 0, got {v}")
            far_out = coordinate_problem([v], f"field {key!r}")
            if far_out:
                raise DatasetError(f"{scene[key + '_file']}: {far_out}")
            near, far = (v, far) if key == "near" else (near, v)
    if near is not None and far is not None and far <= near:
        raise DatasetError(f"{scene['far_file']}: field 'far' ({far}) must be greater than 'near' ({near})")
    film = scene.get("film_transparent")
    if film is not None and not isinstance(film, bool):
        raise DatasetError(
            f"{scene['film_transparent_file']}: field 'film_transparent' must be true or false, got {film!r}"
        )
    world = scene.get("world")
    if world is not None and not isinstance(world, dict):
        raise DatasetError(f"{scene['world_file']}: field 'world' must be an object, got {type(world).__name__}")
    beyond = scene.get("beyond_box", [])
    if not isinstance(beyond, list) or not all(isinstance(n, str) for n in beyond):
        raise DatasetError(
            f"{scene['beyond_box_file']}: field 'beyond_box' must be a list of object names, got {beyond!r}"
        )
    scene_pixel_filter(scene)
    return near, far, film, world, beyond


def scene_pixel_filter(scene: dict):
    """The dataset's ``pixel_filter`` (``nerf_core.image.pixel_filter``; Blender's default when the field is
    absent), validated: DatasetError names the file and the field."""

    try:
        return parse(scene.get("pixel_filter"), str(scene.get("pixel_filter_file", "dataset")))
    except ValueError as exc:
        raise DatasetError(str(exc)) from None


def near_far_problem(near: Optional[float], far: Optional[float], aabb, origins, where: str) -> Optional[str]:
    """Why the dataset's ``near``/``far`` keep every train camera's samples out of the scene box
    ``aabb`` ((2, 3)), or None. Rays are unit length, so a sample at ``t`` lies ``t`` from its camera:
    a camera (``origins`` (n, 3)) whose nearest box point is beyond ``far``, or whose farthest corner is
    nearer than ``near``, sees nothing of the box."""
    if (near is None and far is None) or len(origins) == 0:
        return None
    lo, hi = (np.asarray(v, dtype=np.float64) for v in aabb)
    o = np.asarray(origins, dtype=np.float64)
    d_min = np.linalg.norm(np.clip(o, lo, hi) - o, axis=1)
    d_max = np.linalg.norm(np.maximum(np.abs(o - lo), np.abs(o - hi)), axis=1)
    reach = np.ones(len(o), bool)
    if far is not None:
        reach &= far > d_min
    if near is not None:
        reach &= near < d_max
    if reach.any():
        return None
    return (f"{where}: fields 'near'/'far' ({near} to {far}) never reach the scene box: the train cameras are "
            f"{d_min.min():.4g} to {d_max.max():.4g} units from its nearest and farthest points, so no sample "
            "would land in it. Fix near/far (or the aabb)")


def check_near_far(scene: dict, infos: Dict[str, List[FrameInfo]]) -> None:
    """``near_far_problem`` for a dataset with an ``aabb`` (DatasetError); nothing to say without one
    (the box is then estimated from the cameras) or when the fields themselves are broken."""
    if "aabb" not in scene or not infos.get("train"):
        return
    try:
        near, far = scene_fields(scene)[:2]
        aabb = parse_aabb(scene["aabb"], str(scene["aabb_file"]))
    except DatasetError:
        return  # reported by their own checks
    problem = near_far_problem(near, far, aabb.numpy(), np.stack([f.c2w[:3, 3] for f in infos["train"]]),
                               str(scene.get("far_file") or scene.get("near_file")))
    if problem:
        raise DatasetError(problem)


def depth_scale(scene: dict) -> float:
    """Scene units per count of a 16-bit depth PNG: nerfstudio's ``depth_unit_scale_factor``, else
    instant-ngp's ``integer_depth_scale``, else 1e-3 (millimetres, nerfstudio's default)."""
    key = "depth_unit_scale_factor" if "depth_unit_scale_factor" in scene or "integer_depth_scale" not in scene \
        else "integer_depth_scale"
    v = scene.get(key, 1e-3)
    try:
        f = float(v) if not isinstance(v, (bool, str)) else float("nan")
    except (TypeError, ValueError):
        f = float("nan")
    if not math.isfinite(f) or f <= 0:
        raise DatasetError(f"{scene.get(key + '_file')}: field {key!r} must be a positive number, got {v!r}")
    return f
