"""World-space bounds of what a capture will see.

Bounds come from the evaluated (modifier-applied) geometry's bounding boxes of objects that render:
visible in the view layer and not hidden from renders. Cameras, lights and empties have no extent.
"""
from __future__ import annotations

import bpy
from mathutils import Vector

# Object types whose bound_box is a surface the camera can see.
RENDERABLE_TYPES = {"MESH", "CURVE", "CURVES", "SURFACE", "META", "FONT", "VOLUME", "POINTCLOUD", "GREASEPENCIL"}


class BoundsError(ValueError):
    """Nothing visible to bound; the message says what was looked at."""


def renderable_objects(scene, view_layer=None, only_selected: bool = False) -> list:
    """Objects of ``scene`` that appear in a render (and, optionally, are selected)."""
    view_layer = view_layer or scene.view_layers[0]
    out = []
    for obj in scene.objects:
        if obj.type not in RENDERABLE_TYPES or obj.hide_render:
            continue
        if not obj.visible_get(view_layer=view_layer):
            continue
        if only_selected and not obj.select_get(view_layer=view_layer):
            continue
        out.append(obj)
    return out


def object_bounds(objects, depsgraph=None) -> tuple[Vector, Vector]:
    """Axis-aligned world bounds (min, max) of the objects' evaluated bounding boxes."""
    lo = Vector((float("inf"),) * 3)
    hi = Vector((float("-inf"),) * 3)
    for obj in objects:
        ev = obj.evaluated_get(depsgraph) if depsgraph is not None else obj
        for corner in ev.bound_box:
            p = ev.matrix_world @ Vector(corner)
            lo = Vector(map(min, lo, p))
            hi = Vector(map(max, hi, p))
    return lo, hi


def scene_bounds(scene, only_selected: bool = False, view_layer=None) -> tuple[Vector, Vector]:
    """(min, max) of the visible renderable objects; raises BoundsError when there are none."""
    view_layer = view_layer or scene.view_layers[0]
    objects = renderable_objects(scene, view_layer, only_selected)
    if not objects:
        what = "selected visible objects" if only_selected else "visible objects that render"
        raise BoundsError(f"scene {scene.name!r} has no {what}; nothing to capture")
    depsgraph = bpy.context.evaluated_depsgraph_get() if bpy.context.scene == scene else None
    lo, hi = object_bounds(objects, depsgraph)
    if not all(map(lambda v: v == v and abs(v) != float("inf"), list(lo) + list(hi))):
        raise BoundsError(f"scene {scene.name!r}: could not compute finite bounds")
    return lo, hi


def bounding_sphere(lo, hi) -> tuple[Vector, float]:
    """Centre and radius of the sphere through the corners of the box (lo, hi)."""
    lo, hi = Vector(lo), Vector(hi)
    centre = (lo + hi) / 2
    return centre, max((hi - lo).length / 2, 1e-6)
