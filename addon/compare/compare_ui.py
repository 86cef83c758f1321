"""The Compare panel (3D viewport > N-panel > NeRF): render a run's views and import them as planes.

Its operators start a ``render_job.RenderJob`` the way the Train panel starts training (``train_ui.StartsJob``);
its settings live in ``Scene.nerf_train`` (``train_props``), as the two panels share the run. What a render
writes and how its views come back as planes is ``compare_views``'.
"""
from __future__ import annotations

import bpy
from bpy.props import EnumProperty

from ..bridge import child_process
from ..bridge.child_process import SetupError
from ..common import jobs, prefs
from ..common.ui_common import NerfPanel, abs_path, property_split
from ..train import train_ui
from ..train.train_props import settings_of
from . import compare_views, planes
from .geometry_job import GeometryJob, fresh_file
from .render_job import RenderJob


def sync_render_settings(job: RenderJob) -> None:
    """The panel's status line while views render, then the outcome."""
    scene = job.scene
    if scene is None:
        return
    s = scene.nerf_train
    if job.state == "running":
        s.status = f"Rendering views: {job.rendered()}/{job.n_views}"
    else:
        train_ui.show_outcome(s, job)


def start_render(context) -> RenderJob:
    """Write the cameras to render, then start ``nerf_core render`` into a fresh folder of the run."""
    if jobs.is_running(train_ui.RENDER):
        raise SetupError("Views are already being rendered: wait for them or cancel.")
    s = settings_of(context)
    run = abs_path(s.run_dir)
    compare_views.require_checkpoint(run)  # before the interpreter check: the likelier thing to fix
    python = child_process.resolve_interpreter(prefs.python_preference(context))
    plan = compare_views.prepare_render(context, run, s.view_source)
    job = RenderJob(context.scene.name, python, run, plan.cameras, plan.out, s.layout, s.plane_distance,
                         plan.n_views, checkpoint=plan.checkpoint)
    job.on_update, job.on_end = sync_render_settings, train_ui.refresh_after
    jobs.add(train_ui.RENDER, job)
    s.status = f"Rendering {plan.n_views} view(s)..."
    s.error = ""
    return job


def sync_geometry_settings(job: GeometryJob) -> None:
    """The panel's status line while the export runs (its stage and share done), then the outcome."""
    scene = job.scene
    if scene is None:
        return
    s = scene.nerf_train
    if job.state == "running":
        s.status = f"Exporting the NeRF {job.geometry}: {job.stage() or 'loading the run'}"
    else:
        train_ui.show_outcome(s, job)


def start_geometry(context, geometry: str) -> GeometryJob:
    """Start ``nerf_core export mesh|volume|world`` of the panel's run into a fresh RUN/geometry file; the
    result is imported when it ends. Shares Compare's job slot, so its Cancel stops it."""
    if jobs.is_running(train_ui.RENDER):
        raise SetupError("Compare is already busy (rendering views or exporting): wait for it or cancel.")
    s = settings_of(context)
    run = abs_path(s.run_dir)
    checkpoint = compare_views.require_checkpoint(run)
    python = child_process.resolve_interpreter(prefs.python_preference(context))
    job = GeometryJob(context.scene.name, python, run, geometry, fresh_file(run, geometry), checkpoint=checkpoint)
    job.on_update, job.on_end = sync_geometry_settings, train_ui.refresh_after
    jobs.add(train_ui.RENDER, job)
    s.status = f"Exporting the NeRF {geometry}..."
    s.error = ""
    return job


# -- operators ----------------------------------------------------------------------------------------
class NERF_OT_render_views(train_ui.StartsJob, bpy.types.Operator):
    """Render novel views with the trained NeRF and import them as image planes"""

    bl_idname = "nerf.render_views"
    bl_label = "Render & Import Views"

    def start(self, context):
        return start_render(context)


class NERF_OT_import_geometry(train_ui.StartsJob, bpy.types.Operator):
    """Export the trained NeRF as geometry (in a separate process) and import it beside the scene's objects"""

    bl_idname = "nerf.import_geometry"
    bl_label = "Import NeRF Geometry"

    geometry: EnumProperty(items=[("MESH", "Mesh", "A coloured mesh (marching cubes), in the NeRF Mesh collection"),
                                  ("VOLUME", "Volume", "A Volume object that Cycles renders as the NeRF, in the "
                                                       "NeRF Volume collection"),
                                  ("WORLD", "World", "The world the NeRF learned behind the scene (a run on opaque "
                                                     "images) as the scene's World; the old one is kept")],
                           default="MESH")

    def start(self, context):
        return start_geometry(context, self.geometry.lower())


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
class NERF_UL_view_metrics(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        row.label(text=item.name, icon="IMAGE_DATA")
        row.label(text=f"{item.psnr:.2f} dB" if item.has_metrics else "-")
        row.label(text=f"SSIM {item.ssim:.3f}" if item.has_metrics else "-")


class NERF_PT_compare(NerfPanel, bpy.types.Panel):
    bl_label = "Compare"
    bl_idname = "NERF_PT_compare"

    def draw(self, context):
        layout = property_split(self.layout)
        s = settings_of(context)
        layout.prop(s, "view_source")
        layout.prop(s, "layout")
        if s.layout == "CAMERA":
            layout.prop(s, "plane_distance")
        layout.prop(s, "image_storage")
        row = layout.row(align=True)
        busy = jobs.is_running(train_ui.RENDER)
        if busy:  # a long fly-through or export must be stoppable from here
            text = "Cancel Export" if isinstance(jobs.get(train_ui.RENDER), GeometryJob) else "Cancel Render"
            row.operator(train_ui.NERF_OT_train_cancel.bl_idname, text=text, icon="CANCEL").target = "RENDER"
        else:
            row.operator(NERF_OT_render_views.bl_idname, icon="RENDER_STILL")
        row.operator(NERF_OT_clear_views.bl_idname, text="", icon="TRASH")
        row = layout.row(align=True)
        row.enabled = not busy
        row.operator(NERF_OT_import_geometry.bl_idname, text="Import as Mesh", icon="MESH_DATA").geometry = "MESH"
        row.operator(NERF_OT_import_geometry.bl_idname, text="Import as Volume", icon="VOLUME_DATA").geometry = "VOLUME"
        row.operator(NERF_OT_import_geometry.bl_idname, text="World", icon="WORLD").geometry = "WORLD"
        layout.operator("nerf.export_camera_path", icon="EXPORT")  # the active camera's animation
        if len(s.view_metrics):
            layout.template_list("NERF_UL_view_metrics", "", s, "view_metrics", s, "view_metrics_index", rows=4)
