"""Add-on preferences: which Python interpreter runs nerf_core (the one that has torch).

torch is never imported inside Blender; training and rendering run in this interpreter as a child
process. Empty means "Blender's own Python", used only when it can import torch.
"""
from __future__ import annotations

import bpy
from bpy.props import StringProperty

from ..bridge import child_process
from .ui_common import report_and_cancel

# The add-on's own package (its preferences key): this module lives one level below it, in common/.
ADDON_PACKAGE = (__package__ or "").rpartition(".")[0]


def get_preferences(context=None):
    """The add-on's preferences, or None when the add-on is not registered as an extension/add-on
    (e.g. imported by a script); callers then use the defaults."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_PACKAGE) if ADDON_PACKAGE else None
    return addon.preferences if addon is not None else None


def python_preference(context=None) -> str:
    prefs = get_preferences(context)
    return prefs.python_path if prefs is not None else ""


class NERF_OT_check_python(bpy.types.Operator):
    """Check that the chosen interpreter can import torch and nerf_core"""

    bl_idname = "nerf.check_python"
    bl_label = "Check Python"
    bl_options = {"INTERNAL"}

    def execute(self, context):
        try:
            python = child_process.resolve_interpreter(python_preference(context))
        except child_process.SetupError as exc:
            return report_and_cancel(self, exc)
        result = child_process.probe_interpreter(python)
        self.report({"INFO"}, f"{python}: {result.message}")
        return {"FINISHED"}


class NerfBridgePreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    python_path: StringProperty(
        name="Python with torch",
        description="Interpreter that runs training and rendering (it must be able to import torch), "
        "e.g. the project's .venv/bin/python. Empty: Blender's own Python, if it has torch",
        subtype="FILE_PATH",
        default="",
    )

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "python_path")
        row = layout.row()
        row.label(text="Training runs in this interpreter as a separate process; Blender never loads torch.",
                  icon="INFO")
        layout.operator(NERF_OT_check_python.bl_idname, icon="CHECKMARK")


CLASSES = (NERF_OT_check_python, NerfBridgePreferences)
register, unregister = bpy.utils.register_classes_factory(CLASSES)
