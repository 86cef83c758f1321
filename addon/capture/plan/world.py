"""What a scene's world shows behind everything, as JSON (recorded by every capture).

An opaque film renders the world into every pixel behind the scene, so the capture records it in
the manifest and the transforms files and puts it in the render signature of opaque captures.
"""
from __future__ import annotations

import os

import bpy


def _round_color(values) -> list[float]:
    return [round(float(v), 6) for v in list(values)[:3]]


def _linked_from(socket):
    """The node feeding ``socket`` (through reroutes), or None when it is not linked."""
    while socket is not None and socket.is_linked:
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None
        node = link.from_node
        if node.type != "REROUTE":
            return node
        socket = node.inputs[0]
    return None


def _background_node(node, depth=0):
    """The Background node behind a world's Surface: itself, or the first one inside mix/add shaders."""
    if node is None or depth > 8:
        return None
    if node.type == "BACKGROUND":
        return node
    if node.type in ("MIX_SHADER", "ADD_SHADER"):
        for sock in node.inputs:
            if sock.type == "SHADER":
                found = _background_node(_linked_from(sock), depth + 1)
                if found is not None:
                    return found
    return None


def world_description(world, engine: str | None = None) -> dict:
    """What the scene's world shows behind everything (what an opaque film renders), as JSON.

    ``{"name", "kind", "image", "color", "strength"}`` with ``kind`` one of:
    ``environment_texture`` (``image``: the image file's name), ``sky_texture``, ``color`` (``color``:
    linear RGB), ``other`` (a Background fed by other nodes, or a surface that is not a Background),
    ``none`` (no world, or nothing linked to the World Output: renders black). ``strength`` is the
    Background's Strength (null when driven by a link). The World Output is the active one.
    ``engine`` "BLENDER_WORKBENCH": Workbench ignores the nodes and shows the world's viewport colour.
    """
    out = {"name": world.name if world is not None else None, "kind": "none", "image": None, "color": None,
           "strength": None}
    if world is None:
        return out
    tree = world.node_tree
    if (tree is None or engine == "BLENDER_WORKBENCH"
            or (bpy.app.version < (5, 0, 0) and not world.use_nodes)):  # 5.0 worlds always use nodes
        out.update(kind="color", color=_round_color(world.color), strength=1.0)
        return out
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"]
    active = [n for n in outputs if n.is_active_output] or outputs
    if not active:
        return out
    surface = _linked_from(active[0].inputs["Surface"])
    bg = _background_node(surface)
    if bg is None:
        if surface is not None:
            out["kind"] = "other"
        return out
    strength = bg.inputs["Strength"]
    out["strength"] = None if strength.is_linked else round(float(strength.default_value), 6)
    color_in = bg.inputs["Color"]
    src = _linked_from(color_in)
    if not color_in.is_linked:
        out.update(kind="color", color=_round_color(color_in.default_value))
    elif src is not None and src.type == "TEX_ENVIRONMENT":
        image = src.image
        name = None
        if image is not None:
            name = os.path.basename(bpy.path.abspath(image.filepath)) if image.filepath else image.name
        out.update(kind="environment_texture", image=name)
    elif src is not None and src.type == "TEX_SKY":
        out["kind"] = "sky_texture"
    else:
        out["kind"] = "other"
    return out
