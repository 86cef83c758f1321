"""Procedural demo scenes: deterministic, built in seconds, within about +-1.5 units, lit.

Materials use only Principled BSDF and procedural textures, which Cycles and EEVEE render alike;
each material's viewport colour is set too so Workbench renders are meaningful. Every scene has a
world colour (ambient light) and a sun.

    from addon import demo_scenes
    demo_scenes.build("glossy")          # into the current scene, replacing its objects
"""
from __future__ import annotations

import math

import bpy

SCENES = {
    "cube": "a flat-coloured cube (tiny; for model-sizing tests)",
    "diffuse": "a diffuse, procedurally textured sphere on a pedestal",
    "highfreq": "a cube with a fine checker and stripes (high-frequency texture)",
    "glossy": "a metallic sphere and a glossy torus",
    "thin": "thin rods and a wire lattice (thin structures)",
    "multi": "several objects of different shapes and colours",
}


class DemoSceneError(ValueError):
    pass


def _material(name, color, roughness=0.5, metallic=0.0, texture=None, scale=5.0, color2=(0.05, 0.05, 0.05)):
    """Principled material; ``texture`` in (None, 'checker', 'noise', 'wave') drives the base colour."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender < 5.0 creates materials without nodes
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    if texture:
        kind = {"checker": "ShaderNodeTexChecker", "noise": "ShaderNodeTexNoise", "wave": "ShaderNodeTexWave"}[texture]
        tex = nodes.new(kind)
        tex.inputs["Scale"].default_value = scale
        if texture == "checker":
            tex.inputs["Color1"].default_value = (*color, 1.0)
            tex.inputs["Color2"].default_value = (*color2, 1.0)
            links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            ramp = nodes.new("ShaderNodeValToRGB")
            ramp.color_ramp.elements[0].color = (*color2, 1.0)
            ramp.color_ramp.elements[1].color = (*color, 1.0)
            links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
            links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    mat.diffuse_color = (*color, 1.0)  # Workbench's material colour
    mat.metallic = metallic
    mat.roughness = roughness
    return mat


def _add(op, name, material=None, **kwargs):
    op(**kwargs)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.name = name
    if material is not None:
        obj.data.materials.append(material)
    return obj


def _smooth(obj):
    for poly in obj.data.polygons:
        poly.use_smooth = True


def _lights_and_world(scene, strength=1.0):
    world = bpy.data.worlds.new("NeRF Demo World")
    if world.node_tree is None:
        world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    bg.inputs["Color"].default_value = (0.35, 0.35, 0.38, 1.0)
    bg.inputs["Strength"].default_value = strength
    world.color = (0.35, 0.35, 0.38)
    scene.world = world
    sun_data = bpy.data.lights.new("Sun", "SUN")
    sun_data.energy = 3.0
    sun_data.angle = math.radians(5)
    sun = bpy.data.objects.new("Sun", sun_data)
    scene.collection.objects.link(sun)
    sun.rotation_euler = (math.radians(40), math.radians(15), math.radians(30))
    # Workbench: studio lighting with material colours looks like a lit render.
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "MATERIAL"


def _clear_scene(scene):
    for obj in list(scene.objects):
        bpy.data.objects.remove(obj, do_unlink=True)


def build(name: str, scene=None):
    """Replace the objects of ``scene`` (default: current) with demo scene ``name``; returns the scene."""
    if name not in SCENES:
        raise DemoSceneError(f"unknown demo scene {name!r}; choose one of {', '.join(SCENES)}")
    scene = scene or bpy.context.scene
    _clear_scene(scene)
    mesh = bpy.ops.mesh
    if name == "cube":
        _add(mesh.primitive_cube_add, "Cube", _material("Flat red", (0.8, 0.1, 0.1), roughness=1.0), size=1.5)
    elif name == "diffuse":
        mat = _material("Textured", (0.8, 0.5, 0.15), roughness=0.9, texture="noise", scale=4.0, color2=(0.1, 0.25, 0.6))
        sphere = _add(mesh.primitive_uv_sphere_add, "Sphere", mat, radius=0.8, location=(0, 0, 0.3),
                      segments=48, ring_count=24)
        _smooth(sphere)
        _add(mesh.primitive_cylinder_add, "Pedestal", _material("Pedestal", (0.6, 0.6, 0.6), roughness=0.8),
             radius=0.6, depth=0.6, location=(0, 0, -0.8))
    elif name == "highfreq":
        _add(mesh.primitive_cube_add, "Checker cube",
             _material("Fine checker", (0.9, 0.9, 0.9), roughness=0.8, texture="checker", scale=24.0), size=1.6)
        _add(mesh.primitive_plane_add, "Stripes",
             _material("Stripes", (0.9, 0.7, 0.1), roughness=0.8, texture="wave", scale=12.0), size=2.0,
             location=(0, 0, -0.85))
    elif name == "glossy":
        ball = _add(mesh.primitive_uv_sphere_add, "Metal ball",
                    _material("Gold", (1.0, 0.77, 0.34), roughness=0.15, metallic=1.0), radius=0.7,
                    location=(-0.5, 0, 0), segments=48, ring_count=24)
        _smooth(ball)
        torus = _add(mesh.primitive_torus_add, "Glossy torus",
                     _material("Glossy blue", (0.1, 0.2, 0.8), roughness=0.1), major_radius=0.55,
                     minor_radius=0.18, location=(0.7, 0, 0), rotation=(math.radians(60), 0, 0))
        _smooth(torus)
    elif name == "thin":
        rod = _material("Rods", (0.85, 0.85, 0.8), roughness=0.6)
        for k in range(7):
            a = 2 * math.pi * k / 7
            _add(mesh.primitive_cylinder_add, f"Rod {k}", rod, radius=0.025, depth=2.2, vertices=12,
                 location=(0.9 * math.cos(a), 0.9 * math.sin(a), 0), rotation=(0, math.radians(15), a))
        lattice = _add(mesh.primitive_ico_sphere_add, "Wire lattice",
                       _material("Wire", (0.8, 0.2, 0.2), roughness=0.5), radius=0.6, subdivisions=2)
        wire = lattice.modifiers.new("Wireframe", "WIREFRAME")
        wire.thickness = 0.03
    elif name == "multi":
        specs = [
            (mesh.primitive_cube_add, "Box", (0.8, 0.2, 0.2), dict(size=0.8, location=(-0.8, -0.6, -0.6))),
            (mesh.primitive_uv_sphere_add, "Ball", (0.2, 0.7, 0.3), dict(radius=0.45, location=(0.7, -0.5, -0.55))),
            (mesh.primitive_cone_add, "Cone", (0.2, 0.3, 0.85), dict(radius1=0.5, depth=1.0, location=(0.6, 0.7, -0.5))),
            (mesh.primitive_torus_add, "Ring", (0.9, 0.75, 0.1), dict(major_radius=0.4, minor_radius=0.12,
                                                                       location=(-0.6, 0.7, -0.8))),
            (mesh.primitive_monkey_add, "Suzanne", (0.7, 0.4, 0.8), dict(size=0.8, location=(0, 0, 0.5))),
        ]
        for op, obj_name, color, kw in specs:
            obj = _add(op, obj_name, _material(obj_name, color, roughness=0.6), **kw)
            if op in (mesh.primitive_uv_sphere_add, mesh.primitive_monkey_add):
                _smooth(obj)
        _add(mesh.primitive_plane_add, "Floor", _material("Floor", (0.5, 0.5, 0.5), roughness=0.9,
                                                          texture="checker", scale=6.0, color2=(0.3, 0.3, 0.3)),
             size=2.8, location=(0, 0, -1.1))
    _lights_and_world(scene)
    for obj in scene.objects:
        obj.select_set(False)
    scene.frame_set(1)
    return scene
