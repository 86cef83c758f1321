"""Geometry back into Blender: the volume round trip (npz -> .vdb -> Volume object -> grids back,
equal) and the mesh import, each in its own collection and in the scene's frame."""
import json
import os

import bpy
import numpy as np
import pytest

from addon.compare import geometry_import, volume_files


def _volume_npz(path, shape=(6, 7, 8)):
    rng = np.random.default_rng(0)
    density = rng.random(shape).astype(np.float32) * 50
    density[density < 20] = 0.0  # empty space, as a real volume has
    color = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    box = np.array([[-1.0, -0.5, 0.25], [1.0, 1.5, 2.0]])
    spacing = (box[1] - box[0]) / (np.array(shape) - 1)
    np.savez(path, density=density, color=color, box=box, spacing=spacing, level=np.float64(3.0),
             format=np.str_("nerf_bridge.volume"), version=np.int64(1))
    return density, color, box, spacing


def test_volume_round_trip_gives_the_grids_back_equal_in_the_scene_frame(tmp_path):
    npz = str(tmp_path / "volume.npz")
    density, color, box, spacing = _volume_npz(npz)
    obj = geometry_import.import_volume(bpy.context.scene, npz)
    assert obj.type == "VOLUME" and obj.users_collection[0].name == geometry_import.VOLUME_COLLECTION
    assert np.allclose(np.array(obj.matrix_world), np.eye(4))  # the scene frame: no transform of its own
    vol = obj.data
    assert os.path.isfile(bpy.path.abspath(vol.filepath))
    grids = {g.name: g for g in vol.grids}
    assert set(grids) == {"density", "color"}
    assert grids["density"].data_type == "FLOAT" and grids["color"].data_type == "VECTOR_FLOAT"
    m = np.array(grids["density"].matrix_object)  # index -> object space, as Blender read it
    assert np.allclose(m[:3, :3], np.diag(spacing), atol=1e-6) and np.allclose(m[:3, 3], box[0], atol=1e-6)
    back = volume_files.read_vdb(bpy.path.abspath(vol.filepath), density.shape, geometry_import.openvdb_dirs())
    assert np.array_equal(back["density"], density)
    assert np.allclose(back["color"], volume_files.srgb_to_linear(color / 255.0), atol=1e-6)
    restored = np.rint(volume_files.linear_to_srgb(back["color"]) * 255).astype(np.uint8)
    assert np.array_equal(restored, color)
    assert np.allclose(back["density_origin"], box[0]) and np.allclose(back["density_step"], spacing)
    # the material renders it as the NeRF does: absorption and emission, both from the density grid
    nodes = obj.data.materials[0].node_tree.nodes
    assert {n.type for n in nodes} >= {"VOLUME_ABSORPTION", "EMISSION", "ADD_SHADER", "ATTRIBUTE"}


def test_a_file_that_is_not_a_volume_export_is_refused(tmp_path):
    bad = tmp_path / "x.npz"
    np.savez(bad, a=np.zeros(3))
    with pytest.raises(volume_files.VolumeFileError, match="not a volume file"):
        geometry_import.import_volume(bpy.context.scene, str(bad))
    assert not (tmp_path / "x.vdb").exists()


def test_mesh_import_keeps_positions_and_colours_in_its_collection(tmp_path):
    from nerf_core.export.ply import write_mesh_ply

    v = np.array([[0.5, 1.0, 2.0], [1.5, 1.0, 2.0], [0.5, 2.0, 2.5]])
    c = np.array([[255, 0, 0], [0, 128, 0], [0, 0, 255]], dtype=np.uint8)
    write_mesh_ply(tmp_path / "m.ply", v, np.array([[0, 1, 2]]), c)
    obj = geometry_import.import_mesh(bpy.context.scene, str(tmp_path / "m.ply"))
    assert obj.users_collection[0].name == geometry_import.MESH_COLLECTION
    world = np.array([np.array(obj.matrix_world) @ [*p.co, 1.0] for p in obj.data.vertices])[:, :3]
    assert np.allclose(world, v, atol=1e-6)
    col = np.array([d.color for d in obj.data.color_attributes["Col"].data])[:, :3]
    assert np.allclose(col, volume_files.srgb_to_linear(c / 255.0), atol=2e-3)  # read as sRGB, stored linear
    assert obj.active_material is not None


def _through_view(scene, linear, path):
    """(m, 3) scene-linear colours as ``scene``'s colour management shows them: (m, 3) display values."""
    from PIL import Image

    img = bpy.data.images.new("lin", len(linear), 1, float_buffer=True, alpha=True)
    px = np.ones((len(linear), 4), np.float32)
    px[:, :3] = linear
    img.pixels.foreach_set(px.ravel())
    scene.render.image_settings.file_format = "PNG"
    img.save_render(path, scene=scene)
    bpy.data.images.remove(img)
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64).reshape(-1, 3) / 255.0


def test_volume_colours_undo_the_captures_view_transform(tmp_path):
    """A capture rendered under AgX: the volume's colours, shown through AgX, are the NeRF's colours
    again (the sRGB curve alone is off by up to a fifth of the range), and a scene that shows another
    view transform is told so."""
    scene = bpy.context.scene
    scene.view_settings.view_transform, scene.view_settings.look = "AgX", "None"
    rng = np.random.default_rng(1)
    linear = np.concatenate([rng.random((300, 3)) ** 2 * 2, np.linspace(0, 1.5, 40)[:, None].repeat(3, 1)])
    display = np.rint(_through_view(scene, linear, str(tmp_path / "fwd.png")) * 255).astype(np.uint8)
    shape = (len(display), 1, 1)
    npz = str(tmp_path / "volume.npz")
    cm = {"display_device": "sRGB", "view_transform": "AgX", "look": "None", "exposure": 0.0, "gamma": 1.0}
    np.savez(npz, density=np.ones(shape, np.float32), color=display.reshape(shape + (3,)),
             box=np.array([[0.0, 0, 0], [1.0, 1, 1]]), spacing=np.ones(3), level=np.float64(1.0),
             format=np.str_("nerf_bridge.volume"), version=np.int64(1), color_management=np.str_(json.dumps(cm)))
    scene.cycles.volume_biased = True  # else the import turns it on and says so (below)
    obj = geometry_import.import_volume(scene, npz)
    assert obj[geometry_import.NOTES_PROPERTY] == ""  # the scene shows what the capture was rendered with
    back = volume_files.read_vdb(bpy.path.abspath(obj.data.filepath), shape, geometry_import.openvdb_dirs())
    shown = _through_view(scene, back["color"].reshape(-1, 3), str(tmp_path / "back.png"))
    assert np.abs(shown - display / 255.0).max() <= 2.5 / 255
    srgb = _through_view(scene, volume_files.srgb_to_linear(display / 255.0), str(tmp_path / "srgb.png"))
    assert np.abs(srgb - display / 255.0).max() > 0.1  # what the sRGB curve alone gave
    scene.view_settings.view_transform = "Standard"
    scene.cycles.volume_biased = False
    other = geometry_import.import_volume(scene, npz, str(tmp_path / "other.vdb"))
    assert "'AgX'" in other[geometry_import.NOTES_PROPERTY] and "'Standard'" in other[geometry_import.NOTES_PROPERTY]
    assert geometry_import.BIASED_NOTE in other[geometry_import.NOTES_PROPERTY] and scene.cycles.volume_biased


def test_a_view_transform_without_an_inverse_or_a_look_is_noted():
    from addon.compare import display_colours

    scene = bpy.context.scene
    base = {"display_device": "sRGB", "look": "None", "exposure": 0.0, "gamma": 1.0}
    to_linear, notes = display_colours.to_linear_for({**base, "view_transform": "False Color"}, scene)
    assert any("cannot be undone" in n and "'False Color'" in n for n in notes)
    grey = np.full((1, 3), 0.5, np.float32)
    assert np.allclose(to_linear(grey), volume_files.srgb_to_linear(grey), atol=1e-6)  # taken as sRGB
    _, notes = display_colours.to_linear_for({**base, "view_transform": "AgX", "look": "AgX - Punchy"}, scene)
    assert any("look 'AgX - Punchy' is not undone" in n for n in notes)
    to_linear, notes = display_colours.to_linear_for({}, scene)
    assert any("records no colour management" in n for n in notes)
    # exposure and gamma are undone: display = view(linear * 2^e) ^ (1 / g)
    to_linear, _ = display_colours.to_linear_for({**base, "view_transform": "Standard", "exposure": 1.0,
                                                  "gamma": 2.0}, scene)
    assert np.allclose(to_linear(grey), volume_files.srgb_to_linear(grey ** 2) / 2, atol=1e-6)


def _render_blocks(scene, npz, path):
    """Cycles' render, from above, of the volume of ``npz`` (2 x 2 blocks of colour over [0, 1]^2):
    the display values at the blocks' centres (4, 3)."""
    from mathutils import Matrix
    from PIL import Image

    geometry_import.import_volume(scene, npz, path + ".vdb")
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type, cam.data.ortho_scale = "ORTHO", 1.0
    cam.matrix_world = Matrix.Translation((0.5, 0.5, 3.0))
    scene.camera = cam
    scene.render.engine, scene.cycles.device, scene.cycles.samples = "CYCLES", "CPU", 16
    scene.cycles.use_denoising, scene.render.film_transparent = False, True
    scene.render.resolution_x = scene.render.resolution_y = 24
    scene.render.resolution_percentage, scene.render.threads_mode, scene.render.threads = 100, "FIXED", 1
    scene.render.image_settings.file_format, scene.render.filepath = "PNG", path + ".png"
    bpy.ops.render.render(write_still=True)
    im = np.asarray(Image.open(path + ".png").convert("RGB"), dtype=np.float64) / 255.0
    return np.array([im[24 - 1 - y, x] for x, y in ((6, 6), (18, 6), (6, 18), (18, 18))])


def test_cycles_shows_an_agx_captures_volume_in_the_nerfs_colours(tmp_path):
    """The whole path, rendered: an opaque volume of four display colours from an AgX capture, in a
    scene under AgX, comes out of Cycles as those colours (the sRGB curve alone is 13/255 off here)."""
    scene = bpy.context.scene
    scene.world = bpy.data.worlds.new("black")
    scene.view_settings.view_transform, scene.view_settings.look = "AgX", "None"
    linear = np.array([[0.02, 0.02, 0.02], [0.6, 0.6, 0.6], [0.5, 0.1, 0.05], [0.05, 0.2, 0.6]])
    display = np.rint(_through_view(scene, linear, str(tmp_path / "fwd.png")) * 255).astype(np.uint8)
    color = np.zeros((12, 12, 3, 3), np.uint8)
    for n, (i, j) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        color[6 * i:6 * i + 6, 6 * j:6 * j + 6] = display[n]
    density = np.full((12, 12, 3), 1000.0, np.float32)
    density[:, :, 2] = 0.0  # the top nodes empty: above them Cycles interpolates towards the grid's black outside
    npz = str(tmp_path / "volume.npz")
    cm = {"display_device": "sRGB", "view_transform": "AgX", "look": "None", "exposure": 0.0, "gamma": 1.0}
    np.savez(npz, density=density, color=color, box=np.array([[0.0, 0, 0], [1.0, 1, 0.2]]),
             spacing=np.array([1 / 11, 1 / 11, 0.1]), level=np.float64(1.0), format=np.str_("nerf_bridge.volume"),
             version=np.int64(1), color_management=np.str_(json.dumps(cm)))
    shown = _render_blocks(scene, npz, str(tmp_path / "agx"))
    assert np.abs(shown - display / 255.0).max() <= 4 / 255
    srgb = _through_view(scene, volume_files.srgb_to_linear(display / 255.0), str(tmp_path / "srgb.png"))
    assert np.abs(srgb - display / 255.0).max() > 0.04  # what the sRGB curve alone gave (0.051)


def _world_png(scene, path, cm):
    """A world file (``export world``'s layout) of smooth colours, rendered through ``scene``'s view as a
    capture's are (so that they lie in its gamut): (h, w, 3) uint8 and its directions (h, w, 3)."""
    from nerf_core.export import world

    w, h = 32, 16
    dirs = world.blender_directions(w).numpy()  # what each pixel centre looks along
    linear = (0.5 + 0.45 * dirs.reshape(-1, 3)) ** 2  # a colour per direction
    image = np.rint(_through_view(scene, linear, path + ".fwd.png") * 255).astype(np.uint8).reshape(h, w, 3)
    world.write_world(path, image, cm)
    return image, dirs


def _look_along(scene, d, path):
    """Cycles' display colour (3,) of the world straight along direction ``d``: a camera of a tiny field
    of view, one pixel filter's width."""
    from mathutils import Matrix
    from PIL import Image

    cam = scene.camera
    z = -np.asarray(d, float) / np.linalg.norm(d)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, np.cross(z, x), z
    cam.matrix_world = Matrix(m.tolist())
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)[2, 2] / 255.0


def test_the_imported_world_shows_the_nerfs_world_along_each_direction_and_keeps_the_old_one(tmp_path):
    """``export world``'s PNG as the scene's World, under AgX: a camera looking along a pixel's direction
    sees that pixel's colour (Blender's equirectangular layout, the inverse of the capture's AgX), and the
    scene's former world stays in the file."""
    scene = bpy.context.scene
    scene.world = old = bpy.data.worlds.new("Studio")
    scene.view_settings.view_transform, scene.view_settings.look = "AgX", "None"
    cm = {"display_device": "sRGB", "view_transform": "AgX", "look": "None", "exposure": 0.0, "gamma": 1.0}
    png = str(tmp_path / "world_001.png")
    image, dirs = _world_png(scene, png, cm)
    new = geometry_import.import_world(scene, png)
    assert scene.world == new and new.name == geometry_import.WORLD_NAME
    assert old.use_fake_user and "'Studio' is kept" in new[geometry_import.NOTES_PROPERTY]
    assert os.path.isfile(str(tmp_path / "world_001.exr"))
    env = next(n for n in new.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
    assert env.image.is_float and bpy.path.abspath(env.image.filepath) == str(tmp_path / "world_001.exr")
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera, cam.data.angle = cam, 0.002
    scene.render.engine, scene.cycles.device, scene.cycles.samples = "CYCLES", "CPU", 4
    scene.cycles.use_denoising, scene.render.film_transparent = False, False
    scene.render.resolution_x = scene.render.resolution_y = 5
    scene.render.resolution_percentage, scene.render.threads_mode, scene.render.threads = 100, "FIXED", 1
    scene.render.image_settings.file_format = "PNG"
    for i, j in ((3, 0), (3, 8), (8, 16), (8, 24), (12, 5), (5, 29)):
        seen = _look_along(scene, dirs[i, j], str(tmp_path / f"look_{i}_{j}.png"))
        assert np.abs(seen - image[i, j] / 255.0).max() <= 3 / 255, (i, j, seen * 255, image[i, j])
    mirrored = _look_along(scene, dirs[3, 8] * np.array([1, -1, 1]), str(tmp_path / "mirror.png"))
    assert np.abs(mirrored - image[3, 8] / 255.0).max() > 0.05  # the layout is not mirrored
    with pytest.raises(ValueError, match="not a world file"):
        from PIL import Image

        Image.new("RGB", (8, 4)).save(str(tmp_path / "plain.png"))
        geometry_import.import_world(scene, str(tmp_path / "plain.png"))


def test_an_unbounded_runs_far_levels_become_child_volumes_on_their_own_grids(tmp_path):
    npz = str(tmp_path / "volume.npz")
    density, color, box, spacing = _volume_npz(npz)
    arrays = dict(np.load(npz))
    rng = np.random.default_rng(2)
    far_box = np.stack([box.mean(0) - (box[1] - box[0]), box.mean(0) + (box[1] - box[0])])
    far_density = (rng.random((5, 5, 5)) * 30).astype(np.float32)
    far_color = rng.integers(0, 256, (5, 5, 5, 3), dtype=np.uint8)
    np.savez(npz, **arrays, far_levels=np.int64(1), far1_density=far_density, far1_color=far_color,
             far1_box=far_box, far1_spacing=(far_box[1] - far_box[0]) / 4)
    obj = geometry_import.import_volume(bpy.context.scene, npz)
    far = bpy.data.objects["NeRF Volume far 1"]
    assert far.parent == obj and far.users_collection[0].name == geometry_import.VOLUME_COLLECTION
    assert far.data.filepath == obj.data.filepath  # one .vdb, each object reads its own level's grids
    attrs = {n.attribute_name for n in far.data.materials[0].node_tree.nodes if n.type == "ATTRIBUTE"}
    assert attrs == {"density_far1", "color_far1"}
    back = volume_files.read_vdb(bpy.path.abspath(obj.data.filepath),
                                 {"density": density.shape, "density_far1": (5, 5, 5), "color_far1": (5, 5, 5)},
                                 geometry_import.openvdb_dirs())
    assert np.array_equal(back["density"], density) and np.array_equal(back["density_far1"], far_density)
    assert np.allclose(back["density_far1_origin"], far_box[0]) and np.allclose(back["density_far1_step"],
                                                                               (far_box[1] - far_box[0]) / 4)
    assert np.allclose(back["color_far1"], volume_files.srgb_to_linear(far_color / 255.0), atol=1e-6)
    np.savez(npz, **arrays, far_levels=np.int64(2), far1_density=far_density, far1_color=far_color,
             far1_box=far_box, far1_spacing=(far_box[1] - far_box[0]) / 4)
    with pytest.raises(volume_files.VolumeFileError, match="far level 2 of 2 is missing"):
        geometry_import.import_volume(bpy.context.scene, npz, str(tmp_path / "other.vdb"))
