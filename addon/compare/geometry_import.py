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
- World: the learned world behind the scene (``export world``'s equirectangular PNG, display values) as
  the scene's World: an OpenEXR of its light beside the PNG (the same inverse of the capture's view
  transform as the volume's colours), shown by an Environment Texture at strength 1, so that a camera
  ray that leaves the NeRF's volume meets what the NeRF shows there. The scene's own world is kept.
"""
from __future__ import annotations

import os
import sys

import bpy
import numpy as np

from ..bridge.core_contract import contract
from ..file_writes import PARTIAL_SUFFIX, partial_path
from . import display_colours, volume_files

MESH_COLLECTION, VOLUME_COLLECTION = "NeRF Mesh", "NeRF Volume"
WORLD_NAME = "NeRF World"
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


def volume_material(name: str, grids: tuple = (volume_files.DENSITY, volume_files.COLOR)):
    """Absorption sigma (black Volume Absorption: coefficient = density) plus emission sigma * colour, from
    the Volume's density and colour grids named ``grids``."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender 4.x; 5.x materials always have nodes (use_nodes is deprecated)
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    for n in list(nodes):
        nodes.remove(n)
    out = nodes.new("ShaderNodeOutputMaterial")
    density = nodes.new("ShaderNodeAttribute")
    density.attribute_name = grids[0]
    color = nodes.new("ShaderNodeAttribute")
    color.attribute_name = grids[1]
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


def _volume_object(scene, name: str, vdb_path: str, level: int):
    """A Volume object ``name`` in the ``NeRF Volume`` collection showing level ``level`` of ``vdb_path``."""
    vol = bpy.data.volumes.new(name)
    vol.filepath = vdb_path
    obj = bpy.data.objects.new(name, vol)
    collection(scene, VOLUME_COLLECTION).objects.link(obj)
    vol.materials.append(volume_material(name, volume_files.level_grids(level)))
    vol.grids.load()
    return obj


def import_volume(scene, npz_path: str, vdb_path: str = "", name: str = "NeRF Volume"):
    """Write the ``.vdb`` of a volume ``.npz`` (beside it unless ``vdb_path``) and add it as a Volume
    object in the ``NeRF Volume`` collection, with the NeRF's material, and one child object for each
    far level of an unbounded run's volume (``NAME far K``); returns the box's object."""
    vdb_path = vdb_path or os.path.splitext(npz_path)[0] + ".vdb"
    arrays = volume_files.read_npz(npz_path)
    to_linear, notes = display_colours.to_linear_for(volume_files.recorded_colour_management(arrays), scene)
    volume_files.npz_to_vdb(npz_path, vdb_path, openvdb_dirs(), to_linear=to_linear, arrays=arrays)
    obj = _volume_object(scene, name, vdb_path, 0)
    # An unbounded run's world beyond the box: one object a level (each reads its own grids, so Cycles
    # bounds each by its own voxels), parented to the box's, so that they move with it.
    for level in range(1, volume_files.far_levels(arrays) + 1):
        far = _volume_object(scene, f"{name} far {level}", vdb_path, level)
        far.parent = obj
    cycles = getattr(scene, "cycles", None)
    if cycles is not None and not cycles.volume_biased:
        # Cycles' default (unbiased) volumes estimate the emission by random collisions: grainy, and
        # still 1 dB short of the biased ray marching's 32 samples at 128 (multi: 33.4 against 34.4 dB)
        cycles.volume_biased = True
        notes.append(BIASED_NOTE)
    obj[NOTES_PROPERTY] = "\n".join(notes)  # what the user should read (import_geometry.py prints them)
    return obj


def _pixels(img) -> np.ndarray:
    """(h, w, 4) float32 pixels of a Blender image, row 0 at the bottom (Blender's order)."""
    out = np.empty(img.size[0] * img.size[1] * 4, dtype=np.float32)
    img.pixels.foreach_get(out)
    return out.reshape(img.size[1], img.size[0], 4)


def world_light(scene, png_path: str, exr_path: str) -> list:
    """Write ``exr_path``, the scene-linear light of the world file ``png_path`` (its display values through
    the inverse of the recorded view transform, ``display_colours``); returns the notes."""
    info = contract.world_file.read_world_info(png_path)  # ValueError naming the file: not ours
    to_linear, notes = display_colours.to_linear_for(info["color_management"], scene, what="world")
    src = bpy.data.images.load(png_path, check_existing=False)
    try:
        src.colorspace_settings.name = "Non-Color"  # the bytes / 255 as they are: the display values
        w, h = src.size
        if w < 2 or h < 1:
            raise ValueError(f"{png_path}: an image of {w} x {h} pixels is no world")
        px = _pixels(src)
    finally:
        bpy.data.images.remove(src)
    px[..., :3] = to_linear(px[..., :3].reshape(-1, 3)).reshape(h, w, 3)
    px[..., 3] = 1.0
    img = bpy.data.images.new("nerf world light", w, h, alpha=False, float_buffer=True)
    try:
        img.pixels.foreach_set(px.ravel())
        # never through a link; the extension last, as Blender picks the format by it
        with partial_path(exr_path, os.path.splitext(exr_path)[0] + PARTIAL_SUFFIX + ".exr") as tmp:
            img.filepath_raw, img.file_format = tmp, "OPEN_EXR"
            img.save()
    finally:
        bpy.data.images.remove(img)
    return notes


def import_world(scene, png_path: str, exr_path: str = "", name: str = WORLD_NAME):
    """Make the learned world of ``png_path`` (``export world``) the scene's World, its light written to
    ``exr_path`` (default: beside the PNG, ``.exr``); the scene's former world is kept (a fake user), and
    the notes say so. Returns the new World."""
    exr_path = exr_path or os.path.splitext(png_path)[0] + ".exr"
    notes = world_light(scene, png_path, exr_path)
    image = bpy.data.images.load(exr_path, check_existing=False)  # a float file: scene-linear on load
    image.name = name
    world = bpy.data.worlds.new(name)
    if world.node_tree is None:  # Blender 4.x; 5.x worlds always have nodes
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    for n in list(nodes):
        nodes.remove(n)
    env = nodes.new("ShaderNodeTexEnvironment")
    env.image, env.interpolation, env.projection = image, "Linear", "EQUIRECTANGULAR"  # the NeRF's lookup is bilinear
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = 1.0
    out = nodes.new("ShaderNodeOutputWorld")
    links.new(env.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], out.inputs["Surface"])
    for i, node in enumerate((env, background, out)):
        node.location = (-600 + 300 * i, 0)
    old = scene.world
    if old is not None and old != world:
        old.use_fake_user = True  # saved with the file although no scene shows it any more
        notes.append(f"the scene's world {old.name!r} is kept in the file: World Properties switches back to it")
    scene.world = world
    world[NOTES_PROPERTY] = "\n".join(notes)
    return world


# what each export of the table becomes in Blender (``contract.exports``): import_geometry.py and the
# Compare panel's geometry job look the importer up here
IMPORTERS = {"mesh": import_mesh, "volume": import_volume, "world": import_world}
