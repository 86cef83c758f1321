"""The "NeRF" render engine: a trained run rendered in Blender's viewport and F12 render (``engine``)."""
import bpy

from . import engine
from .engine import NERF_PT_render_run, NerfRenderEngine, NerfRenderSettings

classes = (NerfRenderSettings, NerfRenderEngine, NERF_PT_render_run)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    engine.attach()


def unregister():
    engine.detach()
    _unregister_classes()
