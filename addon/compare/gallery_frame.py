"""Where the comparison gallery stands, and the orthographic camera that frames it.

The gallery is a collection in the user's own scene (not a scene of its own): the Compare panel's
settings live on the scene (``scene.nerf_train``), so a separate gallery scene would show an empty
panel once switched to, and the tiles beside the objects they show are what a user compares in the
viewport. To keep the scene from hiding tiles, the gallery is moved clear of the bounding box of
every other visible object (``place_beside``: to the right of it, +X, standing on its floor and
facing -Y like the front view), and its camera looks at it from -Y, orthographic, framing every tile
and text (``frame_ortho``). World-space boxes are (min, max) Vectors.
"""
from __future__ import annotations

import math
from typing import Iterable, Optional, Tuple

import bpy
from mathutils import Matrix, Vector

from ..scene import scene_bounds

Box = Tuple[Vector, Vector]


def bounds(objects: Iterable) -> Optional[Box]:
    """(min, max) of the objects' evaluated geometry (text included) in world space; None if empty."""
    objects = list(objects)
    if not objects:
        return None
    bpy.context.view_layer.update()
    lo, hi = scene_bounds.object_bounds(objects, bpy.context.evaluated_depsgraph_get())
    return lo, hi


def other_objects_box(scene, exclude) -> Optional[Box]:
    """Box of the scene's visible renderable objects outside collection ``exclude`` (and its children)."""
    own = set(exclude.all_objects) if exclude is not None else set()
    others = [ob for ob in scene_bounds.renderable_objects(scene, bpy.context.view_layer) if ob not in own]
    return bounds(others)


def place_beside(objects, scene_box: Optional[Box], gap: float) -> Vector:
    """Move ``objects`` (the gallery) so their box starts ``gap`` beyond the scene box's +X side, its
    bottom level with the scene's, centred on it in Y; returns the translation. No scene box: no move."""
    own = bounds(objects)
    if own is None or scene_box is None:
        return Vector((0.0, 0.0, 0.0))
    lo, hi = own
    s_lo, s_hi = scene_box
    shift = Vector((s_hi.x + gap - lo.x, (s_lo.y + s_hi.y) / 2 - (lo.y + hi.y) / 2, s_lo.z - lo.z))
    move = Matrix.Translation(shift)
    for ob in objects:
        if ob.parent is None:
            ob.matrix_world = move @ ob.matrix_world
    bpy.context.view_layer.update()
    return shift


def boxes_overlap(a: Box, b: Box) -> bool:
    """Whether two (min, max) boxes share any point (touching counts)."""
    return all(a[0][i] <= b[1][i] and b[0][i] <= a[1][i] for i in range(3))


def frame_ortho(scene, cam, box: Box, margin: float = 0.04) -> None:
    """Point orthographic ``cam`` down +Y at ``box`` and size it to show all of it, ``margin`` (a fraction
    of each side) around, at the aspect of ``scene``'s render resolution and pixel aspect.

    With AUTO sensor fit ``ortho_scale`` spans the longer side of the frame, so the scale is the
    larger of what the width and the height need, measured along that side.
    """
    lo, hi = box
    width = max(hi.x - lo.x, 1e-6) * (1 + 2 * margin)
    height = max(hi.z - lo.z, 1e-6) * (1 + 2 * margin)
    r = scene.render
    aspect = (r.resolution_x * r.pixel_aspect_x) / (r.resolution_y * r.pixel_aspect_y)
    data = cam.data
    data.type = "ORTHO"
    data.sensor_fit = "AUTO"
    data.shift_x = data.shift_y = 0.0
    data.ortho_scale = max(width, height * aspect) if aspect >= 1 else max(height, width / aspect)
    depth = max(hi.y - lo.y, 0.0)
    distance = max(width, height)  # stand well in front; orthographic views do not change with distance
    data.clip_start, data.clip_end = 0.01, distance + depth + 1.0
    centre = (lo + hi) / 2
    cam.matrix_world = Matrix.Translation((centre.x, lo.y - distance, centre.z)) @ Matrix.Rotation(math.pi / 2, 4, "X")


def fit_resolution(scene, box: Box, pixels_per_unit: float, longest: int = 2048, margin: float = 0.04) -> None:
    """Set ``scene``'s resolution to the box's aspect (XZ, with ``margin``) at ``pixels_per_unit``,
    the longer side at most ``longest`` pixels, square pixels, 100 %."""
    lo, hi = box
    width = max(hi.x - lo.x, 1e-6) * (1 + 2 * margin)
    height = max(hi.z - lo.z, 1e-6) * (1 + 2 * margin)
    scale = min(pixels_per_unit, longest / max(width, height))
    r = scene.render
    r.resolution_x, r.resolution_y = max(int(round(width * scale)), 4), max(int(round(height * scale)), 4)
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
