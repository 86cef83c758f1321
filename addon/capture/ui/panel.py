"""Capture panel (3D viewport > N-panel > NeRF > Capture) and its operators.

Settings live in ``Scene.nerf_capture`` (``ui.props``, saved with the .blend). The Capture operator prepares a
``run_job.CaptureJob`` and hands it, as a ``run.task.CaptureTask``, to the job follower that also
advances training and rendering: one frame per timer event, so Blender stays responsive between
frames; Esc or the Cancel button stops it, leaving a folder that resumes on the next capture.
"""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, PointerProperty

from ...common import jobs
from ...common.ui_common import NerfPanel, draw_wrapped, property_split, report_and_cancel
from ...dataset.errors import ExportError
from ...scene import scene_bounds
from ..demo import scenes
from ..layout import cameras, collection, notes, positions
from ..plan import frame_plan
from ..run import job as run_job
from ..run.task import CaptureTask
from .props import NerfCaptureSettings

CAPTURE = "capture"  # this module's key in the job registry (one capture at a time)


_ERRORS = (frame_plan.CaptureError, positions.LayoutError, ExportError, scene_bounds.BoundsError,
           scenes.DemoSceneError)


class NERF_OT_generate_cameras(bpy.types.Operator):
    """Create the capture cameras of the chosen layout in the "NeRF Cameras" collection (replacing them)"""

    bl_idname = "nerf.generate_cameras"
    bl_label = "Generate Cameras"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        s = context.scene.nerf_capture
        try:
            made = cameras.create_cameras(context.scene, s.layout_spec(), s.resolution_x, s.resolution_y)
        except _ERRORS as exc:
            return report_and_cancel(self, exc)
        counts = {sp: sum(o["nerf_split"] == sp for o in made) for sp in positions.SPLITS}
        self.report({"INFO"},
                    f"{len(made)} cameras: {counts['train']} train, {counts['val']} val, {counts['test']} test")
        for note in notes.layout_notes(context.scene, s.layout_spec()):
            self.report({"WARNING"}, note)
        return {"FINISHED"}


class NERF_OT_clear_cameras(bpy.types.Operator):
    """Delete the cameras of the "NeRF Cameras" collection (no other object is touched)"""

    bl_idname = "nerf.clear_cameras"
    bl_label = "Clear Cameras"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        n = collection.clear_cameras(context.scene)
        self.report({"INFO"}, f"removed {n} capture cameras")
        return {"FINISHED"}


class NERF_OT_capture(bpy.types.Operator):
    """Render the capture cameras into a NeRF dataset (Esc cancels; re-running resumes)"""

    bl_idname = "nerf.capture"
    bl_label = "Capture Dataset"

    overwrite: BoolProperty(name="Overwrite", default=False, options={"SKIP_SAVE"},
                            description="Replace a different dataset in the output folder")
    generate: BoolProperty(name="Generate Cameras", default=True, options={"SKIP_SAVE"},
                           description="Create the layout's cameras first when the collection has none")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and not jobs.is_running(CAPTURE)

    def _make_job(self, context):
        s = context.scene.nerf_capture
        if self.generate and not any(collection.capture_cameras(context.scene).values()):
            cameras.create_cameras(context.scene, s.layout_spec(), s.resolution_x, s.resolution_y)
        cams = collection.capture_cameras(context.scene)
        problem = collection.held_out_problem(cams) if cams["train"] else None  # no train: CaptureJob says so
        if problem:
            raise frame_plan.CaptureError(problem)
        return run_job.CaptureJob(context.scene, s.capture_settings(self.overwrite), progress=self._progress(context))

    def _progress(self, context):
        scene_name = context.scene.name

        def report(done, total, info):
            scene = bpy.data.scenes.get(scene_name)
            if scene is not None:
                scene.nerf_capture.progress = done / total if total else 0.0
                scene.nerf_capture.status = f"{done}/{total} {info}".strip()
        return report

    def invoke(self, context, event):
        try:
            job = self._make_job(context)
            _manifest, conflict = job.inspect_folder()
        except _ERRORS as exc:
            return report_and_cancel(self, exc)
        if conflict and not self.overwrite:
            self.overwrite = True  # applies only if the user confirms the dialog
            return context.window_manager.invoke_confirm(
                self, event, title="Replace dataset?", message=conflict, confirm_text="Overwrite", icon="WARNING")
        return self.execute(context)

    def execute(self, context):
        try:
            job = self._make_job(context)
            job.prepare()
        except _ERRORS as exc:
            return report_and_cancel(self, exc)
        s = context.scene.nerf_capture
        stale = collection.stale_layout_note(context.scene, s.layout_spec(), s.resolution_x, s.resolution_y)
        for note in ([stale] if stale else []) + list(job.notes):
            self.report({"WARNING"}, note)
        if context.window is None or bpy.app.background:
            # Scripts and tests (no event loop to deliver timer events): render everything now.
            try:
                while job.step():
                    pass
            except _ERRORS as exc:
                job.cancel()
                return report_and_cancel(self, exc)
            summary = job.finish()
            self.report({"INFO"}, f"captured {summary['frames']} frames into {summary['out']}")
            return {"FINISHED"}
        follow_capture(context.scene, job)
        jobs.follow(context)
        return {"FINISHED"}


def follow_capture(scene, job: run_job.CaptureJob) -> CaptureTask:
    """Hand a prepared capture to the job follower, mirroring it into ``scene.nerf_capture``."""
    name = scene.name

    def settings():
        scene = bpy.data.scenes.get(name)
        return scene.nerf_capture if scene is not None else None

    def cancel_requested() -> bool:
        s = settings()
        return s is not None and s.cancel_requested

    def progress_text() -> str:
        s = settings()
        return f"{s.status} ({100 * s.progress:.0f}%)" if s is not None else ""

    task = CaptureTask(name, job, cancel_requested=cancel_requested, progress_text=progress_text)
    task.on_update, task.on_end = sync_capture_settings, _dataset_to_train
    jobs.add(CAPTURE, task)
    s = scene.nerf_capture
    s.is_running, s.cancel_requested = True, False
    return task


def sync_capture_settings(task: CaptureTask) -> None:
    """After the capture stops: the panel leaves its running state and says how it ended."""
    scene = task.scene
    if scene is None or task.state == "running":
        return
    s = scene.nerf_capture
    s.is_running, s.cancel_requested = False, False
    s.status = task.message.splitlines()[0]


def _dataset_to_train(task: CaptureTask) -> None:
    scene = task.scene
    train = getattr(scene, "nerf_train", None) if scene is not None else None
    if task.state == "done" and train is not None and hasattr(train, "dataset_dir") and not train.dataset_dir:
        train.dataset_dir = task.capture.out  # the Train panel picks up the new dataset


class NERF_OT_capture_cancel(bpy.types.Operator):
    """Stop the running capture after the current frame (the folder stays resumable)"""

    bl_idname = "nerf.capture_cancel"
    bl_label = "Cancel Capture"

    def execute(self, context):
        if not jobs.is_running(CAPTURE):
            # No capture reads the flag: setting it would leave stale state behind (the next capture
            # happens to reset it when it starts; nothing should depend on that), and clear a stale one.
            context.scene.nerf_capture.cancel_requested = False
            self.report({"WARNING"}, "No capture is running: nothing to cancel.")
            return {"CANCELLED"}
        context.scene.nerf_capture.cancel_requested = True  # the follower stops before the next frame
        self.report({"INFO"}, "Cancelling the capture after the current frame (the folder stays resumable).")
        return {"FINISHED"}


class NERF_OT_add_demo_scene(bpy.types.Operator):
    """Build a procedural demo scene in a new scene (your scenes are not touched)"""

    bl_idname = "nerf.add_demo_scene"
    bl_label = "Add Demo Scene"
    bl_options = {"REGISTER", "UNDO"}

    name: EnumProperty(name="Scene", items=[(k, k.title(), v) for k, v in scenes.SCENES.items()])

    def execute(self, context):
        if context.window is None or bpy.app.background:
            self.report({"ERROR"}, "Add Demo Scene needs a window; scripts call addon.capture.demo.scenes.build()")
            return {"CANCELLED"}
        scene = bpy.data.scenes.new(f"NeRF demo: {self.name}")
        context.window.scene = scene
        try:
            scenes.build(self.name, scene)
        except _ERRORS as exc:
            return report_and_cancel(self, exc)
        return {"FINISHED"}


class NERF_PT_capture(NerfPanel, bpy.types.Panel):
    bl_label = "Capture"
    bl_idname = "NERF_PT_capture"

    def draw(self, context):
        layout = property_split(self.layout)
        s = context.scene.nerf_capture
        if s.is_running and jobs.is_running(CAPTURE):  # a flag without a job is stale (an add-on reload)
            if hasattr(layout, "progress"):
                layout.progress(factor=s.progress, type="BAR", text=s.status)
            else:
                layout.label(text=f"{100 * s.progress:.0f}% {s.status}")
            layout.operator(NERF_OT_capture_cancel.bl_idname, icon="CANCEL")
            return

        col = layout.column(heading="Cameras")
        col.prop(s, "layout")
        if s.layout in positions.GENERATED_LAYOUTS:
            col.prop(s, "target")
            if s.layout != "inside":  # inside cameras stand in the target's box: no distance to choose
                col.prop(s, "radius")
            sub = col.column(align=True)
            sub.prop(s, "elevation_min")
            sub.prop(s, "elevation_max")
            if s.layout == "rings":
                col.prop(s, "rings")
            elif s.layout == "spiral":
                col.prop(s, "turns")
            col.prop(s, "focal_length")
        elif s.layout == "animation":
            col.prop(s, "frame_step")
        sub = col.column(align=True)
        if s.layout in positions.GENERATED_LAYOUTS:
            sub.prop(s, "train_count")
        sub.prop(s, "val_count")
        sub.prop(s, "test_count")
        col.prop(s, "seed")
        row = col.row(align=True)
        row.operator(NERF_OT_generate_cameras.bl_idname, icon="OUTLINER_OB_CAMERA")
        row.operator(NERF_OT_clear_cameras.bl_idname, text="", icon="TRASH")
        col.operator("nerf.import_cameras", icon="IMPORT")  # from a transforms file: then Scene Cameras
        cams = collection.capture_cameras(context.scene)
        col.label(text=f"{len(cams['train'])} train, {len(cams['val'])} val, {len(cams['test'])} test cameras")
        stale = collection.stale_layout_note(context.scene, s.layout_spec(), s.resolution_x, s.resolution_y, cams)
        if stale:
            draw_wrapped(col, "Cameras out of date: " + stale, "ERROR")

        col = layout.column(heading="Render")
        col.prop(s, "engine")
        if s.engine != "workbench":
            col.prop(s, "samples")
        if s.engine == "cycles":
            col.prop(s, "denoise")
        sub = col.column(align=True)
        sub.prop(s, "resolution_x", text="Resolution X")
        sub.prop(s, "resolution_y", text="Y")
        col.prop(s, "film_transparent")
        col = layout.column(heading="Extras")
        col.prop(s, "depth")
        row = col.row()
        row.enabled = s.engine != "workbench"
        row.prop(s, "normals")
        col.prop(s, "masks")
        col.prop(s, "points")
        col.prop(s, "normalize_camera_scale")

        layout.prop(s, "output_dir")
        layout.operator(NERF_OT_capture.bl_idname, icon="RENDER_ANIMATION")
        if s.status:
            layout.label(text=s.status)
        layout.operator_menu_enum(NERF_OT_add_demo_scene.bl_idname, "name", icon="SCENE_DATA")


def attach() -> None:
    """What registering the classes does not: the settings on every scene."""
    bpy.types.Scene.nerf_capture = PointerProperty(type=NerfCaptureSettings)


def detach() -> None:
    jobs.forget((CAPTURE,))  # disabling the add-on mid-capture: keep what is rendered, resumable
    del bpy.types.Scene.nerf_capture
