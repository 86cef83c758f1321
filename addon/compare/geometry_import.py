"""The NeRF's geometry in the scene: a coloured mesh (PLY) or a Volume object (OpenVDB), each in its
own collection, in the scene's frame (the capture's world is Blender's: no transform is applied),
beside the objects they were trained on.

- Mesh: Blender's own PLY importer (vertex colours, read as sRGB, become the ``Col`` colour
  attribute) and a material whose base colour is that attribute.
- Volume: ``volume_files.npz_to_vdb`` writes the ``.vdb`` beside the ``.npz``, its colours turned back
  into light through the inverse of the capture's view transform (``display_colours``); the material renders
  it as the NeRF does: absorption with coefficient sigma (``density`` grid, per Blender unit) and
  emission sigma * colour (``color`` grid). Along a ray that is exactly the NeRF's integral
  ``sum T_i (1 - exp(-sigma_i delta_i)) c_i``, which is the solution of dL/ds = -sigma L + sigma c.
  The .blend keeps the .vdb's path, so a render farm renders it without the add-on.
"""
from __future__ import annotations

import os
import sys

import bpy

from . import display_colours, volume_files

MESH_COLLECTION, VOLUME_COLLECTION = "NeRF Mesh", "NeRF Volume"
NOTES_PROPERTY = "nerf_notes"  # a custom property of the imported object: the import's notes, one a line
COLOR_ATTRIBUTE = "Col"  # the name Blender's PLY importer gives the vertex colours
BIASED_NOTE = ("turned on Cycles' biased volumes (Render Properties > Volumes > Biased): the NeRF's volume then "
               "converges by 32 samples; turn it off again if another volume of the scene needs unbiased scattering")


def openvdb_dirs() -> list:
    """Blender's bundled site-packages, where ``openvdb`` lives (importable directly inside Blender)."""
    v = sys.version_info
    return [os.path.join(bpy.utils.resource_path("LOCAL"), "python", "lib", f"python{v.major}.{v.minor}",
                         "site-packages")]


def collection(scene, name: str):
    """The scene's collection ``name`` (created under the scene's root collection when missing)."""
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def _move_to(obj, coll) -> None:
    for c in list(obj.users_collection):
        c.objects.unlink(obj)
    coll.objects.link(obj)


def mesh_material(name: str):
    """A material that shows the colour attribute ``Col`` (Principled BSDF's base colour)."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender 4.x; 5.x materials always have nodes (use_nodes is deprecated)
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type, attr.attribute_name = "GEOMETRY", COLOR_ATTRIBUTE
    attr.location = (bsdf.location.x - 300, bsdf.location.y)
    links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 1.0  # the colours already hold the lighting the NeRF saw
    return mat


def import_mesh(scene, ply_path: str, name: str = "NeRF Mesh"):
    """Import a mesh PLY into the ``NeRF Mesh`` collection, with its colour material; returns the object."""
    before = set(bpy.data.objects)
    result = bpy.ops.wm.ply_import(filepath=ply_path, import_colors="SRGB", forward_axis="Y", up_axis="Z",
                                   global_scale=1.0, use_scene_unit=False, merge_verts=False)
    new = [o for o in bpy.data.objects if o not in before]
    if "FINISHED" not in result or not new:
        raise RuntimeError(f"{ply_path}: Blender's PLY importer read no mesh")
    obj = new[0]
    obj.name = obj.data.name = name
    _move_to(obj, collection(scene, MESH_COLLECTION))
    obj.data.materials.append(mesh_material(name))
    if COLOR_ATTRIBUTE in obj.data.color_attributes:
        obj.data.color_attributes.active_color_name = COLOR_ATTRIBUTE
    return obj


def volume_material(name: str):
    """Absorption sigma (black Volume Absorption: coefficient = density) plus emission sigma * colour."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender 4.x; 5.x materials always have nodes (use_nodes is deprecated)
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    for n in list(nodes):
        nodes.remove(n)
    out = nodes.new("ShaderNodeOutputMaterial")
    density = nodes.new("ShaderNodeAttribute")
    density.attribute_name = volume_files.DENSITY
    color = nodes.new("ShaderNodeAttribute")
    color.attribute_name = volume_files.COLOR
    absorb = nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    emit = nodes.new("ShaderNodeEmission")
    add = nodes.new("ShaderNodeAddShader")
    links.new(density.outputs["Fac"], absorb.inputs["Density"])
    links.new(density.outputs["Fac"], emit.inputs["Strength"])
    links.new(color.outputs["Color"], emit.inputs["Color"])
    links.new(absorb.outputs[0], add.inputs[0])
    links.new(emit.outputs[0], add.inputs[1])
    links.new(add.outputs[0], out.inputs["Volume"])
    for i, node in enumerate((density, color, absorb, emit, add, out)):
        node.location = (-900 + 180 * i, 0)
    return mat


def import_volume(scene, npz_path: str, vdb_path: str = "", name: str = "NeRF Volume"):
    """Write the ``.vdb`` of a volume ``.npz`` (beside it unless ``vdb_path``) and add it as a Volume
    object in the ``NeRF Volume`` collection, with the NeRF's material; returns the object."""
    vdb_path = vdb_path or os.path.splitext(npz_path)[0] + ".vdb"
    arrays = volume_files.read_npz(npz_path)
    to_linear, notes = display_colours.to_linear_for(volume_files.recorded_colour_management(arrays), scene)
    volume_files.npz_to_vdb(npz_path, vdb_path, openvdb_dirs(), to_linear=to_linear, arrays=arrays)
    vol = bpy.data.volumes.new(name)
    vol.filepath = vdb_path
    obj = bpy.data.objects.new(name, vol)
    collection(scene, VOLUME_COLLECTION).objects.link(obj)
    vol.materials.append(volume_material(name))
    vol.grids.load()
    cycles = getattr(scene, "cycles", None)
    if cycles is not None and not cycles.volume_biased:
        # Cycles' default (unbiased) volumes estimate the emission by random collisions: grainy, and
        # still 1 dB short of the biased ray marching's 32 samples at 128 (multi: 33.4 against 34.4 dB)
        cycles.volume_biased = True
        notes.append(BIASED_NOTE)
    obj[NOTES_PROPERTY] = "\n".join(notes)  # what the user should read (import_geometry.py prints them)
    return obj
