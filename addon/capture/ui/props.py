"""The Capture panel's settings, ``Scene.nerf_capture`` (saved with the .blend), and what they make: a
``LayoutSpec`` and ``CaptureSettings``."""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ...common.ui_common import path_options
from ..layout import positions
from ..plan import settings

_LAYOUT_ITEMS = [
    ("hemisphere", "Hemisphere", "Fibonacci points on the upper hemisphere (elevation range)"),
    ("sphere", "Sphere", "Fibonacci points on the full sphere"),
    ("random", "Random", "Random points on the sphere band, reproducible from the seed"),
    ("rings", "Rings", "Horizontal rings at evenly spaced elevations"),
    ("spiral", "Spiral", "A spiral climbing from the lowest to the highest elevation"),
    ("inside", "Inside", "Cameras inside the scene's box (a room), looking outward all around"),
    ("scene-cameras", "Scene Cameras", "Copies of the scene's own cameras"),
    ("animation", "Animation", "The active camera at every Nth frame of the scene's range"),
]
_ENGINE_ITEMS = [
    ("cycles", "Cycles", "Path tracing: the reference; slowest"),
    ("eevee", "EEVEE", "Rasterised; needs a GPU"),
    ("workbench", "Workbench", "Flat studio shading; fastest, no normals"),
]


def _layout_changed(self, _context):
    # Spheres default to the full elevation range, the others to the upper hemisphere.
    if self.layout in ("sphere", "random"):
        self.elevation_min, self.elevation_max = -90.0, 90.0
    elif self.layout in ("hemisphere", "spiral"):
        self.elevation_min, self.elevation_max = 0.0, 90.0
    elif self.layout == "rings":
        self.elevation_min, self.elevation_max = 10.0, 60.0
    elif self.layout == "inside":
        self.elevation_min, self.elevation_max = positions.INSIDE_ELEVATION


class NerfCaptureSettings(bpy.types.PropertyGroup):
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", default="//nerf_dataset/", options=path_options(),
                               description="Dataset folder (relative paths start at the .blend's folder)")
    layout: EnumProperty(name="Layout", items=_LAYOUT_ITEMS, default="hemisphere", update=_layout_changed)
    target: EnumProperty(name="Target", items=[
        ("SCENE", "Whole Scene", "Aim at and frame everything visible"),
        ("SELECTION", "Selection", "Aim at and frame the selected objects (masks cover them only)")], default="SCENE")
    # At least 2: `train` and `check` refuse a train split of one view (there is nothing to triangulate).
    train_count: IntProperty(name="Train", default=100, min=2, soft_max=1000)
    # At least 1 each: `train` and `check` refuse a dataset with an empty split (layout.collection.held_out_problem).
    val_count: IntProperty(name="Val", default=10, min=1, soft_max=200)
    test_count: IntProperty(name="Test", default=20, min=1, soft_max=400)
    radius: FloatProperty(name="Radius", default=0.0, min=0.0, unit="LENGTH",
                          description="Camera distance from the target centre; 0 = auto (target fills the frame)")
    elevation_min: FloatProperty(name="Min Elevation", default=0.0, min=-90.0, max=90.0)
    elevation_max: FloatProperty(name="Max Elevation", default=90.0, min=-90.0, max=90.0)
    seed: IntProperty(name="Seed", default=0, min=0)
    rings: IntProperty(name="Rings", default=3, min=1, max=32)
    turns: FloatProperty(name="Turns", default=3.0, min=0.1, max=50.0)
    frame_step: IntProperty(name="Every Nth Frame", default=10, min=1)
    focal_length: FloatProperty(name="Focal Length", default=50.0, min=1.0, max=500.0, unit="CAMERA",
                                description="Lens of generated cameras (36 mm sensor)")
    engine: EnumProperty(name="Engine", items=_ENGINE_ITEMS, default="cycles")
    samples: IntProperty(name="Samples", default=16, min=1, soft_max=4096)
    denoise: BoolProperty(name="Denoise", default=False)
    resolution_x: IntProperty(name="X", default=200, min=4, soft_max=4096, subtype="PIXEL")
    resolution_y: IntProperty(name="Y", default=200, min=4, soft_max=4096, subtype="PIXEL")
    film_transparent: BoolProperty(name="Transparent Film", default=True,
                                   description="RGBA images with a transparent background (what NeRF loaders expect)")
    depth: BoolProperty(name="Depth", default=False, description="Planar depth EXRs")
    normals: BoolProperty(name="Normals", default=False, description="World-space normal EXRs (Cycles/EEVEE)")
    masks: BoolProperty(name="Masks", default=False, description="Object mask PNGs")
    points: BoolProperty(name="Point Cloud", default=False, description="points3d.ply from the train views")
    normalize_camera_scale: BoolProperty(name="Normalise Camera Scale", default=False,
                                         description="Accept scaled cameras, dropping the scale (recorded)")
    # Runtime state shown by the panel (not user settings).
    is_running: BoolProperty(default=False, options={"SKIP_SAVE"})
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    status: StringProperty(default="", options={"SKIP_SAVE"})
    cancel_requested: BoolProperty(default=False, options={"SKIP_SAVE"})

    def layout_spec(self) -> positions.LayoutSpec:
        return positions.LayoutSpec(
            layout=self.layout, train=self.train_count, val=self.val_count, test=self.test_count,
            radius=self.radius, elevation_min=self.elevation_min, elevation_max=self.elevation_max,
            seed=self.seed, rings=self.rings, turns=self.turns, frame_step=self.frame_step,
            focal_length=self.focal_length, target=self.target)

    def capture_settings(self, overwrite: bool = False) -> settings.CaptureSettings:
        return settings.CaptureSettings(
            out_dir=self.output_dir, engine=self.engine, samples=self.samples,
            res_x=self.resolution_x, res_y=self.resolution_y, film_transparent=self.film_transparent,
            denoise=self.denoise, depth=self.depth, normals=self.normals, masks=self.masks, points=self.points,
            overwrite=overwrite, target=self.target, normalize_camera_scale=self.normalize_camera_scale,
            layout=self.layout_spec().to_dict(), seed=self.seed)
