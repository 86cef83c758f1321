"""Compare feature: render a run's views and import them as image planes beside the scene (``compare_ui``,
``compare_views``, ``planes``), or import the NeRF as a mesh or a volume (``geometry_job``,
``geometry_import``). Compare uses the Train feature's settings and job helpers; the Train panel never
imports Compare."""
import bpy

from .camera_path_ui import NERF_OT_export_camera_path
from .compare_ui import (
    NERF_OT_clear_views,
    NERF_OT_import_geometry,
    NERF_OT_render_views,
    NERF_PT_compare,
    NERF_UL_view_metrics,
)

classes = (NERF_OT_render_views, NERF_OT_clear_views, NERF_OT_import_geometry, NERF_OT_export_camera_path,
           NERF_UL_view_metrics, NERF_PT_compare)
register, unregister = bpy.utils.register_classes_factory(classes)
