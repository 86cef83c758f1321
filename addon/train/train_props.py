"""The Train and Compare panels' settings, ``Scene.nerf_train`` (saved with the .blend), and the live
state a running job mirrors into them for drawing."""
from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from ..common.ui_common import path_options

MAX_TIME_BUDGET_S = 7 * 24 * 3600.0  # the Time Budget's upper limit: a week of training


class NerfViewMetric(bpy.types.PropertyGroup):
    name: StringProperty()
    psnr: FloatProperty()
    ssim: FloatProperty()
    has_metrics: BoolProperty()


class NerfRunItem(bpy.types.PropertyGroup):
    name: StringProperty()
    path: StringProperty(subtype="DIR_PATH")
    method: StringProperty()
    settings: StringProperty()
    metrics: StringProperty()


class NerfTrainSettings(bpy.types.PropertyGroup):
    dataset_dir: StringProperty(name="Dataset", subtype="DIR_PATH", options=path_options(),
                                description="Dataset folder written by Capture (transforms_*.json)")
    run_dir: StringProperty(name="Run", subtype="DIR_PATH", options=path_options(),
                            description="Folder for the training run (checkpoints, previews, metrics)")
    method: StringProperty(name="Method", default="",
                           description="NeRF method name (e.g. nerf, nerf-nope); empty: the library's best fast method")
    # Bounded: an unbounded field took 1e30 s and the panel then showed a 27-digit ETA.
    max_seconds: FloatProperty(name="Time Budget", default=300.0, min=0.0, max=MAX_TIME_BUDGET_S,
                               unit="TIME_ABSOLUTE",
                               description="Stop after this many seconds (0: no time limit; at most 7 days)")
    max_steps: IntProperty(name="Max Steps", default=0, min=0, description="Stop after this many steps (0: no limit)")
    seed: IntProperty(name="Seed", default=0, min=0)
    use_depth: BoolProperty(name="Use Depth", default=True,
                            description="When every train view of the capture has a depth map (Capture > Depth), "
                                        "train with them too: a depth loss, and empty space known from the first "
                                        "step (train --depth). Its scores are then not comparable with a "
                                        "colours-only tool's")
    # live state, mirrored from the job for drawing
    status: StringProperty(name="Status", default="")
    error: StringProperty(name="Last Error", default="")
    running: BoolProperty(default=False)
    step: IntProperty(default=0)
    loss: FloatProperty(default=0.0)
    psnr: FloatProperty(default=0.0)
    elapsed: FloatProperty(default=0.0)
    eta: FloatProperty(default=-1.0)
    fraction: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    rollbacks: IntProperty(default=0)
    background: StringProperty(default="", description="What stands behind the scene in this run, and why")
    depth_note: StringProperty(default="", description="Whether this run trains with the capture's depth, and why")
    preview_path: StringProperty(default="")
    runs: CollectionProperty(type=NerfRunItem)
    runs_index: IntProperty(default=0)
    # compare
    view_source: EnumProperty(name="Views", items=[
        ("TEST", "Test Cameras", "The dataset's held-out test cameras (with Blender's images to compare)"),
        ("VAL", "Val Cameras", "The dataset's validation cameras"),
        ("SELECTED", "Selected Cameras", "Every selected camera object"),
        ("ANIMATION", "Fly-through", "The active camera along its animation, one view per frame"),
    ], default="TEST")
    layout: EnumProperty(name="Layout", items=[
        ("CAMERA", "Camera-Aligned",
         "Each image on a plane in its camera's frustum: look through the camera to overlay"),
        ("GALLERY", "Gallery", "Rows of NeRF | Blender | error heat-map with PSNR/SSIM labels, beside the scene's "
                               "objects; look through 'NeRF Gallery Camera' to see all of it"),
    ], default="GALLERY")
    image_storage: EnumProperty(name="Images", items=[  # default and why: addon/image_storage.py
        ("PACK", "Pack", "Store the images inside the .blend: they still show when the run folder moves"),
        ("RELATIVE", "Relative", "Paths relative to the .blend (save it first; an unsaved file keeps absolute paths)"),
        ("ABSOLUTE", "Absolute", "Absolute paths into the run folder"),
    ], default="PACK")
    plane_distance: FloatProperty(name="Plane Distance", default=0.0, min=0.0, unit="LENGTH",
                                  description="Distance of camera-aligned planes from their camera (0: "
                                              "at the scene centre)")
    view_metrics: CollectionProperty(type=NerfViewMetric)
    view_metrics_index: IntProperty(default=0)


def settings_of(context) -> NerfTrainSettings:
    return context.scene.nerf_train


def attach() -> None:
    """What registering the classes does not: the settings on every scene."""
    bpy.types.Scene.nerf_train = PointerProperty(type=NerfTrainSettings)


def detach() -> None:
    del bpy.types.Scene.nerf_train
