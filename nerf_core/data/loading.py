"""Loading NeRF datasets: the original synthetic layout and nerfstudio's ``transforms.json``.

Layouts:

* synthetic: ``transforms_{train,val,test}.json`` with ``camera_angle_x`` (optionally ``fl_x``,
  ``fl_y``, ``cx``, ``cy``, ``w``, ``h``, ``aabb``, ``near``, ``far``) and ``frames[*].file_path``
  without extension (``./train/r_0`` -> ``train/r_0.png``).
* nerfstudio: one ``transforms.json`` with ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``, ``h`` (per-frame
  values override the global ones), file names with extensions and optional
  ``train_filenames``/``val_filenames``/``test_filenames``; without them every 8th frame is held
  out (the same frames serve as val and test).

Memory: each image is stored once, as uint8 RGBA for PNGs (float32 for EXR), and composited onto a
background per batch, so a 100-view 800x800 dataset costs 256 MB and not several float copies.

Every problem with the input raises ``DatasetError`` whose message names the file, frame and field.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch

from nerf_core.data.backgrounds import small_subject_note
from nerf_core.cameras.rays import Cameras
# Reading transforms files is the contract's (shared with the add-on); DatasetError, FrameInfo,
# detect_layout and dataset_problems stay importable from here for data's long-standing callers.
from nerf_core.contract.intrinsics import resolve_intrinsics
from nerf_core.contract.lens import DISTORTION_KEYS
from nerf_core.contract.transforms import SPLITS, DatasetError, FrameInfo, detect_layout, frame_infos, why_not_a_file
from nerf_core.data.validation import check_duplicate_images, check_near_far, check_train_count, dataset_problems, depth_scale, empty_masks_problem, parse_aabb, scene_fields, scene_pixel_filter, transparent_train_problem, black_train_problem
from nerf_core.cameras.distortion import fold_pixel
from nerf_core.image.metrics import composite
from nerf_core.image.pixel_filter import PixelFilter
from nerf_core.data.scene_box import depth_points, estimate_aabb, pad_box_for_interior
from nerf_core.image.io import ImageReadError, read_depth, read_exr_rgba, read_mask, read_normals, read_png


# An opaque image whose brightest value is at most this (of 1) shows no light: 1 of 255 in an 8-bit PNG.
BLACK_LEVEL = 1.5 / 255


@dataclass
class Split:
    """The images and cameras of one split.

    Attributes:
        images: (n, h, w, c) uint8 (PNG) or float32 (EXR), c = 3 or 4 (straight, not premultiplied, alpha).
        depth: (n, h, w) float32 planar z-depth in scene units, 0 where unknown; or None.
        normals: (n, h, w, 3) float32 or None.
        masks: (n, h, w) bool, False = ignore the pixel; or None.
    """

    name: str
    cameras: Cameras
    images: torch.Tensor
    frames: List[FrameInfo]
    depth: Optional[torch.Tensor] = None
    normals: Optional[torch.Tensor] = None
    masks: Optional[torch.Tensor] = None

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def stems(self) -> List[str]:
        return [f.stem for f in self.frames]

    @property
    def has_alpha(self) -> bool:
        return self.images.shape[-1] == 4

    def shown(self) -> torch.Tensor:
        """(n, h, w) bool: pixels that show something (alpha above 0; every pixel without alpha)."""
        return self.images[..., 3] > 0 if self.has_alpha else torch.ones(self.images.shape[:3], dtype=torch.bool)

    def shows_nothing(self) -> bool:
        """True when every image is transparent everywhere (alpha 0): no pixel shows the scene."""
        return len(self.frames) > 0 and not bool(self.shown().any())

    def is_black(self) -> bool:
        """True when every image is opaque (no alpha, or alpha 1 everywhere) and black everywhere (no
        value above ``BLACK_LEVEL``): the cameras saw no light. Also a cut-out's transparent pixels
        count as showing something (empty space)."""
        if not len(self.frames):
            return False
        full = 255 if self.images.dtype == torch.uint8 else 1.0
        # the colour maximum first: it settles almost every dataset without a mask the size of the split
        if float(self.images[..., :3].max()) / full > BLACK_LEVEL:
            return False
        return not self.has_alpha or bool((self.images[..., 3] >= full).all())

    def masks_select_nothing(self) -> bool:
        """True when there are masks and they mark no pixel that shows something (transparent pixels
        count whatever the masks say, ``load_split``): every loss term would be empty background."""
        if self.masks is None:
            return False
        return not bool((self.masks & self.shown()).any())

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])

    def _to_float(self, px: torch.Tensor) -> torch.Tensor:
        return px.float() / 255.0 if px.dtype == torch.uint8 else px.float()

    def pixels(self, view: torch.Tensor, j: torch.Tensor, i: torch.Tensor, background: torch.Tensor):
        """Ground truth for a batch of pixels.

        Args:
            view, j, i: (m,) int64 view, row, column.
            background: (m, 3) or (3,) colour composited behind the alpha.
        Returns:
            rgb (m, 3) float32 composited, alpha (m,) float32 (ones without an alpha channel).
        """
        px = self._to_float(self.images[view, j, i])
        rgb = px[:, :3]
        if not self.has_alpha:
            return rgb, torch.ones_like(rgb[:, 0])
        alpha = px[:, 3]
        bg = background.to(rgb).expand_as(rgb)
        return rgb * alpha[:, None] + bg * (1.0 - alpha[:, None]), alpha

    def image(self, view: int, background) -> tuple[torch.Tensor, torch.Tensor]:
        """Full image ``view``: rgb (h, w, 3) composited onto ``background`` (3,), alpha (h, w)."""
        px = self._to_float(self.images[view])
        if not self.has_alpha:
            return px[..., :3], torch.ones_like(px[..., 0])
        return composite(px, background), px[..., 3]


@dataclass
class Dataset:
    root: Path
    layout: str  # "synthetic" or "nerfstudio"
    splits: Dict[str, Split]
    aabb: torch.Tensor  # (2, 3)
    aabb_source: str  # "dataset" or a sentence saying how it was estimated
    near: Optional[float] = None
    far: Optional[float] = None
    notes: List[str] = field(default_factory=list)
    film_transparent: Optional[bool] = None  # what the transforms files declare; None when they do not
    world: Optional[dict] = None  # the capture's description of the Blender world, when recorded
    cameras_inside: bool = False  # most train cameras stand inside the scene box: an interior
    beyond_box: List[str] = field(default_factory=list)  # objects the capture says reach beyond ``aabb`` (a floor)
    # What one pixel of the images averages over (``nerf_core.image.pixel_filter``), at the loaded resolution.
    pixel_filter: Optional[PixelFilter] = None

    def split(self, name: str) -> Split:
        if name not in self.splits or len(self.splits[name]) == 0:
            have = ", ".join(k for k, v in self.splits.items() if len(v)) or "none loaded"
            # the loader's note says why a split is empty (cameras only, no held-out list): say it here
            why = [n for n in self.notes if f"_{name}.json" in n or "nothing is evaluated" in n]
            raise DatasetError(f"{self.root}: the dataset has no {name!r} views with images"
                               + (f": {why[0]}" if why else f" (splits with views: {have})"))
        return self.splits[name]

    def held_out_split(self, preferred: Sequence[str] = ("test", "val")) -> Optional[str]:
        """The first non-empty split of ``preferred`` (never train), or None."""
        for name in preferred:
            if name in self.splits and len(self.splits[name]):
                return name
        return None


# ----------------------------------------------------------------------------------------------
# pixels


def _checked_float_pixels(fr: FrameInfo, img: np.ndarray) -> np.ndarray:
    """Float (EXR) pixels (h, w, 3|4) that training can use: NaN or infinite values (a failed render or
    a broken writer) and alpha outside [0, 1] are refused, naming the image and the first pixel;
    colours may exceed 1 (HDR), but light is never negative: those values are clipped to 0."""
    bad = ~np.isfinite(img).all(axis=-1)
    if bad.any():
        y, x = (int(v) for v in np.argwhere(bad)[0])
        raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} has {int(bad.sum())} pixel(s) with NaN or "
                           f"infinite values (the first at x={x}, y={y}); re-render or repair the image")
    if img.shape[-1] == 4:
        a = img[..., 3]
        out = (a < -1e-3) | (a > 1 + 1e-3)
        if out.any():
            y, x = (int(v) for v in np.argwhere(out)[0])
            raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} has alpha {float(a[y, x]):.4g} at x={x}, "
                               f"y={y}; alpha is a coverage in [0, 1]")
        img = img.copy()
        img[..., 3] = np.clip(a, 0.0, 1.0)
    return np.maximum(img, 0.0) if (img[..., :3] < 0).any() else img


def _load_pixels(fr: FrameInfo, downscale: int) -> tuple[np.ndarray, tuple[int, int]]:
    """(image as loaded, downscaled by ``downscale``; (width, height) of the file itself)."""
    if not fr.image.is_file():
        raise DatasetError(f"{fr.where}: field 'file_path': image {fr.image} {why_not_a_file(fr.image, fr.file_path)}")
    try:
        if fr.image.suffix.lower() == ".exr":
            img = _checked_float_pixels(fr, read_exr_rgba(fr.image))
        else:
            img = read_png(fr.image)
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=-1)
            if img.dtype == np.uint16:  # 16-bit PNG: keep the precision as float
                img = img.astype(np.float32) / 65535.0
            elif img.dtype != np.uint8:
                raise DatasetError(f"{fr.where}: field 'file_path': unsupported pixel type {img.dtype} in {fr.image}")
    except ImageReadError as exc:
        raise DatasetError(f"{fr.where}: field 'file_path': {exc}") from exc
    if img.shape[-1] not in (3, 4):
        raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} has {img.shape[-1]} channels, expected RGB or RGBA")
    if downscale > 1:
        if img.shape[0] < downscale or img.shape[1] < downscale:
            raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} is {img.shape[1]}x{img.shape[0]} px; "
                               f"downscaled by {downscale} it would have no pixels (--downscale must be at most "
                               f"{min(img.shape[:2])})")
    full = (int(img.shape[1]), int(img.shape[0]))
    if downscale > 1:
        img = _downscale(img, downscale)
    return img, full


def _downscale(img: np.ndarray, f: int) -> np.ndarray:
    """Box-filter by an integer factor, averaging colours premultiplied by alpha so edges do not darken."""
    h, w = img.shape[0] // f, img.shape[1] // f
    x = img[: h * f, : w * f].astype(np.float32)
    if img.dtype == np.uint8:
        x = x / 255.0
    if x.shape[-1] == 4:
        x = np.concatenate([x[..., :3] * x[..., 3:], x[..., 3:]], -1)
    x = x.reshape(h, f, w, f, -1).mean(axis=(1, 3))
    if x.shape[-1] == 4:
        a = x[..., 3:]
        x = np.concatenate([np.where(a > 0, x[..., :3] / np.maximum(a, 1e-8), 0.0), a], -1)
    if img.dtype == np.uint8:
        return (np.clip(x, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    return x.astype(np.float32)


def _resize_map(m: np.ndarray, f: int, mode: str) -> np.ndarray:
    h, w = m.shape[0] // f, m.shape[1] // f
    m = m[: h * f, : w * f]
    if mode == "nearest":
        return m[f // 2 :: f, f // 2 :: f][:h, :w]
    return m.reshape(h, f, w, f, *m.shape[2:]).mean(axis=(1, 3))


def _camera_params(fr: FrameInfo, full_w: int, full_h: int, downscale: int) -> tuple:
    """(fx, fy, cx, cy) of ``fr`` for its image as loaded: ``full_w`` x ``full_h`` px in the file,
    downscaled by ``downscale`` = F (``_downscale``: cropped to a multiple of F at the right and bottom,
    then box-filtered). Pixel (u, v) of the loaded image averages file pixels [F u, F u + F), so every
    intrinsic divides by F exactly; scaling by the size ratio instead ((W // F) / W) moved the cameras
    of an image whose size F does not divide (35 px at F = 4: 0.44 px at the centre)."""
    w_decl, h_decl = fr.intrinsics.get("w"), fr.intrinsics.get("h")
    # The declared size is checked against the file's: a wrong w/h would silently rescale the focal.
    # Either one alone is checked too: a lone 'w' of twice the image width halved the focal length.
    if ((w_decl is not None and int(w_decl) != full_w) or (h_decl is not None and int(h_decl) != full_h)):
        said = "x".join(str(int(v)) if v is not None else "?" for v in (w_decl, h_decl))
        raise DatasetError(f"{fr.where}: fields 'w'/'h' say {said} but {fr.image} is {full_w}x{full_h}")
    fx, fy, cx, cy, W, H = resolve_intrinsics(fr.intrinsics, None, (full_w, full_h), fr.where)
    if fr.lens is not None:
        at = _lens_fold(fx, fy, cx, cy, int(W), int(H), fr.lens.coeffs, fr.lens.fisheye)
        if at is not None:
            named = [repr(k) for k, c in zip(DISTORTION_KEYS, fr.lens.coeffs) if c != 0.0] or ["'camera_model'"]
            raise DatasetError(
                f"{fr.where}: field{'s' * (len(named) > 1)} {', '.join(named)}: this {fr.lens.model} distortion cannot be undone over the whole "
                f"{int(W)}x{int(H)} image: near pixel ({at[0]:.0f}, {at[1]:.0f}) it turns back, so two pixels would "
                "see one ray. Check the coefficients and the image size they were calibrated for")
    f = float(downscale)
    return fx / f, fy / f, cx / f, cy / f


@functools.lru_cache(maxsize=256)
def _lens_fold(fx, fy, cx, cy, w, h, coeffs, fisheye):
    """``lens.fold_pixel``, once per distinct camera (a dataset repeats one lens in every frame)."""
    return fold_pixel(fx, fy, cx, cy, w, h, coeffs, fisheye)


# Per-frame extra channels: Split attribute -> (FrameInfo attribute, JSON field named in errors, reader,
# value where a frame has none). Depth 0 = unknown; normals 0 = none; a missing mask keeps every pixel.
EXTRAS = {
    "depth": ("depth", "depth_file_path", None, lambda h, w: np.zeros((h, w), np.float32)),
    "normals": ("normal", "normal_file_path", read_normals, lambda h, w: np.zeros((h, w, 3), np.float32)),
    "masks": ("mask", "mask_path", read_mask, lambda h, w: np.ones((h, w), bool)),
}


def _load_extra(attr: str, fr: FrameInfo, h: int, w: int, downscale: int, depth_scale: float) -> np.ndarray:
    """One frame's depth (h, w) float32, normals (h, w, 3) float32 or mask (h, w) bool (``EXTRAS``),
    resized like its image (nearest: averaging depths or normals across an edge would invent surfaces)."""
    fr_attr, json_field, reader, missing = EXTRAS[attr]
    path = getattr(fr, fr_attr)
    if path is None:
        return missing(h, w)
    if not path.is_file():
        raise DatasetError(f"{fr.where}: field {json_field!r}: {path} {why_not_a_file(path)}")
    try:
        m = read_depth(path, png_scale=depth_scale) if attr == "depth" else reader(path)
    except ImageReadError as exc:
        raise DatasetError(f"{fr.where}: field {json_field!r}: {exc}") from exc
    if downscale > 1:
        m = _resize_map(m, downscale, "nearest")
    if m.shape[:2] != (h, w):
        raise DatasetError(f"{fr.where}: field {json_field!r}: {path} is {m.shape[1]}x{m.shape[0]}, image is {w}x{h}")
    return m


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
        img, full = _load_pixels(fr, downscale)
        if size is None:
            size = (img.shape[1], img.shape[0], img.shape[2], img.dtype)
        elif (img.shape[1], img.shape[0]) != size[:2]:
            raise DatasetError(
                f"{fr.where}: field 'file_path': {fr.image} is {img.shape[1]}x{img.shape[0]} but the first "
                f"{name} image ({frames[0].image.name}) is {size[0]}x{size[1]}; all images of a split must have one size"
            )
        elif img.shape[2] != size[2]:
            lacking = fr if img.shape[2] == 3 else frames[0]
            raise DatasetError(
                f"{lacking.where}: field 'file_path': {lacking.image} has no alpha channel while other {name} images do; "
                "the alpha channel is the mask of the object, export every image as RGBA"
            )
        elif img.dtype != size[3]:
            img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img
        params.append(_camera_params(fr, *full, downscale))
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
            setattr(split, attr, torch.from_numpy(np.stack([_load_extra(attr, fr, h, w, downscale, depth_scale)
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

    ``downscale`` (integer >= 1) box-filters the images and scales the intrinsics accordingly.
    """
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
            raise DatasetError(f"{root}: no frames with images in {', '.join(splits)}, and no 'aabb' to place the scene")
        cams = Cameras.cat(all_cams)
        aabb, source = estimate_aabb(cams, far, depth_points(loaded["train"]) if len(loaded["train"]) else None)
        notes.append(source)
    inside_note = None
    if len(loaded["train"]):
        aabb, inside_note = pad_box_for_interior(aabb, loaded["train"].cameras.origins)
        if inside_note:
            notes.append(inside_note)
        small = small_subject_note(loaded["train"].images)
        if small:
            notes.append(small)
            source += "; padded around the cameras standing inside it"
    return Dataset(Path(root), layout, loaded, aabb, source, near, far, notes, film, world,
                   cameras_inside=inside_note is not None, beyond_box=beyond, pixel_filter=pixel_filter)


def load_cameras(path: Path | str, split: str = "test") -> tuple[Cameras, List[FrameInfo]]:
    """Cameras of one split of a transforms file without reading pixels (image sizes come from the
    JSON, or from the image headers when ``w``/``h`` are absent)."""
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
    from nerf_core.image.io import png_info

    params, sizes = [], []
    for fr in frames:
        w, h = fr.intrinsics.get("w"), fr.intrinsics.get("h")
        if w is None or h is None:
            try:
                w, h, _, _ = png_info(fr.image)
            except ImageReadError as exc:
                raise DatasetError(f"{fr.where}: fields 'w'/'h' are missing and the image size cannot be read: {exc}") from exc
        w, h = int(w), int(h)
        fr.intrinsics.setdefault("w", w)
        fr.intrinsics.setdefault("h", h)
        params.append(_camera_params(fr, w, h, 1))
        sizes.append((w, h))
    p = np.asarray(params, dtype=np.float64)
    s = np.asarray(sizes)
    return Cameras.create(np.stack([f.c2w for f in frames]), p[:, 0], p[:, 1], p[:, 2], p[:, 3], s[:, 0], s[:, 1],
                          lenses=[f.lens for f in frames])


# ----------------------------------------------------------------------------------------------
# training batches


class RayBatcher:
    """Random ray batches over every pixel of a (train) split; images stay uint8 on the CPU.

    ``background`` is a ``train --background`` mode other than ``auto`` (see ``nerf_core.data.backgrounds``);
    ``gen`` draws every random number (pixels, random colours), so a saved generator state replays
    the same batches.
    """

    def __init__(self, split: Split, background: str, gen: torch.Generator, device: torch.device):
        self.split, self.gen, self.device = split, gen, device
        self.background = background
        self.hw = split.height * split.width
        self.total = len(split) * self.hw
        # Ground truth is composited onto white in environment mode too (the loaders' convention for the
        # few transparent pixels an opaque capture may have); the model's environment replaces ``bg``.
        self.fixed_bg = torch.tensor([0.0, 0.0, 0.0] if background == "black" else [1.0, 1.0, 1.0])

    def sample(self, n: int, frac: float = 1.0):
        """``n`` random rays at ``frac`` (in [0, 1]) of the training budget.

        Returns rays_o (n, 3), rays_d (n, 3), background (n, 3), ground-truth colour (n, 3) composited
        onto that background, and the mask weight (n,) or None, all on ``device``.
        """
        from nerf_core.data.backgrounds import AUTO_WHITE_FRACTION
        from nerf_core.cameras.rays import rays_for_pixels

        flat = torch.randint(0, self.total, (n,), generator=self.gen)
        view = flat // self.hw
        pix = flat % self.hw
        j, i = pix // self.split.width, pix % self.split.width
        random_bg = self.background == "random" or (self.background == "white-then-random" and frac >= AUTO_WHITE_FRACTION)
        if random_bg:
            bg = torch.rand(n, 3, generator=self.gen)
        else:
            bg = self.fixed_bg.expand(n, 3)
        rgb, _ = self.split.pixels(view, j, i, bg)
        rays_o, rays_d, _ = rays_for_pixels(self.split.cameras, view, i, j)
        weight = self.split.masks[view, j, i].float() if self.split.masks is not None else None
        d = self.device
        return (rays_o.to(d), rays_d.to(d), bg.to(d).contiguous(), rgb.to(d),
                None if weight is None else weight.to(d))
