"""What a render looks like beyond its geometry: materials, the world and lights, as one hash.

``scene_bounds.scene_signature`` covers what renders and where (names, placements, vertices, the
names of materials). An artist who changes a material's colour, the world's strength or a lamp's
power between a capture and its resume changes every picture without moving a vertex, so a resume
would keep pictures of the old look beside new ones. ``appearance_signature`` hashes that look:

* every material on a rendered object, and the world: their node trees (node types, settings and
  unlinked input values, links; node groups followed), or their plain colours without nodes;
* every light that renders: its placement and its light data's settings.

Node positions, names of the UI (labels, colours of frames) and selection are left out: moving a
node in the editor changes no pixel.
"""
from __future__ import annotations

import hashlib

import bpy

from . import scene_bounds

# RNA properties of nodes, lights and materials that never change a render.
_UI_PROPS = {"rna_type", "name", "label", "location", "location_absolute", "width", "height", "dimensions",
             "select", "hide", "mute_ui", "show_options", "show_preview", "show_texture", "use_custom_color",
             "color", "parent", "bl_idname", "bl_label", "bl_description", "bl_icon", "bl_static_type",
             "bl_width_default", "bl_width_min", "bl_width_max", "bl_height_default", "bl_height_min",
             "bl_height_max", "type", "internal_links", "inputs", "outputs", "warning_propagation",
             "is_active_output", "color_tag", "description",
             "use_nodes"}  # deprecated in Blender 5 (always on); the node tree is hashed whenever there is one
_VALUE_TYPES = {"BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"}


def _value(v) -> str:
    """A property value as stable text (floats to 1e-6; arrays, vectors and colours element-wise)."""
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (bool, int, str)):
        return str(v)
    if isinstance(v, (set, frozenset)):
        return ",".join(sorted(map(str, v)))
    try:
        return "(" + ",".join(_value(x) for x in v) + ")"
    except TypeError:
        return type(v).__name__


def _id_props() -> set:
    # Every ID's bookkeeping (users, tag, session_uid, is_evaluated...): it changes between sessions
    # and with unrelated edits, never with the look.
    return {p.identifier for p in bpy.types.ID.bl_rna.properties}


def _settings(struct) -> list[str]:
    """``name=value`` of the render-relevant plain properties of an RNA struct, plus the data it
    points at by name (an image, a node group, an object)."""
    out = []
    skip = _UI_PROPS | (_id_props() if isinstance(struct, bpy.types.ID) else set())
    for prop in struct.bl_rna.properties:
        key = prop.identifier
        if key in skip or key.startswith("show_"):
            continue
        try:
            value = getattr(struct, key)
        except (AttributeError, RuntimeError):
            continue
        if prop.type in _VALUE_TYPES:
            out.append(f"{key}={_value(value)}")
        elif prop.type == "POINTER" and isinstance(value, bpy.types.ID):
            # An image texture's file (and its packed state), a node group, an object: by name and path.
            out.append(f"{key}->{value.name}|{getattr(value, 'filepath', '')}")
    return out


def _tree_rows(tree, seen: set) -> list[str]:
    """Rows describing a node tree and the node groups it uses (each group once)."""
    if tree is None or tree.as_pointer() in seen:
        return []
    seen.add(tree.as_pointer())
    rows = []
    for node in sorted(tree.nodes, key=lambda n: n.name):
        if node.type in ("FRAME", "REROUTE"):
            continue
        inputs = [f"{s.identifier}={_value(s.default_value)}" for s in node.inputs
                  if not s.is_linked and hasattr(s, "default_value")]
        rows.append("|".join([node.name, node.bl_idname, f"mute={node.mute}", *_settings(node), *inputs]))
        if getattr(node, "node_tree", None) is not None:
            rows += _tree_rows(node.node_tree, seen)
    rows += sorted(f"{link.from_node.name}.{link.from_socket.identifier}->{link.to_node.name}."
                   f"{link.to_socket.identifier}|{link.is_muted}" for link in tree.links)
    return rows


def _id_rows(idblock, seen: set) -> list[str]:
    """A material or world: its node tree when it uses nodes, and its own plain settings."""
    if idblock is None:
        return ["none"]
    rows = [f"{type(idblock).__name__}:{idblock.name}", *_settings(idblock)]
    if isinstance(idblock, bpy.types.World):
        # "color" is skipped as a node's UI colour, but a world's is what Workbench shows behind everything
        rows.append(f"color={_value(idblock.color)}")
    # Blender 5 always uses the node tree (use_nodes is deprecated, gone in 6); 4.x may not.
    if getattr(idblock, "node_tree", None) is not None:
        rows += _tree_rows(idblock.node_tree, seen)
    return rows


def appearance_signature(scene, view_layer=None) -> str:
    """A hash of the materials of the rendered objects, the world and the rendering lights of
    ``scene`` (see the module docstring); equal for two scenes that differ only in geometry."""
    view_layer = view_layer or scene_bounds.render_view_layer(scene)
    seen: set = set()
    rows = _id_rows(scene.world, seen)
    materials = {}
    for obj in scene_bounds.renderable_objects(scene, view_layer):
        for slot in getattr(obj, "material_slots", ()):
            if slot.material is not None:
                materials.setdefault(slot.material.name, slot.material)
    for obj in scene_bounds.rendering_lights(scene, view_layer):
        rows.append("|".join(["light", obj.name, *(f"{v:.6f}" for row in obj.matrix_world for v in row),
                              *_settings(obj.data)]))
        rows += _tree_rows(getattr(obj.data, "node_tree", None), seen)
    for name in sorted(materials):
        rows += _id_rows(materials[name], seen)
    return hashlib.sha256("\n".join(rows).encode()).hexdigest()
