"""Loading NeRF datasets: the original synthetic layout, nerfstudio's ``transforms.json`` and COLMAP folders.

Layouts:

* synthetic: ``transforms_{train,val,test}.json`` with ``camera_angle_x`` (optionally ``fl_x``,
  ``fl_y``, ``cx``, ``cy``, ``w``, ``h``, ``aabb``, ``near``, ``far``) and ``frames[*].file_path``
  without extension (``./train/r_0`` -> ``train/r_0.png``).
* nerfstudio: one ``transforms.json`` with ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``, ``h`` (per-frame
  values override the global ones), file names with extensions and optional
  ``train_filenames``/``val_filenames``/``test_filenames``; without them every 8th frame is held
  out (the same frames serve as val and test).
* colmap: ``images/`` and a sparse model in ``sparse/0`` or ``sparse`` (``.bin`` or ``.txt``), read by
  ``contract.colmap_dataset`` into the same frames (poses converted to OpenGL camera-to-world, every 8th
  image by name held out unless our export's manifest lists the splits; no normalisation).

Memory: each image is stored once, as uint8 RGBA for PNGs (float32 for EXR), and composited onto a
background per batch, so a 100-view 800x800 dataset costs 256 MB and not several float copies.

Every problem with the input raises ``DatasetError`` whose message names the file, frame and field.
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Sequence

import numpy as np
import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.numbers import is_number

# Reading transforms files is the contract's (shared with the add-on); DatasetError, FrameInfo,
# detect_layout and dataset_problems stay importable from here for data's long-standing callers.
from nerf_core.contract.transforms import SPLITS, FrameInfo, frame_infos
from nerf_core.data.backgrounds import small_subject_note
from nerf_core.data.pixels import EXTRAS, camera_params, load_extra, load_pixels
from nerf_core.data.scene_box import FACE_PAD, depth_points, estimate_aabb, pad_box_for_faces, pad_box_for_interior
from nerf_core.data.split import Dataset, Split
from nerf_core.data.validation import (
    black_train_problem,
    check_duplicate_images,
    check_near_far,
    check_train_count,
    depth_scale,
    empty_masks_problem,
    hdr_note,
    parse_aabb,
    repeated_frames_note,
    scene_fields,
    scene_pixel_filter,
    transparent_train_problem,
)
from nerf_core.errors import ImageReadError
from nerf_core.image.io import png_info
from nerf_core.utils import arguments

# ----------------------------------------------------------------------------------------------
# pixels


def load_split(
    name: str,
    frames: List[FrameInfo],
    downscale: int = 1,
    depth_scale: float = 1e-3,
    load_extras: bool = True,
    extras: Sequence[str] = ("depth", "normals", "masks"),
) -> Split:
    """Read the pixels (and, with ``load_extras``, the ``extras`` of ``EXTRAS``) of one split's frames."""
    images, params = [], []
    size = None
    for fr in frames:
        img, full = load_pixels(fr, downscale)
        if size is None:
            size = (img.shape[1], img.shape[0], img.shape[2], img.dtype)
        elif (img.shape[1], img.shape[0]) != size[:2]:
            raise DatasetError(
                f"{fr.where}: field 'file_path': {fr.image} is {img.shape[1]}x{img.shape[0]} but the first "
                f"{name} image ({frames[0].image.name}) is {size[0]}x{size[1]}; all images of a split must have "
                "one size"
            )
        elif img.shape[2] != size[2]:
            lacking = fr if img.shape[2] == 3 else frames[0]
            raise DatasetError(
                f"{lacking.where}: field 'file_path': {lacking.image} has no alpha channel while other {name} "
                "images do; "
                "the alpha channel is the mask of the object, export every image as RGBA"
            )
        elif img.dtype != size[3]:
            img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img
        params.append(camera_params(fr, *full, downscale))
        images.append(img)
    if not images:
        w = h = 0
        stack = torch.zeros((0, 0, 0, 3), dtype=torch.uint8)
    else:
        if any(im.dtype != images[0].dtype for im in images):
            images = [im.astype(np.float32) / 255.0 if im.dtype == np.uint8 else im for im in images]
        stack = torch.from_numpy(np.stack(images))
        h, w = images[0].shape[:2]
    p = np.asarray(params, dtype=np.float64).reshape(-1, 4)
    cams = Cameras.create(
        np.stack([f.c2w for f in frames]) if frames else np.zeros((0, 4, 4)),
        p[:, 0], p[:, 1], p[:, 2], p[:, 3], np.full(len(frames), w), np.full(len(frames), h),
        lenses=[f.lens for f in frames],
    )
    split = Split(name, cams, stack, list(frames))
    if not load_extras or not frames:
        return split
    for attr in extras:
        if any(getattr(f, EXTRAS[attr][0]) for f in frames):
            setattr(split, attr, torch.from_numpy(np.stack([load_extra(attr, fr, h, w, downscale, depth_scale)
                                                            for fr in frames])))
    if split.masks is not None and split.has_alpha:
        # A pixel the image leaves transparent shows empty space along its whole ray: a fact about the
        # scene, masked or not. Left out, free space would never be taught, and fog or floaters stay
        # where the masked objects are not (the masks mark objects, not the pixels worth learning).
        split.masks = split.masks | ~split.shown()
    return split


# ----------------------------------------------------------------------------------------------


def load_dataset(
    path: Path | str,
    splits: Sequence[str] = SPLITS,
    downscale: int = 1,
    min_train_views: int = 2,
) -> Dataset:
    """Load a dataset folder (or one transforms file) with the pixels of ``splits``.

    Every frame's metadata is read and checked; only the splits in ``splits`` get their pixels (and
    depth, normals, masks), the others come back empty. Without an ``aabb`` in the transforms files the
    scene box is estimated from the cameras (``Dataset.aabb_source`` says how).

    Args:
        path: a dataset folder (``transforms_{train,val,test}.json``, nerfstudio's ``transforms.json``, or a
            COLMAP folder with ``images/`` and ``sparse/0``) or one transforms file in it.
        splits: names among "train", "val", "test" whose images to read.
        downscale: integer >= 1; box-filters the images and scales the intrinsics accordingly.
        min_train_views: fewest train views accepted (when "train" is in ``splits``).

    Returns:
        A ``Dataset`` whose ``splits`` holds all three of "train", "val" and "test" (those not in
        ``splits`` empty); images are (n, h, w, 3 or 4) uint8 (float32 for EXR), ``aabb`` (2, 3) float32.

    Raises:
        DatasetError: any problem with the input (the message names the file, frame and field), a
            ``downscale`` that is not a positive integer, an unknown split name, or train images that
            show nothing (all transparent, all black, masks that select nothing).
    """
    path = arguments.path("load_dataset", "path", path)
    if isinstance(splits, str) or not all(isinstance(s, str) for s in splits):
        raise TypeError(f"load_dataset: splits must be a list of split names ({', '.join(SPLITS)}), got {splits!r}")
    arguments.integer("load_dataset", "min_train_views", min_train_views, low=1)
    if not is_number(downscale):
        raise TypeError(f"load_dataset: downscale must be an integer >= 1, got {downscale!r}")
    if int(downscale) != downscale or downscale < 1:
        raise DatasetError(f"downscale must be a positive integer, got {downscale!r}")
    downscale = int(downscale)
    unknown = [s for s in splits if s not in SPLITS]
    if unknown:
        raise DatasetError(f"unknown split {unknown[0]!r}; choose one of {', '.join(SPLITS)}")
    layout, root, infos, scene = frame_infos(path, SPLITS)
    notes = list(scene.get("notes", []))
    for key in ("split_note", "path_note"):
        if key in scene:
            notes.append(scene[key])
    dscale = depth_scale(scene)
    if "train" in splits:
        check_train_count(root, infos, min_train_views)
    check_duplicate_images(infos)
    repeats = repeated_frames_note(infos["train"])
    if repeats:
        notes.append(repeats)
    train_names = {str(f.image) for f in infos["train"]}
    for name in ("val", "test"):
        if name in splits:
            leaked = [f for f in infos[name] if str(f.image) in train_names]
            if leaked:
                notes.append(f"{leaked[0].where}: {len(leaked)} {name} frame(s) use training images; "
                             "their metrics will not measure novel views")
    near, far, film, world, beyond = scene_fields(scene)
    pixel_filter = scene_pixel_filter(scene).downscaled(downscale)
    check_near_far(scene, infos)
    loaded = {name: load_split(name, infos[name], downscale, dscale) for name in splits}
    if "train" in loaded and loaded["train"].shows_nothing():
        raise DatasetError(transparent_train_problem(infos["train"]))
    if "train" in loaded and loaded["train"].is_black():
        raise DatasetError(black_train_problem(infos["train"]))
    if "train" in loaded and loaded["train"].masks_select_nothing():
        raise DatasetError(empty_masks_problem(infos["train"]))
    for name in SPLITS:
        if name not in loaded:
            loaded[name] = load_split(name, [], downscale, dscale)
    if "aabb" in scene:
        aabb = parse_aabb(scene["aabb"], str(scene["aabb_file"]))
        source = f"dataset ({Path(scene['aabb_file']).name})"
    else:
        all_cams = [s.cameras for s in loaded.values() if len(s)]
        if not all_cams and infos["train"]:
            # eval of a split without images (BlenderNeRF's camera-only test poses): the train cameras
            # place the box, read without their pixels
            all_cams = [cameras_of_frames(infos["train"])]
        if not all_cams:
            raise DatasetError(
                f"{root}: no frames with images in {', '.join(splits)}, and no 'aabb' to place the scene"
            )
        cams = Cameras.cat(all_cams)
        aabb, source = estimate_aabb(cams, far, depth_points(loaded["train"]) if len(loaded["train"]) else None)
        notes.append(source)
    inside_note = None
    if len(loaded["train"]):
        aabb, inside_note = pad_box_for_interior(aabb, loaded["train"].cameras.origins)
        if inside_note:
            notes.append(inside_note)
            source += "; padded around the cameras standing inside it"
    if inside_note is None:
        aabb = pad_box_for_faces(aabb)
        source += f"; grown {100 * FACE_PAD:g} % on each side, so that surfaces on its faces lie inside it"
    if len(loaded["train"]):
        small = small_subject_note(loaded["train"].images)
        if small:
            notes.append(small)
        hdr = hdr_note(loaded["train"].images, infos["train"])
        if hdr:
            notes.append(hdr)
    return Dataset(Path(root), layout, loaded, aabb, source, near, far, notes, film, world,
                   cameras_inside=inside_note is not None, beyond_box=beyond, pixel_filter=pixel_filter)


def load_cameras(path: Path | str, split: str = "test") -> tuple[Cameras, List[FrameInfo]]:
    """Cameras of one split of a transforms file without reading pixels (image sizes come from the
    JSON, or from the image headers when ``w``/``h`` are absent).

    A held-out split whose images do not exist (camera-only test poses) still gives its cameras.

    Args:
        path: a dataset folder or one transforms file in it.
        split: "train", "val" or "test".

    Returns:
        (cameras, frames): ``Cameras`` of n views (``c2w`` (n, 4, 4) float32, intrinsics (n,) float32,
        sizes (n,) int64) and the n parsed frames (``FrameInfo``: file paths, (4, 4) float64 ``c2w``,
        intrinsics), in the order of the transforms file.

    Raises:
        DatasetError: an unknown split, a split without frames, unreadable transforms, or a frame
            without ``w``/``h`` whose image size cannot be read.
    """
    path = arguments.path("load_cameras", "path", path)
    if not isinstance(split, str):
        raise TypeError(f"load_cameras: split must be one of {', '.join(SPLITS)}, got {split!r}")
    if split not in SPLITS:
        raise DatasetError(f"unknown split {split!r}; choose one of {', '.join(SPLITS)}")
    layout, root, infos, scene = frame_infos(path, SPLITS)
    # a split of cameras only (BlenderNeRF's test poses) has nothing to score, but its views render
    frames = infos.get(split) or scene.get("cameras_only", {}).get(split) or []
    if not frames:
        raise DatasetError(f"{path}: no frames in split {split!r}")
    return cameras_of_frames(frames), frames


def cameras_of_frames(frames: List[FrameInfo]) -> Cameras:
    """Cameras of parsed frames without reading pixels: sizes from ``w``/``h``, else the image headers."""

    params, sizes = [], []
    for fr in frames:
        w, h = fr.intrinsics.get("w"), fr.intrinsics.get("h")
        if w is None or h is None:
            try:
                w, h, _, _ = png_info(fr.image)
            except ImageReadError as exc:
                raise DatasetError(
                    f"{fr.where}: fields 'w'/'h' are missing and the image size cannot be read: {exc}"
                ) from exc
        w, h = int(w), int(h)
        fr.intrinsics.setdefault("w", w)
        fr.intrinsics.setdefault("h", h)
        params.append(camera_params(fr, w, h, 1))
        sizes.append((w, h))
    p = np.asarray(params, dtype=np.float64)
    s = np.asarray(sizes)
    return Cameras.create(np.stack([f.c2w for f in frames]), p[:, 0], p[:, 1], p[:, 2], p[:, 3], s[:, 0], s[:, 1],
                          lenses=[f.lens for f in frames])


# ----------------------------------------------------------------------------------------------
# training batches


