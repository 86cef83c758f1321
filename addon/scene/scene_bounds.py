"""World-space bounds of what a capture will see.

Bounds come from the evaluated (modifier-applied) geometry's bounding boxes of objects that render
(in a collection the view layer renders, not disabled in renders, seen by camera rays; the viewport's
eye and monitor icons play no part), and of every instance they make (collection instances, as
linked assets arrive; geometry-node and particle instances), which are objects of no view layer of
their own. Cameras, lights and empties have no extent.
"""
from __future__ import annotations

import hashlib
from contextlib import contextmanager

import bpy
import numpy as np
from mathutils import Vector

# Object types whose bound_box is a surface the camera can see.
RENDERABLE_TYPES = {"MESH", "CURVE", "CURVES", "SURFACE", "META", "FONT", "VOLUME", "POINTCLOUD", "GREASEPENCIL"}


class BoundsError(ValueError):
    """Nothing visible to bound; the message says what was looked at."""


def _collections_where(view_layer, start: bool, step) -> set:
    """Pointers of the collections of ``view_layer`` whose flag holds, the flag passed down the tree:
    a collection's is ``step(layer_collection, its parent's flag)``, the scene collection's parent's
    is ``start``."""
    out = set()

    def walk(layer_coll, flag: bool) -> None:
        flag = step(layer_coll, flag)
        if flag:
            out.add(layer_coll.collection.as_pointer())
        for child in layer_coll.children:
            walk(child, flag)

    walk(view_layer.layer_collection, start)
    return out


def _rendered_collections(view_layer) -> set:
    """Pointers of the collections whose objects ``view_layer`` renders: included in it and, with every
    collection above, not disabled in renders. The viewport's eye and monitor icons play no part."""
    return _collections_where(view_layer, True, lambda lc, ok: ok and not lc.exclude
                              and not getattr(lc.collection, "hide_render", False))


def render_view_layer(scene):
    """The view layer that a single-layer render of ``scene`` (a capture's) uses: the window's active
    one when ``scene`` is the context's, else its first. Bounds, framing and masks read this layer,
    so that a file saved with its second layer active is boxed by what that layer renders."""
    if bpy.context.scene == scene and getattr(bpy.context, "view_layer", None) is not None:
        return bpy.context.view_layer
    return scene.view_layers[0]


def _in_render(obj, rendered: set) -> bool:
    """``obj`` (of any type: an instancer is an empty) is part of a render whose collections are ``rendered``."""
    return not obj.hide_render and any(c.as_pointer() in rendered for c in obj.users_collection)


def _renders(obj, rendered: set) -> bool:
    # An object hidden from camera rays (a bounce card, a light blocker) lights the scene but is never
    # in a picture: no NeRF sees it, so it must not stretch the box either.
    return obj.type in RENDERABLE_TYPES and getattr(obj, "visible_camera", True) and _in_render(obj, rendered)


def renderable_objects(scene, view_layer=None, only_selected: bool = False) -> list:
    """Objects of ``scene`` that appear in a render of ``view_layer`` (and, optionally, are selected).
    An object hidden in the viewport only (eye or monitor icon) renders, so it counts: artists hide
    heavy objects there."""
    view_layer = view_layer or render_view_layer(scene)
    rendered = _rendered_collections(view_layer)
    return [obj for obj in scene.objects if _renders(obj, rendered)
            and (not only_selected or obj.select_get(view_layer=view_layer))]


def rendering_lights(scene, view_layer=None) -> list:
    """Light objects of ``scene`` that light a render of ``view_layer`` (lights are never in the
    picture themselves, so ``renderable_objects`` leaves them out)."""
    view_layer = view_layer or render_view_layer(scene)
    rendered = _rendered_collections(view_layer)
    return [obj for obj in scene.objects if obj.type == "LIGHT" and _in_render(obj, rendered)]


def _with_their_drivers(objects) -> list:
    """``objects`` and what places them: parents and constraint targets, each once, in order."""
    out, seen, todo = [], set(), list(objects)
    while todo:
        obj = todo.pop(0)
        if obj is None or obj.as_pointer() in seen:
            continue
        seen.add(obj.as_pointer())
        out.append(obj)
        todo.append(obj.parent)
        todo += [getattr(c, "target", None) for c in getattr(obj, "constraints", ())
                 if isinstance(getattr(c, "target", None), bpy.types.Object)]
    return out


@contextmanager
def fresh_matrices(scene, objects, view_layer=None):
    """Inside the block, ``matrix_world`` of ``objects`` (and of their evaluated geometry) is where
    the render puts them, also for objects the viewport does not evaluate.

    Blender 5 does not save ``matrix_world`` in the .blend: an object disabled in viewports (monitor
    icon, of the object or of a collection) or in an excluded collection is never evaluated after
    the file is opened, and reads back as the identity, while the render, which evaluates it, places
    it where it belongs. A camera read that way gave a dataset of identity poses. The block links
    such objects (and their parents and constraint targets) into the scene collection with viewport
    display on, so the viewport evaluates them, and undoes both afterwards. Only matrices and
    geometry are meant to be read inside: whether an object renders is decided outside.
    """
    view_layer = view_layer or render_view_layer(scene)
    if bpy.context.scene != scene:
        yield
        return
    graph = bpy.context.evaluated_depsgraph_get()
    evaluated = {inst.object.original.as_pointer() for inst in graph.object_instances if not inst.is_instance}
    stale = [o for o in _with_their_drivers(objects) if o.as_pointer() not in evaluated]
    linked, shown = [], []
    try:
        for obj in stale:
            if obj.hide_viewport:
                obj.hide_viewport = False
                shown.append(obj)
            if scene.collection.objects.get(obj.name) is not obj:
                scene.collection.objects.link(obj)
                linked.append(obj)
        if stale:
            view_layer.update()
        yield
    finally:
        for obj in linked:
            scene.collection.objects.unlink(obj)
        for obj in shown:
            obj.hide_viewport = True
        if stale:
            view_layer.update()


def _box_of(bound_box, matrix) -> tuple[Vector, Vector]:
    """World (min, max) of a local ``bound_box`` (8 corners) placed by ``matrix``."""
    corners = [matrix @ Vector(c) for c in bound_box]
    return (Vector([min(c[i] for c in corners) for i in range(3)]),
            Vector([max(c[i] for c in corners) for i in range(3)]))


def object_bounds(objects, depsgraph=None) -> tuple[Vector, Vector]:
    """Axis-aligned world bounds (min, max) of the objects' evaluated bounding boxes."""
    evaluated = [o.evaluated_get(depsgraph) if depsgraph is not None else o for o in objects]
    if not evaluated:
        return Vector((float("inf"),) * 3), Vector((float("-inf"),) * 3)
    return box_union([_box_of(ev.bound_box, ev.matrix_world) for ev in evaluated])


def _rendered_pieces(scene, view_layer, objects, only_selected: bool):
    """Yield (evaluated object, world matrix, name, instancer or None) for each renderable object in
    ``objects`` that the evaluated scene holds, and for each instance that one of the render's
    instancers makes (named "instancer/object"). An instance renders when its instancer is part of
    the render (and selected, for ``only_selected``) and its object is not hidden from renders or
    camera rays. Needs ``scene`` to be the context's (its evaluated depsgraph)."""
    # Pointers, not names: a linked library's object may share its name with a local one.
    wanted = {o.as_pointer() for o in objects}
    rendered = _rendered_collections(view_layer)
    owners: dict = {}  # instancer pointer -> is it part of the render (and selected when that is asked)
    for inst in bpy.context.evaluated_depsgraph_get().object_instances:
        obj = inst.object
        if obj.type not in RENDERABLE_TYPES:
            continue
        if not inst.is_instance:
            if obj.original.as_pointer() in wanted:
                yield obj, obj.matrix_world, obj.name, None
            continue
        owner = inst.parent.original if inst.parent is not None else None
        if owner is None or obj.original.hide_render or not getattr(obj.original, "visible_camera", True):
            continue
        key = owner.as_pointer()
        if key not in owners:
            owners[key] = _in_render(owner, rendered) and (not only_selected or owner.select_get(view_layer=view_layer))
        if owners[key]:
            yield obj, inst.matrix_world.copy(), f"{owner.name}/{obj.name}", owner


def renderable_boxes(scene, view_layer=None, only_selected: bool = False) -> list:
    """[((min, max), name)]: the world box of each renderable object (``renderable_objects``) and of
    each instance one of them makes, named "instancer/object" (``_rendered_pieces``). Without the
    evaluated scene at hand (``scene`` is not the context's), instances are not seen and the objects'
    own boxes are used."""
    view_layer = view_layer or render_view_layer(scene)
    objects = renderable_objects(scene, view_layer, only_selected)
    if bpy.context.scene != scene:
        return [(object_bounds([o]), o.name) for o in objects]
    out, seen = [], set()
    for ev, matrix, name, owner in _rendered_pieces(scene, view_layer, objects, only_selected):
        if owner is None:
            seen.add(ev.original.as_pointer())
        box = _piece_box(ev, matrix, owner is not None)
        if box is not None:
            out.append((box, name))
        hair = _hair_box(ev, matrix) if owner is None else None
        if hair is not None:
            out.append((hair, f"{name} (hair)"))
    # Disabled in the viewport, an object still renders but is not evaluated there: evaluate it for the
    # moment (``fresh_matrices``; its stored matrix_world is the identity) and take its box then
    # (instances it makes are still not seen).
    hidden = [o for o in objects if o.as_pointer() not in seen]
    if hidden:
        with fresh_matrices(scene, hidden, view_layer):
            graph = bpy.context.evaluated_depsgraph_get()
            for o in hidden:
                ev = o.evaluated_get(graph)
                box = _piece_box(ev, ev.matrix_world, False, hidden=True)
                if box is not None:
                    out.append((box, o.name))
                hair = _hair_box(ev, ev.matrix_world)
                if hair is not None:
                    out.append((hair, f"{o.name} (hair)"))
    return out


# Object types whose evaluated surface the depsgraph hands out as a mesh instance of the object itself
# (owner = the object): their own bound_box is the curve's control cage padded by one unit (an
# unbevelled 8-unit camera path gave a box 2 units thick), so the instance's box is the one to use.
CONVERTED_TYPES = {"CURVE", "FONT", "SURFACE", "META"}


def _piece_box(ev, matrix, is_instance: bool, hidden: bool = False):
    """World (min, max) of one rendered piece, or None where it shows nothing: a mesh without faces
    (loose edges and vertices do not render: a rig's guide, an emitter of hair only), a curve or
    text whose evaluated geometry is empty (a camera path without bevel, a text with no body, the
    second metaball of a family, whose surface its basis object holds), a Grease Pencil object
    without strokes. Such objects counted as a point at their origin and stretched the box to it.
    ``hidden``: an object the viewport does not evaluate (``fresh_matrices``), whose surface is not
    handed out as an instance; it is converted here."""
    if ev.type in CONVERTED_TYPES and not is_instance:
        if not hidden:
            return None  # its surface arrives as a mesh instance of itself (or nothing renders)
        try:
            mesh = ev.to_mesh()
        except RuntimeError:
            return _box_of(ev.bound_box, matrix)
        try:
            if not mesh.polygons:
                return None
            return _box_of([v.co for v in mesh.vertices], matrix)
        finally:
            ev.to_mesh_clear()
    if ev.type == "MESH" and not ev.data.polygons:
        return None
    lo, hi = _box_of(ev.bound_box, matrix)
    if ev.type != "MESH" and lo == hi:
        return None  # an empty Grease Pencil, point cloud or volume: a box of no size at its origin
    return lo, hi


# Hair strands read for the box: every key of at most this many strands, spread evenly over them
# (reading 100 000 strands key by key through the Python API takes seconds).
HAIR_SAMPLE = 2000


def _hair_box(ev, matrix):
    """World (min, max) of the hair that the particle systems of an evaluated object render as strands
    (``render_type`` PATH), or None. Hair is drawn from the object's particles, not its mesh, so its
    bound_box leaves it out: a plane with 4-unit hair was boxed 0.04 units thick and the hair cut off
    in every view. Child strands spread about their parents by the children's radius."""
    if ev.type != "MESH":
        return None
    points, pad = [], 0.0
    for psys in getattr(ev, "particle_systems", ()):
        st = psys.settings
        if st.type != "HAIR" or st.render_type != "PATH" or not len(psys.particles):
            continue
        n = len(psys.particles)
        for i in np.unique(np.linspace(0, n - 1, min(n, HAIR_SAMPLE)).astype(int)):
            points += [k.co for k in psys.particles[int(i)].hair_keys]
        if st.child_type != "NONE":
            pad = max(pad, float(getattr(st, "child_radius", 0.0) or 0.0))
    if not points:
        return None
    lo, hi = _box_of(points, matrix)
    grow = pad * max(matrix.to_scale())
    return lo - Vector((grow,) * 3), hi + Vector((grow,) * 3)


def scene_signature(scene, view_layer=None) -> str | None:
    """A hash of what the render shows: every renderable piece's name, placement (to 1e-6), material
    names and evaluated geometry (vertex positions), instances included. It changes when an object is
    added, removed, moved or edited, or its modifiers change; not when a material's nodes change.
    None when ``scene`` is not the context's (its evaluated scene is not at hand)."""
    if bpy.context.scene != scene:
        return None
    view_layer = view_layer or render_view_layer(scene)
    objects = renderable_objects(scene, view_layer)
    geometry: dict = {}  # evaluated data pointer -> hash of its vertices
    rows = []
    for ev, matrix, name, _owner in _rendered_pieces(scene, view_layer, objects, False):
        data = getattr(ev, "data", None)
        key = data.as_pointer() if data is not None else 0
        if key not in geometry:
            verts = getattr(data, "vertices", None) if ev.type == "MESH" else None
            if verts is not None:
                co = np.empty(len(verts) * 3, np.float32)
                verts.foreach_get("co", co)
                geometry[key] = hashlib.sha256(co.tobytes()).hexdigest()[:16]
            else:  # curves, text, volumes...: their box stands for their shape
                geometry[key] = ",".join(f"{v:.6f}" for c in ev.bound_box for v in c)
        mats = [slot.material.name if slot.material is not None else "" for slot in ev.material_slots]
        rows.append("|".join([name, ",".join(f"{v:.6f}" for row in matrix for v in row), geometry[key], *mats]))
    return hashlib.sha256("\n".join(sorted(rows)).encode()).hexdigest()


def instanced_objects(scene, view_layer=None, only_selected: bool = False) -> list:
    """The original objects that the render shows as instances (of a collection instance, geometry
    nodes or particles) of its instancers, selected ones for ``only_selected``: objects that
    ``renderable_objects`` may not list (their collection is often excluded, as for a linked asset).
    Empty when ``scene`` is not the context's."""
    view_layer = view_layer or render_view_layer(scene)
    if bpy.context.scene != scene:
        return []
    found: dict = {}
    for ev, _m, _name, owner in _rendered_pieces(scene, view_layer, [], only_selected):
        if owner is not None:
            found.setdefault(ev.original.as_pointer(), ev.original)
    return list(found.values())


# Cycles' object index pass holds the index of the surface a ray hits: volumes have no surface, and
# Grease Pencil is drawn over the render by its own engine, so neither ever gets an index.
NO_INDEX_TYPES = {"VOLUME": "volume", "GREASEPENCIL": "Grease Pencil"}


def unindexed_pieces(scene, view_layer=None, only_selected: bool = False) -> list:
    """Names ("name (kind)") of the rendered pieces, instances and evaluated geometry included (a mesh
    turned into a volume by a modifier), that Cycles' object index pass never marks: an object mask
    built from it calls their pixels background. Empty when ``scene`` is not the context's."""
    view_layer = view_layer or render_view_layer(scene)
    if bpy.context.scene != scene:
        return []
    objects = renderable_objects(scene, view_layer, only_selected)
    out = []
    for ev, _m, name, owner in _rendered_pieces(scene, view_layer, objects, only_selected):
        label = f"{(owner or ev.original).name} ({NO_INDEX_TYPES[ev.type]})" if ev.type in NO_INDEX_TYPES else None
        if label and label not in out:
            out.append(label)
    return out


def _has_holdout_shader(tree, seen=None) -> bool:
    """A node tree (or a node group inside it) holds a Holdout shader node."""
    seen = set() if seen is None else seen
    if tree is None or tree.as_pointer() in seen:
        return False
    seen.add(tree.as_pointer())
    return any(n.type == "HOLDOUT" or (n.type == "GROUP" and _has_holdout_shader(n.node_tree, seen))
               for n in tree.nodes)


def holdout_objects(scene, view_layer=None) -> list:
    """Names of the objects that render as holdouts, which cut transparent holes (alpha 0) through
    everything behind them: an object's Holdout flag, a view-layer collection set to Holdout, or a
    material with a Holdout shader. Renderable objects and the objects instances show, in that order."""
    view_layer = view_layer or render_view_layer(scene)
    held = _collections_where(view_layer, False, lambda lc, on: on or bool(getattr(lc, "holdout", False)))
    out = []
    for obj in renderable_objects(scene, view_layer) + instanced_objects(scene, view_layer):
        shaders = any(slot.material is not None and slot.material.node_tree is not None
                      and _has_holdout_shader(slot.material.node_tree) for slot in obj.material_slots)
        if (getattr(obj, "is_holdout", False) or shaders
                or any(c.as_pointer() in held for c in obj.users_collection)) and obj.name not in out:
            out.append(obj.name)
    return out


def scene_bounds(scene, only_selected: bool = False, view_layer=None) -> tuple[Vector, Vector]:
    """(min, max) of the visible renderable objects and their instances; raises BoundsError when there
    are none."""
    boxes = renderable_boxes(scene, view_layer, only_selected)
    if not boxes:
        what = "selected visible objects" if only_selected else "visible objects that render"
        raise BoundsError(f"scene {scene.name!r} has no {what}; nothing to capture")
    lo, hi = box_union([b for b, _ in boxes])
    if not all(map(lambda v: v == v and abs(v) != float("inf"), list(lo) + list(hi))):
        raise BoundsError(f"scene {scene.name!r}: could not compute finite bounds")
    return lo, hi


def bounding_sphere(lo, hi) -> tuple[Vector, float]:
    """Centre and radius of the sphere through the corners of the box (lo, hi)."""
    lo, hi = Vector(lo), Vector(hi)
    centre = (lo + hi) / 2
    return centre, max((hi - lo).length / 2, 1e-6)


# What the framing leaves out: an object counts as the *surroundings* of the subject when it is at
# least this many times the size (bounding-box diagonal) of the subject and is either flat (a floor,
# a shadow catcher) or holds the whole subject in its box (a sky dome, a cyclorama backdrop). Framed
# on them, a 2 m object on a 100 m floor came out 2 px wide from cameras 219 m away.
SURROUNDINGS_RATIO = 4.0
FLAT_SHARE = 0.01  # thinnest side over the longest: a plane, or a 10 cm slab 10 m wide
# The scene box around a subject reaches this share of its diagonal beyond it on every side (clipped
# to the scene), so the ground it stands on, its contact shadow and what is close by stay inside.
SUBJECT_MARGIN = 0.25


# A flat subject (a plane, an image imported as a plane, unextruded text) has a box of no thickness,
# which no NeRF grid can hold and every loader refuses (min < max): each axis gets at least this share
# of the box diagonal, about its middle.
MIN_THICKNESS = 0.05


def with_thickness(lo, hi) -> tuple[Vector, Vector]:
    """(lo, hi) grown about its middle so that no axis is thinner than ``MIN_THICKNESS`` of its diagonal;
    BoundsError for a box of no size at all (the visible objects are a single point)."""
    need = MIN_THICKNESS * box_size((lo, hi))
    if need <= 0:
        raise BoundsError(f"the visible objects span no space (all at {tuple(round(v, 6) for v in lo)}); "
                          "nothing to capture")
    lo, hi = Vector(lo), Vector(hi)
    for i in range(3):
        if hi[i] - lo[i] < need:
            mid = 0.5 * (lo[i] + hi[i])
            lo[i], hi[i] = mid - 0.5 * need, mid + 0.5 * need
    return lo, hi


def box_size(box) -> float:
    """Diagonal of a (min, max) box."""
    return (Vector(box[1]) - Vector(box[0])).length


def box_union(boxes):
    """The (min, max) box holding every (min, max) box of ``boxes`` (at least one)."""
    return (Vector([min(b[0][i] for b in boxes) for i in range(3)]),
            Vector([max(b[1][i] for b in boxes) for i in range(3)]))


def _surrounds(box, subject) -> bool:
    """``box`` is ``SURROUNDINGS_RATIO`` times the size of ``subject`` and flat or holding all of it."""
    if box_size(box) < SURROUNDINGS_RATIO * box_size(subject):
        return False
    ext = box[1] - box[0]
    if min(ext) <= FLAT_SHARE * max(ext):
        return True
    return all(box[0][i] <= subject[0][i] and subject[1][i] <= box[1][i] for i in range(3))


def subject_bounds(scene, only_selected: bool = False, view_layer=None) -> tuple[Vector, Vector, list]:
    """(min, max, surroundings): the bounds of what a capture looks at, without the objects that only
    surround it (``_surrounds``), and those objects' names. With a selection, or when nothing
    surrounds anything, it is ``scene_bounds``.

    Objects are taken from the smallest up: each that surrounds the subject so far is set aside, and
    one that does not joins the subject together with everything set aside before it (a large
    building beside a car makes the floor under both part of the subject).
    """
    lo, hi = scene_bounds(scene, only_selected, view_layer)
    if only_selected:
        return lo, hi, []
    boxes = sorted(renderable_boxes(scene, view_layer), key=lambda item: (box_size(item[0]), item[1]))
    subject, aside = boxes[0][0], []  # the subject's box so far (a running union: scatters hold 100k instances)
    for item in boxes[1:]:
        if _surrounds(item[0], subject):
            aside.append(item)
        else:
            subject = box_union([subject] + [b for b, _ in aside] + [item[0]])
            aside = []
    if not aside:
        return lo, hi, []
    return subject[0], subject[1], sorted(name for _, name in aside)


def subject_box(scene, lo, hi) -> tuple[Vector, Vector]:
    """The scene box around subject bounds (lo, hi): ``SUBJECT_MARGIN`` of its diagonal beyond each
    side, but no further than the scene's own bounds."""
    s_lo, s_hi = scene_bounds(scene)
    pad = SUBJECT_MARGIN * box_size((lo, hi))
    return (Vector([max(a - pad, b) for a, b in zip(lo, s_lo)]), Vector([min(a + pad, b) for a, b in zip(hi, s_hi)]))
