"""Procedural demo scenes: deterministic, built in seconds, lit.

Object scenes fit in about +-1.5 units and are meant for a transparent film: every one of them has a
world colour (ambient light) and a sun. Two "real scene" demos carry their background with them:
``hdri`` (objects in a visible photographed world: one of Blender's own studio-light HDRIs) and
``interior`` (a closed 6 x 5 x 3 m room with furniture, lit from inside, captured from inside with the
``inside`` layout). Both set ``render.film_transparent = False``; ``CAPTURE_DEFAULTS`` /
``capture_flags(name)`` (from ``demo.capture_flags``) say which ``scripts/capture.py`` flags each scene needs.

Materials use only Principled BSDF and procedural textures, which Cycles and EEVEE render alike;
each material's viewport colour is set too so Workbench renders are meaningful.

    from addon.capture.demo import scenes
    scenes.build("glossy")               # into the current scene, replacing its objects
"""
from __future__ import annotations

import math
import os

import bpy

from .capture_flags import CAPTURE_DEFAULTS, SCENES, capture_defaults, capture_flags  # noqa: F401  (re-exported)

# Blender's own studio-light worlds ship inside every Blender (and the bpy module): real photographs.
HDRI_NAME = "forest.exr"
ROOM_SIZE = (6.0, 5.0, 3.0)  # interior: x, y, z extent in metres; floor at z = 0, centred on x = y = 0


class DemoSceneError(ValueError):
    pass


def _material(name, color, roughness=0.5, metallic=0.0, texture=None, scale=5.0, color2=(0.05, 0.05, 0.05),
              object_coords=False):
    """Principled material; ``texture`` in (None, 'checker', 'noise', 'wave') drives the base colour.

    ``object_coords``: the texture reads object coordinates (metres, for meshes built in place) instead of
    the default generated ones (the object's box stretched to 0..1, which distorts long walls).
    """
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
        if object_coords:
            coords = nodes.new("ShaderNodeTexCoord")
            links.new(coords.outputs["Object"], tex.inputs["Vector"])
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
    _sun_and_workbench(scene, energy=3.0)


def _sun_and_workbench(scene, energy):
    """The demo scenes' sun, and Workbench shading that looks like a lit render."""
    sun_data = bpy.data.lights.new("Sun", "SUN")
    sun_data.energy = energy
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


def hdri_path() -> str:
    """Path of the studio-light HDRI the ``hdri`` scene shows; DemoSceneError when this Blender lacks it."""
    folder = os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world")
    path = os.path.join(folder, HDRI_NAME)
    if not os.path.isfile(path):
        have = sorted(f for f in os.listdir(folder) if f.endswith(".exr")) if os.path.isdir(folder) else []
        raise DemoSceneError(f"demo scene 'hdri' needs Blender's studio-light world {HDRI_NAME!r}, which is not at "
                             f"{path} (this Blender has: {', '.join(have) or 'none'}); "
                             "use a Blender or bpy that ships its studio lights")
    return path


def _hdri_world(scene, path, strength=1.0):
    """A world showing the HDRI (Environment Texture -> Background), a weak sun for crisper shadows."""
    world = bpy.data.worlds.new("NeRF Demo HDRI")
    if world.node_tree is None:
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    bg = next(n for n in nodes if n.type == "BACKGROUND")
    bg.inputs["Strength"].default_value = strength
    env = nodes.new("ShaderNodeTexEnvironment")
    env.name = env.label = "HDRI"
    image = bpy.data.images.load(path, check_existing=True)
    image.pack()  # the .blend stays self-contained when opened by another Blender install
    env.image = image
    links.new(env.outputs["Color"], bg.inputs["Color"])
    world.color = (0.3, 0.35, 0.3)  # Workbench and the viewport's solid mode
    scene.world = world
    _sun_and_workbench(scene, energy=1.0)


def _mesh(scene, name, verts, faces, material):
    """A mesh object built in place (identity transform: object coordinates are world coordinates)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], faces)
    me.update()
    me.materials.append(material)
    obj = bpy.data.objects.new(name, me)
    scene.collection.objects.link(obj)
    return obj


def _box_geometry(boxes):
    """Vertices and outward quads of axis-aligned boxes given as ((x0, y0, z0), (x1, y1, z1))."""
    verts, faces = [], []
    for lo, hi in boxes:
        base = len(verts)
        verts += [((hi if i & 1 else lo)[0], (hi if i & 2 else lo)[1], (hi if i & 4 else lo)[2]) for i in range(8)]
        faces += [tuple(base + k for k in f) for f in
                  ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5))]
    return verts, faces


def _boxes(scene, name, material, boxes):
    return _mesh(scene, name, *_box_geometry(boxes), material)


def _contrast(material, lo=0.38, hi=0.62):
    """Squeeze a textured material's colour ramp so the noise shows both colours, not their grey mix."""
    ramp = next(n for n in material.node_tree.nodes if n.type == "VALTORGB")
    ramp.color_ramp.elements[0].position, ramp.color_ramp.elements[1].position = lo, hi


def _build_hdri(scene, mesh):
    _add(mesh.primitive_cylinder_add, "Platform",
         _material("Stone", (0.55, 0.52, 0.48), roughness=0.7, texture="wave", scale=1.2, color2=(0.25, 0.23, 0.21)),
         radius=1.4, depth=0.1, vertices=64, location=(0, 0, -1.25))
    _add(mesh.primitive_cylinder_add, "Pedestal", _material("Pedestal", (0.7, 0.7, 0.68), roughness=0.6),
         radius=0.4, depth=0.75, vertices=48, location=(-0.35, 0.3, -0.825))
    sphere = _add(mesh.primitive_uv_sphere_add, "Sphere",
                  _material("Textured", (0.85, 0.45, 0.1), roughness=0.45, texture="noise", scale=4.0,
                            color2=(0.1, 0.25, 0.65)),
                  radius=0.6, location=(-0.35, 0.3, 0.15), segments=48, ring_count=24)
    _smooth(sphere)
    _contrast(sphere.data.materials[0])
    _add(mesh.primitive_cube_add, "Checker cube",
         _material("Checker", (0.9, 0.9, 0.85), roughness=0.6, texture="checker", scale=6.0, color2=(0.7, 0.08, 0.08)),
         size=0.7, location=(0.75, -0.5, -0.85), rotation=(0, 0, math.radians(25)))


def _build_interior(scene):
    sx, sy, sz = ROOM_SIZE[0] / 2, ROOM_SIZE[1] / 2, ROOM_SIZE[2]
    # The shell: six inward-facing quads whose textures read world metres.
    floor = _material("Floor tiles", (0.62, 0.48, 0.32), roughness=0.6, texture="checker", scale=2.0,
                      color2=(0.32, 0.22, 0.14), object_coords=True)
    wall_a = _material("Plaster green", (0.5, 0.62, 0.42), roughness=0.9, texture="noise", scale=1.2,
                       color2=(0.22, 0.32, 0.2), object_coords=True)
    _contrast(wall_a)
    wall_b = _material("Plaster blue", (0.5, 0.55, 0.7), roughness=0.9, texture="wave", scale=0.6,
                       color2=(0.25, 0.3, 0.48), object_coords=True)
    ceiling = _material("Ceiling", (0.7, 0.69, 0.66), roughness=0.9, texture="noise", scale=0.8,
                        color2=(0.5, 0.49, 0.46), object_coords=True)
    x0, x1, y0, y1, z0, z1 = -sx, sx, -sy, sy, 0.0, sz
    _mesh(scene, "Floor", [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)], [(0, 1, 2, 3)], floor)
    _mesh(scene, "Ceiling", [(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)], [(0, 1, 2, 3)], ceiling)
    _mesh(scene, "Wall -X", [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)], [(0, 1, 2, 3)], wall_a)
    _mesh(scene, "Wall +X", [(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)], [(0, 1, 2, 3)], wall_a)
    _mesh(scene, "Wall -Y", [(x0, y0, z0), (x0, y0, z1), (x1, y0, z1), (x1, y0, z0)], [(0, 1, 2, 3)], wall_b)
    _mesh(scene, "Wall +Y", [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)], [(0, 1, 2, 3)], wall_b)
    # Furniture along the walls and in the corners; the middle stays open for the cameras.
    wood = _material("Wood", (0.5, 0.3, 0.14), roughness=0.55, texture="wave", scale=6.0, color2=(0.3, 0.16, 0.07))
    _boxes(scene, "Table", wood, [((-2.1, 0.9, 0.72), (-0.7, 1.7, 0.77))] + [
        ((x, y, 0.0), (x + 0.06, y + 0.06, 0.72)) for x in (-2.05, -0.81) for y in (0.95, 1.59)])
    seat = _material("Chair red", (0.7, 0.12, 0.1), roughness=0.7)
    for k, cx in enumerate((-1.75, -1.05)):  # two chairs facing the table, backs towards the room
        cy = 0.45
        legs = [((cx + dx, cy + dy, 0.0), (cx + dx + 0.04, cy + dy + 0.04, 0.45))
                for dx in (-0.2, 0.16) for dy in (-0.2, 0.16)]
        _boxes(scene, f"Chair {k}", seat, legs + [((cx - 0.22, cy - 0.22, 0.45), (cx + 0.22, cy + 0.22, 0.5)),
                                                  ((cx - 0.22, cy - 0.22, 0.5), (cx + 0.22, cy - 0.18, 0.95))])
    shelf_mat = _material("Shelf", (0.82, 0.8, 0.74), roughness=0.6)
    sx0, sx1, sy0, sy1 = 0.6, 2.2, y0 + 0.02, y0 + 0.4
    _boxes(scene, "Shelf", shelf_mat, [((sx0, sy0, 0.0), (sx0 + 0.04, sy1, 2.0)),
                                       ((sx1 - 0.04, sy0, 0.0), (sx1, sy1, 2.0))]
           + [((sx0, sy0, z), (sx1, sy1, z + 0.03)) for z in (0.05, 0.55, 1.05, 1.55, 1.97)])
    book_colours = [(0.75, 0.15, 0.1), (0.1, 0.35, 0.7), (0.9, 0.7, 0.1), (0.15, 0.55, 0.25), (0.5, 0.2, 0.6)]
    for k, colour in enumerate(book_colours):
        z = (0.08, 0.58, 1.08, 1.58)[k % 4]
        x = sx0 + 0.1 + 0.27 * k
        _boxes(scene, f"Books {k}", _material(f"Books {k}", colour, roughness=0.7),
               [((x, sy0 + 0.05, z), (x + 0.22, sy1 - 0.05, z + 0.3 + 0.03 * (k % 3)))])
    crate = _material("Crate", (0.7, 0.55, 0.3), roughness=0.8, texture="checker", scale=3.0, color2=(0.45, 0.32, 0.15))
    _boxes(scene, "Crate low", crate, [((x1 - 0.75, y1 - 0.75, 0.0), (x1 - 0.1, y1 - 0.1, 0.65))])
    _add(bpy.ops.mesh.primitive_cube_add, "Crate top", crate, size=0.45,
         location=(x1 - 0.42, y1 - 0.45, 0.65 + 0.225), rotation=(0, 0, math.radians(20)))
    ball = _add(bpy.ops.mesh.primitive_uv_sphere_add, "Ball",
                _material("Ball", (0.15, 0.45, 0.85), roughness=0.4, texture="noise", scale=6.0,
                          color2=(0.9, 0.9, 0.9)),
                radius=0.18, location=(-1.2, 1.3, 0.77 + 0.18), segments=32, ring_count=16)
    _smooth(ball)
    rug = _material("Rug", (0.65, 0.15, 0.2), roughness=0.95, texture="wave", scale=3.0, color2=(0.9, 0.8, 0.55),
                    object_coords=True)
    _mesh(scene, "Rug", [(-1.0, -1.3, 0.005), (1.4, -1.3, 0.005), (1.4, 0.3, 0.005), (-1.0, 0.3, 0.005)],
          [(0, 1, 2, 3)], rug)
    painting = _material("Painting", (0.95, 0.75, 0.2), roughness=0.5, texture="noise", scale=3.0,
                         color2=(0.1, 0.2, 0.5), object_coords=True)
    _contrast(painting)
    _mesh(scene, "Painting", [(x1 - 0.01, -1.0, 1.1), (x1 - 0.01, -1.0, 2.1), (x1 - 0.01, 0.6, 2.1),
                              (x1 - 0.01, 0.6, 1.1)],
          [(0, 1, 2, 3)], painting)
    # A floor lamp in a corner: a pole and a glowing shade.
    lamp_x, lamp_y = x0 + 0.45, y0 + 0.45
    _add(bpy.ops.mesh.primitive_cylinder_add, "Lamp pole", _material("Lamp metal", (0.2, 0.2, 0.2), roughness=0.4,
                                                                       metallic=1.0),
         radius=0.025, depth=1.5, vertices=16, location=(lamp_x, lamp_y, 0.75))
    glow = _material("Lamp shade", (1.0, 0.85, 0.6), roughness=0.8)
    bsdf = next(n for n in glow.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Emission Color"].default_value = (1.0, 0.8, 0.55, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 6.0
    shade = _add(bpy.ops.mesh.primitive_uv_sphere_add, "Lamp shade", glow, radius=0.2,
                 location=(lamp_x, lamp_y, 1.65), segments=32, ring_count=16)
    _smooth(shade)


def _room_lights(scene):
    """Area lights under the ceiling; a dark world (it cannot be seen from inside the closed room)."""
    world = bpy.data.worlds.new("NeRF Demo Room World")
    if world.node_tree is None:
        world.use_nodes = True
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (0.05, 0.05, 0.05, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    world.color = (0.05, 0.05, 0.05)
    scene.world = world
    top = ROOM_SIZE[2] - 0.05
    for name, (x, y), size, energy in (("Ceiling light", (0.3, 0.0), (2.0, 1.4), 150.0),
                                       ("Fill light", (-1.6, 1.2), (0.8, 0.8), 40.0)):
        data = bpy.data.lights.new(name, "AREA")
        data.shape = "RECTANGLE"
        data.size, data.size_y = size
        data.energy = energy
        obj = bpy.data.objects.new(name, data)
        scene.collection.objects.link(obj)
        obj.location = (x, y, top)  # area lights shine along their local -Z: down
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "MATERIAL"


def build(name: str, scene=None):
    """Replace the objects of ``scene`` (default: current) with demo scene ``name``; returns the scene."""
    if name not in SCENES:
        raise DemoSceneError(f"unknown demo scene {name!r}; choose one of {', '.join(SCENES)}")
    scene = scene or bpy.context.scene
    hdri = hdri_path() if name == "hdri" else None  # before clearing: a missing file leaves the scene alone
    _clear_scene(scene)
    mesh = bpy.ops.mesh
    if name == "cube":
        _add(mesh.primitive_cube_add, "Cube", _material("Flat red", (0.8, 0.1, 0.1), roughness=1.0), size=1.5)
    elif name == "diffuse":
        mat = _material("Textured", (0.8, 0.5, 0.15), roughness=0.9, texture="noise", scale=4.0,
                        color2=(0.1, 0.25, 0.6))
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
            (mesh.primitive_cone_add, "Cone", (0.2, 0.3, 0.85), dict(radius1=0.5, depth=1.0,
                                                                     location=(0.6, 0.7, -0.5))),
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
    elif name == "hdri":
        _build_hdri(scene, mesh)
    elif name == "interior":
        _build_interior(scene)
    elif name == "ground":
        # The floor dwarfs the subject: the capture frames the figure and leaves the floor out of the
        # scene box (``scene_bounds.subject_bounds``), and train models it beyond the box (``beyond_box``).
        figure = _add(mesh.primitive_monkey_add, "Suzanne", _material("Figure", (0.8, 0.35, 0.12), roughness=0.5),
                      size=1.2, location=(-0.3, 0, 0.6), rotation=(0, 0, math.radians(-20)))
        _smooth(figure)
        _add(mesh.primitive_cube_add, "Box", _material("Box", (0.2, 0.45, 0.8), roughness=0.6, texture="checker",
                                                      scale=4.0, color2=(0.9, 0.9, 0.9)),
             size=0.6, location=(0.7, 0.3, 0.3), rotation=(0, 0, math.radians(30)))
        _add(mesh.primitive_plane_add, "Ground", _material("Ground", (0.8, 0.8, 0.78), roughness=0.9,
                                                           texture="checker", scale=100.0, color2=(0.2, 0.2, 0.2)),
             size=100.0)
    if name == "hdri":
        _hdri_world(scene, hdri)
        scene.render.film_transparent = False  # the world is part of the picture
    elif name == "interior":
        _room_lights(scene)
        scene.render.film_transparent = False
    elif name == "ground":
        _lights_and_world(scene)
        scene.render.film_transparent = False  # the sky and the floor's horizon are part of the picture
    else:
        _lights_and_world(scene)
    for obj in scene.objects:
        obj.select_set(False)
    scene.frame_set(1)
    return scene
