"""Train and Compare panels (3D viewport > N-panel > NeRF): train in a child process, follow its
progress live, render novel views and bring them back as image planes.

The operators only start jobs; a job (``TrainJob``/``RenderJob``) owns its child process and is
advanced by ``Job.update()``, which a modal timer operator calls a few times a second. Nothing here
ever waits on the child, so Blender stays responsive. Jobs live in ``_JOBS`` (Python objects cannot
live in scene properties); the scene's ``nerf_train`` settings mirror their state for the panel.
"""
from __future__ import annotations

import atexit
import json
import os
import sys
from typing import Dict, List, Optional

import bpy
import bpy.utils.previews
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty,
                       PointerProperty, StringProperty)

from . import planes, prefs, runs, trainer_process
from .trainer_process import SetupError

_JOBS: Dict[str, "Job"] = {}
_PREVIEWS = None  # bpy.utils.previews collection holding the latest training preview
TIMER_INTERVAL = 0.25


def format_seconds(seconds: Optional[float]) -> str:
    """``75.2`` -> ``'1:15'``; None -> ``'?'`` (nerf_core.progressbar is not importable from an
    installed extension, where nerf_core lives in the vendored folder for the child only)."""
    if seconds is None or seconds != seconds or seconds in (float("inf"), float("-inf")):
        return "?"
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


# -- jobs ---------------------------------------------------------------------------------------------
class Job:
    """A child process plus what to do when it ends. ``update()`` returns 'running', 'done',
    'failed' or 'cancelled'; ``message`` says why for the last two."""

    kind = "job"

    def __init__(self, scene_name: str):
        self.scene_name = scene_name
        self.process: Optional[trainer_process.BackgroundProcess] = None
        self.state = "running"
        self.message = ""

    @property
    def scene(self):
        return bpy.data.scenes.get(self.scene_name)

    def cancel(self, wait: bool = True) -> None:
        """Stop the child. ``wait=False`` (the Cancel button) only asks it to stop, so Blender never
        waits; ``update()`` then finishes the cancel, killing the group if it does not exit in time."""
        if self.process is None or self.state != "running":
            return
        if wait:
            self.process.cancel()
            self._cancelled()
        else:
            self.process.request_stop()

    def _cancelled(self) -> str:
        p = self.process.progress
        self.state = "cancelled"
        self.message = f"{self.kind.capitalize()} cancelled"
        if p.step is not None:
            self.message += f" at step {p.step}"
        if p.error and "checkpoint saved" in p.error:
            self.message += "; checkpoint saved: Resume continues from it"
        return self.state

    def _check_cancel(self) -> Optional[str]:
        """While a requested stop is under way: None to keep going, else the final state."""
        if self.process.stop_requested_at is None:
            return None
        self.process.poll()
        if self.process.finished():
            return self._cancelled()
        self.process.kill_if_overdue()
        return self.state

    def fail(self, message: str) -> str:
        self.state, self.message = "failed", message
        return self.state


class TrainJob(Job):
    """``nerf_core check`` on the dataset, then ``nerf_core train``, both in the background."""

    kind = "training"

    def __init__(self, scene_name: str, python: str, dataset: str, run: str, command: List[str],
                 check: bool = True):
        super().__init__(scene_name)
        self.python, self.dataset, self.run, self.command = python, dataset, run, command
        if check:
            self.stage = "check"
            self.process = trainer_process.BackgroundProcess([python, "-m", "nerf_core", "check", dataset]).start()
        else:
            self.stage = "train"
            self.process = trainer_process.BackgroundProcess(command).start()

    def update(self) -> str:
        if self.state != "running":
            return self.state
        stopping = self._check_cancel()
        if stopping is not None:
            return stopping
        self.process.poll()
        if self.stage == "check":
            if not self.process.finished():
                return self.state
            if self.process.returncode != 0:
                lines = [ln for ln in self.process.tail if ln.strip()]
                detail = "\n".join(lines[-5:]) or f"exit code {self.process.returncode}"
                return self.fail(f"Dataset {self.dataset} is not usable:\n{detail}")
            self.stage = "train"
            self.process = trainer_process.BackgroundProcess(self.command).start()
            return self.state
        if self.process.finished():
            failure = self.process.failure_message()
            if failure:
                return self.fail(f"Training stopped: {failure}")
            self.state = "done"
            self.message = f"Training finished: {self.run}"
        return self.state


class RenderJob(Job):
    """``nerf_core render`` of a transforms file, then the planes import."""

    kind = "rendering"

    def __init__(self, scene_name: str, python: str, run: str, cameras: str, out: str, layout: str,
                 distance: float, n_views: int):
        super().__init__(scene_name)
        self.run, self.cameras, self.out, self.layout, self.distance = run, cameras, out, layout, distance
        self.n_views = n_views
        self.process = trainer_process.BackgroundProcess(
            trainer_process.render_command(python, run, cameras, out)).start()
        self.views: List[planes.View] = []

    def rendered(self) -> int:
        try:
            return sum(1 for f in os.listdir(self.out) if f.endswith(".png") and not f.endswith("_error.png"))
        except OSError:
            return 0

    def update(self) -> str:
        if self.state != "running":
            return self.state
        stopping = self._check_cancel()
        if stopping is not None:
            return stopping
        self.process.poll()
        if not self.process.finished():
            return self.state
        failure = self.process.failure_message()
        if failure:
            return self.fail(f"Rendering stopped: {failure}")
        scene = self.scene
        try:
            self.views = planes.views_from_render(self.out, self.cameras)
            import_views(scene, self.views, self.layout, self.out, self.run, self.distance)
        except (ValueError, RuntimeError) as exc:
            return self.fail(str(exc))
        except OSError as exc:
            return self.fail(trainer_process.describe_os_error(exc, self.out))
        self.state = "done"
        self.message = f"Imported {len(self.views)} view(s) from {self.out}"
        return self.state


def import_views(scene, views: List[planes.View], layout: str, out_dir: str, run: str, distance: float = 0.0):
    """Import ``views`` with ``layout`` ('CAMERA' or 'GALLERY') and list their metrics on the scene."""
    if layout == "GALLERY":
        planes.import_gallery(views, out_dir, origin=tuple(scene.cursor.location),
                              background=runs.run_background(run), scene=scene)
    else:
        planes.import_camera_aligned(views, distance or auto_distances(views, run), scene=scene)
    settings = getattr(scene, "nerf_train", None)
    if settings is not None:
        settings.view_metrics.clear()
        for view in views:
            item = settings.view_metrics.add()
            item.name = view.name
            item.psnr = view.metrics.get("psnr", 0.0)
            item.ssim = view.metrics.get("ssim", 0.0)
            item.has_metrics = bool(view.metrics)


def auto_distances(views: List[planes.View], run: str) -> List[float]:
    """Per view, where a camera-aligned plane goes when no distance is set: at the depth of the scene
    centre (middle of the run's aabb, else the dataset's), so the image sits among the objects it
    shows; just beyond ``near`` when the centre is behind that; 1 scene unit when nothing is known."""
    import mathutils

    meta = _dataset_meta(run)
    try:
        with open(os.path.join(run, "config.json"), encoding="utf-8") as fh:
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


def _dataset_meta(run: str) -> dict:
    dataset = runs.run_dataset(run)
    for name in ("transforms_test.json", "transforms_val.json", "transforms_train.json", "transforms.json"):
        path = os.path.join(dataset, name) if dataset else None
        if path and os.path.isfile(path):
            try:
                with open(path, encoding="utf-8") as fh:
                    return json.load(fh)
            except (OSError, ValueError):
                return {}
    return {}


# -- settings -------------------------------------------------------------------------------------
class NerfViewMetric(bpy.types.PropertyGroup):
    name: StringProperty()
    psnr: FloatProperty()
    ssim: FloatProperty()
    has_metrics: BoolProperty()


class NerfRunItem(bpy.types.PropertyGroup):
    name: StringProperty()
    path: StringProperty(subtype="DIR_PATH")
    method: StringProperty()
    settings: StringProperty()
    metrics: StringProperty()


class NerfTrainSettings(bpy.types.PropertyGroup):
    dataset_dir: StringProperty(name="Dataset", subtype="DIR_PATH",
                                description="Dataset folder written by Capture (transforms_*.json)")
    run_dir: StringProperty(name="Run", subtype="DIR_PATH",
                            description="Folder for the training run (checkpoints, previews, metrics)")
    method: StringProperty(name="Method", default="",
                           description="NeRF method name (e.g. nerf, nerf-nope); empty: the library's best fast method")
    max_seconds: FloatProperty(name="Time Budget", default=300.0, min=0.0, unit="TIME_ABSOLUTE",
                               description="Stop after this many seconds (0: no time limit)")
    max_steps: IntProperty(name="Max Steps", default=0, min=0, description="Stop after this many steps (0: no limit)")
    seed: IntProperty(name="Seed", default=0, min=0)
    # live state, mirrored from the job for drawing
    status: StringProperty(name="Status", default="")
    error: StringProperty(name="Last Error", default="")
    running: BoolProperty(default=False)
    step: IntProperty(default=0)
    loss: FloatProperty(default=0.0)
    psnr: FloatProperty(default=0.0)
    elapsed: FloatProperty(default=0.0)
    eta: FloatProperty(default=-1.0)
    fraction: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    rollbacks: IntProperty(default=0)
    background: StringProperty(default="", description="What stands behind the scene in this run, and why")
    preview_path: StringProperty(default="")
    runs: CollectionProperty(type=NerfRunItem)
    runs_index: IntProperty(default=0)
    # compare
    view_source: EnumProperty(name="Views", items=[
        ("TEST", "Test Cameras", "The dataset's held-out test cameras (with Blender's images to compare)"),
        ("VAL", "Val Cameras", "The dataset's validation cameras"),
        ("SELECTED", "Selected Cameras", "Every selected camera object"),
        ("ANIMATION", "Fly-through", "The active camera along its animation, one view per frame"),
    ], default="TEST")
    layout: EnumProperty(name="Layout", items=[
        ("CAMERA", "Camera-Aligned", "Each image on a plane in its camera's frustum: look through the camera to overlay"),
        ("GALLERY", "Gallery", "Rows of NeRF | Blender | error heat-map with PSNR/SSIM labels, at the 3D cursor"),
    ], default="GALLERY")
    plane_distance: FloatProperty(name="Plane Distance", default=0.0, min=0.0, unit="LENGTH",
                                  description="Distance of camera-aligned planes from their camera (0: at the scene centre)")
    view_metrics: CollectionProperty(type=NerfViewMetric)
    view_metrics_index: IntProperty(default=0)


def settings_of(context) -> NerfTrainSettings:
    return context.scene.nerf_train


def _abs(path: str) -> str:
    return os.path.abspath(bpy.path.abspath(path)) if path else ""


# -- starting and following jobs ----------------------------------------------------------------------
def start_training(context, resume: bool = False) -> TrainJob:
    """Validate the settings and start the check + train job; SetupError says what to fix."""
    if "train" in _JOBS and _JOBS["train"].state == "running":
        raise SetupError("A training run is already in progress: cancel it first.")
    s = settings_of(context)
    capture = getattr(context.scene, "nerf_capture", None)
    if not s.dataset_dir and capture is not None and getattr(capture, "output_dir", ""):
        # Nothing chosen yet: train on what the Capture panel writes, the usual next step.
        s.dataset_dir = capture.output_dir
    dataset, run = _abs(s.dataset_dir), _abs(s.run_dir)
    if not dataset:
        raise SetupError("No dataset folder is set: capture a dataset (Capture panel) or choose its folder.")
    if not os.path.isdir(dataset):
        raise SetupError(f"Dataset folder {dataset} does not exist: capture a dataset first.")
    if not run:
        raise SetupError("No run folder is set: choose where the training run should be written.")
    state = trainer_process.run_folder_state(run)
    if resume and state != "resumable":
        raise SetupError(f"Run folder {run} has no checkpoint to resume (checkpoints/latest.pt): press Train instead.")
    if not resume and state in ("resumable", "occupied"):
        what = "holds a training run: press Resume to continue it" if state == "resumable" else "is not empty"
        raise SetupError(f"Run folder {run} already {what}, or press New Name to train into "
                         f"{trainer_process.suggest_run_name(run)}. Nothing was overwritten.")
    python = trainer_process.resolve_interpreter(prefs.python_preference(context))
    cmd = trainer_process.train_command(python, dataset, run, method=s.method.strip(), max_seconds=s.max_seconds,
                                        max_steps=s.max_steps, seed=s.seed, resume=resume)
    job = TrainJob(context.scene.name, python, dataset, run, cmd)
    _JOBS["train"] = job
    s.running, s.error, s.step, s.loss, s.psnr, s.fraction, s.rollbacks = True, "", 0, 0.0, 0.0, 0.0, 0
    s.elapsed, s.eta, s.preview_path, s.background = 0.0, -1.0, "", ""
    s.status = f"Checking dataset {os.path.basename(dataset)}..."
    return job


def sync_train_settings(job: TrainJob) -> None:
    """Mirror the job's progress into the scene settings the panel draws."""
    scene = job.scene
    if scene is None:
        return
    s = scene.nerf_train
    p = job.process.progress if job.stage == "train" else None
    if p is not None:
        s.step = p.step or 0
        s.loss = p.loss or 0.0
        s.psnr = p.psnr or 0.0
        s.elapsed = p.elapsed or 0.0
        s.eta = -1.0 if p.eta is None else p.eta
        s.fraction = p.fraction() or 0.0
        s.rollbacks = len(p.rollbacks)
        if p.background:
            s.background = p.background + (f": {p.background_reason}" if p.background_reason else "")
        if p.preview_path and p.preview_path != s.preview_path and os.path.isfile(p.preview_path):
            s.preview_path = p.preview_path
            _load_preview(p.preview_path)
    if job.state == "running":
        s.status = "Checking dataset..." if job.stage == "check" else (
            f"Step {s.step}" + (f" ({100 * s.fraction:.0f}%)" if s.fraction else ""))
    else:
        s.running = False
        s.status = job.message.splitlines()[0] if job.message else job.state
        s.error = job.message if job.state == "failed" else ""


def _load_preview(path: str) -> None:
    global _PREVIEWS
    if _PREVIEWS is None:
        _PREVIEWS = bpy.utils.previews.new()
    _PREVIEWS.clear()  # only the latest preview is shown; dropping old ones bounds memory
    _PREVIEWS.load("latest", path, "IMAGE")


def cancel_jobs(wait: bool = True) -> None:
    """Stop every running child. The Cancel button passes ``wait=False`` (the modal timer finishes the
    cancel); file loads and unregister wait, since nothing polls afterwards: no orphans either way."""
    for job in list(_JOBS.values()):
        if job.state == "running":
            job.cancel(wait=wait)


def refresh_runs(settings) -> None:
    run = _abs(settings.run_dir)
    root = os.path.dirname(os.path.normpath(run)) if run else ""
    settings.runs.clear()
    for info in runs.list_runs(root):
        item = settings.runs.add()
        item.name, item.path, item.method = info.name, info.path, info.method
        item.settings = info.settings_summary()
        item.metrics = info.problem or info.metrics_summary()


def start_render(context) -> RenderJob:
    """Write the cameras to render, then start ``nerf_core render`` into a fresh folder of the run."""
    if "render" in _JOBS and _JOBS["render"].state == "running":
        raise SetupError("Views are already being rendered: wait for them or cancel.")
    s = settings_of(context)
    run = _abs(s.run_dir)
    if not run or not os.path.isfile(os.path.join(run, "checkpoints", "latest.pt")):
        raise SetupError(f"Run folder {run or '(not set)'} has no trained checkpoint yet: train first.")
    python = trainer_process.resolve_interpreter(prefs.python_preference(context))
    cameras, n_views, label = write_cameras_file(context, run, s.view_source)
    out = _fresh_dir(os.path.join(run, "views"), label)
    job = RenderJob(context.scene.name, python, run, cameras, out, s.layout, s.plane_distance, n_views)
    _JOBS["render"] = job
    s.status = f"Rendering {n_views} view(s)..."
    s.error = ""
    return job


def _fresh_dir(parent: str, label: str) -> str:
    """``parent/label_001``, ``_002``...: each render gets its own folder, earlier ones stay intact."""
    k = 1
    while os.path.exists(os.path.join(parent, f"{label}_{k:03d}")):
        k += 1
    path = os.path.join(parent, f"{label}_{k:03d}")
    try:
        os.makedirs(path)
    except OSError as exc:
        raise SetupError(trainer_process.describe_os_error(exc, path, "creating")) from None
    return path


def write_cameras_file(context, run: str, source: str):
    """(transforms path, number of views, label) for ``source``: the dataset's split file, or a file
    written into RUN/views/ for the selected cameras / the active camera's animation."""
    dataset = runs.run_dataset(run)
    if source in ("TEST", "VAL"):
        split = source.lower()
        path = os.path.join(dataset, f"transforms_{split}.json") if dataset else ""
        if not path or not os.path.isfile(path):
            raise SetupError(f"The run's dataset ({dataset or 'unknown: config.json has no dataset'}) has no "
                             f"transforms_{split}.json.")
        try:
            with open(path, encoding="utf-8") as fh:
                n = len(json.load(fh).get("frames", []))
        except (OSError, ValueError) as exc:
            raise SetupError(f"{path}: cannot read ({exc})") from None
        return path, n, split
    meta = _dataset_meta(run)
    if not meta.get("w") or not meta.get("h"):
        raise SetupError(f"The run's dataset has no image size (w, h) in its transforms: cannot match camera aspect.")
    scene = context.scene
    try:
        if source == "SELECTED":
            cams = [ob for ob in context.selected_objects if ob.type == "CAMERA"]
            if not cams:
                raise SetupError("No camera is selected: select the camera(s) to render.")
            data = planes.cameras_transforms(cams, scene, (meta["w"], meta["h"]), base=meta, prefix="selected")
            label = "selected"
        else:
            cam = scene.camera if scene.camera is not None else None
            if context.active_object is not None and context.active_object.type == "CAMERA":
                cam = context.active_object
            if cam is None:
                raise SetupError("No active camera for the fly-through: make a camera active.")
            frames = list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))
            data = planes.cameras_transforms([cam], scene, (meta["w"], meta["h"]), frames=frames, base=meta,
                                             prefix="flythrough")
            label = "flythrough"
    except ValueError as exc:
        raise SetupError(str(exc)) from None
    path = os.path.join(run, "views", f"cameras_{label}.json")
    try:
        trainer_process.write_json_atomic(path, data)
    except OSError as exc:
        raise SetupError(str(exc) if isinstance(exc, trainer_process.DiskFullError)
                         else trainer_process.describe_os_error(exc, path)) from None
    return path, len(data["frames"]), label


# -- operators -----------------------------------------------------------------------------------------
def _redraw(context) -> None:
    wm = context.window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


class _JobOperator:
    """Shared modal loop: a timer polls the job; other events pass through so Blender stays usable."""

    job_key = ""
    _timer = None

    def start(self, context):  # -> Job
        raise NotImplementedError

    def invoke(self, context, event):
        try:
            self.start(context)
        except SetupError as exc:
            settings_of(context).error = str(exc)
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self._timer = context.window_manager.event_timer_add(TIMER_INTERVAL, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):  # scripts and tests: start, then let update() be driven by the caller
        try:
            self.start(context)
        except SetupError as exc:
            settings_of(context).error = str(exc)
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return {"FINISHED"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        job = _JOBS.get(self.job_key)
        state = job.update() if job else "cancelled"
        if job is not None:
            self.sync(job)
        _redraw(context)
        if state == "running":
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        if state == "failed":
            print(f"NeRF Bridge: {job.message}", file=sys.stderr)  # the whole log tail, for the console
            self.report({"ERROR"}, job.message.splitlines()[0])
            return {"CANCELLED"}
        if job is not None:
            self.report({"INFO"}, job.message)
        refresh_runs(settings_of(context))
        return {"FINISHED"}

    def sync(self, job) -> None:
        scene = job.scene
        if scene is None:
            return
        s = scene.nerf_train
        if job.state == "running":
            done = job.rendered() if isinstance(job, RenderJob) else 0
            s.status = f"Rendering views: {done}/{job.n_views}" if isinstance(job, RenderJob) else s.status
        else:
            s.status = job.message.splitlines()[0] if job.message else job.state
            s.error = job.message if job.state == "failed" else ""


class NERF_OT_train(_JobOperator, bpy.types.Operator):
    """Train a NeRF on the dataset in a separate process (Blender stays responsive)"""

    bl_idname = "nerf.train"
    bl_label = "Train"
    job_key = "train"

    resume: BoolProperty(name="Resume", default=False, options={"SKIP_SAVE"},
                         description="Continue the run from its last checkpoint")

    def start(self, context):
        return start_training(context, resume=self.resume)

    def sync(self, job) -> None:
        sync_train_settings(job)


class NERF_OT_train_cancel(bpy.types.Operator):
    """Stop the training or rendering process (checkpoints written so far are kept)"""

    bl_idname = "nerf.train_cancel"
    bl_label = "Cancel"

    def execute(self, context):
        running = [job for job in _JOBS.values() if job.state == "running"]
        if not running:
            self.report({"WARNING"}, "Nothing is running")
            return {"CANCELLED"}
        # The modal operator that follows the job sees it stop and reports; when none is polling
        # (a script, or the modal was lost), finish the cancel right here.
        cancel_jobs(wait=not self.background)
        s = settings_of(context)
        s.status = "Stopping: the trainer saves a checkpoint first..." if self.background else "Cancelled"
        for job in running:
            if isinstance(job, TrainJob) and job.state != "running":
                sync_train_settings(job)
        return {"FINISHED"}

    background: BoolProperty(default=True, options={"SKIP_SAVE", "HIDDEN"},
                             description="Return at once; the panel's timer finishes the cancel")


class NERF_OT_run_new_name(bpy.types.Operator):
    """Point the run folder at a new, unused name next to the current one"""

    bl_idname = "nerf.run_new_name"
    bl_label = "New Name"

    def execute(self, context):
        s = settings_of(context)
        if not s.run_dir:
            self.report({"ERROR"}, "No run folder is set")
            return {"CANCELLED"}
        s.run_dir = trainer_process.suggest_run_name(_abs(s.run_dir))
        s.error = ""
        return {"FINISHED"}


class NERF_OT_refresh_runs(bpy.types.Operator):
    """List the training runs next to the run folder, with their method, settings and metrics"""

    bl_idname = "nerf.refresh_runs"
    bl_label = "Refresh Runs"

    def execute(self, context):
        refresh_runs(settings_of(context))
        return {"FINISHED"}


class NERF_OT_use_run(bpy.types.Operator):
    """Make the highlighted run the current one"""

    bl_idname = "nerf.use_run"
    bl_label = "Use Run"

    def execute(self, context):
        s = settings_of(context)
        if not (0 <= s.runs_index < len(s.runs)):
            return {"CANCELLED"}
        s.run_dir = s.runs[s.runs_index].path
        dataset = runs.run_dataset(s.run_dir)
        if dataset:
            s.dataset_dir = dataset
        return {"FINISHED"}


class NERF_OT_render_views(_JobOperator, bpy.types.Operator):
    """Render novel views with the trained NeRF and import them as image planes"""

    bl_idname = "nerf.render_views"
    bl_label = "Render & Import Views"
    job_key = "render"

    def start(self, context):
        return start_render(context)


class NERF_OT_clear_views(bpy.types.Operator):
    """Remove the imported NeRF planes (and the images and materials they used)"""

    bl_idname = "nerf.clear_views"
    bl_label = "Clear Views"

    def execute(self, context):
        n = planes.clear_collection(planes.VIEWS_COLLECTION) + planes.clear_collection(planes.GALLERY_COLLECTION)
        settings_of(context).view_metrics.clear()
        self.report({"INFO"}, f"Removed {n} object(s)")
        return {"FINISHED"}


# -- panels ------------------------------------------------------------------------------------------
class NERF_UL_runs(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        row.label(text=item.name, icon="FILE_FOLDER")
        row.label(text=item.method)
        row.label(text=item.metrics)


class NERF_UL_view_metrics(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        row.label(text=item.name, icon="IMAGE_DATA")
        row.label(text=f"{item.psnr:.2f} dB" if item.has_metrics else "-")
        row.label(text=f"SSIM {item.ssim:.3f}" if item.has_metrics else "-")


def _draw_error(layout, text: str) -> None:
    """The headline and the END of the log (where the cause is); the full text is in the console."""
    lines = text.splitlines()
    if len(lines) > 12:
        lines = lines[:2] + ["..."] + lines[-9:]
    box = layout.box()
    for i, line in enumerate(lines):
        box.label(text=line[:120], icon="ERROR" if i == 0 else "BLANK1")


class NERF_PT_train(bpy.types.Panel):
    bl_label = "Train"
    bl_idname = "NERF_PT_train"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "NeRF"

    def draw(self, context):
        layout = self.layout
        s = settings_of(context)
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.prop(s, "dataset_dir")
        row = col.row(align=True)
        row.prop(s, "run_dir")
        row.operator(NERF_OT_run_new_name.bl_idname, text="", icon="ADD")
        col.prop(s, "method")
        col.prop(s, "max_seconds")
        col.prop(s, "max_steps")
        col.prop(s, "seed")
        row = layout.row(align=True)
        if s.running:
            row.operator(NERF_OT_train_cancel.bl_idname, icon="CANCEL")
        else:
            row.operator(NERF_OT_train.bl_idname, icon="PLAY").resume = False
            row.operator(NERF_OT_train.bl_idname, text="Resume", icon="FF").resume = True
        if s.running or s.step:
            box = layout.box()
            box.progress(factor=s.fraction, type="BAR", text=s.status or "Training")
            grid = box.grid_flow(columns=2, align=True)
            grid.label(text=f"Step {s.step}")
            grid.label(text=f"Loss {s.loss:.4g}")
            grid.label(text=f"PSNR {s.psnr:.2f} dB")
            grid.label(text=f"Elapsed {format_seconds(s.elapsed)}")
            grid.label(text=f"ETA {format_seconds(s.eta if s.eta >= 0 else None)}")
            if s.rollbacks:
                grid.label(text=f"{s.rollbacks} rollback(s)", icon="LOOP_BACK")
            if s.background:
                # Which background model the run uses: a learned world (opaque captures) or random colours.
                box.label(text=f"Background: {s.background}"[:120], icon="WORLD")
            if _PREVIEWS is not None and "latest" in _PREVIEWS and s.preview_path:
                box.template_icon(icon_value=_PREVIEWS["latest"].icon_id, scale=8.0)
        elif s.status:
            layout.label(text=s.status, icon="INFO")
        if s.error:
            _draw_error(layout, s.error)
        row = layout.row()
        row.label(text="Runs")
        row.operator(NERF_OT_refresh_runs.bl_idname, text="", icon="FILE_REFRESH")
        layout.template_list("NERF_UL_runs", "", s, "runs", s, "runs_index", rows=3)
        if 0 <= s.runs_index < len(s.runs):
            item = s.runs[s.runs_index]
            layout.label(text=f"{item.method}: {item.settings}")
            layout.operator(NERF_OT_use_run.bl_idname)


class NERF_PT_compare(bpy.types.Panel):
    bl_label = "Compare"
    bl_idname = "NERF_PT_compare"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "NeRF"

    def draw(self, context):
        layout = self.layout
        s = settings_of(context)
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "view_source")
        layout.prop(s, "layout")
        if s.layout == "CAMERA":
            layout.prop(s, "plane_distance")
        row = layout.row(align=True)
        row.operator(NERF_OT_render_views.bl_idname, icon="RENDER_STILL")
        row.operator(NERF_OT_clear_views.bl_idname, text="", icon="TRASH")
        if len(s.view_metrics):
            layout.template_list("NERF_UL_view_metrics", "", s, "view_metrics", s, "view_metrics_index", rows=4)


# -- registration -------------------------------------------------------------------------------------
@bpy.app.handlers.persistent
def _cancel_on_load(_dummy=None):
    # A new file drops the modal operators; the children must not outlive them.
    cancel_jobs()


CLASSES = (
    NerfViewMetric, NerfRunItem, NerfTrainSettings,
    NERF_OT_train, NERF_OT_train_cancel, NERF_OT_run_new_name, NERF_OT_refresh_runs, NERF_OT_use_run,
    NERF_OT_render_views, NERF_OT_clear_views,
    NERF_UL_runs, NERF_UL_view_metrics, NERF_PT_train, NERF_PT_compare,
)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def register():
    _register_classes()
    bpy.types.Scene.nerf_train = PointerProperty(type=NerfTrainSettings)
    if _cancel_on_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_cancel_on_load)
    # The children live in their own session, so quitting Blender would not take them down by itself.
    atexit.register(cancel_jobs)


def unregister():
    global _PREVIEWS
    cancel_jobs()
    _JOBS.clear()
    atexit.unregister(cancel_jobs)
    if _cancel_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_load)
    if _PREVIEWS is not None:
        bpy.utils.previews.remove(_PREVIEWS)
        _PREVIEWS = None
    del bpy.types.Scene.nerf_train
    _unregister_classes()
