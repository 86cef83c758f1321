"""Capture feature: lay out cameras (``layout.positions``, ``layout.cameras``) and render them into a NeRF dataset
(``run.job``); the Capture panel and its operators are ``ui.panel``, its settings ``ui.props``."""
import bpy

from .ui import panel
from .ui.import_cameras import NERF_OT_import_cameras
from .ui.panel import (
    NERF_OT_add_demo_scene,
    NERF_OT_capture,
    NERF_OT_capture_cancel,
    NERF_OT_clear_cameras,
    NERF_OT_generate_cameras,
    NERF_PT_capture,
)
from .ui.props import NerfCaptureSettings

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
    panel.attach()


def unregister():
    panel.detach()
    _unregister_classes()
