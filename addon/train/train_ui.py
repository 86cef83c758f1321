"""The Train panel (3D viewport > N-panel > NeRF) and its operators.

The operators only start jobs (``train_job.TrainJob``) and hand them to the one job follower
(``jobs.NERF_OT_follow_jobs``), which advances them a few times a second, so Blender never waits on a
child. Each job mirrors its progress into ``Scene.nerf_train`` (``train_props``) for the panels to draw.
The Compare feature (``compare/compare_ui``) reuses ``StartsJob``, ``show_outcome``, ``refresh_after``
and the Cancel operator, which stops training and rendering alike.
"""
from __future__ import annotations

import os

import bpy
import bpy.utils.previews
from bpy.props import BoolProperty, EnumProperty

from ..bridge import child_process, runs
from ..bridge.child_process import SetupError
from ..bridge.core_contract import contract
from ..common import jobs, prefs
from ..common.ui_common import (
    NerfPanel,
    abs_path,
    draw_error,
    draw_wrapped,
    format_seconds,
    property_split,
    report_and_cancel,
)
from . import train_props
from .train_job import TrainJob
from .train_props import settings_of

TRAIN, RENDER = "train", "render"  # keys in the job registry; Cancel (this module) stops either
_PREVIEWS = None  # bpy.utils.previews collection holding the latest training preview


# -- starting and following jobs ----------------------------------------------------------------------
def start_training(context, resume: bool = False) -> TrainJob:
    """Validate the settings and start the check + train job; SetupError says what to fix."""
    if jobs.is_running(TRAIN):
        raise SetupError("A training run is already in progress: cancel it first.")
    s = settings_of(context)
    capture = getattr(context.scene, "nerf_capture", None)
    chosen = s.dataset_dir
    if not chosen and capture is not None and getattr(capture, "output_dir", ""):
        # Nothing chosen yet: train on what the Capture panel writes, the usual next step.
        chosen = capture.output_dir
    dataset, run = abs_path(chosen), abs_path(s.run_dir)
    if not dataset:
        raise SetupError("No dataset folder is set: capture a dataset (Capture panel) or choose its folder.")
    # a path the user did not type must say where it came from
    origin = "" if s.dataset_dir else " (the Capture panel's Output, as the Dataset field is empty)"
    if os.path.isfile(dataset) and not dataset.lower().endswith(".json"):
        raise SetupError(f"Dataset {dataset}{origin} is a file: choose the dataset's folder (or its transforms .json "
                         "file).")
    if not os.path.exists(dataset):  # a folder, or a transforms file, which nerf_core train reads too
        raise SetupError(f"Dataset folder {dataset}{origin} does not exist: capture a dataset first, or choose one.")
    s.dataset_dir = chosen
    if not run:
        raise SetupError("No run folder is set: choose where the training run should be written.")
    state = runs.run_folder_state(run)
    if state == "file":
        raise SetupError(f"Run folder {run} is a file, not a folder: choose a folder for the run.")
    if resume and state != "resumable":
        latest = os.path.relpath(contract.latest_checkpoint(run), run)
        if state in ("new", "empty"):
            raise SetupError(f"Run folder {run} holds no run to resume: press Train to start one.")
        raise SetupError(f"Run folder {run} holds no checkpoint to resume ({latest} or "
                         f"{contract.CHECKPOINTS_DIR}/{contract.step_glob('.pt')}; a run stopped before its first "
                         f"checkpoint has none): press New Name to train into {runs.suggest_run_name(run)}. "
                         "Nothing was overwritten.")
    if not resume and state in ("resumable", "occupied"):
        what = ("holds a training run: press Resume to continue it, or" if state == "resumable"
                else "is not empty and holds no run to resume:")
        raise SetupError(f"Run folder {run} {what} press New Name to train into "
                         f"{runs.suggest_run_name(run)}. Nothing was overwritten.")
    if s.max_seconds > train_props.MAX_TIME_BUDGET_S:
        # The field is bounded, but a .blend saved by an older add-on keeps what it held.
        raise SetupError(f"Time Budget is {s.max_seconds:g} s, more than 7 days ({train_props.MAX_TIME_BUDGET_S:g} s): "
                         "lower it (0 means no time limit).")
    python = child_process.resolve_interpreter(prefs.python_preference(context))
    depth, depth_note = depth_choice(dataset, s.use_depth, resume)
    cmd = child_process.train_command(python, dataset, run, method=s.method.strip(), max_seconds=s.max_seconds,
                                        max_steps=s.max_steps, seed=s.seed, resume=resume,
                                        extra=["--depth"] if depth else [])
    job = TrainJob(context.scene.name, python, dataset, run, cmd)
    job.on_update, job.on_end = sync_train_settings, refresh_after
    jobs.add(TRAIN, job)
    s.running, s.error, s.step, s.loss, s.psnr, s.fraction, s.rollbacks = True, "", 0, 0.0, 0.0, 0.0, 0
    s.elapsed, s.eta, s.preview_path, s.background, s.depth_note = 0.0, -1.0, "", "", depth_note
    s.status = f"Checking dataset {os.path.basename(dataset)}..."
    return job


def depth_choice(dataset: str, use_depth: bool, resume: bool) -> tuple[bool, str]:
    """Whether to pass ``train --depth``, and the line the panel shows about it: on when Use Depth is
    checked and every train frame of the capture names a depth map (metadata only; the trainer checks
    the maps and refuses bad ones naming the frame). A resumed run keeps what it trained with."""
    if resume:
        return False, "Depth: as the run started (a resumed run keeps its own settings)"
    if not use_depth:
        return False, "Depth: off (Use Depth is unchecked); colours only"
    try:
        with_depth, total = contract.depth_coverage(dataset)
        beyond = contract.frame_infos(dataset, ("train",))[3].get("beyond_box")
    except (contract.DatasetError, OSError):
        return False, "Depth: off (the dataset's frames could not be read here; the check says why)"
    if total and with_depth == total and beyond:
        # the run is unbounded: its occupancy grid spans the contracted world, which depth cannot carve,
        # and the loss alone slowed training (ground demo scene, 60 s: 0.42x the steps, -3.0 dB)
        return False, ("Depth: off, the capture says objects reach past its box, so the run models the world "
                       "beyond it, where depth slows training; train --depth on the command line to use it anyway")
    if total and with_depth == total:
        return True, f"Depth: on, every one of the {total} train views has a depth map (train --depth)"
    if with_depth:
        return False, (f"Depth: off, only {with_depth} of the {total} train views have a depth map; "
                       "capture again with Depth for all")
    return False, "Depth: off, the capture has no depth maps (Capture > Depth adds them); colours only"


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
        show_outcome(s, job)


def show_outcome(s, job: jobs.Job) -> None:
    # The status line gets the headline; the error box the whole message (the log tail names the cause).
    s.status = job.message.splitlines()[0] if job.message else job.state
    s.error = job.message if job.state == "failed" else ""


def refresh_after(job: jobs.Job) -> None:
    # A finished or cancelled run changes what the run list shows (metrics, checkpoint).
    scene = job.scene
    if job.state != "failed" and scene is not None:
        refresh_runs(scene.nerf_train)


def _load_preview(path: str) -> None:
    global _PREVIEWS
    if _PREVIEWS is None:
        _PREVIEWS = bpy.utils.previews.new()
    _PREVIEWS.clear()  # only the latest preview is shown; dropping old ones bounds memory
    _PREVIEWS.load("latest", path, "IMAGE")


def refresh_runs(settings) -> tuple:
    """List the runs beside the run folder; returns (report kind, message) saying what was listed or
    why nothing was, for the Refresh Runs button (a job's end ignores it)."""
    settings.runs.clear()
    try:
        run = abs_path(settings.run_dir)
    except SetupError as exc:  # an unsaved .blend's "//" folder: nothing to list yet
        return "WARNING", f"No runs listed: {exc}"
    if not run:
        return "WARNING", "No runs listed: the Run folder is not set; choose it, and the runs beside it are listed."
    root = os.path.dirname(os.path.normpath(run))
    if not os.path.isdir(root):
        return "WARNING", f"No runs listed: folder {root} (the Run folder's parent) does not exist."
    for info in runs.list_runs(root):
        item = settings.runs.add()
        item.name, item.path, item.method = info.name, info.path, info.method
        item.settings = info.settings_summary()
        item.metrics = info.problem or info.metrics_summary()
    if not settings.runs:
        return "INFO", f"No training runs found in {root}."
    return "INFO", f"Listed {len(settings.runs)} run(s) in {root}."


def highlighted_run(settings):
    """The run list's highlighted item, or None."""
    return settings.runs[settings.runs_index] if 0 <= settings.runs_index < len(settings.runs) else None


def use_highlighted_run(settings) -> bool:
    """Make the highlighted run the current one, with the dataset it was trained on when its config
    names one; False when no run is highlighted."""
    item = highlighted_run(settings)
    if item is None:
        return False
    settings.run_dir = item.path
    dataset = runs.run_dataset(settings.run_dir)
    if dataset:
        settings.dataset_dir = dataset
    return True


# -- operators -----------------------------------------------------------------------------------------
class StartsJob:
    """Operators that start a job: the UI hands it to the follower; scripts and tests (``execute``)
    drive ``update()`` themselves."""

    def start(self, context) -> jobs.Job:
        raise NotImplementedError

    def invoke(self, context, event):
        result = self.execute(context)
        if result == {"FINISHED"}:
            jobs.follow(context)
        return result

    def execute(self, context):
        try:
            self.start(context)
        except SetupError as exc:
            settings_of(context).error = str(exc)
            return report_and_cancel(self, exc)
        return {"FINISHED"}


class NERF_OT_train(StartsJob, bpy.types.Operator):
    """Train a NeRF on the dataset in a separate process (Blender stays responsive)"""

    bl_idname = "nerf.train"
    bl_label = "Train"

    resume: BoolProperty(name="Resume", default=False, options={"SKIP_SAVE"},
                         description="Continue the run from its last checkpoint")

    def start(self, context):
        return start_training(context, resume=self.resume)


class NERF_OT_train_cancel(bpy.types.Operator):
    """Stop the training or rendering process (checkpoints written so far are kept)"""

    bl_idname = "nerf.train_cancel"
    bl_label = "Cancel"

    background: BoolProperty(default=True, options={"SKIP_SAVE", "HIDDEN"},
                             description="Return at once; the job follower finishes the cancel")
    target: EnumProperty(items=[("ALL", "All", "Training and rendering"), ("TRAIN", "Training", "The training"),
                                ("RENDER", "Rendering", "The Compare render")],
                         default="ALL", options={"SKIP_SAVE", "HIDDEN"})

    def execute(self, context):
        keys = {"ALL": (TRAIN, RENDER), "TRAIN": (TRAIN,), "RENDER": (RENDER,)}[self.target]
        running = jobs.running(keys)
        if not running:
            self.report({"WARNING"}, "Nothing is running")
            return {"CANCELLED"}
        # The follower sees the job stop and reports; when none is following (a script, or the
        # follower was lost), finish the cancel right here.
        jobs.cancel_jobs(wait=not self.background, keys=keys)
        s = settings_of(context)
        s.status = "Stopping: the trainer saves a checkpoint first..." if self.background else "Cancelled"
        for job in running:
            if isinstance(job, TrainJob) and job.state != "running":
                sync_train_settings(job)
        return {"FINISHED"}


class NERF_OT_run_new_name(bpy.types.Operator):
    """Point the run folder at a new, unused name next to the current one"""

    bl_idname = "nerf.run_new_name"
    bl_label = "New Name"

    def execute(self, context):
        s = settings_of(context)
        if not s.run_dir:
            return report_and_cancel(self, "No run folder is set")
        try:
            s.run_dir = runs.suggest_run_name(abs_path(s.run_dir))
        except SetupError as exc:
            return report_and_cancel(self, exc)
        s.error = ""
        return {"FINISHED"}


class NERF_OT_refresh_runs(bpy.types.Operator):
    """List the training runs next to the run folder, with their method, settings and metrics"""

    bl_idname = "nerf.refresh_runs"
    bl_label = "Refresh Runs"

    def execute(self, context):
        kind, message = refresh_runs(settings_of(context))
        self.report({kind}, message)
        return {"FINISHED"}


class NERF_OT_use_run(bpy.types.Operator):
    """Make the highlighted run the current one"""

    bl_idname = "nerf.use_run"
    bl_label = "Use Run"

    def execute(self, context):
        s = settings_of(context)
        if not use_highlighted_run(s):
            self.report({"WARNING"}, "No run is highlighted in the Runs list: press Refresh Runs, then click a run.")
            return {"CANCELLED"}
        dataset = runs.run_dataset(s.run_dir)  # the dataset field changed only when the run names one
        self.report({"INFO"}, f"Using run {s.run_dir}" + (f" (dataset {dataset})" if dataset else ""))
        return {"FINISHED"}


# -- panels ------------------------------------------------------------------------------------------
class NERF_UL_runs(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        row.label(text=item.name, icon="FILE_FOLDER")
        row.label(text=item.method)
        row.label(text=item.metrics)


class NERF_PT_train(NerfPanel, bpy.types.Panel):
    bl_label = "Train"
    bl_idname = "NERF_PT_train"

    def draw(self, context):
        layout = property_split(self.layout)
        s = settings_of(context)
        col = layout.column()
        col.prop(s, "dataset_dir")
        row = col.row(align=True)
        row.prop(s, "run_dir")
        row.operator(NERF_OT_run_new_name.bl_idname, text="", icon="ADD")
        col.prop(s, "method")
        col.prop(s, "max_seconds")
        col.prop(s, "max_steps")
        col.prop(s, "seed")
        col.prop(s, "use_depth")
        row = layout.row(align=True)
        # The flag is saved with the file and survives an add-on reload; a job only lives in this
        # session: a flag without a job is stale (the panel would otherwise offer only a dead Cancel).
        running = s.running and jobs.is_running(TRAIN)
        if running:
            row.operator(NERF_OT_train_cancel.bl_idname, icon="CANCEL").target = "TRAIN"
        else:
            row.operator(NERF_OT_train.bl_idname, icon="PLAY").resume = False
            row.operator(NERF_OT_train.bl_idname, text="Resume", icon="FF").resume = True
        if s.running and not running:
            # Saved with the file mid-training (or left by an add-on reload): the numbers are a snapshot
            # of a job that no longer reports here, so no progress bar or ETA that would never move.
            draw_wrapped(layout, f"Training was running when this was saved (step {s.step}); it is not running in "
                                 "this session. Its run folder keeps what it wrote: Resume continues it, Refresh Runs "
                                 "lists it.", "INFO")
        elif running or s.step:
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
            if s.depth_note:  # whether the run learns from the capture's depth too, and why
                box.label(text=s.depth_note[:120], icon="MOD_OPACITY")
            if _PREVIEWS is not None and "latest" in _PREVIEWS and s.preview_path:
                box.template_icon(icon_value=_PREVIEWS["latest"].icon_id, scale=8.0)
        elif s.status:
            layout.label(text=s.status, icon="INFO")
        if s.error:
            draw_error(layout, s.error)
        row = layout.row()
        row.label(text="Runs")
        row.operator(NERF_OT_refresh_runs.bl_idname, text="", icon="FILE_REFRESH")
        layout.template_list("NERF_UL_runs", "", s, "runs", s, "runs_index", rows=3)
        item = highlighted_run(s)
        if item is not None:
            layout.label(text=f"{item.method}: {item.settings}")
            layout.operator(NERF_OT_use_run.bl_idname)


# -- what registering the classes does not ----------------------------------------------------------
def detach() -> None:
    global _PREVIEWS
    jobs.forget((TRAIN, RENDER))  # no child outlives the panels that follow it
    if _PREVIEWS is not None:
        bpy.utils.previews.remove(_PREVIEWS)
        _PREVIEWS = None
