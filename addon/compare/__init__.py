"""Compare feature: render a run's views and import them as image planes beside the scene (``compare_ui``).
Compare uses the Train feature's settings and job helpers; the Train panel never imports Compare."""
import bpy

from .compare_ui import classes

register, unregister = bpy.utils.register_classes_factory(classes)
