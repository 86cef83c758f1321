"""How a compare .blend keeps the images its planes show: packed, relative or absolute paths.

Default ``pack``: a compare file is a snapshot of one render (each render gets a fresh
``RUN/views/<label>_NNN`` that is never written into again), so linking to it gains nothing, while a
packed file still shows every tile after the run folder is moved, renamed, archived or deleted, or
the .blend is sent to someone else. The cost is small: the images are NeRF-sized PNGs, stored as the
PNG bytes themselves. ``relative`` (``//`` paths, relative to the .blend) suits a .blend kept inside
the project beside its runs and moved with them; ``absolute`` is Blender's importer's own behaviour.
"""
from __future__ import annotations

import os
from typing import Iterable, List

import bpy

MODES = ("pack", "relative", "absolute")
DEFAULT = "pack"


def plane_images(objects: Iterable) -> List:
    """The images (bpy.types.Image) shown by the materials of ``objects``, each once, in order."""
    seen, out = set(), []
    for ob in objects:
        for mat in getattr(ob.data, "materials", None) or []:
            if mat is None or mat.node_tree is None:
                continue
            for node in mat.node_tree.nodes:
                img = getattr(node, "image", None) if node.bl_idname == "ShaderNodeTexImage" else None
                if img is not None and img.name not in seen:
                    seen.add(img.name)
                    out.append(img)
    return out


def store(images, mode: str, start_dir: str = "") -> str:
    """Keep ``images`` as ``mode`` says; returns a one-line note when the mode could not be applied.

    ``pack``: the file's bytes go into the .blend. ``relative``: ``//`` paths relative to
    ``start_dir`` (default: the open .blend's folder; saving elsewhere with Blender's
    ``relative_remap`` rebases them); without a folder the paths stay absolute and the note says so.
    ``absolute``: absolute paths (and nothing packed).
    """
    if mode not in MODES:
        raise ValueError(f"image storage {mode!r}: choose one of {', '.join(MODES)}")
    start = start_dir or (os.path.dirname(bpy.data.filepath) if bpy.data.filepath else "")
    note = ""
    for img in images:
        path = os.path.abspath(bpy.path.abspath(img.filepath))
        if mode == "pack":
            if img.packed_file is None:
                img.pack()
        elif img.packed_file is not None:
            img.unpack(method="REMOVE")  # forget the packed copy, keep reading the file on disk
        if mode == "relative":
            if not start:
                note = "the .blend is not saved yet: image paths stay absolute (save it, then import again)"
                img.filepath = path
                continue
            try:
                img.filepath = bpy.path.relpath(path, start=start)
            except ValueError:  # another drive (Windows): no relative path exists
                note = f"{path} has no path relative to {start}: kept absolute"
                img.filepath = path
        elif mode == "absolute":
            img.filepath = path
    return note
