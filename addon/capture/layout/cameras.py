"""``create_cameras``: a layout made into real camera objects in the "NeRF Cameras" collection, which
users can inspect and edit before capturing (a capture renders whatever cameras that collection holds).

Each layout first becomes a plan, a list of (split, camera-to-world matrix, source camera, frame), by
its own small function; ``create_cameras`` then checks the poses, replaces the collection's cameras
and fits their clipping.
"""
from __future__ import annotations

import json

import bpy
from mathutils import Matrix

from ...scene import scene_bounds
from ...scene.camera_checks import camera_shape_error
from . import collection
from .camera_import import IMPORT_INDEX, IMPORT_SPLIT, is_imported
from .notes import framing_bounds
from .positions import (
    GENERATED_LAYOUTS,
    INSIDE_CLIP_START,
    LAYOUTS,
    SPLITS,
    LayoutError,
    LayoutSpec,
    assign_splits,
    auto_radius,
    check_distinct_poses,
    fov_from_lens,
    inside_poses,
    layout_positions,
    look_at,
)


def _user_cameras(scene, coll):
    return sorted((o for o in scene.objects if o.type == "CAMERA" and (coll is None or o.name not in coll.all_objects)),
                  key=lambda o: o.name)


# What a camera's intrinsics and clipping come from: the values an animation layout's copy takes from
# its own frame.
LENS_PROPS = ("type", "lens", "lens_unit", "shift_x", "shift_y", "sensor_width", "sensor_height", "sensor_fit",
              "clip_start", "clip_end")


def _new_camera(scene, coll, name, split, matrix, lens, sensor=36.0, src=None):
    data = src.data.copy() if src is not None else bpy.data.cameras.new(name)
    data.name = name
    if src is None:
        data.lens = lens
        data.sensor_width = sensor
        data.sensor_fit = "AUTO"
    data.animation_data_clear()
    obj = bpy.data.objects.new(name, data)
    coll.objects.link(obj)
    obj.matrix_world = Matrix(matrix)
    obj["nerf_split"] = split
    return obj


def create_cameras(scene, spec: LayoutSpec, res_x: int, res_y: int) -> list:
    """Replace the "NeRF Cameras" collection's cameras with the layout's; returns the new objects.

    Generated layouts aim every camera at the target centre from ``spec.radius`` (auto when 0), except
    "inside", which stands the cameras inside the target's box looking outward (``inside_poses``; the
    renderable objects' bounding boxes are the obstacles; ``radius`` is unused; clip_start 5 cm).
    "scene-cameras" copies the scene's other cameras; "animation" copies the active camera at every
    ``frame_step``-th frame (recording the frame in ``obj["nerf_frame"]``). User cameras are never moved.
    """
    planned = _layout_plan(scene, spec, res_x, res_y)
    check_distinct_poses([m for _s, m, _src, _f in planned.plan], spec.layout)
    made = _make_cameras(scene, planned, spec.focal_length)
    _fit_clipping(made, planned.radius, planned.clip_start)
    collection.nerf_collection(scene)[collection.LAYOUT_RECORD] = json.dumps(
        collection.layout_record(spec, res_x, res_y))
    return made


class LayoutPlan:
    """What a layout asks for before any camera exists: ``plan`` rows (split, matrix, source camera,
    frame), the lens of each animation frame (``lens_at``) and the distances that set clipping."""

    def __init__(self, plan: list, radius=None, clip_start=None, lens_at: dict | None = None):
        self.plan, self.radius, self.clip_start, self.lens_at = plan, radius, clip_start, lens_at or {}


def _layout_plan(scene, spec: LayoutSpec, res_x: int, res_y: int) -> LayoutPlan:
    if spec.layout == "inside":
        return _plan_inside(scene, spec)
    if spec.layout in GENERATED_LAYOUTS:
        return _plan_looking_in(scene, spec, res_x, res_y)
    if spec.layout == "scene-cameras":
        return _plan_scene_cameras(scene, spec)
    if spec.layout == "animation":
        return _plan_animation(scene, spec)
    raise LayoutError(f"unknown layout {spec.layout!r}; choose one of {', '.join(LAYOUTS)}")


def _splits(spec: LayoutSpec, heights=None) -> list:
    if spec.train < 1:
        raise LayoutError("a capture needs at least one train view")
    n_total = spec.train + spec.val + spec.test
    if spec.val + spec.test:
        return assign_splits(n_total, spec.val, spec.test, spec.seed, heights=heights)
    return ["train"] * spec.train


def _plan_inside(scene, spec: LayoutSpec) -> LayoutPlan:
    """Cameras inside the target's box looking outward, around the renderable objects."""
    splits = _splits(spec)
    lo, hi = scene_bounds.scene_bounds(scene, only_selected=spec.target == "SELECTION")
    obstacles = [box for box, _ in scene_bounds.renderable_boxes(scene)]
    poses = inside_poses(len(splits), tuple(lo), tuple(hi), spec.elevation_range(), spec.seed,
                         [(tuple(a), tuple(b)) for a, b in obstacles])
    plan = [(s, look_at(p, tuple(pc + dc for pc, dc in zip(p, d))), None, None) for s, (p, d) in zip(splits, poses)]
    # clip_end from the radius: the whole room stays in view
    return LayoutPlan(plan, radius=(hi - lo).length, clip_start=INSIDE_CLIP_START)


def _plan_looking_in(scene, spec: LayoutSpec, res_x: int, res_y: int) -> LayoutPlan:
    """A generated layout around the target, every camera aimed at its centre."""
    lo, hi, _around = framing_bounds(scene, spec)
    centre, sphere_r = scene_bounds.bounding_sphere(lo, hi)
    radius = spec.radius
    if radius <= 0:
        radius = auto_radius(sphere_r, *fov_from_lens(spec.focal_length, res_x, res_y), spec.margin)
    # Blender's default clip_start (10 cm) would cut away a subject nearer than that: a 2 cm object
    # is framed from 6 cm. Half the gap to the bounding sphere keeps it whole (never raised: a
    # floor passing under the cameras must not be clipped either).
    gap = radius - sphere_r
    clip_start = 0.5 * gap if gap > 0 else 1e-3 * radius
    if spec.train < 1:
        raise LayoutError("a capture needs at least one train view")
    positions = layout_positions(spec, spec.train + spec.val + spec.test, tuple(centre), radius)
    splits = _splits(spec, heights=[p[2] for p in positions])
    plan = [(s, look_at(p, tuple(centre)), None, None) for s, p in zip(splits, positions)]
    return LayoutPlan(plan, radius=radius, clip_start=clip_start)


def _plan_scene_cameras(scene, spec: LayoutSpec) -> LayoutPlan:
    """Copies of the scene's own cameras. When some were imported from a transforms file
    (``layout.camera_import``), exactly those, in the file's order, each in the file's split when the file
    had splits: a capture then re-renders that file's views."""
    sources = _user_cameras(scene, collection.nerf_collection(scene, create=False))
    if not sources:
        raise LayoutError(f"layout 'scene-cameras': scene {scene.name!r} has no camera of its own")
    imported = sorted((o for o in sources if is_imported(o)), key=lambda o: int(o[IMPORT_INDEX]))
    if imported:
        sources = imported
    with scene_bounds.fresh_matrices(scene, sources):  # a camera disabled in viewports reads as identity
        placed = [(o, o.matrix_world.copy(), None) for o in sources]
    splits = [o.get(IMPORT_SPLIT) for o in sources]
    if imported and all(s in SPLITS for s in splits):
        for obj, _m, _f in placed:
            err = camera_shape_error(obj)
            if err:
                raise LayoutError(err)
        order = sorted(range(len(placed)), key=lambda k: SPLITS.index(splits[k]))  # stable: file order in a split
        return LayoutPlan([(splits[k], placed[k][1], placed[k][0], None) for k in order])
    return LayoutPlan(_plan_from_sources(spec, placed))


def _plan_animation(scene, spec: LayoutSpec) -> LayoutPlan:
    """The active camera at every ``frame_step``-th frame, with its lens as it is at that frame."""
    cam = scene.camera
    existing = collection.nerf_collection(scene, create=False)
    if cam is None or (existing is not None and cam.name in existing.all_objects):
        raise LayoutError("layout 'animation': the scene has no active camera of its own (set one with Ctrl+Numpad0)")
    frames = list(range(scene.frame_start, scene.frame_end + 1, max(1, spec.frame_step)))
    current = scene.frame_current
    sources, lens_at = [], {}
    try:
        for f in frames:
            scene.frame_set(f)
            sources.append((cam, cam.matrix_world.copy(), f))
            # The lens as it is at this frame: an animated zoom is part of the shot, and the copy's
            # animation is cleared (``_new_camera``).
            lens_at[f] = {p: getattr(cam.data, p) for p in LENS_PROPS}
    finally:
        scene.frame_set(current)
    return LayoutPlan(_plan_from_sources(spec, sources), lens_at=lens_at)


def _make_cameras(scene, planned: LayoutPlan, focal_length: float) -> list:
    """Clear the collection's layout cameras and make the plan's, named NeRF_<split>_<nnn>."""
    coll = collection.nerf_collection(scene)
    collection.clear_cameras(scene)
    counters = {s: 0 for s in SPLITS}
    made = []
    for split, matrix, src, frame in planned.plan:
        name = f"NeRF_{split}_{counters[split]:03d}"
        counters[split] += 1
        obj = _new_camera(scene, coll, name, split, matrix, focal_length, src=src)
        for prop, value in planned.lens_at.get(frame, {}).items():
            setattr(obj.data, prop, value)
        if frame is not None:
            obj["nerf_frame"] = frame
        if src is not None:
            obj["nerf_source"] = src.name
        made.append(obj)
    return made


def _fit_clipping(cameras: list, radius, clip_start) -> None:
    for obj in cameras:
        # The default 100 m clip would cut far scenes out of the render; the depth pass needs it too.
        obj.data.clip_end = max(obj.data.clip_end, 4.0 * (radius or 0.0))
        if clip_start is not None:
            obj.data.clip_start = min(obj.data.clip_start, clip_start)


def _plan_from_sources(spec: LayoutSpec, sources):
    """Split existing camera poses (obj, matrix, frame) into train/val/test."""
    # A scale alone waits for the capture, which may normalise it; shear and mirror never pass.
    for obj, _m, _f in sources:
        err = camera_shape_error(obj)
        if err:
            raise LayoutError(err)
    n = len(sources)
    if spec.val + spec.test == 0:
        splits = ["train"] * n
    else:
        splits = assign_splits(n, spec.val, spec.test, spec.seed)
    return [(s, m, obj, f) for s, (obj, m, f) in zip(splits, sources)]
