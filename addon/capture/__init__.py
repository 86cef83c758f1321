"""Capture feature: lay out cameras (``layouts``, ``layout_cameras``) and render them into a NeRF dataset
(``capture_job``); the Capture panel and its operators are ``capture_ui``, its settings ``capture_props``."""
import bpy

from . import capture_ui
from .capture_props import NerfCaptureSettings
from .capture_ui import (
    NERF_OT_add_demo_scene,
    NERF_OT_capture,
    NERF_OT_capture_cancel,
    NERF_OT_clear_cameras,
    NERF_OT_generate_cameras,
    NERF_PT_capture,
)
from .import_ui import NERF_OT_import_cameras

classes = (
    NerfCaptureSettings,
    NERF_OT_generate_cameras,
    NERF_OT_clear_cameras,
    NERF_OT_capture,
    NERF_OT_capture_cancel,
    NERF_OT_add_demo_scene,
    NERF_OT_import_cameras,
    NERF_PT_capture,
)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    capture_ui.attach()


def unregister():
    capture_ui.detach()
    _unregister_classes()
