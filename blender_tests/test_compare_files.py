"""Compare .blend files you can look through: view cameras (addon/compare/view_cameras.py), the gallery's
place and camera (addon/compare/gallery_frame.py) and how images are kept (addon/compare/image_storage.py)."""
from __future__ import annotations

import os
import shutil

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from addon.dataset import cameras
from addon.compare import gallery_frame, image_storage, planes, view_cameras
from test_planes import fake_render

INTRINSICS = [
    {"fx": 50.0, "fy": 50.0, "cx": 23.5, "cy": 12.0, "w": 40, "h": 30},  # shifted principal point
    {"fx": 80.0, "fy": 60.0, "cx": 20.0, "cy": 15.0, "w": 40, "h": 30},  # non-square pixels, fx > fy
    {"fx": 30.0, "fy": 45.0, "cx": 11.0, "cy": 33.0, "w": 24, "h": 60},  # portrait, fy > fx
    {"fx": 2.0, "fy": 2.0, "cx": 50.0, "cy": 50.0, "w": 100, "h": 100},  # ~175 degrees: the sensor moves
]


@pytest.mark.parametrize("intr", INTRINSICS)
def test_camera_params_invert_the_capture_intrinsics_rule(intr):
    p = view_cameras.camera_params(intr)
    back = cameras.intrinsics_from_params(p["lens"], p["sensor_width"], p["sensor_height"], p["sensor_fit"],
                                         p["shift_x"], p["shift_y"], p["res_x"], p["res_y"],
                                         p["pixel_aspect_x"], p["pixel_aspect_y"])
    got = [back[k] for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")]
    assert got == pytest.approx([intr[k] for k in ("fx", "fy", "cx", "cy", "w", "h")], rel=1e-9, abs=1e-9)
    assert min(p["pixel_aspect_x"], p["pixel_aspect_y"]) == 1.0 and 1.0 <= p["lens"] <= 5000.0


def test_camera_params_refuse_what_blender_cannot_hold():
    with pytest.raises(ValueError, match="whole number of pixels"):
        view_cameras.camera_params({"fx": 10, "fy": 10, "cx": 5, "cy": 5, "w": 10.5, "h": 10})
    with pytest.raises(ValueError, match="outside what a Blender camera can hold"):
        view_cameras.camera_params({"fx": 0.001, "fy": 0.001, "cx": 50, "cy": 50, "w": 100, "h": 100})


def corners_through(scene, cam, ob):
    """(ndc x, ndc y, uv) of each plane vertex seen through ``cam``: ndc 0..1 spans the frame."""
    uv = ob.data.uv_layers.active.data
    out = []
    for loop in ob.data.loops:
        ndc = world_to_camera_view(scene, cam, ob.matrix_world @ ob.data.vertices[loop.vertex_index].co)
        out.append((ndc.x, ndc.y, ndc.z, tuple(uv[loop.index].uv)))
    return out


@pytest.mark.parametrize("intr", INTRINSICS[:3])
def test_looking_through_camera_k_puts_plane_k_exactly_over_the_frame(tmp_path, intr):
    render, cams = fake_render(tmp_path, n=3, intr={"fl_x": intr["fx"], "fl_y": intr["fy"], "cx": intr["cx"],
                                                    "cy": intr["cy"], "w": intr["w"], "h": intr["h"]})
    # fake_render writes 40x30 images; declare the views' own size so the planes' aspect is theirs
    views = planes.views_from_render(render, cams)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080  # the user's scene: anything
    obs = planes.import_camera_aligned(views, [2.0, 3.5, 5.0], scene=scene, set_scene_camera=True)
    assert (scene.render.resolution_x, scene.render.resolution_y) == (intr["w"], intr["h"])
    assert scene.render.resolution_percentage == 100
    assert scene.camera is obs[0].parent and scene.camera.name == "NeRF Cam r_0"
    cam_coll = bpy.data.collections[planes.VIEW_CAMERAS_COLLECTION]
    assert cam_coll.name in bpy.data.collections[planes.VIEWS_COLLECTION].children
    assert sorted(o.name for o in cam_coll.objects) == ["NeRF Cam r_0", "NeRF Cam r_1", "NeRF Cam r_2"]
    for ob, view in zip(obs, views):
        cam = ob.parent
        assert cam.type == "CAMERA" and ob["nerf_camera"] == cam.name and cam["nerf_view"] == view.name
        assert [x for r in cam.matrix_world for x in r] == pytest.approx(sum(view.c2w, []), abs=1e-6)
        for x, y, z, (u, v) in corners_through(scene, cam, ob):
            assert u in (0.0, 1.0) and v in (0.0, 1.0)  # each vertex shows one image corner
            assert (x, y) == pytest.approx((u, v), abs=1e-4) and z > 0
        # and through any other camera it is not over the frame (the test can fail)
        other = obs[(obs.index(ob) + 1) % len(obs)].parent
        assert max(abs(x - u) + abs(y - v) for x, y, _, (u, v) in corners_through(scene, other, ob)) > 0.05


def test_moving_a_view_camera_carries_its_plane(tmp_path):
    render, cams = fake_render(tmp_path)
    ob = planes.import_camera_aligned(planes.views_from_render(render, cams), 2.0, set_scene_camera=True)[0]
    cam = ob.parent
    cam.location.x += 1.5
    cam.rotation_euler.z += 0.3
    bpy.context.view_layer.update()
    for x, y, _, (u, v) in corners_through(bpy.context.scene, cam, ob):
        assert (x, y) == pytest.approx((u, v), abs=1e-4)


def demo_like_scene():
    """A cube and a sphere around the origin, like the demo scene, and a floor."""
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-0.6, 0.0, 0.5))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.7, 0.2, 0.6))
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    return gallery_frame.bounds([o for o in bpy.context.scene.objects])


def gallery_corners(scene, cam, objects):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for ob in objects:
        ev = ob.evaluated_get(depsgraph)
        for corner in ev.bound_box:
            yield ob.name, world_to_camera_view(scene, cam, ev.matrix_world @ Vector(corner))


@pytest.mark.parametrize("set_scene_camera", [True, False])
def test_gallery_stands_clear_of_the_scene_and_its_camera_frames_all_of_it(tmp_path, set_scene_camera):
    scene_box = demo_like_scene()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
    render, cams = fake_render(tmp_path, n=3)
    planes.import_gallery(planes.views_from_render(render, cams), scene=scene, set_scene_camera=set_scene_camera)
    coll = bpy.data.collections[planes.GALLERY_COLLECTION]
    cam = bpy.data.objects[planes.GALLERY_CAMERA]
    shown = [o for o in coll.objects if o.type in ("MESH", "FONT")]
    names = {o.name for o in shown}
    assert {"Gallery NeRF", "Gallery Blender", "Gallery |error|", "Gallery NeRF r_0", "Gallery Error r_2",
            "Label r_2"} <= names and len(shown) == 3 + 3 * 3 + 3
    box = gallery_frame.bounds(shown)
    assert not gallery_frame.boxes_overlap(box, scene_box)
    assert box[0].x > scene_box[1].x  # beside it, to the right
    assert gallery_frame.bounds([o for o in scene.objects if o not in set(coll.objects)]) == scene_box  # untouched
    assert cam.data.type == "ORTHO" and cam.users_collection[0] == coll
    assert (scene.camera == cam) == set_scene_camera
    if set_scene_camera:  # the gallery's aspect, a tile at its rendered height (30 px per row)
        r = scene.render
        assert r.resolution_y == pytest.approx((box[1].z - box[0].z) * 1.08 * 30, abs=1.5)
        assert r.resolution_x / r.resolution_y == pytest.approx((box[1].x - box[0].x) / (box[1].z - box[0].z), rel=0.05)
    xs, ys = [], []
    for name, ndc in gallery_corners(scene, cam, shown):
        assert 0.0 < ndc.x < 1.0 and 0.0 < ndc.y < 1.0 and ndc.z > cam.data.clip_start, name
        xs.append(ndc.x)
        ys.append(ndc.y)
    assert max(xs) - min(xs) > 0.85 or max(ys) - min(ys) > 0.85  # framed, not a speck
    # nothing of the scene lies inside the camera's view when the frame has the gallery's aspect
    if set_scene_camera:
        for ob in scene.objects:
            if ob not in set(coll.objects) and ob.type == "MESH":
                for corner in ob.bound_box:
                    ndc = world_to_camera_view(scene, cam, ob.matrix_world @ Vector(corner))
                    assert not (0 <= ndc.x <= 1 and 0 <= ndc.y <= 1), ob.name


def test_an_empty_scene_keeps_the_gallery_at_the_origin(tmp_path):
    render, cams = fake_render(tmp_path)
    planes.import_gallery(planes.views_from_render(render, cams))
    nerf = bpy.data.objects["Gallery NeRF r_0"]
    assert nerf.matrix_world.translation.x == pytest.approx(40 / 30 / 2)  # first column's centre at x = 0 + w/2


def saved_compare(tmp_path, mode):
    """What scripts/import_views.py does: import into a saved scene, store images, save a copy elsewhere.
    Returns (compare .blend, render folder, {image name: pixels})."""
    (tmp_path / "scenes").mkdir()
    scene_file = str(tmp_path / "scenes" / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=scene_file)
    render, cams = fake_render(tmp_path)
    views = planes.views_from_render(render, cams)
    made = planes.import_camera_aligned(views, 2.0, set_scene_camera=True)
    images = image_storage.plane_images(made)
    pixels = {img.name: np.array(img.pixels[:]) for img in images}
    assert len(pixels) == 2
    assert image_storage.store(images, mode) == ""
    out = str(tmp_path / "out" / "compare.blend")
    os.makedirs(os.path.dirname(out))
    bpy.ops.wm.save_as_mainfile(filepath=out, copy=True, relative_remap=True)
    return out, render, pixels


def test_packed_images_survive_the_run_folder_moving(tmp_path):
    out, render, pixels = saved_compare(tmp_path, "pack")
    os.rename(render, render + "_moved")  # the run folder is renamed after the file was written
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=out)
    for name, want in pixels.items():
        img = bpy.data.images[name]
        assert img.packed_file is not None and not os.path.exists(bpy.path.abspath(img.filepath))
        assert np.array(img.pixels[:]) == pytest.approx(want, abs=1e-6)
    assert bpy.context.scene.camera.name == "NeRF Cam r_0"


def test_relative_paths_start_at_the_compare_file_and_move_with_it(tmp_path):
    out, render, pixels = saved_compare(tmp_path, "relative")
    bpy.ops.wm.open_mainfile(filepath=out)
    for name in pixels:
        img = bpy.data.images[name]
        assert img.packed_file is None and img.filepath.startswith("//../render/")
        assert os.path.samefile(bpy.path.abspath(img.filepath), os.path.join(render, f"{name}"))
    # moving the compare file and the render together keeps the images; the original place is gone
    moved = tmp_path.parent / (tmp_path.name + "_moved")
    shutil.move(str(tmp_path), str(moved))
    bpy.ops.wm.open_mainfile(filepath=str(moved / "out" / "compare.blend"))
    for name, want in pixels.items():
        img = bpy.data.images[name]
        assert bpy.path.abspath(img.filepath).startswith(str(moved))
        assert np.array(img.pixels[:]) == pytest.approx(want, abs=1e-6)


def test_absolute_paths_and_unknown_modes(tmp_path):
    render, cams = fake_render(tmp_path)
    made = planes.import_camera_aligned(planes.views_from_render(render, cams), 2.0)
    images = image_storage.plane_images(made)
    assert image_storage.store(images, "absolute") == ""
    assert all(os.path.isabs(img.filepath) and img.packed_file is None for img in images)
    # an unsaved .blend has no folder for relative paths: they stay absolute and the note says why
    assert "not saved yet" in image_storage.store(images, "relative")
    assert all(os.path.isabs(img.filepath) for img in images)
    with pytest.raises(ValueError, match="choose one of pack, relative, absolute"):
        image_storage.store(images, "zip")


def test_the_compare_panel_leaves_the_users_camera_and_images_alone(tmp_path):
    from addon.compare import compare_views as compare
    from addon import train

    train.register()
    try:
        scene = bpy.context.scene
        mine = bpy.data.objects.new("My Camera", bpy.data.cameras.new("My Camera"))
        scene.collection.objects.link(mine)
        scene.camera = mine
        scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
        render, cams = fake_render(tmp_path)
        # a user's own textured plane inside the gallery collection keeps its image on disk
        shutil.copy(os.path.join(render, "r_1.png"), tmp_path / "mine.png")
        user_img = bpy.data.images.load(str(tmp_path / "mine.png"), check_existing=False)
        mat = bpy.data.materials.new("user")
        mat.node_tree.nodes.new("ShaderNodeTexImage").image = user_img
        bpy.ops.mesh.primitive_plane_add()
        user_plane = bpy.context.object
        user_plane.data.materials.append(mat)
        gallery = planes.ensure_collection(planes.GALLERY_COLLECTION, scene)
        for coll in list(user_plane.users_collection):
            coll.objects.unlink(user_plane)
        gallery.objects.link(user_plane)
        views = planes.views_from_render(render, cams)
        assert scene.nerf_train.image_storage == "PACK"
        assert compare.import_views(scene, views, "GALLERY", render, str(tmp_path / "run")) == ""
        assert compare.import_views(scene, views, "CAMERA", render, str(tmp_path / "run"), 2.0) == ""
        assert scene.camera == mine and (scene.render.resolution_x, scene.render.resolution_y) == (1920, 1080)
        assert user_img.packed_file is None
        shown = [o for o in gallery.objects if o.get(planes.TAG) and o.type == "MESH"]
        assert len(shown) == 6 and all(i.packed_file is not None for i in image_storage.plane_images(shown))
        scene.nerf_train.image_storage = "RELATIVE"  # an unsaved .blend: the note says why paths stay absolute
        note = compare.import_views(scene, views, "CAMERA", render, str(tmp_path / "run"), 2.0)
        assert "not saved yet" in note
    finally:
        train.unregister()
