"""The external files a render of the scene reads, and which of them are missing.

Blender renders a scene whose image texture or linked library has gone missing without complaint: a
missing texture renders magenta, a missing library's objects not at all. A capture of it is a dataset
of the wrong scene that no check after the fact can tell from the right one, so the capture says so
before rendering (``capture/plan/notes.capture_notes``).
"""
from __future__ import annotations

import glob
import os

import bpy

from . import scene_bounds

# Image sources that name files on disk (a generated or viewer image has none).
_FILE_SOURCES = {"FILE", "MOVIE", "SEQUENCE", "TILED"}


def _image_missing(image) -> bool:
    """``image`` names a file that is not there, and is not packed into the .blend."""
    if image.source not in _FILE_SOURCES or image.packed_file is not None or getattr(image, "packed_files", None):
        return False
    if not image.filepath:
        return True
    path = bpy.path.abspath(image.filepath, library=image.library)
    if image.source == "TILED" or image.source == "SEQUENCE":
        # a UDIM set or a numbered sequence: missing when no file of the set is there
        pattern = path.replace("<UDIM>", "*").replace("<UVTILE>", "*")
        stem, ext = os.path.splitext(pattern)
        return not (glob.glob(pattern) or glob.glob(stem.rstrip("0123456789") + "*" + ext))
    return not os.path.isfile(path)


def _tree_images(tree, seen: set) -> list:
    """Images the nodes of ``tree`` (and the node groups it uses) read."""
    if tree is None or tree.as_pointer() in seen:
        return []
    seen.add(tree.as_pointer())
    out = []
    for node in tree.nodes:
        image = getattr(node, "image", None)
        if isinstance(image, bpy.types.Image):
            out.append(image)
        out += _tree_images(getattr(node, "node_tree", None), seen)
    return out


def render_images(scene, view_layer=None) -> list:
    """The images that the materials of the rendered objects (instances' objects included), the
    world and the rendering lights read, each once."""
    view_layer = view_layer or scene_bounds.render_view_layer(scene)
    seen: set = set()
    trees = [getattr(scene.world, "node_tree", None)] if scene.world is not None else []
    for obj in scene_bounds.renderable_objects(scene, view_layer) + scene_bounds.instanced_objects(scene, view_layer):
        trees += [slot.material.node_tree for slot in obj.material_slots if slot.material is not None]
    trees += [getattr(obj.data, "node_tree", None) for obj in scene_bounds.rendering_lights(scene, view_layer)]
    images: dict = {}
    for tree in trees:
        for image in _tree_images(tree, seen):
            images.setdefault(image.as_pointer(), image)
    return list(images.values())


def _names(items: list, limit: int = 5) -> str:
    return ", ".join(items[:limit]) + (f" and {len(items) - limit} more" if len(items) > limit else "")


def missing_file_notes(scene, view_layer=None) -> list:
    """One note each for the missing image files the render reads and for missing linked libraries
    (with the objects of the scene they should have brought); empty when nothing is missing."""
    notes = []
    images = [i for i in render_images(scene, view_layer) if _image_missing(i)]
    if images:
        notes.append("image file(s) not found, which render magenta (Blender's colour for a missing texture) in "
                     "every view: " + _names([f"{i.name!r} ({i.filepath})" for i in images])
                     + ". Find them (File > External Data > Find Missing Files) or pack them before capturing")
    libraries = [lib for lib in bpy.data.libraries if getattr(lib, "is_missing", False)]
    if libraries:
        lost = sorted(o.name for o in scene.objects if getattr(o, "is_missing", False))
        notes.append("linked librar" + ("y" if len(libraries) == 1 else "ies") + " not found: "
                     + _names([f"{lib.name!r} ({lib.filepath})" for lib in libraries])
                     + (f"; {_names([repr(n) for n in lost])} will not render" if lost else "")
                     + ". Relocate the library (File > External Data > Relink) before capturing")
    return notes
