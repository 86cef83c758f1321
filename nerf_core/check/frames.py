"""The checks of one transforms file and its frames: JSON, intrinsics, poses, image and extra files,
lens fields; every problem is reported, not only the first.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from nerf_core.check.report import CheckReport
from nerf_core.contract.errors import DatasetError, PoseError
from nerf_core.contract.intrinsics import declaring, focal_from_fov
from nerf_core.contract.jsonfile import parse_json_file
from nerf_core.contract.lens import lens_problem, parse_lens
from nerf_core.contract.paths import why_not_a_file
from nerf_core.contract.poses import check_pose
from nerf_core.errors import ImageReadError
from nerf_core.image.io import png_info

REQUIRED_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


SPLIT_FILES = ("transforms_train.json", "transforms_val.json", "transforms_test.json")
# nerfstudio's file lives in a subfolder: instant-ngp loads every *.json of the folder it is given, and
# beside the split files it would load every frame twice (CONVENTIONS.md, "Files and splits").
NERFSTUDIO_FILE = "nerfstudio/transforms.json"


def resolved(path: Path) -> Path:
    """``path.resolve()``, or the absolute path where resolving fails (a symlink loop: the image
    check reports that file)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        return path.absolute()


def load_json(report: CheckReport, path: Path) -> Optional[dict]:
    try:
        meta = parse_json_file(path)
    except DatasetError as exc:
        report.error(path.name, str(exc).split(": ", 1)[-1])
        return None
    if not isinstance(meta, dict):
        report.error(path.name, "expected a JSON object")
        return None
    try:
        with open(path, "rb") as f:
            bom = f.read(3) == b"\xef\xbb\xbf"
    except OSError:
        bom = False
    if bom:
        report.warn(path.name, "starts with a UTF-8 byte-order mark (as Windows editors save): read here, but "
                               "Python's json.load, and so nerfstudio's and instant-ngp's loaders, refuse it; "
                               "save it as UTF-8 without BOM")
    frames = meta.get("frames")
    if not isinstance(frames, list):
        report.error(path.name, "missing or not a list", field="frames")
        return None
    if not frames:
        report.error(path.name, "no frames: the split is empty", field="frames")
    return meta


def number_field(report, fname, value, key, frame=None, fpath=None, positive=True) -> Optional[float]:
    try:
        v = float(value)
    except (TypeError, ValueError):
        report.error(fname, f"not a number ({value!r})", frame, fpath, key)
        return None
    if not math.isfinite(v) or (positive and v <= 0):
        report.error(
            fname, f"must be a {'positive ' if positive else ''}finite number, got {value!r}", frame, fpath, key
        )
        return None
    return v


def declared_intrinsics(
    report: CheckReport, fname: str, meta: dict, fr: dict, k: int, fpath: str, need_angle: bool
) -> Optional[dict]:
    """The effective intrinsics of one frame (frame values override the file's), or None if incomplete."""
    vals = {}
    ok = True
    for key in REQUIRED_INTRINSICS + ("camera_angle_x",):
        src = declaring(meta, fr, key)
        if src is None:
            if key in REQUIRED_INTRINSICS or need_angle:
                # Report missing top-level fields once per file, not per frame.
                if k == 0:
                    report.error(fname, "missing (write it at the top level or in every frame)", field=key)
                ok = False
            continue
        v = number_field(report, fname, src[key], key, k if src is fr else None, fpath if src is fr else None,
                    positive=key not in ("cx", "cy"))
        if v is not None and key == "camera_angle_x" and v >= math.pi:
            report.error(fname, f"a field of view in radians must lie in (0, pi), got {v:g}",
                         k if src is fr else None, fpath if src is fr else None, key)
            v = None
        if v is None:
            ok = False
        vals[key] = v
    if not ok:
        return None
    for key in ("w", "h"):
        if vals[key] != int(vals[key]):
            report.error(fname, f"image size must be an integer, got {vals[key]}", k, fpath, key)
            return None
    return vals


def check_intrinsics_consistency(report: CheckReport, fname: str, intr: dict, k: int, fpath: str, seen: set) -> None:
    w, h = intr["w"], intr["h"]
    key = (fname, tuple(sorted(intr.items())))
    if key in seen:  # same numbers as an earlier frame: already reported
        return
    seen.add(key)
    for c, size, name in (("cx", w, "w"), ("cy", h, "h")):
        if not 0.0 < intr[c] < size:
            report.error(fname, f"{intr[c]} lies outside the image (0..{name}={size:g})", k, fpath, c)
    if "camera_angle_x" in intr and intr.get("camera_angle_x"):
        fx_from_angle = focal_from_fov(intr["camera_angle_x"], w)
        if abs(fx_from_angle - intr["fl_x"]) > 1e-3 * intr["fl_x"] + 1e-3:
            report.error(
                fname,
                f"camera_angle_x {intr['camera_angle_x']:.6g} gives fl_x {fx_from_angle:.4f} "
                f"but fl_x is {intr['fl_x']:.4f}; loaders that read only camera_angle_x would use another focal length",
                k,
                fpath,
                "camera_angle_x",
            )


def missing_file_text(path: Path, written: str) -> str:
    """``contract.why_not_a_file`` in check's words ("does not exist; r_1.PNG exists there ...")."""
    return why_not_a_file(path, written).replace("not found", "does not exist", 1)


def check_image(
    report: CheckReport, fname: str, img: Path, intr: Optional[dict], k: int, fpath: str, field_name: str, rgba: bool
) -> None:
    if not img.is_file():
        report.error(fname, f"image {img} {missing_file_text(img, fpath)}", k, fpath, field_name)
        return
    if img.suffix.lower() == ".exr":
        return
    try:
        w, h, mode, bits = png_info(img)
    except ImageReadError as exc:
        report.error(fname, str(exc), k, fpath, field_name)
        return
    fmt, _, pil_mode = mode.rpartition(" ")  # png_info prefixes a format the suffix does not say
    what = (f"a {fmt} image ({pil_mode} {bits}-bit) under a {img.suffix} name" if fmt
            else f"{mode} {bits}-bit")
    if rgba and (mode != "RGBA" or bits != 8):
        report.error(fname, f"{img.name} is {what}; images must be RGBA 8-bit PNGs rendered with a transparent film",
                     k, fpath, field_name)
    elif fmt:  # nerfstudio and instant-ngp decode by content, but a misnamed file misleads every other tool
        report.warn(fname, f"{img.name} is {what}", k, fpath, field_name)
    if intr is not None and (w, h) != (int(intr["w"]), int(intr["h"])):
        report.error(
            fname, f"{img.name} is {w}x{h} but w x h says {int(intr['w'])}x{int(intr['h'])}", k, fpath, field_name
        )


def frame_entries(report: CheckReport, fname: str, meta: dict, seen: set) -> Iterator[tuple]:
    """``(k, frame, file_path, intrinsics or None)`` for each frame of ``meta`` that is an object with
    a ``file_path``, its intrinsics checked (``seen``: intrinsics already checked); the other frames
    are reported and skipped."""
    for k, fr in enumerate(meta["frames"]):
        if not isinstance(fr, dict):
            report.error(fname, "not an object", k)
            continue
        fp = fr.get("file_path")
        if not isinstance(fp, str) or not fp:
            report.error(fname, "missing", k, None, "file_path")
            continue
        if "\0" in fp or len(fp) > 4096:
            report.error(fname, "contains a NUL character, which no file name can hold" if "\0" in fp
                         else f"is {len(fp)} characters long; no file system accepts a path that long",
                         k, None, "file_path")
            continue
        check_lens_fields(report, fname, fr, k, fp)
        intr = declared_intrinsics(report, fname, meta, fr, k, fp, need_angle=False)
        if intr is not None:
            check_intrinsics_consistency(report, fname, intr, k, fp, seen)
        yield k, fr, fp, intr


def check_frame_pose(report: CheckReport, fname: str, fr: dict, k: int, fpath: str) -> Optional[np.ndarray]:
    if "transform_matrix" not in fr:
        report.error(fname, "missing", k, fpath, "transform_matrix")
        return None
    m = fr["transform_matrix"]
    if not (isinstance(m, list) and len(m) == 4 and all(isinstance(r, list) and len(r) == 4 for r in m)):
        report.error(fname, "must be a 4x4 matrix written as a list of 4 rows", k, fpath, "transform_matrix")
        return None
    try:
        return check_pose(m, "transform_matrix")
    except PoseError as exc:
        report.error(fname, str(exc).split(": ", 1)[-1], k, fpath, "transform_matrix")
        return None


def check_extras(report: CheckReport, fname: str, root: Path, fr: dict, k: int, fpath: str) -> None:
    for key in ("depth_file_path", "depth_path", "normal_file_path", "mask_path"):
        if key in fr:
            p = root / str(fr[key])
            if not p.is_file():
                report.error(fname, f"{p} {missing_file_text(p, str(fr[key]))}", k, fpath, key)
            elif key == "depth_file_path" and p.suffix.lower() not in (".exr", ".png", ".npy"):
                # nerfstudio's loader reads .npy, and 16-bit PNGs through OpenCV; train reads EXR too
                report.warn(fname, f"{p.name}: depth should be EXR (float), 16-bit PNG (millimetres) or .npy", k,
                            fpath, key)


def check_lens_fields(
    report: CheckReport, fname: str, src: dict, k: Optional[int] = None, fpath: Optional[str] = None
) -> None:
    """Report lens fields that cannot be read (``contract.lens.lens_problem``), and warn where a
    distorting lens is read: other tools' loaders may take its images for pinhole ones."""
    problem = lens_problem(src)
    if problem is not None:
        report.error(fname, problem[1], k, fpath, problem[0])
        return
    lens, _ = parse_lens(src, None)
    if lens is not None:
        report.warn(fname, f"{lens.model} lens distortion: nerf_core undistorts every ray, but loaders that read only "
                    "camera_angle_x or fl_x (original NeRF, blender-data, 3DGS) treat these images as pinhole ones",
                    k, fpath, "camera_model")


def check_meta_common(report: CheckReport, fname: str, meta: dict) -> None:
    check_lens_fields(report, fname, meta)
    if "aabb_scale" in meta:
        v = meta["aabb_scale"]
        ok = (
            isinstance(v, (int, float))
            and v >= 1
            and float(v).is_integer()
            and (int(v) & (int(v) - 1)) == 0
            and v <= 128
        )
        if not ok:
            report.error(
                fname, f"must be a power of two between 1 and 128 (instant-ngp), got {v!r}", field="aabb_scale"
            )
    if "aabb" in meta:
        try:
            box = np.asarray(meta["aabb"], dtype=float)
            if box.shape != (2, 3) or not np.all(np.isfinite(box)) or not np.all(box[1] > box[0]):
                raise ValueError
        except (TypeError, ValueError):
            report.error(
                fname, f"must be [[xmin,ymin,zmin],[xmax,ymax,zmax]] with min < max, got {meta['aabb']!r}", field="aabb"
            )
    for key in ("near", "far"):
        if key in meta:
            number_field(report, fname, meta[key], key, positive=False)


