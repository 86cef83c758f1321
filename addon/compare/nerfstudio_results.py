"""nerfstudio's results back in the scene's frame: point clouds and meshes it exported (PLY, OBJ).

nerfstudio trains in its own world (``contract.nerfstudio_frame``: the dataparser re-orients, re-centres
and re-scales the poses, and records how in ``dataparser_transforms.json``); ``ns-export`` writes its
point clouds and meshes there. ``import_geometry`` reads such a file as written and gives the new
object the inverse transform as its ``matrix_world``, so the vertices land in the dataset's world, which
for our captures is the Blender scene's own (nothing of the mesh data is changed: clearing the
object's transform shows nerfstudio's coordinates again).
"""
from __future__ import annotations

import os

import bpy
from mathutils import Matrix

from ..bridge.core_contract import contract
from ..dataset.errors import ExportError

GEOMETRY_EXTS = (".ply", ".obj")
TAG = "nerf_nerfstudio_result"  # custom property: the file an object was imported from


def import_geometry(scene, path: str, dataparser: str) -> list:
    """Import the PLY or OBJ at ``path`` (as written: no axis conversion) into ``scene`` and put it in
    the dataset's world with nerfstudio's ``dataparser`` transforms file; returns the new objects.
    Raises ExportError naming the file."""
    path = os.path.abspath(path)
    problem = contract.file_problem(path)
    if problem:
        raise ExportError(f"{path}: {problem}")
    ext = os.path.splitext(path)[1].lower()
    if ext not in GEOMETRY_EXTS:
        raise ExportError(f"{path}: expected a .ply or .obj file (nerfstudio's ns-export writes these)")
    try:
        transform, scale = contract.nerfstudio_frame.read_dataparser_transform(dataparser)
    except contract.DatasetError as exc:
        raise ExportError(str(exc)) from None
    before = set(bpy.data.objects)
    with bpy.context.temp_override(scene=scene):
        try:
            if ext == ".ply":
                bpy.ops.wm.ply_import(filepath=path, forward_axis="Y", up_axis="Z", global_scale=1.0)
            else:
                bpy.ops.wm.obj_import(filepath=path, forward_axis="Y", up_axis="Z", global_scale=1.0)
        except RuntimeError as exc:
            raise ExportError(f"{path}: Blender could not import it: {str(exc).strip()}") from None
    made = [o for o in bpy.data.objects if o not in before]
    if not made:
        raise ExportError(f"{path}: no geometry in it")
    back = Matrix(contract.nerfstudio_frame.nerfstudio_to_dataset_matrix(transform, scale).tolist())
    for obj in made:
        obj.matrix_world = back @ obj.matrix_world
        obj[TAG] = path
    return made
