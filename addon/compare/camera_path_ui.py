"""The Compare panel's *Export Camera Path* operator: a thin wrapper of ``camera_path_export``."""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, StringProperty

from ..dataset.errors import ExportError
from . import camera_path_export


class NERF_OT_export_camera_path(bpy.types.Operator):
    """Write the active camera's animation over the scene's frame range as nerfstudio's camera_path.json
    (per-frame field of view; `nerf_core render --cameras` renders it like the NeRF render engine)"""

    bl_idname = "nerf.export_camera_path"
    bl_label = "Export Camera Path"

    filepath: StringProperty(subtype="FILE_PATH", default="camera_path.json")
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})
    overwrite: BoolProperty(name="Overwrite", default=False, description="replace the file when it exists")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and context.scene.camera is not None

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        scene = context.scene
        frames = range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step))
        try:
            summary = camera_path_export.export_camera_path(scene, scene.camera, frames,
                                                            bpy.path.abspath(self.filepath),
                                                            overwrite=self.overwrite)
        except ExportError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Wrote {summary['frames']} frames to {summary['out']}")
        return {"FINISHED"}
