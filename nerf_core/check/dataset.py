"""Validating a dataset folder against ../shared/CONVENTIONS.md: ``python -m nerf_core check DATASET``.

Every loader our users rely on (original NeRF, nerfstudio's blender-data and nerfstudio-data,
instant-ngp, 3DGS) must read the folder unchanged, so the check lists *every* problem, each naming
its file, frame and field, instead of stopping at the first. Warnings are things that load but may
surprise (an off-centre principal point that camera_angle_x-only loaders ignore).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Dict, List

import numpy as np

from nerf_core.check.frames import (
    NERFSTUDIO_FILE,
    SPLIT_FILES,
    check_extras,
    check_frame_pose,
    check_image,
    check_meta_common,
    frame_entries,
    load_json,
    resolved,
)
from nerf_core.check.report import CheckReport, Problem, shown_path
from nerf_core.check.scene import (
    check_background,
    check_nerfstudio,
    check_synthetic_scale,
    check_world_coverage,
    training_plan,
    warn_empty_views,
)
from nerf_core.contract.colmap_model import find_sparse
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.intrinsics import angle_only_caveats
from nerf_core.contract.transforms import frame_infos, resolve_image
from nerf_core.data.backgrounds import BACKGROUNDS
from nerf_core.data.problems import dataset_problems
from nerf_core.utils import arguments

_FRAME_RE = re.compile(r"^(?P<file>.+?\.json): frame (?P<frame>\d+) \((?P<path>.*?)\): (?P<rest>.*)$", re.S)
_FILE_RE = re.compile(r"^(?P<file>.+?\.json): (?P<rest>.*)$", re.S)
_FIELD_RE = re.compile(r"^field '(?P<field>[^']+)'")


def check_dataset(path: Path | str, background: str = "auto", for_training: bool = False) -> CheckReport:
    """Check a dataset folder; never raises for dataset problems (they go into the report).

    ``background`` is the training background mode to check the images against (``train --background``).
    ``for_training``: only what ``train`` refuses is an error; what the conventions of an export ask
    for other tools' loaders (``fl_x``... beside ``camera_angle_x``, ``nerfstudio/transforms.json``)
    becomes a warning. A dataset of another tool (the original NeRF scenes, instant-ngp, nerfstudio)
    trains, and the add-on runs this before training.

    Args:
        path: a dataset folder, or a ``transforms*.json`` in it (its folder is checked).
        background: a ``train --background`` mode ("auto", "environment", "random", "white", "black",
            "white-then-random").
        for_training: check for training only (see above).

    Returns:
        A ``CheckReport``: ``ok`` (no errors), ``errors`` and ``warnings`` (problems naming the file,
        frame and field), ``n_frames`` per split, ``plan`` (what ``train`` will decide), ``notes``,
        ``trainable``; ``format()`` gives the text the ``check`` command prints, ``as_dict()`` its JSON.
    """
    root = Path(arguments.path("check_dataset", "path", path))
    arguments.choice("check_dataset", "background", background, BACKGROUNDS)
    if not isinstance(for_training, bool):
        raise TypeError(f"check_dataset: for_training must be True or False, got {for_training!r}")
    if root.is_file() and root.suffix == ".json" and root.name.startswith("transforms"):
        root = root.parent  # DATASET/transforms_train.json, as `train` accepts it: check its dataset
    if _is_nerfstudio_copy(root):
        return _check_nerfstudio_copy(root, background, for_training)
    report = CheckReport(root)
    if not root.is_dir():
        report.error(str(root), "dataset folder not found" if not root.exists() else "not a folder")
        return report
    if not any((root / f).exists() for f in ("transforms_train.json", "transforms.json")) and (
            (root / "images").is_dir() and find_sparse(root) not in (None, root)):
        # a COLMAP folder: its conventions are COLMAP's own (the readers check them); what train refuses
        # is all there is to say
        _check_loadable(report, root)
        if report.ok:
            training_plan(report, root, background)
        return report

    one_file = _check_root_json(report, root)
    poses, frame_intrinsics, boxes = _check_split_files(report, root, one_file)
    _check_held_out_views(report, poses)
    check_synthetic_scale(report, boxes, poses)
    check_nerfstudio(report, root, frame_intrinsics, "transforms.json" if one_file else NERFSTUDIO_FILE)
    opaque = check_background(report, root, background)
    if opaque:
        check_world_coverage(report, root)
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
        training_plan(report, root, background)
    return report


def _is_nerfstudio_copy(root: Path) -> bool:
    """Whether ``root`` is our export's ``nerfstudio/`` folder (one layout of the dataset above it)."""
    return (root.name == Path(NERFSTUDIO_FILE).parent.name and (root / "transforms.json").is_file()
            and any((root.parent / name).is_file() for name in SPLIT_FILES))


def _check_nerfstudio_copy(root: Path, background: str, for_training: bool) -> CheckReport:
    """Check the dataset above our export's ``nerfstudio/`` copy, that file included.

    Checked on its own, the folder looked like a dataset missing every file it is not meant to hold."""
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


def _check_root_json(report: CheckReport, root: Path) -> bool:
    """Report JSON files at the root that instant-ngp would load as transforms files. Returns whether
    the dataset is the one-file layout (transforms.json alone: what nerfstudio-data and instant-ngp read)."""
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
    return one_file


def _check_split_files(report: CheckReport, root: Path, one_file: bool):
    """Check the three split files and their frames. Returns (poses: split -> [(frame, file_path,
    c2w (4, 4), resolved image)], image file -> its intrinsics, split file -> its ``aabb``)."""
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
            report.error(
                fname, f"missing: {layout}the original NeRF loader reads train, val and test; 3DGS needs train and test"
            )
            continue
        meta = load_json(report, fpath_json)
        if meta is None:
            continue
        check_meta_common(report, fname, meta)
        boxes[fname] = meta.get("aabb")
        if "camera_angle_x" not in meta:
            report.error(fname, "missing: the only camera field the original NeRF loader, blender-data and 3DGS read",
                         field="camera_angle_x")
        report.n_frames[split] = len(meta["frames"])
        poses[split] = []
        cameras = []
        for k, fr, fp, intr in frame_entries(report, fname, meta, seen):
            if intr is not None:
                cameras.append(intr)
            img = resolve_image(root, fp, add_png=True)
            if Path(fp).suffix and img.name == Path(fp).name:
                report.error(fname, f"{fp!r} has an extension; loaders of this layout add '.png' themselves "
                                    f"(write {str(Path(fp).with_suffix(''))!r})", k, fp, "file_path")
            check_image(report, fname, img, intr, k, fp, "file_path", rgba=True)
            m = check_frame_pose(report, fname, fr, k, fp)
            check_extras(report, fname, root, fr, k, fp)
            if m is not None:
                poses[split].append((k, fp, m, resolved(img)))
            if intr is not None:
                frame_intrinsics[str(resolved(img))] = intr
        # nerfstudio-data reads every intrinsic itself; the split files feed camera_angle_x-only loaders.
        for field, message in angle_only_caveats(cameras):
            report.warn(fname, message, field=field)
    return poses, frame_intrinsics, boxes


def _check_held_out_views(report: CheckReport, poses: Dict[str, List[tuple]]) -> None:
    """Held-out cameras must be new viewpoints: not a training image, not a training camera."""
    for split in ("val", "test"):
        for k, fp, m, img in poses.get(split, []):
            for k2, fp2, m2, img2 in poses.get("train", []):
                if img == img2:
                    report.error(
                        f"transforms_{split}.json",
                        f"uses the training image of train frame {k2} ({fp2})",
                        k,
                        fp,
                        "file_path",
                    )
                    break
                if np.allclose(m, m2, atol=1e-6):
                    report.error(
                        f"transforms_{split}.json",
                        f"camera equals train frame {k2} ({fp2}): held-out views must be new viewpoints",
                        k,
                        fp,
                        "transform_matrix",
                    )
                    break


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
                report.warn(
                    shown_path(root, str(fr.json_file)),
                    "points outside the dataset folder (absolute or '../'): "
                    "the file is read, but a copy of the folder or another machine will not find it",
                    fr.index,
                    fr.file_path,
                    key,
                )


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
            report.error(shown_path(root, m["file"]), m["rest"], frame, m["path"])
            reported.add((fname, frame))
            continue
        m = _FILE_RE.match(msg)
        if m:
            fname = Path(m["file"]).name
            if any(f"field '{fld}'" in m["rest"] for (fn, fld) in fields if fn == fname):
                continue
            if any(Path(p.file).name == fname and p.message == m["rest"] for p in report.errors):
                continue  # the same problem, already reported by the convention checks
            report.error(shown_path(root, m["file"]), m["rest"])
        else:
            report.error(str(root), msg)
    warn_empty_views(report, root, empty, "transparent everywhere",
                      "does its camera look away from it, or stand inside an object?")
    warn_empty_views(report, root, black, "opaque and black everywhere",
                      "is the scene lit where this camera looks? A camera inside a closed object, lights that are "
                      "off or an exposure far too low all render black")


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


