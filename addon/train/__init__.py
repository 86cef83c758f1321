"""Train feature: the Train panel and its operators (``train_ui``), its settings (``train_props``, shared
with the Compare panel) and the training job (``train_job``)."""
import bpy

from . import train_props, train_ui
from .train_props import NerfRunItem, NerfTrainSettings, NerfViewMetric
from .train_ui import (
    NERF_OT_refresh_runs,
    NERF_OT_run_new_name,
    NERF_OT_train,
    NERF_OT_train_cancel,
    NERF_OT_use_run,
    NERF_PT_train,
    NERF_UL_runs,
)

classes = (
    NerfViewMetric, NerfRunItem, NerfTrainSettings,
    NERF_OT_train, NERF_OT_train_cancel, NERF_OT_run_new_name, NERF_OT_refresh_runs, NERF_OT_use_run,
    NERF_UL_runs, NERF_PT_train,
)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    train_props.attach()


def unregister():
    train_ui.detach()
    train_props.detach()
    _unregister_classes()
