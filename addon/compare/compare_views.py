"""Rendering a trained run's novel views and bringing them back as image planes (no UI here).

``prepare_render`` writes the cameras to render (the dataset's test/val split, or a
transforms file for selected cameras / a fly-through) and makes a fresh output folder;
``render_job.RenderJob`` runs ``nerf_core render`` into it, then ``import_views`` lays the images out as
camera-aligned planes or a NeRF | Blender | error gallery. scripts/import_views.py uses the same
functions headless. Earlier renders are never overwritten: each gets its own ``RUN/views/<label>_NNN``.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import List, Optional, Tuple

import bpy
import mathutils

from ..bridge import child_process, runs
from ..bridge.child_process import SetupError
from ..bridge.core_contract import contract
from ..dataset import cameras
from . import image_storage, planes

VIEWS_DIR = "views"  # RUN/views/: cameras files and render folders made by the add-on
SPLIT_FILES = ("transforms_test.json", "transforms_val.json", "transforms_train.json", "transforms.json")


@dataclass
class RenderPlan:
    """What one render writes: the cameras file, how many views it holds, and the fresh output folder."""

    run: str
    cameras: str
    n_views: int
    label: str
    out: str
    checkpoint: str = ""  # a step_*.pt to pass as --checkpoint when latest.pt is gone; '' for latest.pt


def require_checkpoint(run: str) -> str:
    """The checkpoint ``nerf_core render`` should use: '' for RUN/checkpoints/latest.pt (its default),
    else the newest step_*.pt, as ``train --resume`` falls back to when a full disk cost latest.pt.
    SetupError when the run has neither."""
    if run and os.path.isfile(contract.latest_checkpoint(run)):
        return ""
    steps = runs.step_checkpoints(run) if run else []
    if steps:
        return steps[0]
    raise SetupError(f"Run folder {run or '(not set)'} has no trained checkpoint yet: train first.")


def prepare_render(context, run: str, source: str) -> RenderPlan:
    """Write the cameras for ``source`` ('TEST', 'VAL', 'SELECTED', 'ANIMATION') and create
    ``RUN/views/<label>_NNN``; SetupError says what to fix."""
    checkpoint = require_checkpoint(run)
    cameras, n_views, label = write_cameras_file(context, run, source)
    out = fresh_dir(views_dir(run), label)
    return RenderPlan(run, cameras, n_views, label, out, checkpoint)


def views_dir(run: str) -> str:
    """``RUN/views``; SetupError when a file of that name is in the way (the user's: never replaced)."""
    path = os.path.join(run, VIEWS_DIR)
    if os.path.lexists(path) and not os.path.isdir(path):
        what = "a file" if os.path.isfile(path) else "in the way"
        raise SetupError(f"{path} is {what}, not a folder: Compare writes its cameras and renders there; move it "
                         "away (it was left untouched).")
    return path


def run_dataset_of(run: str) -> str:
    """The dataset folder RUN/config.json records; SetupError naming the file when it cannot be read,
    is not the JSON object ``train`` writes, or records no dataset."""
    path = contract.config_path(run)
    try:
        with open(path, encoding="utf-8") as fh:
            cfg = json.load(fh)
    except FileNotFoundError:
        raise SetupError(f"{path} not found: is {run} a folder written by training?") from None
    except OSError as exc:
        raise SetupError(f"{path}: cannot read ({exc.strerror or exc}).") from None
    except (ValueError, RecursionError) as exc:  # invalid JSON or text (UnicodeDecodeError is a ValueError)
        raise SetupError(f"{path}: invalid JSON ({exc}); the run's settings cannot be read.") from None
    if not isinstance(cfg, dict):
        raise SetupError(f"{path}: expected the JSON object that training writes, got a {type(cfg).__name__}.")
    dataset = runs.config_dataset(cfg, run)
    if not dataset:
        raise SetupError(f"{path} records no dataset (key 'dataset'): the run's cameras and image size are unknown.")
    return dataset


def fresh_dir(parent: str, label: str) -> str:
    """``parent/label_001``, ``_002``...: each render gets its own folder, earlier ones stay intact."""
    k = 1
    while os.path.exists(os.path.join(parent, f"{label}_{k:03d}")):
        k += 1
    path = os.path.join(parent, f"{label}_{k:03d}")
    try:
        os.makedirs(path)
    except OSError as exc:
        raise SetupError(child_process.describe_os_error(exc, path, "creating")) from None
    return path


def dataset_meta(run: str, dataset: Optional[str] = None) -> dict:
    """The run's dataset's first transforms file (test, val, train, single) as a dict; {} if none reads.
    ``dataset``: the folder when the caller has it, else the one RUN/config.json records."""
    dataset = dataset if dataset is not None else runs.run_dataset(run)
    for name in SPLIT_FILES:
        path = os.path.join(dataset, name) if dataset else None
        if path and os.path.isfile(path):
            try:
                with open(path, encoding="utf-8") as fh:
                    meta = json.load(fh)
            except (OSError, ValueError, RecursionError):
                return {}
            return meta if isinstance(meta, dict) else {}  # a damaged file: no size, said by the caller
    return {}


def write_cameras_file(context, run: str, source: str) -> Tuple[str, int, str]:
    """(transforms path, number of views, label) for ``source``: the dataset's split file, or a file
    written into RUN/views/ for the selected cameras / the active camera's animation."""
    dataset = run_dataset_of(run)
    if source in ("TEST", "VAL"):
        split = source.lower()
        path = os.path.join(dataset, f"transforms_{split}.json")
        if not os.path.isfile(path):
            raise SetupError(f"The run's dataset ({dataset}) has no transforms_{split}.json.")
        try:
            with open(path, encoding="utf-8") as fh:
                doc = json.load(fh)
        except (OSError, ValueError, RecursionError) as exc:
            raise SetupError(f"{path}: cannot read ({exc})") from None
        frames = doc.get("frames") if isinstance(doc, dict) else None
        if not isinstance(frames, list):
            raise SetupError(f"{path}: expected a transforms object with a 'frames' list; run "
                             "`python -m nerf_core check` on the dataset")
        return path, len(frames), split
    meta = dataset_meta(run, dataset)
    if not meta.get("w") or not meta.get("h"):
        raise SetupError("The run's dataset has no image size (w, h) in its transforms: cannot match camera aspect.")
    scene = context.scene
    try:
        if source == "SELECTED":
            cams = [ob for ob in context.selected_objects if ob.type == "CAMERA"]
            if not cams:
                raise SetupError("No camera is selected: select the camera(s) to render.")
            data = cameras.cameras_transforms(cams, scene, (meta["w"], meta["h"]), base=meta, prefix="selected")
            label = "selected"
        else:
            cam = scene.camera if scene.camera is not None else None
            if context.active_object is not None and context.active_object.type == "CAMERA":
                cam = context.active_object
            if cam is None:
                raise SetupError("No active camera for the fly-through: make a camera active.")
            frames = list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))
            data = cameras.cameras_transforms([cam], scene, (meta["w"], meta["h"]), frames=frames, base=meta,
                                             prefix="flythrough")
            label = "flythrough"
    except ValueError as exc:
        raise SetupError(str(exc)) from None
    path = os.path.join(views_dir(run), f"cameras_{label}.json")
    try:
        child_process.write_json_atomic(path, data)
    except OSError as exc:
        raise SetupError(str(exc) if isinstance(exc, child_process.DiskFullError)
                         else child_process.describe_os_error(exc, path)) from None
    return path, len(data["frames"]), label


def rendered_count(out_dir: str) -> int:
    """How many views ``nerf_core render`` has written into ``out_dir`` so far (error maps excluded)."""
    try:
        return sum(1 for f in os.listdir(out_dir) if f.endswith(".png") and not f.endswith("_error.png"))
    except OSError:
        return 0


def render_notes(out_dir: str) -> List[str]:
    """The notes ``nerf_core render`` left in ``out_dir``/renders.json (the run's dataset changed since
    it trained, ...); [] when there are none or the file cannot be read (the import reports that)."""
    try:
        with open(os.path.join(out_dir, "renders.json"), encoding="utf-8") as fh:
            notes = json.load(fh).get("notes")
    except (OSError, ValueError, AttributeError):
        return []
    return [n for n in notes if isinstance(n, str)] if isinstance(notes, list) else []


def import_views(scene, views: List[planes.View], layout: str, out_dir: str, run: str, distance: float = 0.0) -> str:
    """Import ``views`` with ``layout`` ('CAMERA' or 'GALLERY'), keep their images as the Compare
    panel's ``image_storage`` says (``image_storage``: pack by default) and list their metrics on the
    scene. The gallery goes beside the scene's objects; the user's active camera and resolution are
    left alone. Returns a note when the images could not be stored as asked or the views were rendered
    through a distorted lens (``planes.lens_note``), else ''."""
    if layout == "GALLERY":
        planes.import_gallery(views, out_dir, background=runs.run_background(run), scene=scene)
        made = [o for o in bpy.data.collections[planes.GALLERY_COLLECTION].all_objects if o.get(planes.TAG)]
    else:
        made = planes.import_camera_aligned(views, distance or auto_distances(views, run), scene=scene)
    settings = getattr(scene, "nerf_train", None)
    mode = settings.image_storage.lower() if settings is not None else image_storage.DEFAULT
    note = image_storage.store(image_storage.plane_images(made), mode)
    if settings is not None:
        settings.view_metrics.clear()
        for view in views:
            item = settings.view_metrics.add()
            item.name = view.name
            item.psnr = view.metrics.get("psnr", 0.0)
            item.ssim = view.metrics.get("ssim", 0.0)
            item.has_metrics = bool(view.metrics)
    return "; ".join(n for n in (note, planes.lens_note(views)) if n)


def auto_distances(views: List[planes.View], run: str) -> List[float]:
    """Per view, where a camera-aligned plane goes when no distance is set: at the depth of the scene
    centre (middle of the run's aabb, else the dataset's), so the image sits among the objects it
    shows; just beyond ``near`` when the centre is behind that; 1 scene unit when nothing is known."""
    meta = dataset_meta(run)
    try:
        with open(contract.config_path(run), encoding="utf-8") as fh:
            config = json.load(fh)
    except (OSError, ValueError):
        config = {}
    aabb = config.get("aabb") or meta.get("aabb")
    near = config.get("near", meta.get("near")) or 0.0
    out = []
    for view in views:
        if not (isinstance(aabb, list) and len(aabb) == 2):
            out.append(near * 1.05 if near > 0 else 1.0)
            continue
        centre = (mathutils.Vector(aabb[0]) + mathutils.Vector(aabb[1])) / 2
        depth = -(mathutils.Matrix(view.c2w).inverted() @ centre).z
        out.append(depth if depth > max(near, 1e-6) else (near * 1.05 if near > 0 else 1.0))
    return out
