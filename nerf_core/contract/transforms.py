"""Reading transforms files: the JSON, its frames, camera poses and the file paths they name.

The one reader behind ``nerf_core.data.loading`` (training, eval), ``nerf_core.render.views`` (camera files) and the
add-on. Standard library and numpy only (see ``nerf_core.contract``).

Layouts (docs/CONTRACTS.md):

* synthetic: ``transforms_{train,val,test}.json``, ``frames[*].file_path`` without extension
  (``./train/r_0`` -> ``train/r_0.png``);
* nerfstudio: one ``transforms.json`` with real file names and optional
  ``train_filenames``/``val_filenames``/``test_filenames``; without them every ``HOLDOUT_EVERY``-th
  frame (by file name) is held out and serves as val and test.

Every problem raises ``DatasetError`` whose message names the file, frame and field.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from .colmap_model import find_sparse
from .errors import DatasetError, PoseError
from .jsonfile import read_json
from .lens import DISTORTION_KEYS, Lens, lens_problem, parse_lens
from .naming import frame_stem
from .paths import IMAGE_EXTS, file_problem, not_a_regular_file, why_not_a_file
from .poses import MAX_COORDINATE, check_pose, short_repr

SPLITS = ("train", "val", "test")
# Top-level fields that describe the scene rather than one camera; the first split file that has one
# gives it. ``integer_depth_scale`` is instant-ngp's metres per 16-bit depth count, nerfstudio's
# ``depth_unit_scale_factor`` the same (``dataset_checks.depth_scale``).
SCENE_KEYS = ("aabb", "near", "far", "depth_unit_scale_factor", "integer_depth_scale", "film_transparent", "world",
              "beyond_box", "pixel_filter")
HOLDOUT_EVERY = 8  # nerfstudio-style deterministic split when transforms.json lists no split files
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")
# Per-frame extra channels: JSON field -> FrameInfo attribute. Earlier fields win for one attribute
# (nerfstudio's ``depth_file_path`` before instant-ngp's ``depth_path``).
EXTRA_FIELDS = (("depth_file_path", "depth"), ("depth_path", "depth"), ("normal_file_path", "normal"),
                ("mask_path", "mask"))
# Focal lengths in pixels that float32 rays survive: at 1e-3 px a pixel's ray is 1000 image widths off
# the axis (a field of view within a hair of 180 degrees); at 1e8 px a 100 k-pixel image spans 1e-3 rad.
MIN_FOCAL_PX, MAX_FOCAL_PX = 1e-3, 1e8
# Readers of layouts without transforms files: layout -> fn(root, splits) -> (root, {split: frames}, scene).
# ``contract.colmap_dataset`` registers "colmap" (it builds on this module, so it cannot be imported here).
LAYOUT_READERS: dict = {}


def check_camera_model(src: dict, where: str) -> None:
    """Lens fields of ``src`` that cannot be read (``contract.lens.lens_problem``: a model other than a
    pinhole, OPENCV or OPENCV_FISHEYE, a coefficient that is not a finite number or belongs to a model
    not read here) as a DatasetError naming ``where`` and the field."""
    problem = lens_problem(src)
    if problem is not None:
        raise DatasetError(f"{where}: field {problem[0]!r}: {problem[1]}")


def parse_intrinsics(src: dict, where: str) -> Dict[str, float]:
    """The intrinsic fields (``INTRINSIC_KEYS``) present in ``src``, as validated floats; refuses lens
    fields that cannot be read (``check_camera_model``; the lens itself is ``FrameInfo.lens``)."""
    check_camera_model(src, where)
    out = {}
    for key in INTRINSIC_KEYS:
        if key in src and src[key] is not None:
            if isinstance(src[key], (bool, str)):  # "44.4" or true: a writer's bug, as in a matrix (check_pose)
                raise DatasetError(f"{where}: field {key!r} is not a number ({src[key]!r})")
            try:
                value = float(src[key])
            except (TypeError, ValueError, OverflowError) as exc:
                raise DatasetError(f"{where}: field {key!r} is not a number ({short_repr(src[key])})") from exc
            if not math.isfinite(value) or (key != "cx" and key != "cy" and value <= 0):
                raise DatasetError(
                    f"{where}: field {key!r} must be a positive finite number, got {short_repr(src[key])}"
                )
            if key in ("fl_x", "fl_y") and not MIN_FOCAL_PX <= value <= MAX_FOCAL_PX:
                raise DatasetError(f"{where}: field {key!r} is a focal length in pixels and must lie in "
                                   f"[{MIN_FOCAL_PX:g}, {MAX_FOCAL_PX:g}] (float32 rays turn to NaN or parallel "
                                   f"beyond), got {value:.4g}")
            if key in ("cx", "cy", "w", "h") and abs(value) > MAX_COORDINATE:
                raise DatasetError(f"{where}: field {key!r} is {value:.4g} pixels, beyond {MAX_COORDINATE:.0e}")
            if key in ("w", "h") and not value.is_integer():
                raise DatasetError(f"{where}: field {key!r} is an image size and must be a whole number of pixels, "
                                   f"got {src[key]!r}")
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
    root = Path(root)
    if not isinstance(value, str) or not value.strip():
        raise DatasetError(f"{where}: field {field_name!r} must be a non-empty string (a file path), got {value!r}")
    if "\0" in value:
        raise DatasetError(f"{where}: field {field_name!r} contains a NUL character, which no file name can hold: "
                           f"{value!r}")
    if len(value) > 4096:
        raise DatasetError(f"{where}: field {field_name!r} is {len(value)} characters long; no file system "
                           "accepts a path that long")
    p = Path(value)
    if p.is_absolute():
        return p, True
    lexical = os.path.normpath(os.path.join(str(root), value))
    inside = os.path.commonpath([os.path.abspath(lexical), os.path.abspath(str(root))]) == os.path.abspath(str(root))
    return (root / value).resolve(), not inside


def resolve_image(root: Path, file_path: str, add_png: bool) -> Path:
    """The image a ``file_path`` names. ``add_png`` (synthetic layout): a path without extension gets
    ``.png`` (else ``.exr``, when only that exists), as the original loaders add it."""
    if "\0" in file_path:  # no file has this name (resolve() would raise); the caller names the field
        return Path(root) / file_path
    p = (Path(root) / file_path).resolve() if not Path(file_path).is_absolute() else Path(file_path)
    if p.suffix.lower() in IMAGE_EXTS and p.is_file():
        return p
    if add_png:
        for ext in (".png", ".exr"):
            cand = p.with_name(p.name + ext)
            if cand.is_file():
                return cand
        return p.with_name(p.name + ".png") if not p.suffix else p
    return p


@dataclass
class FrameInfo:
    """One frame's metadata before its pixels are read."""

    index: int  # position in its JSON file's ``frames`` list
    json_file: Path
    file_path: str  # as written in the JSON
    image: Path  # resolved image file
    c2w: np.ndarray  # (4, 4) float64
    intrinsics: Dict[str, float]  # any of INTRINSIC_KEYS, frame values over the file's
    depth: Optional[Path] = None
    normal: Optional[Path] = None
    mask: Optional[Path] = None
    outside: List[str] = field(default_factory=list)  # fields whose file lies outside the dataset folder
    name: Optional[str] = None  # the frame's optional ``name`` field (names its render outputs)
    lens: Optional[Lens] = None  # the distortion of its camera (``contract.lens``); None = a pinhole
    # 8-bit alpha that ``image`` (RGB) was composited with onto white (our COLMAP export's masks/): the
    # loader restores the RGBA film from the two; None for every other dataset
    alpha: Optional[Path] = None

    @property
    def where(self) -> str:
        return f"{self.json_file}: frame {self.index} ({self.file_path})"

    @property
    def stem(self) -> str:
        """The frame's name before de-duplication (``naming.frame_stem``)."""

        return frame_stem({"name": self.name, "file_path": self.file_path}, self.index)


def read_frames(meta: dict, json_file: Path, add_png: bool) -> List[FrameInfo]:
    """The validated frames of one transforms file's object ``meta`` (read from ``json_file``)."""
    json_file = Path(json_file)
    frames = meta.get("frames")
    if not isinstance(frames, list):
        raise DatasetError(f"{json_file}: field 'frames' is missing or not a list")
    glob = parse_intrinsics(meta, f"{json_file}")
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
        intr.update(parse_intrinsics(fr, where))
        extra = {}
        outside = ["file_path"] if image_outside else []
        for key, attr in EXTRA_FIELDS:
            if fr.get(key) not in (None, "") and attr not in extra:
                extra[attr], out_of_root = resolve_dataset_path(root, fr[key], where, key)
                if out_of_root:
                    outside.append(key)
        name = fr.get("name") if isinstance(fr.get("name"), str) else None
        lens, problem = parse_lens(meta, fr)
        if problem:
            raise DatasetError(f"{where}: field {problem[0]!r}: {problem[1]}")
        out.append(FrameInfo(k, json_file, fp, resolve_image(root, fp, add_png), c2w, intr, outside=outside,
                             name=name, lens=lens, **extra))
    return out


def read_transforms(path: Path | str) -> List[FrameInfo]:
    """Every frame of one transforms file (``.png`` is added to extension-less paths)."""
    path = Path(path)
    frames = read_frames(read_json(path), path, add_png=True)
    if not frames:
        raise DatasetError(f"{path}: field 'frames' has no entries")
    return frames


def detect_layout(path: Path | str) -> tuple[str, Path]:
    """('synthetic'|'nerfstudio'|'colmap', dataset root) for a dataset folder or one of its transforms files
    (a COLMAP folder: ``images/`` and ``sparse/0`` or ``sparse`` with a model, and no transforms file)."""
    path = Path(path)
    if path.is_file():
        if path.name.startswith("transforms_") and path.suffix == ".json":
            return "synthetic", path.parent
        return "nerfstudio", path.parent
    if not path.exists():
        raise DatasetError(f"{path}: dataset folder {why_not_a_file(path)}")
    if not path.is_dir():
        raise DatasetError(f"{path}: {not_a_regular_file(path) or 'is not a dataset folder'}")
    for name, layout in (("transforms_train.json", "synthetic"), ("transforms.json", "nerfstudio")):
        if os.path.lexists(path / name):  # a pipe or a dangling link is named below, not "missing"
            problem = file_problem(path / name)
            if problem:
                raise DatasetError(f"{path / name}: {problem}")
            return layout, path
    if (path / "images").is_dir() and find_sparse(path) not in (None, path):
        return "colmap", path
    raise DatasetError(f"{path}: no transforms_train.json or transforms.json in this folder (nor a COLMAP model: "
                       "images/ and sparse/0/)")


def frame_infos(path: Path | str, splits: Sequence[str] = SPLITS) -> tuple[str, Path, Dict[str, List[FrameInfo]], dict]:
    """Parse the metadata of a dataset without reading pixels.

    Returns (layout, root, {split: [FrameInfo]}, scene) where scene holds ``aabb``, ``near``,
    ``far``, ``depth_unit_scale_factor``, ``integer_depth_scale``, ``film_transparent``, ``world`` and
    ``beyond_box`` when the dataset gives them (each with ``KEY_file``, the file it came from),
    ``split_note``/``path_note``, ``notes`` (held-out splits left out, instant-ngp fields not applied),
    and ``cameras_only``: {split: [FrameInfo]}
    of held-out splits none of whose images exists (left out of the split itself, but views to render).
    """
    path = Path(path)
    layout, root = detect_layout(path)
    out: Dict[str, List[FrameInfo]] = {}
    scene: dict = {}
    if layout in LAYOUT_READERS:
        root, out, scene = LAYOUT_READERS[layout](root, splits)
    elif layout == "synthetic":
        for name in splits:
            jf = root / f"transforms_{name}.json"
            if path.is_file() and path.name.startswith("transforms_") and jf != path and name == "train":
                if not jf.is_file():
                    jf = path
                else:
                    # `train DS/transforms_test.json` looks like a request to train on the test views.
                    scene.setdefault("notes", []).append(
                        f"{path.name} is given as the dataset: the dataset is its folder, {root}, so training "
                        f"uses {jf.name} and {path.name} stays held out")
            if not jf.is_file():
                if name == "train":
                    raise DatasetError(f"{jf}: file not found (the training split is required)")
                out[name] = []
                continue
            meta = read_json(jf)
            out[name] = read_frames(meta, jf, add_png=True)
            if name == "train" and not out[name]:
                raise DatasetError(f"{jf}: split {name!r} is empty (field 'frames' has no entries)")
            if not out[name]:
                # 3DGS's Blender loader takes an empty test split (BlenderNeRF writes one): no held-out
                # views there, as when the file is missing.
                scene.setdefault("notes", []).append(f"{jf}: no frames; nothing of split {name!r} is "
                                                              "evaluated")
            elif name != "train" and not any(f.image.exists() for f in out[name]):
                # A split of cameras only (BlenderNeRF's test poses): nothing to score, but render can
                # draw them (``render RUN --cameras`` that file).
                scene.setdefault("notes", []).append(
                    f"{jf}: none of its {len(out[name])} images exists (a split of cameras only): not evaluated; "
                    f"`python -m nerf_core render RUN` renders those views")
                # kept apart: they hold no pixels to train or score, but they are views to render
                scene.setdefault("cameras_only", {})[name] = out[name]
                out[name] = []
            for key in SCENE_KEYS:
                if key in meta and key not in scene:
                    scene[key] = meta[key]
                    scene[key + "_file"] = jf
    else:
        jf = path if path.is_file() else root / "transforms.json"
        meta = read_json(jf)
        frames = read_frames(meta, jf, add_png=False)
        if not frames:
            raise DatasetError(f"{jf}: field 'frames' has no entries")
        for key in SCENE_KEYS:
            if key in meta:
                scene[key] = meta[key]
                scene[key + "_file"] = jf
        ngp = [k for k in ("scale", "offset") if k in meta]
        if ngp:
            # instant-ngp fits its own unit cube with these; the poses as written are the scene's, and
            # the box comes from the cameras (or 'aabb'), so they change nothing here: say so.
            scene.setdefault("notes", []).append(
                f"{jf}: instant-ngp's {' and '.join(repr(k) for k in ngp)} are not applied: poses are read as "
                "written, and the scene box comes from 'aabb' or the cameras")
        overridden = _overridden_intrinsics(meta)
        if overridden:
            scene.setdefault("notes", []).append(f"{jf}: {overridden}")
        _nerfstudio_splits(meta, jf, frames, splits, out, scene)
    for name in splits:
        out.setdefault(name, [])
    away = [(f, key) for frames in out.values() for f in frames for key in f.outside]
    if away:
        f, key = away[0]
        scene["path_note"] = (f"{len(away)} file path(s) point outside the dataset folder (absolute or '../'), e.g. "
                              f"{f.where}: field {key!r}; they are read, but a copy of the folder or another "
                              "machine will not find them")
    return layout, root, out, scene


def _overridden_intrinsics(meta: dict) -> Optional[str]:
    """A sentence when frames of one ``transforms.json`` give a camera value (focal, centre, size,
    model, distortion) that differs from the top level's, else None. The tools disagree on which wins:
    instant-ngp (and this loader) take the frame's, nerfstudio's parser the top level's for every
    frame, so the one file means two cameras."""

    frames = meta.get("frames") if isinstance(meta.get("frames"), list) else []
    for key in (*INTRINSIC_KEYS, "camera_model", *DISTORTION_KEYS):
        if key not in meta:
            continue
        differ = [(k, fr[key]) for k, fr in enumerate(frames)
                  if isinstance(fr, dict) and key in fr and fr[key] != meta[key]]
        if differ:
            k, value = differ[0]
            return (f"{len(differ)} frame(s) give their own {key!r} beside the top-level one (frame {k}: {value!r}, "
                    f"top level: {meta[key]!r}); train uses each frame's own, as instant-ngp does, but nerfstudio's "
                    "parser uses the top-level value for every frame. Keep one of the two")
    return None


def _nerfstudio_splits(meta: dict, jf: Path, frames: List[FrameInfo], splits: Sequence[str],
                       out: Dict[str, List[FrameInfo]], scene: dict) -> None:
    """Fill ``out`` with the frames of each split of a nerfstudio ``transforms.json``."""

    def norm(p: str) -> str:
        return str(Path(p))  # "./images/a.png" and "images/a.png" name the same frame

    lists = {name: meta.get(f"{name}_filenames") for name in SPLITS}
    for name, names in lists.items():
        if names is None:
            continue
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise DatasetError(f"{jf}: field '{name}_filenames' must be a list of file paths (strings), got "
                               f"{short_repr(names)}")
        twice = next((n for k, n in enumerate(names) if norm(n) in {norm(m) for m in names[:k]}), None)
        if twice is not None:  # one image twice is one view, however often it is listed
            raise DatasetError(f"{jf}: field '{name}_filenames' lists {twice!r} twice")
    if lists["train"] is not None:
        by_name = {norm(f.file_path): f for f in frames}
        for name in splits:
            names = (
                lists.get(name)
                or (lists.get("val") if name == "test" else lists.get("test") if name == "val" else None)
                or []
            )
            chosen = []
            for n in names:
                if norm(n) not in by_name:
                    raise DatasetError(f"{jf}: field '{name}_filenames' lists {n!r}, which is not a frame's file_path")
                chosen.append(by_name[norm(n)])
            out[name] = chosen
        if not out.get("train"):
            raise DatasetError(f"{jf}: field 'train_filenames' is empty")
        if lists["val"] is None and lists["test"] is None:
            unused = len(frames) - len(out["train"])
            # nerfstudio itself refuses this file; we train, but must say why no score comes out.
            scene.setdefault("notes", []).append(
                f"{jf}: train_filenames is given without val_filenames or test_filenames, so no view is held "
                "out and nothing is evaluated" + (f"; {unused} frame(s) in no list are not used" if unused else ""))
        return
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


def depth_coverage(path: Path | str) -> tuple[int, int]:
    """How many of a dataset's train frames name a depth map, of how many: (with depth, train frames).

    Metadata only (no pixel is read), so that the add-on's Train panel can decide ``train --depth``
    without torch; the trainer checks the maps themselves (``nerf_core.data.depth.check_depth``).

    Raises:
        DatasetError: the dataset cannot be parsed (as ``frame_infos``).
    """
    _, _, splits, _ = frame_infos(path, ("train",))
    frames = splits.get("train") or []
    return sum(f.depth is not None for f in frames), len(frames)
