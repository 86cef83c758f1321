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

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch

from .cameras import Cameras, PoseError, check_pose
from .imageio import ImageReadError, read_depth, read_exr_rgba, read_mask, read_normals, read_png

SPLITS = ("train", "val", "test")
HOLDOUT_EVERY = 8  # nerfstudio-style deterministic split when transforms.json lists no split files


class DatasetError(Exception):
    """Bad dataset input; the message names the file, frame and field concerned."""


@dataclass
class FrameInfo:
    """One frame's metadata before its pixels are read."""

    index: int  # position in its JSON file's ``frames`` list
    json_file: Path
    file_path: str  # as written in the JSON
    image: Path  # resolved image file
    c2w: np.ndarray  # (4, 4)
    intrinsics: Dict[str, float]  # any of fl_x fl_y cx cy w h camera_angle_x camera_angle_y
    depth: Optional[Path] = None
    normal: Optional[Path] = None
    mask: Optional[Path] = None
    outside: List[str] = field(default_factory=list)  # fields whose file lies outside the dataset folder

    @property
    def where(self) -> str:
        return f"{self.json_file}: frame {self.index} ({self.file_path})"

    @property
    def stem(self) -> str:
        return Path(self.file_path).stem if Path(self.file_path).suffix else Path(self.file_path).name


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
        rgb = px[..., :3]
        if not self.has_alpha:
            return rgb, torch.ones_like(rgb[..., 0])
        alpha = px[..., 3]
        bg = torch.as_tensor(background, dtype=torch.float32)
        return rgb * alpha[..., None] + bg * (1.0 - alpha[..., None]), alpha


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

    def split(self, name: str) -> Split:
        if name not in self.splits or len(self.splits[name]) == 0:
            have = ", ".join(k for k, v in self.splits.items() if len(v)) or "none"
            raise DatasetError(f"{self.root}: the dataset has no {name!r} split (splits with views: {have})")
        return self.splits[name]

    def held_out_split(self, preferred: Sequence[str] = ("test", "val")) -> Optional[str]:
        """The first non-empty split of ``preferred`` (never train), or None."""
        for name in preferred:
            if name in self.splits and len(self.splits[name]):
                return name
        return None


# ----------------------------------------------------------------------------------------------
# metadata


def _read_json(path: Path) -> dict:
    try:
        with open(path, encoding="utf-8") as f:
            meta = json.load(f)
    except FileNotFoundError as exc:
        raise DatasetError(f"{path}: file not found") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from exc
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: expected a JSON object with 'frames'")
    return meta


INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")


def _intrinsics(src: dict, where: str) -> Dict[str, float]:
    out = {}
    for key in INTRINSIC_KEYS:
        if key in src and src[key] is not None:
            try:
                value = float(src[key])
            except (TypeError, ValueError) as exc:
                raise DatasetError(f"{where}: field {key!r} is not a number ({src[key]!r})") from exc
            if not math.isfinite(value) or (key != "cx" and key != "cy" and value <= 0):
                raise DatasetError(f"{where}: field {key!r} must be a positive finite number, got {src[key]!r}")
            if key in ("camera_angle_x", "camera_angle_y") and value >= math.pi:
                # tan(fov / 2) turns negative past pi: a negative focal length would mirror every ray.
                raise DatasetError(f"{where}: field {key!r} is a field of view in radians and must lie in (0, pi), "
                                   f"got {src[key]!r}")
            out[key] = value
    return out


def resolve_dataset_path(root: Path, value, where: str, field_name: str) -> tuple[Path, bool]:
    """The one rule for file paths written in a dataset's JSON: (resolved path, lies outside ``root``).

    Relative paths are taken from the JSON file's folder. Policy: absolute paths and relative paths
    that climb out of the dataset folder (``../``) are *allowed*, because other tools write them and
    reading an image runs nothing, but they are reported (``load_dataset`` adds a note, ``check`` a
    warning): a copy of the folder, or another machine, will not find those files. Containment is
    decided on the path as written (normalised, not following symlinks), so a dataset that links its
    image folders from elsewhere stays inside. A value that is not a non-empty string is refused.
    """
    if not isinstance(value, str) or not value.strip():
        raise DatasetError(f"{where}: field {field_name!r} must be a non-empty string (a file path), got {value!r}")
    p = Path(value)
    if p.is_absolute():
        return p, True
    lexical = os.path.normpath(os.path.join(str(root), value))
    inside = os.path.commonpath([os.path.abspath(lexical), os.path.abspath(str(root))]) == os.path.abspath(str(root))
    return (root / value).resolve(), not inside


def _resolve_image(root: Path, file_path: str, add_png: bool) -> Path:
    p = (root / file_path).resolve() if not Path(file_path).is_absolute() else Path(file_path)
    if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".exr") and p.is_file():
        return p
    if add_png:
        for ext in (".png", ".exr"):
            cand = p.with_name(p.name + ext)
            if cand.is_file():
                return cand
        return p.with_name(p.name + ".png") if not p.suffix else p
    return p


def _frames_of(meta: dict, json_file: Path, add_png: bool) -> List[FrameInfo]:
    frames = meta.get("frames")
    if not isinstance(frames, list):
        raise DatasetError(f"{json_file}: field 'frames' is missing or not a list")
    glob = _intrinsics(meta, f"{json_file}")
    root = json_file.parent
    out = []
    for k, fr in enumerate(frames):
        if not isinstance(fr, dict) or "file_path" not in fr:
            raise DatasetError(f"{json_file}: frame {k}: field 'file_path' is missing")
        _, image_outside = resolve_dataset_path(root, fr["file_path"], f"{json_file}: frame {k}", "file_path")
        fp = str(fr["file_path"])
        where = f"{json_file}: frame {k} ({fp})"
        if "transform_matrix" not in fr:
            raise DatasetError(f"{where}: field 'transform_matrix' is missing")
        try:
            c2w = check_pose(fr["transform_matrix"], f"{where}: field 'transform_matrix'")
        except PoseError as exc:
            raise DatasetError(str(exc)) from exc
        intr = dict(glob)
        intr.update(_intrinsics(fr, where))
        extra = {}
        outside = ["file_path"] if image_outside else []
        for key, attr in (("depth_file_path", "depth"), ("depth_path", "depth"), ("normal_file_path", "normal"), ("mask_path", "mask")):
            if fr.get(key) not in (None, "") and attr not in extra:
                extra[attr], out_of_root = resolve_dataset_path(root, fr[key], where, key)
                if out_of_root:
                    outside.append(key)
        out.append(FrameInfo(k, json_file, fp, _resolve_image(root, fp, add_png), c2w, intr, outside=outside, **extra))
    return out


def detect_layout(path: Path) -> tuple[str, Path]:
    """('synthetic'|'nerfstudio', dataset root) for a dataset folder or one of its transforms files."""
    path = Path(path)
    if path.is_file():
        if path.name.startswith("transforms_") and path.suffix == ".json":
            return "synthetic", path.parent
        return "nerfstudio", path.parent
    if not path.exists():
        raise DatasetError(f"{path}: dataset folder not found")
    if (path / "transforms_train.json").is_file():
        return "synthetic", path
    if (path / "transforms.json").is_file():
        return "nerfstudio", path
    raise DatasetError(f"{path}: no transforms_train.json or transforms.json in this folder")


def frame_infos(path: Path | str, splits: Sequence[str] = SPLITS) -> tuple[str, Path, Dict[str, List[FrameInfo]], dict]:
    """Parse the metadata of a dataset without reading pixels.

    Returns (layout, root, {split: [FrameInfo]}, scene) where scene holds ``aabb``, ``near``,
    ``far``, ``depth_unit_scale_factor`` and ``aabb_file`` when the dataset gives them.
    """
    path = Path(path)
    layout, root = detect_layout(path)
    out: Dict[str, List[FrameInfo]] = {}
    scene: dict = {}
    if layout == "synthetic":
        for name in splits:
            jf = root / f"transforms_{name}.json"
            if path.is_file() and path.name.startswith("transforms_") and jf != path and name == "train" and not jf.is_file():
                jf = path
            if not jf.is_file():
                if name == "train":
                    raise DatasetError(f"{jf}: file not found (the training split is required)")
                out[name] = []
                continue
            meta = _read_json(jf)
            out[name] = _frames_of(meta, jf, add_png=True)
            if name in ("train", "val", "test") and not out[name]:
                raise DatasetError(f"{jf}: split {name!r} is empty (field 'frames' has no entries)")
            for key in ("aabb", "near", "far", "film_transparent", "world"):
                if key in meta and key not in scene:
                    scene[key] = meta[key]
                    scene[key + "_file"] = jf
    else:
        jf = path if path.is_file() else root / "transforms.json"
        meta = _read_json(jf)
        frames = _frames_of(meta, jf, add_png=False)
        if not frames:
            raise DatasetError(f"{jf}: field 'frames' has no entries")
        for key in ("aabb", "near", "far", "depth_unit_scale_factor", "film_transparent", "world"):
            if key in meta:
                scene[key] = meta[key]
                scene[key + "_file"] = jf

        def norm(p: str) -> str:
            return str(Path(p))  # "./images/a.png" and "images/a.png" name the same frame

        lists = {name: meta.get(f"{name}_filenames") for name in SPLITS}
        if lists["train"] is not None:
            by_name = {norm(f.file_path): f for f in frames}
            for name in splits:
                names = lists.get(name) or (lists.get("val") if name == "test" else lists.get("test") if name == "val" else None) or []
                chosen = []
                for n in names:
                    if norm(n) not in by_name:
                        raise DatasetError(f"{jf}: field '{name}_filenames' lists {n!r}, which is not a frame's file_path")
                    chosen.append(by_name[norm(n)])
                out[name] = chosen
            if not out.get("train"):
                raise DatasetError(f"{jf}: field 'train_filenames' is empty")
        else:
            order = sorted(range(len(frames)), key=lambda k: frames[k].file_path)
            held = {k for pos, k in enumerate(order) if len(frames) > 1 and pos % HOLDOUT_EVERY == 0}
            for name in splits:
                if name == "train":
                    out[name] = [frames[k] for k in order if k not in held]
                else:
                    out[name] = [frames[k] for k in order if k in held]
            scene["split_note"] = (
                f"{jf}: no train_filenames/val_filenames/test_filenames; held out every {HOLDOUT_EVERY}th frame "
                f"(by file name) as val/test: {len(held)} of {len(frames)}"
            )
    for name in splits:
        out.setdefault(name, [])
    away = [(f, key) for frames in out.values() for f in frames for key in f.outside]
    if away:
        f, key = away[0]
        scene["path_note"] = (f"{len(away)} file path(s) point outside the dataset folder (absolute or '../'), e.g. "
                              f"{f.where}: field {key!r}; they are read, but a copy of the folder or another "
                              "machine will not find them")
    return layout, root, out, scene


# ----------------------------------------------------------------------------------------------
# pixels


def _load_pixels(fr: FrameInfo, downscale: int) -> np.ndarray:
    if not fr.image.is_file():
        raise DatasetError(f"{fr.where}: field 'file_path': image {fr.image} not found")
    try:
        if fr.image.suffix.lower() == ".exr":
            img = read_exr_rgba(fr.image)
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
        img = _downscale(img, downscale)
    return img


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


def _camera_params(fr: FrameInfo, img_w: int, img_h: int, downscale: int) -> tuple:
    intr = fr.intrinsics
    w_decl, h_decl = intr.get("w"), intr.get("h")
    full_w = img_w * downscale if downscale > 1 else img_w
    full_h = img_h * downscale if downscale > 1 else img_h
    if w_decl is not None and h_decl is not None and downscale == 1 and (int(w_decl) != img_w or int(h_decl) != img_h):
        raise DatasetError(
            f"{fr.where}: fields 'w'/'h' say {int(w_decl)}x{int(h_decl)} but {fr.image} is {img_w}x{img_h}"
        )
    W = float(w_decl) if w_decl is not None else float(full_w)
    H = float(h_decl) if h_decl is not None else float(full_h)
    if "fl_x" in intr:
        fx = intr["fl_x"]
    elif "camera_angle_x" in intr:
        fx = 0.5 * W / math.tan(0.5 * intr["camera_angle_x"])
    elif "fl_y" in intr:
        fx = intr["fl_y"]
    else:
        raise DatasetError(f"{fr.where}: no focal length (fields 'fl_x' or 'camera_angle_x' missing)")
    if "fl_y" in intr:
        fy = intr["fl_y"]
    elif "camera_angle_y" in intr and "fl_x" not in intr and "camera_angle_x" not in intr:
        fy = 0.5 * H / math.tan(0.5 * intr["camera_angle_y"])
    else:
        fy = fx
    cx = intr.get("cx", W / 2.0)
    cy = intr.get("cy", H / 2.0)
    s_x, s_y = img_w / W, img_h / H
    return fx * s_x, fy * s_y, cx * s_x, cy * s_y


def load_split(
    name: str,
    frames: List[FrameInfo],
    downscale: int = 1,
    depth_scale: float = 1e-3,
    load_extras: bool = True,
) -> Split:
    """Read the pixels (and depth, normals, masks) of one split's frames."""
    images, params = [], []
    size = None
    for fr in frames:
        img = _load_pixels(fr, downscale)
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
        params.append(_camera_params(fr, img.shape[1], img.shape[0], downscale))
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
        p[:, 0], p[:, 1], p[:, 2], p[:, 3], np.full(len(frames), w), np.full(len(frames), h)
    )
    split = Split(name, cams, stack, list(frames))
    if not load_extras or not frames:
        return split
    if any(f.depth for f in frames):
        depths = []
        for fr in frames:
            if fr.depth is None:
                depths.append(np.zeros((h, w), np.float32))
                continue
            try:
                d = read_depth(fr.depth, png_scale=depth_scale)
            except ImageReadError as exc:
                raise DatasetError(f"{fr.where}: field 'depth_file_path': {exc}") from exc
            if downscale > 1:
                d = _resize_map(d, downscale, "nearest")
            if d.shape != (h, w):
                raise DatasetError(f"{fr.where}: field 'depth_file_path': {fr.depth} is {d.shape[1]}x{d.shape[0]}, image is {w}x{h}")
            depths.append(d)
        split.depth = torch.from_numpy(np.stack(depths))
    if any(f.normal for f in frames):
        normals = []
        for fr in frames:
            if fr.normal is None:
                normals.append(np.zeros((h, w, 3), np.float32))
                continue
            try:
                nm = read_normals(fr.normal)
            except ImageReadError as exc:
                raise DatasetError(f"{fr.where}: field 'normal_file_path': {exc}") from exc
            if downscale > 1:
                nm = _resize_map(nm, downscale, "nearest")
            if nm.shape[:2] != (h, w):
                raise DatasetError(f"{fr.where}: field 'normal_file_path': {fr.normal} is {nm.shape[1]}x{nm.shape[0]}, image is {w}x{h}")
            normals.append(nm)
        split.normals = torch.from_numpy(np.stack(normals))
    if any(f.mask for f in frames):
        masks = []
        for fr in frames:
            if fr.mask is None:
                masks.append(np.ones((h, w), bool))
                continue
            try:
                mk = read_mask(fr.mask)
            except ImageReadError as exc:
                raise DatasetError(f"{fr.where}: field 'mask_path': {exc}") from exc
            if downscale > 1:
                mk = _resize_map(mk, downscale, "nearest")
            if mk.shape != (h, w):
                raise DatasetError(f"{fr.where}: field 'mask_path': {fr.mask} is {mk.shape[1]}x{mk.shape[0]}, image is {w}x{h}")
            masks.append(mk)
        split.masks = torch.from_numpy(np.stack(masks))
    return split


# ----------------------------------------------------------------------------------------------
# scene box


def _parse_aabb(value, where: str) -> torch.Tensor:
    try:
        box = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: field 'aabb' is not a numeric [[xmin,ymin,zmin],[xmax,ymax,zmax]]") from exc
    if box.shape != (2, 3) or not np.all(np.isfinite(box)) or not np.all(box[1] > box[0]):
        raise DatasetError(f"{where}: field 'aabb' must be [[xmin,ymin,zmin],[xmax,ymax,zmax]] with min < max, got {value!r}")
    return torch.tensor(box, dtype=torch.float32)


def estimate_aabb(cameras: Cameras, far: Optional[float] = None,
                  seen: Optional[torch.Tensor] = None) -> tuple[torch.Tensor, str]:
    """A scene box from the cameras alone, for datasets that give no ``aabb``.

    Inward-facing captures: the box is centred on the point closest (least squares) to all optical
    axes, with half-size 0.5 x the median camera distance to that point (the synthetic scenes fit
    in +-1.5 with cameras at radius 4 -> +-2). Cameras that look outward or the same way (an
    interior, a street; the least squares is ill-posed or behind them): a box holding every camera
    and what they see, from ``seen`` (m, 3) surface points back-projected from depth maps when the
    dataset has them (``depth_points``), else ``far`` (or twice the camera spread) ahead of each camera.
    """
    o = cameras.origins.double().numpy()
    d = cameras.forward.double().numpy()
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = proj.sum(0)
    b = np.einsum("nij,nj->i", proj, o)
    if np.linalg.cond(A) < 1e3:
        centre = np.linalg.solve(A, b)
        in_front = np.einsum("ni,ni->n", centre[None] - o, d)
        if np.all(in_front > 0):
            radius = float(np.median(np.linalg.norm(o - centre, axis=1)))
            half = 0.5 * radius
            box = np.stack([centre - half, centre + half])
            note = (f"no 'aabb' in the dataset: estimated a box centred at {np.round(centre, 3).tolist()} "
                    f"(where the cameras look) of half-size {half:.3g} (0.5 x median camera distance)")
            return torch.tensor(box, dtype=torch.float32), note
    if seen is not None and len(seen) >= 16:
        pts = seen.double().numpy()
        # Robust extent of what the cameras see (a few stray depth pixels must not blow the box up).
        lo, hi = np.percentile(pts, 0.5, axis=0), np.percentile(pts, 99.5, axis=0)
        lo, hi = np.minimum(lo, o.min(0)), np.maximum(hi, o.max(0))
        pad = 0.05 * (hi - lo)
        box = np.stack([lo - pad, hi + pad])
        note = ("no 'aabb' in the dataset and the cameras do not look at a common centre: estimated a box holding "
                f"every camera and the {len(pts)} surface points their depth maps show")
        return torch.tensor(box, dtype=torch.float32), note
    spread = float(np.linalg.norm(o.max(0) - o.min(0))) or 1.0
    depth = float(far) if far else 2.0 * spread
    ahead = o + d * depth
    pts = np.concatenate([o, ahead])
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.05 * (hi - lo).max()
    box = np.stack([lo - pad, hi + pad])
    note = ("no 'aabb' in the dataset and the cameras do not look at a common centre: using a box spanning the "
            f"cameras and {depth:.3g} units in front of them; add 'aabb' to the transforms file for better results")
    return torch.tensor(box, dtype=torch.float32), note


def depth_points(split: "Split", max_points: int = 100_000, seed: int = 0) -> Optional[torch.Tensor]:
    """Up to ``max_points`` (m, 3) world points back-projected from a split's depth maps (planar
    z-depth; 0 or inf = no surface), or None without depth."""
    from .cameras import rays_for_pixels

    if split.depth is None or len(split) == 0:
        return None
    z = split.depth.reshape(-1)
    valid = torch.nonzero(torch.isfinite(z) & (z > 0)).squeeze(-1)
    if valid.numel() == 0:
        return None
    gen = torch.Generator().manual_seed(seed)
    pick = valid[torch.randperm(valid.numel(), generator=gen)[:max_points]]
    hw = split.height * split.width
    view, pix = pick // hw, pick % hw
    rays_o, rays_d, z_per_t = rays_for_pixels(split.cameras, view, pix % split.width, pix // split.width)
    return rays_o + rays_d * (z[pick] / z_per_t)[:, None]


INSIDE_PAD = 0.05  # share of the box's extent added on each side when the cameras stand inside it


def pad_box_for_interior(aabb: torch.Tensor, origins: torch.Tensor) -> tuple[torch.Tensor, Optional[str]]:
    """Grow ``aabb`` (2, 3) by ``INSIDE_PAD`` per side when most camera ``origins`` (n, 3) are inside it.

    Cameras inside the box mean an interior: the box is the room's bounds, so its walls, floor and
    ceiling lie exactly on the box's faces, where a grid has half a cell of support and rays end. The
    surfaces the images show most then sit where the model is weakest, and the transmittance that the
    walls fail to stop leaks into the background. A margin puts them inside. Returns the box and a
    note (None when unchanged).
    """
    if origins.numel() == 0:
        return aabb, None
    inside = ((origins >= aabb[0]) & (origins <= aabb[1])).all(dim=-1)
    if float(inside.float().mean()) < 0.5:
        return aabb, None
    pad = INSIDE_PAD * (aabb[1] - aabb[0])
    note = (f"{int(inside.sum())} of {len(origins)} train cameras stand inside the scene box (an interior): "
            f"grew the box by {100 * INSIDE_PAD:.0f} % of its size on each side so that walls, floor and ceiling "
            "on its faces lie inside it")
    return torch.stack([aabb[0] - pad, aabb[1] + pad]), note


# ----------------------------------------------------------------------------------------------


def _check_train_count(root: Path, infos: Dict[str, List[FrameInfo]], min_train_views: int) -> None:
    n_train = len(infos["train"])
    if n_train < min_train_views:
        jf = infos["train"][0].json_file if infos["train"] else root
        raise DatasetError(
            f"{jf}: field 'frames': the train split has {n_train} view{'s' if n_train != 1 else ''}; a NeRF needs "
            f"many views of the scene (at least {min_train_views}, typically 50-200)"
        )


def _scene_checks(scene: dict) -> tuple:
    """(near, far, film_transparent, world) of a dataset's top-level fields, validated (raises DatasetError)."""
    near = far = None
    for key in ("near", "far"):
        if key in scene:
            try:
                v = float(scene[key])
            except (TypeError, ValueError):
                raise DatasetError(f"{scene[key + '_file']}: field {key!r} is not a number ({scene[key]!r})") from None
            if not math.isfinite(v) or v < 0:
                raise DatasetError(f"{scene[key + '_file']}: field {key!r} must be a finite number >= 0, got {v}")
            near, far = (v, far) if key == "near" else (near, v)
    if near is not None and far is not None and far <= near:
        raise DatasetError(f"{scene['far_file']}: field 'far' ({far}) must be greater than 'near' ({near})")
    film = scene.get("film_transparent")
    if film is not None and not isinstance(film, bool):
        raise DatasetError(f"{scene['film_transparent_file']}: field 'film_transparent' must be true or false, got {film!r}")
    world = scene.get("world")
    if world is not None and not isinstance(world, dict):
        raise DatasetError(f"{scene['world_file']}: field 'world' must be an object, got {type(world).__name__}")
    return near, far, film, world


def dataset_problems(path: Path | str, downscale: int = 1, min_train_views: int = 2) -> List[str]:
    """Every problem that makes ``load_dataset`` refuse ``path``, one message each (file, frame, field).

    The one validation pass behind ``train`` and ``check``: it runs the loader's own rules
    (``frame_infos``, ``_scene_checks``, ``_check_train_count`` and ``load_split`` frame by frame, which
    decodes every image, depth, normal and mask file and checks its size against the JSON and the
    split), collecting the errors that ``load_dataset`` raises at the first of. An empty list means
    ``train`` accepts the dataset. Pixels are read one frame at a time and dropped.
    """
    try:
        layout, root, infos, scene = frame_infos(path, SPLITS)
    except DatasetError as exc:
        return [str(exc)]
    problems: List[str] = []
    for check in (lambda: _check_train_count(root, infos, min_train_views), lambda: _scene_checks(scene),
                  lambda: _parse_aabb(scene["aabb"], str(scene["aabb_file"])) if "aabb" in scene else None):
        try:
            check()
        except DatasetError as exc:
            problems.append(str(exc))
    try:
        depth_scale = _depth_scale(scene)
    except DatasetError as exc:
        problems.append(str(exc))
        depth_scale = 1e-3
    for name in SPLITS:
        first = None
        for fr in infos[name]:
            try:
                sp = load_split(name, [fr], downscale, depth_scale)
            except DatasetError as exc:
                problems.append(str(exc))
                continue
            shape = (sp.width, sp.height, sp.images.shape[-1])
            if first is None:
                first = (fr, shape)
                continue
            try:
                if shape[:2] != first[1][:2]:
                    raise DatasetError(
                        f"{fr.where}: field 'file_path': {fr.image} is {shape[0]}x{shape[1]} but the first {name} image "
                        f"({first[0].image.name}) is {first[1][0]}x{first[1][1]}; all images of a split must have one size")
                if shape[2] != first[1][2]:
                    lacking = fr if shape[2] == 3 else first[0]
                    raise DatasetError(
                        f"{lacking.where}: field 'file_path': {lacking.image} has no alpha channel while other {name} "
                        "images do; the alpha channel is the mask of the object, export every image as RGBA")
            except DatasetError as exc:
                problems.append(str(exc))
    return problems


def _depth_scale(scene: dict) -> float:
    v = scene.get("depth_unit_scale_factor", 1e-3)
    try:
        f = float(v)
    except (TypeError, ValueError):
        f = float("nan")
    if not math.isfinite(f) or f <= 0:
        raise DatasetError(f"{scene.get('depth_unit_scale_factor_file')}: field 'depth_unit_scale_factor' must be a "
                           f"positive number, got {v!r}")
    return f


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
    notes = []
    for key in ("split_note", "path_note"):
        if key in scene:
            notes.append(scene[key])
    depth_scale = _depth_scale(scene)
    if "train" in splits:
        _check_train_count(root, infos, min_train_views)
    train_names = {str(f.image) for f in infos["train"]}
    for name in ("val", "test"):
        if name in splits:
            leaked = [f for f in infos[name] if str(f.image) in train_names]
            if leaked:
                notes.append(f"{leaked[0].where}: {len(leaked)} {name} frame(s) use training images; "
                             "their metrics will not measure novel views")
    near, far, film, world = _scene_checks(scene)
    loaded = {name: load_split(name, infos[name], downscale, depth_scale) for name in splits}
    for name in SPLITS:
        if name not in loaded:
            loaded[name] = load_split(name, [], downscale, depth_scale)
    if "aabb" in scene:
        aabb = _parse_aabb(scene["aabb"], str(scene["aabb_file"]))
        source = f"dataset ({Path(scene['aabb_file']).name})"
    else:
        all_cams = [s.cameras for s in loaded.values() if len(s)]
        cams = Cameras(*(torch.cat([getattr(c, f) for c in all_cams]) for f in ("c2w", "fx", "fy", "cx", "cy", "width", "height")))
        aabb, source = estimate_aabb(cams, far, depth_points(loaded["train"]) if "train" in loaded else None)
        notes.append(source)
    inside_note = None
    if len(loaded["train"]):
        aabb, inside_note = pad_box_for_interior(aabb, loaded["train"].cameras.origins)
        if inside_note:
            notes.append(inside_note)
            source += "; padded around the cameras standing inside it"
    return Dataset(Path(root), layout, loaded, aabb, source, near, far, notes, film, world,
                   cameras_inside=inside_note is not None)


def load_cameras(path: Path | str, split: str = "test") -> tuple[Cameras, List[FrameInfo]]:
    """Cameras of one split of a transforms file without reading pixels (image sizes come from the
    JSON, or from the image headers when ``w``/``h`` are absent)."""
    if split not in SPLITS:
        raise DatasetError(f"unknown split {split!r}; choose one of {', '.join(SPLITS)}")
    layout, root, infos, _ = frame_infos(path, SPLITS)
    frames = infos.get(split) or []
    if not frames:
        raise DatasetError(f"{path}: no frames in split {split!r}")
    return cameras_of_frames(frames), frames


def cameras_of_frames(frames: List[FrameInfo]) -> Cameras:
    """Cameras of parsed frames without reading pixels: sizes from ``w``/``h``, else the image headers."""
    from .imageio import png_info

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
    return Cameras.create(np.stack([f.c2w for f in frames]), p[:, 0], p[:, 1], p[:, 2], p[:, 3], s[:, 0], s[:, 1])


# ----------------------------------------------------------------------------------------------
# training batches


class RayBatcher:
    """Random ray batches over every pixel of a (train) split; images stay uint8 on the CPU.

    ``background`` is a ``train --background`` mode other than ``auto`` (see ``nerf_core.backgrounds``);
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
        from .backgrounds import AUTO_WHITE_FRACTION
        from .cameras import rays_for_pixels

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
