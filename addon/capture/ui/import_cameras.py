"""The Capture panel's *Import Cameras* operator: a thin wrapper of ``layout.camera_import.import_cameras``."""
from __future__ import annotations

import bpy
from bpy.props import StringProperty

from ..layout import camera_import


class NERF_OT_import_cameras(bpy.types.Operator):
    """Import the cameras of a transforms file (synthetic, nerfstudio, instant-ngp, camera_path.json) as
    exact Blender cameras in the "Imported Cameras" collection; the Scene Cameras layout re-renders them"""

    bl_idname = "nerf.import_cameras"
    bl_label = "Import Cameras"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(subtype="FILE_PATH")
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})
    dataparser: StringProperty(name="nerfstudio Dataparser Transforms", subtype="FILE_PATH",
                               description="dataparser_transforms.json when the poses are in nerfstudio's world")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            summary = camera_import.import_cameras(context.scene, bpy.path.abspath(self.filepath),
                                                   bpy.path.abspath(self.dataparser) if self.dataparser else None)
        except camera_import.CameraImportError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for warning in summary["warnings"]:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"Imported {summary['cameras']} cameras ({summary['format']}) into "
                              f"{summary['collection']!r}")
        return {"FINISHED"}
