"""The transforms JSON files of a dataset.

Follows ../shared/CONVENTIONS.md and docs/CONTRACTS.md: ``transforms_{train,val,test}.json`` with
``file_path`` without extension (the only JSON at the root), nerfstudio's ``transforms.json`` with
real file names and split lists in ``nerfstudio/`` (instant-ngp loads every ``*.json`` of the folder
it is given: beside the split files it would load every frame twice), every intrinsic.
"""
from __future__ import annotations

import json
import os

from ..file_writes import write_atomic
from .errors import ExportError

NERFSTUDIO_DIR = "nerfstudio"  # holds nerfstudio's transforms.json; its paths are relative to it ("../train/r_0.png")
SPLITS = ("train", "val", "test")
PER_FRAME_INTRINSICS = ("camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h")  # what a frame may carry


def shared_intrinsics(frames: list[dict]) -> dict | None:
    """The intrinsics all frames share (to write once at the top level), else None."""
    keys = ("fl_x", "fl_y", "cx", "cy", "w", "h")
    first = frames[0]["intrinsics"]
    for fr in frames[1:]:
        if any(abs(fr["intrinsics"][k] - first[k]) > 1e-6 for k in keys):
            return None
    return first


def _frame_entry(f: dict, folder: str, per_frame_intrinsics: bool, nerfstudio: bool, path_prefix: str = "") -> dict:
    """One frame of a transforms file: ``./folder/name`` (synthetic) or ``folder/name.png`` (nerfstudio),
    every file path behind ``path_prefix`` (``../`` for nerfstudio's file in its own folder)."""
    path = f"{path_prefix}{folder}/{f['name']}.png" if nerfstudio else f"./{folder}/{f['name']}"
    entry = {"file_path": path, "transform_matrix": f["transform_matrix"]}
    if per_frame_intrinsics:  # instant-ngp and nerfstudio both read these
        for k in PER_FRAME_INTRINSICS:
            entry[k] = f["intrinsics"][k]
    for key in ("depth_file_path", "normal_file_path", "mask_path"):
        if f.get(key):
            entry[key] = path_prefix + f[key]
    if f.get("frame") is not None:
        entry["blender_frame"] = f["frame"]  # not "time": nerfstudio reads that as dynamic-scene time
    if f.get("camera"):
        entry["camera"] = f["camera"]
    return entry


def transforms_document(frames: list[dict], common: dict, folder: str, nerfstudio: bool = False,
                        intrinsics_of: list[dict] | None = None, per_frame: bool = False,
                        path_prefix: str = "") -> dict:
    """The transforms object of ``frames``, all in ``folder``: the one writer of transforms JSON, for
    the capture's files and the Compare panel's camera files alike.

    ``frames``: dicts with name ("r_3"), transform_matrix, intrinsics (``intrinsics_from_params``),
    optional depth/normal/mask relative paths (with extension), ``frame`` (Blender frame) and
    ``camera`` (object name). Intrinsics that all of ``intrinsics_of`` (default ``frames``) share go
    to the top level, else (or with ``per_frame``) they go on every frame. ``nerfstudio``: real file names
    (``folder/name.png``) instead of ``./folder/name``; ``path_prefix`` goes before every file path of a
    frame (nerfstudio's file lives in ``nerfstudio/``, one folder below the images). ``common``: aabb, near,
    far, ply_file_path...
    """
    basis = frames if intrinsics_of is None else intrinsics_of
    if not basis:
        raise ExportError("no frames to write")
    shared = shared_intrinsics(basis)
    top = {k: v for k, v in (shared or basis[0]["intrinsics"]).items() if k not in ("camera_angle_y",)}
    top.update(common)
    top["frames"] = [_frame_entry(f, folder, per_frame or shared is None, nerfstudio, path_prefix) for f in frames]
    return top


def write_transforms(out_dir: str, frames: list[dict], common: dict) -> list[str]:
    """Write transforms_{train,val,test}.json and nerfstudio's nerfstudio/transforms.json; return the paths.

    ``frames``: as ``transforms_document`` wants them, each with its ``split`` (and, with depth, the
    ``nerfstudio_depth_file_path`` of its millimetre PNG, ``files.write.nerfstudio_depth``). Every file shares one
    top level, taken from all frames. Paths in the split files are relative to ``out_dir``; in
    nerfstudio's file (which nerfstudio resolves against its own folder) they start with ``../``.
    """
    if not frames:
        raise ExportError(f"{out_dir}: no rendered frames to export")
    written = []
    ns_frames = []
    per_split_files = {s: [] for s in SPLITS}
    for split in SPLITS:
        split_frames = [f for f in frames if f["split"] == split]
        doc = transforms_document(split_frames, common, split, intrinsics_of=frames)
        ns_split = transforms_document(split_frames, common, split, nerfstudio=True, intrinsics_of=frames,
                                       path_prefix="../")["frames"]
        for f, entry in zip(split_frames, ns_split):
            if f.get("nerfstudio_depth_file_path"):  # millimetre PNGs, the depth nerfstudio reads
                entry["depth_file_path"] = "../" + f["nerfstudio_depth_file_path"]
        if common.get("film_transparent"):
            # nerfstudio samples rays only where mask_path is white: with object masks it would never
            # see the transparent background, so free space would go untaught (and a batch larger than
            # the object's pixels fails). The alpha already outlines the objects there.
            for entry in ns_split:
                entry.pop("mask_path", None)
        ns_frames += ns_split
        per_split_files[split] = [e["file_path"] for e in ns_split]
        path = os.path.join(out_dir, f"transforms_{split}.json")
        write_atomic(path, lambda fh: json.dump(doc, fh, indent=2))
        written.append(path)
    ns_doc = transforms_document([], common, "", intrinsics_of=frames)
    if shared_intrinsics(frames) is None:
        # nerfstudio-data reads a top-level intrinsic for every frame, ignoring the frame's own: here
        # the frames alone carry them. (The split files keep the first frame's camera_angle_x, the one
        # field their loaders read; the capture and `check` warn that those loaders misplace the rest.)
        for key in PER_FRAME_INTRINSICS:
            ns_doc.pop(key, None)
    if any(f.get("nerfstudio_depth_file_path") for f in frames):
        ns_doc["depth_unit_scale_factor"] = 1e-3  # nerfstudio's own default: its PNGs hold millimetres
    if "ply_file_path" in ns_doc:
        ns_doc["ply_file_path"] = "../" + ns_doc["ply_file_path"]
    ns_doc.update({f"{s}_filenames": per_split_files[s] for s in SPLITS})
    ns_doc["frames"] = ns_frames
    os.makedirs(os.path.join(out_dir, NERFSTUDIO_DIR), exist_ok=True)
    path = os.path.join(out_dir, NERFSTUDIO_DIR, "transforms.json")
    write_atomic(path, lambda fh: json.dump(ns_doc, fh, indent=2))
    written.append(path)
    return written
