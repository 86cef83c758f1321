"""Validating a dataset folder against ../shared/CONVENTIONS.md: ``python -m nerf_core check DATASET``.

Every loader our users rely on (original NeRF, nerfstudio's blender-data and nerfstudio-data,
instant-ngp, 3DGS) must read the folder unchanged, so the check lists *every* problem, each naming
its file, frame and field, instead of stopping at the first. Warnings are things that load but may
surprise (an off-centre principal point that camera_angle_x-only loaders ignore).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, Optional

import numpy as np
import torch

from nerf_core.contract.intrinsics import angle_only_caveats, focal_from_fov
from nerf_core.contract.lens import lens_problem, parse_lens
from nerf_core.contract.naming import evenly_spaced
from nerf_core.contract.transforms import (
    IMAGE_EXTS,
    DatasetError,
    PoseError,
    check_pose,
    frame_infos,
    parse_json_file,
    resolve_image,
    why_not_a_file,
)
from nerf_core.data.backgrounds import (
    BACKGROUNDS,
    FIXED_BACKGROUNDS,
    TRANSPARENT_SHARE,
    choose,
    for_run,
    percent_text,
    transparent_share,
)
from nerf_core.data.loading import cameras_of_frames, load_dataset
from nerf_core.data.problems import dataset_problems
from nerf_core.data.scene_box import beyond_box_reason, estimate_aabb
from nerf_core.data.validation import parse_aabb, scene_fields
from nerf_core.errors import ImageReadError
from nerf_core.fields.world_coverage import covered_directions, unseen_world_share
from nerf_core.image.io import png_info, read_png
from nerf_core.methods.catalog import DEFAULT_METHOD
from nerf_core.methods.registry import has_option

SPLIT_FILES = ("transforms_train.json", "transforms_val.json", "transforms_test.json")
# nerfstudio's file lives in a subfolder: instant-ngp loads every *.json of the folder it is given, and
# beside the split files it would load every frame twice (CONVENTIONS.md, "Files and splits").
NERFSTUDIO_FILE = "nerfstudio/transforms.json"
REQUIRED_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


@dataclass
class Problem:
    file: str
    message: str
    frame: Optional[int] = None
    frame_path: Optional[str] = None
    field: Optional[str] = None

    def __str__(self) -> str:
        where = self.file
        if self.frame is not None:
            where += f": frame {self.frame}" + (f" ({self.frame_path})" if self.frame_path else "")
        if self.field:
            where += f": field '{self.field}'"
        return f"{where}: {self.message}"


@dataclass
class CheckReport:
    root: Path
    errors: List[Problem] = field(default_factory=list)
    warnings: List[Problem] = field(default_factory=list)
    n_frames: Dict[str, int] = field(default_factory=dict)
    plan: List[str] = field(default_factory=list)  # what `train` will decide for a valid dataset
    notes: List[str] = field(default_factory=list)  # what was checked, when it is not the folder given
    trainable: Optional[bool] = None  # train reads the dataset (``dataset_problems`` is empty); None: not asked

    @property
    def ok(self) -> bool:
        return not self.errors

    def error(self, *a, **k) -> None:
        self.errors.append(Problem(*a, **k))

    def warn(self, *a, **k) -> None:
        self.warnings.append(Problem(*a, **k))

    def format(self) -> str:
        lines = [f"NOTE    {n}" for n in self.notes]
        lines += [f"ERROR   {p}" for p in self.errors] + [f"WARNING {p}" for p in self.warnings]
        lines += [f"TRAIN   {line}" for line in self.plan]
        counts = ", ".join(f"{k} {v}" for k, v in self.n_frames.items())
        verdict = "valid" if self.ok else f"INVALID: {len(self.errors)} error(s)"
        lines.append(f"{self.root}: {verdict}, {len(self.warnings)} warning(s)" + (f" ({counts} frames)" if counts else ""))
        if not self.ok and self.trainable:
            # A dataset of another tool: wrong as an export of ours, and still what train reads.
            lines.append("train reads this dataset as it is: the errors above are conventions of an export "
                         "(`check --for-training` checks it for training only)")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"dataset": str(self.root), "ok": self.ok, "errors": [str(p) for p in self.errors],
                "warnings": [str(p) for p in self.warnings], "frames": self.n_frames, "train_plan": self.plan,
                "trainable": self.trainable, "notes": self.notes}


def _resolved(path: Path) -> Path:
    """``path.resolve()``, or the absolute path where resolving fails (a symlink loop: the image
    check reports that file)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        return path.absolute()


def _load_json(report: CheckReport, path: Path) -> Optional[dict]:
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


def _number(report, fname, value, key, frame=None, fpath=None, positive=True) -> Optional[float]:
    try:
        v = float(value)
    except (TypeError, ValueError):
        report.error(fname, f"not a number ({value!r})", frame, fpath, key)
        return None
    if not math.isfinite(v) or (positive and v <= 0):
        report.error(fname, f"must be a {'positive ' if positive else ''}finite number, got {value!r}", frame, fpath, key)
        return None
    return v


def _intrinsics(report: CheckReport, fname: str, meta: dict, fr: dict, k: int, fpath: str, need_angle: bool) -> Optional[dict]:
    """The effective intrinsics of one frame (frame values override the file's), or None if incomplete."""
    vals = {}
    ok = True
    for key in REQUIRED_INTRINSICS + ("camera_angle_x",):
        src = fr if key in fr else meta if key in meta else None
        if src is None:
            if key in REQUIRED_INTRINSICS or need_angle:
                # Report missing top-level fields once per file, not per frame.
                if k == 0:
                    report.error(fname, "missing (write it at the top level or in every frame)", field=key)
                ok = False
            continue
        v = _number(report, fname, src[key], key, k if src is fr else None, fpath if src is fr else None,
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


def _check_intrinsics_consistency(report: CheckReport, fname: str, intr: dict, k: int, fpath: str, seen: set) -> None:
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
            report.error(fname, f"camera_angle_x {intr['camera_angle_x']:.6g} gives fl_x {fx_from_angle:.4f} "
                                f"but fl_x is {intr['fl_x']:.4f}; loaders that read only camera_angle_x would use another focal length",
                         k, fpath, "camera_angle_x")


def _missing(path: Path, written: str) -> str:
    """``contract.why_not_a_file`` in check's words ("does not exist; r_1.PNG exists there ...")."""
    return why_not_a_file(path, written).replace("not found", "does not exist", 1)


def _check_image(report: CheckReport, fname: str, img: Path, intr: Optional[dict], k: int, fpath: str, field_name: str, rgba: bool) -> None:
    if not img.is_file():
        report.error(fname, f"image {img} {_missing(img, fpath)}", k, fpath, field_name)
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
        report.error(fname, f"{img.name} is {w}x{h} but w x h says {int(intr['w'])}x{int(intr['h'])}", k, fpath, field_name)


def _frame_entries(report: CheckReport, fname: str, meta: dict, seen: set) -> Iterator[tuple]:
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
        _camera_model(report, fname, fr, k, fp)
        intr = _intrinsics(report, fname, meta, fr, k, fp, need_angle=False)
        if intr is not None:
            _check_intrinsics_consistency(report, fname, intr, k, fp, seen)
        yield k, fr, fp, intr


def _check_pose(report: CheckReport, fname: str, fr: dict, k: int, fpath: str) -> Optional[np.ndarray]:
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


def _check_extras(report: CheckReport, fname: str, root: Path, fr: dict, k: int, fpath: str) -> None:
    for key in ("depth_file_path", "depth_path", "normal_file_path", "mask_path"):
        if key in fr:
            p = root / str(fr[key])
            if not p.is_file():
                report.error(fname, f"{p} {_missing(p, str(fr[key]))}", k, fpath, key)
            elif key == "depth_file_path" and p.suffix.lower() not in (".exr", ".png", ".npy"):
                # nerfstudio's loader reads .npy, and 16-bit PNGs through OpenCV; train reads EXR too
                report.warn(fname, f"{p.name}: depth should be EXR (float), 16-bit PNG (millimetres) or .npy", k,
                            fpath, key)


def _camera_model(report: CheckReport, fname: str, src: dict, k: Optional[int] = None, fpath: Optional[str] = None) -> None:
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


def _check_meta_common(report: CheckReport, fname: str, meta: dict) -> None:
    _camera_model(report, fname, meta)
    if "aabb_scale" in meta:
        v = meta["aabb_scale"]
        ok = isinstance(v, (int, float)) and v >= 1 and float(v).is_integer() and (int(v) & (int(v) - 1)) == 0 and v <= 128
        if not ok:
            report.error(fname, f"must be a power of two between 1 and 128 (instant-ngp), got {v!r}", field="aabb_scale")
    if "aabb" in meta:
        try:
            box = np.asarray(meta["aabb"], dtype=float)
            if box.shape != (2, 3) or not np.all(np.isfinite(box)) or not np.all(box[1] > box[0]):
                raise ValueError
        except (TypeError, ValueError):
            report.error(fname, f"must be [[xmin,ymin,zmin],[xmax,ymax,zmax]] with min < max, got {meta['aabb']!r}", field="aabb")
    for key in ("near", "far"):
        if key in meta:
            _number(report, fname, meta[key], key, positive=False)


def check_dataset(path: Path | str, background: str = "auto", for_training: bool = False) -> CheckReport:
    """Check a dataset folder; never raises for dataset problems (they go into the report).

    ``background`` is the training background mode to check the images against (``train --background``).
    ``for_training``: only what ``train`` refuses is an error; what the conventions of an export ask
    for other tools' loaders (``fl_x``... beside ``camera_angle_x``, ``nerfstudio/transforms.json``)
    becomes a warning. A dataset of another tool (the original NeRF scenes, instant-ngp, nerfstudio)
    trains, and the add-on runs this before training.
    """
    root = Path(path)
    if root.is_file() and root.suffix == ".json" and root.name.startswith("transforms"):
        root = root.parent  # DATASET/transforms_train.json, as `train` accepts it: check its dataset
    ns_folder = Path(NERFSTUDIO_FILE).parent.name
    if root.name == ns_folder and (root / "transforms.json").is_file() \
            and any((root.parent / name).is_file() for name in SPLIT_FILES):
        # Our export's nerfstudio/ copy: its file is one layout of the dataset above, checked with it.
        # Checked on its own, the folder looked like a dataset missing every file it is not meant to hold.
        report = check_dataset(root.parent, background, for_training)
        # nerfstudio reads this folder with its own loader rules (split lists, paths): what train would
        # refuse in it is an error too, named as the parent's report names the file.
        own = CheckReport(root)
        _check_loadable(own, root)
        known = {str(p) for p in report.errors}
        for p in own.errors:
            p.file = f"{root.name}/{p.file}" if not Path(p.file).is_absolute() else p.file
            if str(p) not in known:
                report.errors.append(p)
        report.notes.insert(0, f"{root} holds the nerfstudio-data file of the dataset {root.parent}: checked that "
                               f"dataset, its {NERFSTUDIO_FILE} included (`--data {root}` is what nerfstudio reads)")
        return report
    report = CheckReport(root)
    if not root.is_dir():
        report.error(str(root), "dataset folder not found" if not root.exists() else "not a folder")
        return report

    # instant-ngp loads every *.json at the root as a transforms file.
    splits_here = any((root / name).is_file() for name in SPLIT_FILES)
    # One transforms.json and no split files: the layout nerfstudio-data and instant-ngp read, where
    # that file is the dataset, not a stray JSON or a misplaced copy of nerfstudio's.
    one_file = (root / "transforms.json").is_file() and not splits_here
    for j in sorted(root.glob("*.json")):
        if j.name == "transforms.json" and one_file:
            continue
        if j.name == "transforms.json" and splits_here:
            report.error(j.name, "beside transforms_{train,val,test}.json at the dataset root, instant-ngp loads "
                                 "every frame twice (it reads every *.json here); nerfstudio's file belongs in "
                                 f"{NERFSTUDIO_FILE} with paths relative to it ('../train/r_0.png')")
        elif j.name not in SPLIT_FILES:
            report.error(j.name, "stray JSON at the dataset root: instant-ngp loads every *.json here; "
                                 "move it into a subfolder (e.g. nerf_capture/)")

    poses: Dict[str, List[tuple]] = {}
    frame_intrinsics: Dict[str, dict] = {}  # image file -> intrinsics, to compare with transforms.json
    seen: set = set()
    boxes: Dict[str, object] = {}
    for fname in SPLIT_FILES:
        split = fname[len("transforms_"):-len(".json")]
        fpath_json = root / fname
        if not fpath_json.is_file():
            layout = ("this is the one-file layout (transforms.json, read by nerfstudio-data and instant-ngp), but "
                      if one_file else "")
            report.error(fname, f"missing: {layout}the original NeRF loader reads train, val and test; 3DGS needs train and test")
            continue
        meta = _load_json(report, fpath_json)
        if meta is None:
            continue
        _check_meta_common(report, fname, meta)
        boxes[fname] = meta.get("aabb")
        if "camera_angle_x" not in meta:
            report.error(fname, "missing: the only camera field the original NeRF loader, blender-data and 3DGS read",
                         field="camera_angle_x")
        report.n_frames[split] = len(meta["frames"])
        poses[split] = []
        cameras = []
        for k, fr, fp, intr in _frame_entries(report, fname, meta, seen):
            if intr is not None:
                cameras.append(intr)
            img = resolve_image(root, fp, add_png=True)
            if Path(fp).suffix and img.name == Path(fp).name:
                report.error(fname, f"{fp!r} has an extension; loaders of this layout add '.png' themselves "
                                    f"(write {str(Path(fp).with_suffix(''))!r})", k, fp, "file_path")
            _check_image(report, fname, img, intr, k, fp, "file_path", rgba=True)
            m = _check_pose(report, fname, fr, k, fp)
            _check_extras(report, fname, root, fr, k, fp)
            if m is not None:
                poses[split].append((k, fp, m, _resolved(img)))
            if intr is not None:
                frame_intrinsics[str(_resolved(img))] = intr
        # nerfstudio-data reads every intrinsic itself; the split files feed camera_angle_x-only loaders.
        for field, message in angle_only_caveats(cameras):
            report.warn(fname, message, field=field)

    # Held-out cameras must be new viewpoints.
    for split in ("val", "test"):
        for k, fp, m, img in poses.get(split, []):
            for k2, fp2, m2, img2 in poses.get("train", []):
                if img == img2:
                    report.error(f"transforms_{split}.json", f"uses the training image of train frame {k2} ({fp2})", k, fp, "file_path")
                    break
                if np.allclose(m, m2, atol=1e-6):
                    report.error(f"transforms_{split}.json", f"camera equals train frame {k2} ({fp2}): held-out views must be new viewpoints",
                                 k, fp, "transform_matrix")
                    break

    _check_synthetic_scale(report, boxes, poses)
    _check_nerfstudio(report, root, frame_intrinsics, "transforms.json" if one_file else NERFSTUDIO_FILE)
    opaque = _check_background(report, root, background)
    if opaque:
        _check_world_coverage(report, root)
    converted: List[Problem] = []
    if for_training:
        converted = [Problem(p.file, f"(conventions of an export) {p.message}", p.frame, p.frame_path, p.field)
                     for p in report.errors]
        report.warnings = converted + report.warnings
        report.errors = []
    _check_loadable(report, root)
    if converted:
        _drop_repeats(report, converted)
    _check_paths(report, root)
    if report.ok:
        _training_plan(report, root, background)
    return report


def _training_plan(report: CheckReport, root: Path, background: str) -> None:
    """What `train` (with ``--background background``) will decide for this valid dataset on its own, by
    the trainer's own rules: the scene box, the background and scene contraction. Nothing is trained."""

    try:
        ds = load_dataset(root)
    except (DatasetError, ImageReadError, OSError, ValueError):
        return  # _check_loadable reported it
    box = [[round(float(v), 3) for v in row] for row in ds.aabb.tolist()]
    report.plan.append(f"scene box {box} from the {ds.aabb_source}" if ds.aabb_source.startswith("dataset")
                       else f"scene box {box}: {ds.aabb_source}")
    report.plan.extend(note for note in ds.notes if not ds.aabb_source.startswith(note))
    mode, why = for_run(background, None, ds)
    report.plan.append(f"background: {mode} ({why})")
    reason = beyond_box_reason(ds, mode)
    if reason and has_option(DEFAULT_METHOD, "contract"):
        report.plan.append(f"{DEFAULT_METHOD} (the default method) will model the world beyond the box "
                           f"(contract=true): {reason}; --set contract=false turns it off")


def _check_paths(report: CheckReport, root: Path) -> None:
    """Warn about file paths that point outside the dataset folder (``contract.resolve_dataset_path``
    holds the policy: read, but reported)."""
    try:
        _, _, infos, _ = frame_infos(root)
    except DatasetError:
        return  # reported by the loader's own checks
    for frames in infos.values():
        for fr in frames:
            for key in fr.outside:
                report.warn(_relative(root, str(fr.json_file)), "points outside the dataset folder (absolute or '../'): "
                            "the file is read, but a copy of the folder or another machine will not find it",
                            fr.index, fr.file_path, key)


_FRAME_RE = re.compile(r"^(?P<file>.+?\.json): frame (?P<frame>\d+) \((?P<path>.*?)\): (?P<rest>.*)$", re.S)
_FILE_RE = re.compile(r"^(?P<file>.+?\.json): (?P<rest>.*)$", re.S)


def _check_loadable(report: CheckReport, root: Path) -> None:
    """Add every problem that makes ``train`` refuse the dataset (``nerf_core.data.problems.dataset_problems``,
    the loader's own rules), so that `check` never calls valid what `train` refuses. A problem the
    convention checks above already reported for the same file and frame (or file and field) is not
    repeated. Also warns about views that show nothing (transparent everywhere, or opaque and black
    everywhere)."""

    reported = {(Path(p.file).name, p.frame) for p in report.errors}
    fields = {(Path(p.file).name, p.field) for p in report.errors if p.field}
    empty: Dict[str, list] = {}
    black: Dict[str, list] = {}

    def look(split, fr, sp) -> None:  # pixels the loader decodes anyway
        if sp.shows_nothing():
            empty.setdefault(split, []).append(fr)
        elif sp.is_black():
            black.setdefault(split, []).append(fr)

    problems = dataset_problems(root, visit=look)
    report.trainable = not problems
    for msg in problems:
        m = _FRAME_RE.match(msg)
        if m:
            fname, frame = Path(m["file"]).name, int(m["frame"])
            if (fname, frame) in reported:
                continue
            report.error(_relative(root, m["file"]), m["rest"], frame, m["path"])
            reported.add((fname, frame))
            continue
        m = _FILE_RE.match(msg)
        if m:
            fname = Path(m["file"]).name
            if any(f"field '{fld}'" in m["rest"] for (fn, fld) in fields if fn == fname):
                continue
            if any(Path(p.file).name == fname and p.message == m["rest"] for p in report.errors):
                continue  # the same problem, already reported by the convention checks
            report.error(_relative(root, m["file"]), m["rest"])
        else:
            report.error(str(root), msg)
    _warn_empty_views(report, root, empty, "transparent everywhere",
                      "does its camera look away from it, or stand inside an object?")
    _warn_empty_views(report, root, black, "opaque and black everywhere",
                      "is the scene lit where this camera looks? A camera inside a closed object, lights that are "
                      "off or an exposure far too low all render black")


_FIELD_RE = re.compile(r"^field '(?P<field>[^']+)'")


def _where(p: Problem) -> tuple:
    """(file name, frame, field) of a problem; the loader's messages carry the field in their text."""
    m = _FIELD_RE.match(p.message.removeprefix("(conventions of an export) "))
    return Path(p.file).name, p.frame, p.field or (m["field"] if m else None)


def _drop_repeats(report: CheckReport, converted: List[Problem]) -> None:
    """With ``--for-training``, the convention checks' errors became warnings before the loader's rules
    ran, so a problem both report (a missing image, a matrix entry that is text) showed twice: once as
    an error, once as a warning. Keep the error."""
    errors = {_where(p) for p in report.errors}
    ids = {id(p) for p in converted}
    report.warnings = [w for w in report.warnings if id(w) not in ids or _where(w) not in errors]


def _relative(root: Path, file: str) -> str:
    try:
        return str(Path(file).resolve().relative_to(root.resolve()))
    except ValueError:
        return file


BACKGROUND_PROBE_IMAGES = 16  # evenly spaced train images read to tell opaque from cut-out captures


def _check_background(report: CheckReport, root: Path, background: str) -> Optional[bool]:
    """Warn when opaque images meet a background mode that cannot show their background, and when the
    declared ``film_transparent`` contradicts the images (``nerf_core.data.backgrounds`` owns the rules).

    Returns whether the train images are opaque (their background is the world), or None when the
    images could not be read."""

    fname = "transforms_train.json"
    meta = None
    if (root / fname).is_file():
        try:
            meta = parse_json_file(root / fname)
        except DatasetError:
            return None  # reported above
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        return None
    if background not in BACKGROUNDS:
        report.error(fname, f"background mode {background!r} is not one of {', '.join(BACKGROUNDS)}")
        return None
    frames = meta["frames"]
    pick = evenly_spaced(len(frames), BACKGROUND_PROBE_IMAGES)
    images = []
    for k in pick:
        fp = frames[k].get("file_path") if isinstance(frames[k], dict) else None
        if not isinstance(fp, str):
            continue
        img = resolve_image(root, fp, add_png=True)
        try:
            px = read_png(img) if img.suffix.lower() == ".png" else None
        except (ImageReadError, OSError):
            continue  # reported above
        if px is not None and px.ndim == 3 and px.dtype == np.uint8:
            images.append(torch.from_numpy(np.array(px)))
    if not images or len({tuple(im.shape) for im in images}) != 1:
        return None
    stack = torch.stack(images)
    film = meta.get("film_transparent")
    share = transparent_share(stack)
    opaque = share < TRANSPARENT_SHARE
    if film is not None and not isinstance(film, bool):
        report.error(fname, f"must be true or false, got {film!r}", field="film_transparent")
        return bool(opaque)
    if film is True and opaque:
        report.warn(fname, "declares a transparent film, but the train images have no transparent pixel "
                           "(train learns their background as an environment)", field="film_transparent")
    if film is False and not opaque:
        report.warn(fname, f"declares an opaque film, but {percent_text(share)} of the train images' pixels are "
                           "transparent", field="film_transparent")
    mode = choose(stack, film if isinstance(film, bool) else None)[0] if background == "auto" else background
    if opaque and mode in FIXED_BACKGROUNDS:
        report.warn(fname, f"the train images are opaque (their background is part of the picture) but --background "
                           f"{mode} puts a fixed or random colour there: the model would have to paint the background "
                           "onto geometry inside the scene box. Use --background environment (what auto picks for "
                           "opaque images)", field="background")
    return bool(opaque)


def _warn_empty_views(report: CheckReport, root: Path, empty: Dict[str, list], how: str, ask: str) -> None:
    """Warn about views whose image shows nothing (``empty``: split -> FrameInfos, found while
    ``_check_loadable`` reads the pixels): transparent everywhere on a transparent film, where the
    camera saw none of the scene, or opaque and black everywhere, where it saw no light. A held-out
    one measures nothing, and a train one teaches nothing of the scene. ``how`` says which, ``ask``
    what to look at. Most readers would call such a dataset fine."""
    for split, frames in empty.items():
        for fr in frames[:10]:
            report.warn(_relative(root, str(fr.json_file)),
                        f"the image is {how}: this view shows nothing of the scene ({ask})"
                        + ("; a held-out view of nothing measures nothing" if split != "train" else ""),
                        fr.index, fr.file_path)
        if len(frames) > 10:
            report.warn(_relative(root, str(frames[0].json_file)),
                        f"{len(frames) - 10} more views show nothing ({how})")


UNSEEN_WORLD_WARN = 0.02  # share of a held-out view's pixels on unseen world that earns a warning


def _check_world_coverage(report: CheckReport, root: Path) -> None:
    """Warn about held-out views that look at parts of the world no train view shows
    (``nerf_core.fields.world_coverage``): those pixels cannot be learnt, so the view will score low."""

    try:
        _, _, infos, scene = frame_infos(root)
        _, far, _, _, _ = scene_fields(scene)
        train = cameras_of_frames(infos["train"])
        aabb = (parse_aabb(scene["aabb"], str(scene["aabb_file"])) if "aabb" in scene
                else estimate_aabb(train, far)[0])
    except (DatasetError, ImageReadError, OSError, ValueError):
        return  # the loader's own checks report why
    covered = None
    for split in ("val", "test"):
        frames = infos.get(split) or []
        if not frames:
            continue
        try:
            held = cameras_of_frames(frames)
        except (DatasetError, ImageReadError, OSError, ValueError):
            continue
        if covered is None:
            covered = covered_directions(train)
        for k, fr in enumerate(frames):
            share = unseen_world_share(held, k, covered, aabb)
            if share >= UNSEEN_WORLD_WARN:
                report.warn(_relative(root, str(fr.json_file)),
                            f"{100 * share:.0f} % of this view's pixels look at parts of the world behind the scene "
                            "that no train view shows; no model can learn them, so the view will score low there. "
                            "Train views that look in those directions (often lower cameras, nearer the horizon) "
                            "fix it", fr.index, fr.file_path)


# The scale of the original synthetic scenes, which some loaders hard-code instead of reading the
# file: the original NeRF samples rays from near 2 to far 6 (run_nerf.py), TensoRF and nerfstudio's
# blender-data bound the scene by a +-1.5 box. Cameras of those scenes sit about 4 from the origin.
SYNTHETIC_BOX_HALF = 1.5
SYNTHETIC_CAMERA_DISTANCE = (2.0, 7.5)  # from near 2 to far 6 past the box's edge


def _check_synthetic_scale(report: CheckReport, boxes: Dict[str, object], poses: Dict[str, list]) -> None:
    """Warn, once, when the scene is not at the synthetic scenes' scale: legal, and read right by the
    loaders that read ``aabb`` and near/far (nerfstudio-data, instant-ngp, 3DGS, nerf_core), but
    the loaders that hard-code that scale sample or bound the wrong region."""
    fname = "transforms_train.json"
    reach = None
    try:
        box = np.asarray(boxes.get(fname), dtype=float)
        if box.shape == (2, 3) and np.all(np.isfinite(box)):
            reach = float(np.abs(box).max())
    except (TypeError, ValueError):
        pass
    dists = [float(np.linalg.norm(m[:3, 3])) for _, _, m, _ in poses.get("train", [])]
    lo, hi = SYNTHETIC_CAMERA_DISTANCE
    outside = [d for d in dists if not lo <= d <= hi]
    if (reach is None or reach <= 1.1 * SYNTHETIC_BOX_HALF) and not outside:
        return
    said = []
    if reach is not None and reach > 1.1 * SYNTHETIC_BOX_HALF:
        said.append(f"the aabb reaches {reach:.3g} units from the origin (theirs: {SYNTHETIC_BOX_HALF})")
    if outside:
        said.append(f"{len(outside)} of {len(dists)} train cameras lie {min(dists):.3g}-{max(dists):.3g} units from the "
                    f"origin (theirs: about 4)")
    report.warn(fname, "not at the scale of the synthetic NeRF scenes: " + "; ".join(said) + ". Loaders that "
                "hard-code it (the original NeRF: near 2, far 6; TensoRF and nerfstudio blender-data: a +-1.5 box) "
                "will miss the scene; nerfstudio-data, instant-ngp and 3DGS read the file's own aabb and cameras",
                field="aabb")


def _check_nerfstudio(report: CheckReport, root: Path, split_intrinsics: Dict[str, dict],
                      name: str = NERFSTUDIO_FILE) -> None:
    """nerfstudio-data's file ``name`` (relative to ``root``): ``nerfstudio/transforms.json`` of an export
    of ours, or ``transforms.json`` of the one-file layout. Its frames' images, poses and intrinsics."""
    path = root / name
    if not path.is_file():
        report.error(name, "missing: nerfstudio's nerfstudio-data parser needs one transforms.json with real file names "
                                      "(`--data DATASET/nerfstudio`)")
        return
    base = path.parent  # nerfstudio resolves file paths against the JSON's own folder
    meta = _load_json(report, path)
    if meta is None:
        return
    _check_meta_common(report, name, meta)
    names = set()
    seen: set = set()
    for k, fr, fp, intr in _frame_entries(report, name, meta, seen):
        names.add(str(Path(fp)))
        if Path(fp).suffix.lower() not in IMAGE_EXTS:
            report.error(name, f"{fp!r} needs its real file name with the extension (nerfstudio does not add one)",
                         k, fp, "file_path")
            continue
        img = base / fp
        _check_image(report, name, img, intr, k, fp, "file_path", rgba=False)
        _check_pose(report, name, fr, k, fp)
        _check_extras(report, name, base, fr, k, fp)
        # nerfstudio-data takes a top-level intrinsic for every frame and never reads the frame's own.
        ignored = [key for key in REQUIRED_INTRINSICS if key in meta and key in fr and fr[key] != meta[key]]
        if ignored:
            report.error(name, f"{ignored[0]} {fr[ignored[0]]!r} differs from the top-level {meta[ignored[0]]!r}, "
                         "which nerfstudio-data uses for every frame: leave the top-level intrinsics out when the "
                         "frames differ", k, fp, ignored[0])
        other = split_intrinsics.get(str(_resolved(img)))
        if other is not None and intr is not None:
            diff = [key for key in REQUIRED_INTRINSICS if abs(other[key] - intr[key]) > 1e-4 * max(1.0, abs(other[key]))]
            if diff:
                report.error(name, "differs from the transforms_<split>.json entry of the same image "
                             + ", ".join(f"{d}: {intr[d]:g} vs {other[d]:g}" for d in diff), k, fp, diff[0])
    for key in ("train_filenames", "val_filenames", "test_filenames"):
        if key in meta:
            lst = meta[key]
            if not isinstance(lst, list):
                report.error(name, "must be a list of file names", field=key)
                continue
            for n in lst:
                if str(Path(str(n))) not in names:
                    report.error(name, f"lists {n!r}, which is not the file_path of any frame", field=key)
    if "train_filenames" in meta and isinstance(meta["train_filenames"], list):
        train = {str(Path(str(n))) for n in meta["train_filenames"]}
        for key in ("val_filenames", "test_filenames"):
            if isinstance(meta.get(key), list):
                both = sorted(train & {str(Path(str(n))) for n in meta[key]})
                if both:
                    report.error(name, f"{len(both)} file(s) are also in train_filenames (e.g. {both[0]!r})", field=key)
