"""The checks of a dataset as a whole, as training will see it: the training plan, the background
against the images, empty views, the world the train views cover, the synthetic scale and nerfstudio's file.
"""
from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional

import numpy as np
import torch

from nerf_core.check import frames as frame_checks
from nerf_core.check.report import CheckReport, shown_path
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.jsonfile import parse_json_file
from nerf_core.contract.naming import evenly_spaced
from nerf_core.contract.paths import IMAGE_EXTS
from nerf_core.contract.transforms import frame_infos, resolve_image
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
from nerf_core.data.scene_box import beyond_box_reason, estimate_aabb
from nerf_core.data.validation import parse_aabb, scene_fields
from nerf_core.errors import ImageReadError
from nerf_core.fields.world_coverage import covered_directions, unseen_world_share
from nerf_core.image.io import read_png
from nerf_core.methods.catalog import DEFAULT_METHOD
from nerf_core.methods.registry import has_option

BACKGROUND_PROBE_IMAGES = 16  # evenly spaced train images read to tell opaque from cut-out captures
UNSEEN_WORLD_WARN = 0.02  # share of a held-out view's pixels on unseen world that earns a warning
# The scale of the original synthetic scenes, which some loaders hard-code instead of reading the
# file: the original NeRF samples rays from near 2 to far 6 (run_nerf.py), TensoRF and nerfstudio's
# blender-data bound the scene by a +-1.5 box. Cameras of those scenes sit about 4 from the origin.
SYNTHETIC_BOX_HALF = 1.5
SYNTHETIC_CAMERA_DISTANCE = (2.0, 7.5)  # from near 2 to far 6 past the box's edge


def training_plan(report: CheckReport, root: Path, background: str) -> None:
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
    if reason and has_option(DEFAULT_METHOD, "unbounded"):
        report.plan.append(f"{DEFAULT_METHOD} (the default method) will model the world beyond the box "
                           f"(unbounded=true): {reason}; --set unbounded=false turns it off")


def check_background(report: CheckReport, root: Path, background: str) -> Optional[bool]:
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


def warn_empty_views(report: CheckReport, root: Path, empty: Dict[str, list], how: str, ask: str) -> None:
    """Warn about views whose image shows nothing (``empty``: split -> FrameInfos, found while
    ``_check_loadable`` reads the pixels): transparent everywhere on a transparent film, where the
    camera saw none of the scene, or opaque and black everywhere, where it saw no light. A held-out
    one measures nothing, and a train one teaches nothing of the scene. ``how`` says which, ``ask``
    what to look at. Most readers would call such a dataset fine."""
    for split, frames in empty.items():
        for fr in frames[:10]:
            report.warn(shown_path(root, str(fr.json_file)),
                        f"the image is {how}: this view shows nothing of the scene ({ask})"
                        + ("; a held-out view of nothing measures nothing" if split != "train" else ""),
                        fr.index, fr.file_path)
        if len(frames) > 10:
            report.warn(shown_path(root, str(frames[0].json_file)),
                        f"{len(frames) - 10} more views show nothing ({how})")


def check_world_coverage(report: CheckReport, root: Path) -> None:
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
                report.warn(shown_path(root, str(fr.json_file)),
                            f"{100 * share:.0f} % of this view's pixels look at parts of the world behind the scene "
                            "that no train view shows; no model can learn them, so the view will score low there. "
                            "Train views that look in those directions (often lower cameras, nearer the horizon) "
                            "fix it", fr.index, fr.file_path)


def check_synthetic_scale(report: CheckReport, boxes: Dict[str, object], poses: Dict[str, list]) -> None:
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
        said.append(
            f"{len(outside)} of {len(dists)} train cameras lie {min(dists):.3g}-{max(dists):.3g} units from the "
            f"origin (theirs: about 4)"
        )
    report.warn(fname, "not at the scale of the synthetic NeRF scenes: " + "; ".join(said) + ". Loaders that "
                "hard-code it (the original NeRF: near 2, far 6; TensoRF and nerfstudio blender-data: a +-1.5 box) "
                "will miss the scene; nerfstudio-data, instant-ngp and 3DGS read the file's own aabb and cameras",
                field="aabb")


def check_nerfstudio(report: CheckReport, root: Path, split_intrinsics: Dict[str, dict],
                      name: str = frame_checks.NERFSTUDIO_FILE) -> None:
    """nerfstudio-data's file ``name`` (relative to ``root``): ``nerfstudio/transforms.json`` of an export
    of ours, or ``transforms.json`` of the one-file layout. Its frames' images, poses and intrinsics."""
    path = root / name
    if not path.is_file():
        report.error(
            name,
            "missing: nerfstudio's nerfstudio-data parser needs one transforms.json with real file names "
            "(`--data DATASET/nerfstudio`)",
        )
        return
    base = path.parent  # nerfstudio resolves file paths against the JSON's own folder
    meta = frame_checks.load_json(report, path)
    if meta is None:
        return
    frame_checks.check_meta_common(report, name, meta)
    names = set()
    seen: set = set()
    for k, fr, fp, intr in frame_checks.frame_entries(report, name, meta, seen):
        names.add(str(Path(fp)))
        if Path(fp).suffix.lower() not in IMAGE_EXTS:
            report.error(name, f"{fp!r} needs its real file name with the extension (nerfstudio does not add one)",
                         k, fp, "file_path")
            continue
        img = base / fp
        frame_checks.check_image(report, name, img, intr, k, fp, "file_path", rgba=False)
        frame_checks.check_frame_pose(report, name, fr, k, fp)
        frame_checks.check_extras(report, name, base, fr, k, fp)
        # nerfstudio-data takes a top-level intrinsic for every frame and never reads the frame's own.
        ignored = [
            key for key in frame_checks.REQUIRED_INTRINSICS if key in meta and key in fr and fr[key] != meta[key]
        ]
        if ignored:
            report.error(name, f"{ignored[0]} {fr[ignored[0]]!r} differs from the top-level {meta[ignored[0]]!r}, "
                         "which nerfstudio-data uses for every frame: leave the top-level intrinsics out when the "
                         "frames differ", k, fp, ignored[0])
        other = split_intrinsics.get(str(frame_checks.resolved(img)))
        if other is not None and intr is not None:
            diff = [
                key
                for key in frame_checks.REQUIRED_INTRINSICS
                if abs(other[key] - intr[key]) > 1e-4 * max(1.0, abs(other[key]))
            ]
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
