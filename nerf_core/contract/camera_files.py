"""The cameras of any transforms file, for importing them into Blender (standard library + numpy).

``read_camera_file(path)`` reads every format our users bring, by one set of rules (the intrinsics
rule ``contract.resolve_intrinsics``, the lens rule ``contract.parse_lens``, the pose rule ``check_pose``):

- the synthetic layout: a dataset folder, or one of its ``transforms_{train,val,test}.json`` (the
  split files beside it are read too, so a re-render keeps every split);
- nerfstudio's ``transforms.json`` (per-frame ``fl_x fl_y cx cy w h``; splits from its
  ``train_filenames``/``val_filenames``/``test_filenames`` lists when it has them) and instant-ngp's
  (the same reader: ``scale``/``offset`` are instant-ngp's own fitting and are not applied, as in ``train``);
- nerfstudio's ``camera_path.json`` (``contract.camera_path``);
- a COLMAP sparse model folder (``sparse/0`` with ``cameras.bin``/``.txt``), or the COLMAP folder above it
  (``contract.colmap_dataset.camera_intrinsics``: PINHOLE, OPENCV, ... with their lens; poses from
  ``colmap_model.pose_from_colmap``), one view per registered image, in image-id order.

A frame that gives no ``w``/``h`` takes its image's size (PNG or JPEG header; else the size of
another frame's image of the same file, with a note). Every problem raises DatasetError naming the
file, frame and field.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np

from .camera_path import CameraPathError, is_camera_path, path_views
from .colmap_dataset import camera_intrinsics, read_manifest
from .colmap_model import ColmapError, find_sparse, pose_from_colmap, read_model
from .errors import DatasetError
from .intrinsics import resolve_intrinsics
from .jsonfile import read_json
from .lens import Lens
from .numbers import is_whole
from .transforms import SPLITS, read_frames


@dataclass
class CameraView:
    """One camera of a file: where it came from, its split, pose and pinhole intrinsics (pixels)."""

    name: str  # the frame's stem (``r_0``, ``frame_00000``): what it is called in Blender
    split: Optional[str]  # "train" | "val" | "test", or None when the file has no splits
    index: int  # its place in its file
    where: str  # "FILE: frame K (file_path)", for messages
    c2w: np.ndarray  # (4, 4) float64, OpenGL axes
    fx: float
    fy: float
    cx: float
    cy: float
    w: int
    h: int
    lens: Optional[Lens] = None  # distortion a Blender camera cannot hold (None: a pinhole)
    blender_frame: Optional[int] = None  # the scene frame it was rendered at (our animation layout)

    def intrinsics(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "w": self.w, "h": self.h}


def image_size(path: Path) -> Optional[Tuple[int, int]]:
    """(w, h) from a PNG or JPEG file's header, or None (missing, unreadable or another format)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                return struct.unpack(">II", head[16:24])
            if head[:2] != b"\xff\xd8":
                return None
            fh.seek(2)
            while True:
                marker = fh.read(2)
                if len(marker) < 2 or marker[0] != 0xFF:
                    return None
                length = struct.unpack(">H", fh.read(2))[0]
                if marker[1] in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
                    h, w = struct.unpack(">xHH", fh.read(5))
                    return w, h
                fh.seek(length - 2, 1)
    except (OSError, struct.error):
        return None


def _split_files(path: Path) -> List[Tuple[str, Path]]:
    """(split, file) of the synthetic layout's split files in ``path`` (a folder) or beside it (a file)."""
    root = path if path.is_dir() else path.parent
    return [(s, root / f"transforms_{s}.json") for s in SPLITS if (root / f"transforms_{s}.json").is_file()]


def _file_views(meta: dict, jf: Path, split: Optional[str], add_png: bool, notes: list) -> List[CameraView]:
    frames = read_frames(meta, jf, add_png)
    raw = meta["frames"]
    sizes = {}
    for f in frames:
        size = image_size(f.image)
        if size:
            sizes[f.index] = size
    fallback = next(iter(sizes.values()), None)
    views, guessed = [], []
    for f in frames:
        size = sizes.get(f.index)
        declared = all(k in f.intrinsics for k in ("w", "h"))
        if size is None and not declared and fallback is not None:
            size = fallback
            guessed.append(f.stem)
        try:
            fx, fy, cx, cy, w, h = resolve_intrinsics(meta, raw[f.index], size, f.where)
        except DatasetError as exc:
            if size is None and not declared:
                raise DatasetError(f"{f.where}: no 'w'/'h' and no readable image ({f.image}) to take the size from; "
                                   "add 'w' and 'h' (pixels) to the file") from exc
            raise
        frame_no = raw[f.index].get("blender_frame")
        views.append(CameraView(f.stem, split, f.index, f.where, f.c2w, fx, fy, cx, cy, int(w), int(h), f.lens,
                                frame_no if is_whole(frame_no) else None))
    if guessed:
        notes.append(f"{jf}: {len(guessed)} frame(s) give no 'w'/'h' and have no image ({', '.join(guessed[:5])}"
                     f"{', ...' if len(guessed) > 5 else ''}): they take the size of the file's other images, "
                     f"{fallback[0]}x{fallback[1]}")
    return views


def _nerfstudio_split(meta: dict, jf: Path, views: List[CameraView]) -> None:
    """Each view's split from the file's ``*_filenames`` lists (left None without a train list)."""
    lists = {s: meta.get(f"{s}_filenames") for s in SPLITS}
    if not isinstance(lists["train"], list):
        return
    where = {}
    for s, names in lists.items():
        if names is None:
            continue
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise DatasetError(f"{jf}: field '{s}_filenames' must be a list of file paths (strings)")
        for n in names:
            where.setdefault(str(Path(n)), s)
    for v, fr in zip(views, meta["frames"]):
        v.split = where.get(str(Path(fr["file_path"])), "train")


def read_camera_file(path: Path | str) -> Tuple[str, List[CameraView], List[str]]:
    """(format, views, notes) of a transforms file of any layout (module doc), or a dataset folder.

    ``format`` is "synthetic", "nerfstudio", "instant-ngp", "camera_path" or "colmap". Views come in file order
    (split by split for the synthetic layout). Raises DatasetError naming the file, frame and field.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: file not found")
    notes: List[str] = []
    files = _split_files(path) if path.is_dir() or path.name in {f"transforms_{s}.json" for s in SPLITS} else []
    if files:
        if path.is_file() and len(files) > 1:
            notes.append(f"{path.name} is one split of the dataset in {path.parent}: "
                         f"{', '.join(f.name for _, f in files)} are imported, each camera tagged with its split")
        views = []
        for split, jf in files:
            views += _file_views(read_json(jf), jf, split, True, notes)
        return "synthetic", views, notes
    if path.is_dir() and not (path / "transforms.json").is_file() and find_sparse(path) is not None:
        return "colmap", colmap_views(find_sparse(path)), notes
    if path.is_dir():
        if not (path / "transforms.json").is_file():
            raise DatasetError(f"{path}: no transforms_train.json, transforms_val.json, transforms_test.json or "
                               "transforms.json in this folder")
        path = path / "transforms.json"
    meta = read_json(path)
    if is_camera_path(meta):
        try:
            raw = path_views(meta, path)
        except CameraPathError as exc:
            raise DatasetError(str(exc)) from None
        views = [CameraView(f"frame_{k:05d}", None, k, f"{path}: camera_path[{k}]", v["c2w"], v["fx"], v["fy"], v["cx"],
                            v["cy"], v["w"], v["h"]) for k, v in enumerate(raw)]
        return "camera_path", views, notes
    if not isinstance(meta, dict) or "frames" not in meta:
        raise DatasetError(
            f"{path}: neither a transforms file (field 'frames') nor a camera path (field 'camera_path')"
        )
    views = _file_views(meta, path, None, False, notes)
    _nerfstudio_split(meta, path, views)
    ngp = any(k in meta for k in ("aabb_scale", "scale", "offset", "is_fisheye")) or \
        any("sharpness" in fr for fr in meta["frames"] if isinstance(fr, dict))
    if any(k in meta for k in ("scale", "offset")):
        notes.append(f"{path}: instant-ngp's 'scale'/'offset' are its own fitting of the scene into its unit cube; "
                     "the cameras are placed as written")
    return ("instant-ngp" if ngp and "train_filenames" not in meta else "nerfstudio"), views, notes


def colmap_views(sparse: Path) -> List[CameraView]:
    """One view per registered image of the sparse model in ``sparse``, in image-id order; each tagged
    with its split when our export's manifest (in the COLMAP folder above) lists it."""
    model = read_model(sparse)
    manifest = read_manifest(sparse.parent.parent if sparse.name == "0" else sparse.parent) or {}
    listed = manifest.get("images") if isinstance(manifest.get("images"), dict) else {}
    split_of = {n: s for s, names in listed.items() if s in SPLITS and isinstance(names, list) for n in names}
    images_file = next(sparse.glob("images.*"), sparse / "images.bin")
    cameras_file = next(sparse.glob("cameras.*"), sparse / "cameras.bin")
    views = []
    for k, im in enumerate(sorted(model.images.values(), key=lambda i: i.id)):
        where = f"{images_file}: image {im.id} ({im.name})"
        if not (np.isfinite(im.qvec).all() and np.isfinite(im.tvec).all()) or not np.linalg.norm(im.qvec) > 0:
            raise ColmapError(f"{where}: its pose (qvec {im.qvec.tolist()}, tvec {im.tvec.tolist()}) is not finite")
        intr, lens = camera_intrinsics(model.cameras[im.camera_id], str(cameras_file))
        views.append(CameraView(Path(im.name).stem, split_of.get(im.name), k, where, pose_from_colmap(im.qvec, im.tvec),
                                intr["fl_x"], intr["fl_y"], intr["cx"], intr["cy"], int(intr["w"]), int(intr["h"]),
                                lens))
    return views


def distortion_warning(views: List[CameraView]) -> Optional[str]:
    """A sentence naming the views whose lens a Blender camera cannot model (distortion, fisheye), or None."""
    bent = [v for v in views if v.lens is not None]
    if not bent:
        return None
    names = ", ".join(f"{v.split + '/' if v.split else ''}{v.name}" for v in bent[:8]) + (
        ", ..." if len(bent) > 8 else ""
    )
    models = sorted({v.lens.model for v in bent})
    return (f"{len(bent)} camera(s) have a lens Blender cannot model ({'/'.join(models)} distortion): {names}. "
            "They are imported as pinholes with the same focal length and centre, which line up with the "
            "images only near the image centre")
