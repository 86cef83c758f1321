"""Camera layouts: counts, elevation ranges, split disjointness, framing, and the camera collection."""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest
from mathutils import Matrix

from addon.dataset import cameras
from addon.capture.layout import positions
from addon.capture.layout import collection, cameras as layout_cameras, notes
from addon.capture.plan.settings import RenderView


def _elevations(points, centre=(0, 0, 0)):
    p = np.asarray(points) - np.asarray(centre)
    return np.degrees(np.arcsin(p[:, 2] / np.linalg.norm(p, axis=1)))


@pytest.mark.parametrize("gen", ["fib", "random", "rings", "spiral"])
def test_generators_count_radius_and_elevation_range(gen):
    centre, radius, elev = (1.0, -2.0, 0.5), 3.0, (10.0, 70.0)
    pts = {
        "fib": lambda: positions.fibonacci_positions(37, radius, centre, elev),
        "random": lambda: positions.random_positions(37, radius, centre, elev, seed=3),
        "rings": lambda: positions.ring_positions(37, radius, centre, elev, rings=4),
        "spiral": lambda: positions.spiral_positions(37, radius, centre, elev, turns=2),
    }[gen]()
    p = np.asarray(pts)
    assert p.shape == (37, 3)
    np.testing.assert_allclose(np.linalg.norm(p - centre, axis=1), radius, rtol=1e-9)
    e = _elevations(pts, centre)
    assert e.min() >= 10.0 - 1e-6 and e.max() <= 70.0 + 1e-6
    # distinct cameras: no two closer than a small fraction of the radius
    d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(37) * 1e9
    assert d.min() > 1e-3 * radius


def test_hemisphere_covers_its_range_evenly():
    e = _elevations(positions.fibonacci_positions(200, 1.0, (0, 0, 0), (0.0, 90.0)))
    assert e.min() < 3 and e.max() > 80  # spans the band
    # equal-area: half the points lie below 30 degrees (sin 30 = 0.5)
    assert abs((e < 30).mean() - 0.5) < 0.02


def test_random_layout_is_reproducible_from_seed():
    a = positions.random_positions(10, 2.0, seed=7)
    assert a == positions.random_positions(10, 2.0, seed=7)
    assert a != positions.random_positions(10, 2.0, seed=8)


def test_rings_use_that_many_elevations():
    e = np.round(_elevations(positions.ring_positions(12, 1.0, (0, 0, 0), (0.0, 60.0), rings=3)), 6)
    assert sorted(set(e)) == [0.0, 30.0, 60.0]


def test_spiral_climbs():
    e = _elevations(positions.spiral_positions(20, 1.0, (0, 0, 0), (5.0, 80.0), turns=3))
    assert np.all(np.diff(e) > 0)


def test_assign_splits_counts_disjoint_and_spread():
    s = positions.assign_splits(130, 10, 20, seed=1)
    assert (s.count("train"), s.count("val"), s.count("test")) == (100, 10, 20)
    assert s != positions.assign_splits(130, 10, 20, seed=2)
    with pytest.raises(positions.LayoutError, match="cannot hold"):
        positions.assign_splits(5, 3, 2)


def test_the_lowest_cameras_always_train():
    heights = [math.sin(0.1 * k) for k in range(121)]  # any order: the rule sorts by height
    for seed in range(5):
        s = positions.assign_splits(121, 1, 20, seed=seed, heights=heights)
        assert (s.count("train"), s.count("val"), s.count("test")) == (100, 1, 20)
        lowest = sorted(range(121), key=lambda k: heights[k])[:13]  # ceil(10 % of 121)
        assert all(s[k] == "train" for k in lowest)
    # Without heights (a user's cameras, an animation), or when the rest could not hold val and test,
    # every camera may be held out, as before.
    assert positions.assign_splits(130, 10, 20, seed=1) == positions.assign_splits(130, 10, 20, seed=1, heights=None)
    s = positions.assign_splits(10, 4, 5, seed=0, heights=list(range(10)))
    assert s.count("train") == 1


def _unseen_world_shares(n_train, n_val, n_test, seed, heights_rule: bool):
    """Per held-out view of a default 200 px hemisphere capture: the share of its pixels that see
    world no train view shows (``nerf_core.fields.world_coverage``, as ``check`` warns)."""
    import torch

    from nerf_core.cameras.rays import Cameras
    from nerf_core.fields.world_coverage import covered_directions, unseen_world_share

    lo, hi = np.array([-1.4, -1.4, -1.3]), np.array([1.4, 1.4, 0.75])  # the hdri demo scene's bounds
    centre, sphere_r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    fov = positions.fov_from_lens(50.0, 200, 200)
    radius = positions.auto_radius(sphere_r, *fov)
    n = n_train + n_val + n_test
    pos = positions.fibonacci_positions(n, radius, tuple(centre), (0.0, 90.0))
    splits = positions.assign_splits(n, n_val, n_test, seed, heights=[p[2] for p in pos] if heights_rule else None)
    focal = 100.0 / math.tan(fov[0] / 2)
    cams = Cameras.create(np.array([positions.look_at(p, tuple(centre)) for p in pos]), focal, focal, 100,
                          100, 200, 200)
    train = Cameras.cat([cams[k] for k, s in enumerate(splits) if s == "train"])
    covered = covered_directions(train)
    aabb = torch.tensor(np.stack([lo, hi]), dtype=torch.float32)
    return [unseen_world_share(cams, k, covered, aabb) for k, s in enumerate(splits) if s != "train"]


@pytest.mark.parametrize("seed", [0, 2])
def test_held_out_views_of_a_hemisphere_see_no_world_that_training_misses(seed):
    # With every camera eligible, seed 0 held out 6 views with 3-18 % such pixels, seed 2 nine (3-26 %).
    before = _unseen_world_shares(100, 1, 20, seed, heights_rule=False)
    assert sum(share >= 0.02 for share in before) >= 6
    after = _unseen_world_shares(100, 1, 20, seed, heights_rule=True)
    assert max(after) < 0.02, after


def test_look_at_points_minus_z_at_target_with_z_up():
    pos, target = (3.0, -4.0, 2.0), (0.5, 0.5, 0.0)
    m = np.asarray(positions.look_at(pos, target))
    r = m[:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    fwd = -r[:, 2]
    want = np.subtract(target, pos) / np.linalg.norm(np.subtract(target, pos))
    np.testing.assert_allclose(fwd, want, atol=1e-12)
    assert r[2, 1] > 0  # camera +Y has a world +Z component: image is upright
    assert abs(r[2, 0]) < 1e-12  # no roll: camera +X is horizontal
    top = np.asarray(positions.look_at((0, 0, 5.0), (0, 0, 0)))  # straight down still valid
    np.testing.assert_allclose(-top[:3, 2], (0, 0, -1), atol=1e-12)


def _add_box(size=2.0, location=(0.0, 0.0, 0.0)):
    bpy.ops.mesh.primitive_cube_add(size=size, location=location)
    return bpy.context.active_object


@pytest.mark.parametrize("res", [(64, 64), (96, 40), (40, 96)])
def test_auto_radius_frames_the_scene_bounds(res):
    _add_box(2.0, (0.3, -0.2, 0.4))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(1.5, 0.0, 0.0))
    spec = positions.LayoutSpec(layout="sphere", train=30, val=0, test=0)
    cams = layout_cameras.create_cameras(bpy.context.scene, spec, *res)
    lo, hi = np.array([-0.7, -1.2, -0.6]), np.array([2.0, 0.8, 1.4])
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    tightest = 1.0
    for cam in cams:
        intr = cameras.camera_intrinsics(cam, RenderView(bpy.context.scene.render, *res))
        w2c = np.linalg.inv(np.asarray(cam.matrix_world))
        x, y, z = (w2c @ corners.T)[:3]
        u = intr["cx"] + intr["fl_x"] * x / -z
        v = intr["cy"] - intr["fl_y"] * y / -z
        assert np.all(z < 0)
        assert np.all((u >= 0) & (u <= res[0]) & (v >= 0) & (v <= res[1])), cam.name
        tightest = min(tightest, (u.min() / res[0]), (v.min() / res[1]), 1 - u.max() / res[0], 1 - v.max() / res[1])
    assert tightest < 0.2  # and not absurdly far away: some view has a corner near the border


def test_create_cameras_replaces_only_its_collection():
    _add_box()
    user_cam = bpy.data.objects.new("UserCam", bpy.data.cameras.new("UserCam"))
    bpy.context.scene.collection.objects.link(user_cam)
    user_cam.matrix_world = Matrix.Translation((0, -10, 0))
    spec = positions.LayoutSpec(train=8, val=2, test=3)
    layout_cameras.create_cameras(bpy.context.scene, spec, 32, 32)
    spec.train = 5
    made = layout_cameras.create_cameras(bpy.context.scene, spec, 32, 32)
    cams = collection.capture_cameras(bpy.context.scene)
    assert [len(cams[s]) for s in positions.SPLITS] == [5, 2, 3]
    assert len(made) == 10
    assert all(o.name in bpy.data.collections[positions.COLLECTION_NAME].objects for o in made)
    assert "UserCam" in bpy.data.objects and bpy.data.objects["UserCam"].location.y == -10
    assert sum(o.type == "CAMERA" for o in bpy.data.objects) == 11  # old layout fully removed
    assert not any(o.name.startswith("NeRF_") and o.name.endswith(".001") for o in bpy.data.objects)
    mine = bpy.data.objects.new("MovedIntoCollection", None)  # a user's object put in our collection
    bpy.data.collections[positions.COLLECTION_NAME].objects.link(mine)
    assert collection.clear_cameras(bpy.context.scene) == 10
    assert [o.name for o in bpy.data.objects if o.type == "CAMERA"] == ["UserCam"]
    assert "MovedIntoCollection" in bpy.data.objects


def test_scene_cameras_layout_copies_user_cameras_and_splits_them():
    _add_box()
    for k in range(6):
        cam = bpy.data.objects.new(f"Cam{k}", bpy.data.cameras.new(f"Cam{k}"))
        bpy.context.scene.collection.objects.link(cam)
        cam.matrix_world = Matrix(positions.look_at((5 * math.cos(k), 5 * math.sin(k), 1.0), (0, 0, 0)))
    spec = positions.LayoutSpec(layout="scene-cameras", val=1, test=2)
    made = layout_cameras.create_cameras(bpy.context.scene, spec, 32, 32)
    assert len(made) == 6
    assert sorted(o["nerf_source"] for o in made) == [f"Cam{k}" for k in range(6)]
    for obj in made:
        src = bpy.data.objects[obj["nerf_source"]]
        np.testing.assert_allclose(np.asarray(obj.matrix_world), np.asarray(src.matrix_world), atol=1e-6)
    cams = collection.capture_cameras(bpy.context.scene)
    assert [len(cams[s]) for s in positions.SPLITS] == [3, 1, 2]


def _flying_camera(active_camera):
    """The scene's camera flying from x = -5 (frame 1) to x = 5 (frame 40), the scene at frame 7."""
    cam = active_camera("Anim", frames=(1, 40))
    for f, x in ((1, -5.0), (40, 5.0)):
        cam.location = (x, -6.0, 1.0)
        cam.keyframe_insert("location", frame=f)
    bpy.context.scene.frame_set(7)
    return bpy.context.scene


def test_animation_layout_samples_every_nth_frame(active_camera):
    scene = _flying_camera(active_camera)
    made = layout_cameras.create_cameras(scene, positions.LayoutSpec(layout="animation", frame_step=10, val=1,
                                                                     test=1), 32, 32)
    assert sorted(o["nerf_frame"] for o in made) == [1, 11, 21, 31]
    xs = {o["nerf_frame"]: o.matrix_world.translation.x for o in made}
    assert xs[1] == pytest.approx(-5.0) and xs[31] > xs[21] > xs[11] > xs[1]
    assert scene.frame_current == 7  # the user's frame is restored


def test_animation_layout_keeps_an_animated_zoom(active_camera):
    # Each copy took the lens of the frame the layout was made at (20 mm for a 20 -> 80 mm zoom), and
    # its animation was cleared: the dataset's views were rendered unzoomed, without a word.
    scene = _flying_camera(active_camera)
    lens = scene.camera.data
    for f, mm in ((1, 20.0), (40, 80.0)):
        lens.lens = mm
        lens.keyframe_insert("lens", frame=f)
    scene.frame_set(7)
    made = layout_cameras.create_cameras(scene, positions.LayoutSpec(layout="animation", frame_step=10, val=1,
                                                                     test=1), 32, 32)
    mm = {o["nerf_frame"]: o.data.lens for o in made}
    assert mm[1] == pytest.approx(20.0) and mm[31] > mm[21] > mm[11] > 20.0 and mm[31] < 80.0
    assert scene.frame_current == 7 and all(o.data.animation_data is None for o in made)


def test_objects_that_move_during_an_animation_capture_are_named(active_camera):
    # Each view of the animation layout renders at its own frame: what moves there breaks the one
    # still scene a NeRF assumes. The camera itself may move; the cube of the fixture stands still.
    scene = _flying_camera(active_camera)
    spec = positions.LayoutSpec(layout="animation", frame_step=10, val=1, test=1)
    assert notes.motion_note(scene, spec) is None and notes.layout_notes(scene, spec) == []
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(3.0, 0.0, 0.0))
    ball = bpy.context.active_object
    ball.keyframe_insert("location", frame=30)
    ball.location.z = 2.0
    ball.keyframe_insert("location", frame=40)
    note = notes.motion_note(scene, spec)
    assert note.startswith("'Sphere' move(s) between the animation's frames") and "ghosts" in note
    assert notes.layout_notes(scene, spec) == [note]
    assert notes.motion_note(scene, positions.LayoutSpec()) is None  # generated layouts render one frame
    assert scene.frame_current == 7


def test_layouts_that_need_a_camera_say_so():
    _add_box()
    with pytest.raises(positions.LayoutError, match="scene-cameras.*no camera"):
        layout_cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(layout="scene-cameras", val=0,
                                                                              test=0), 32, 32)
    with pytest.raises(positions.LayoutError, match="animation.*no active camera"):
        layout_cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(layout="animation", val=0,
                                                                              test=0), 32, 32)


def test_bad_elevation_range_is_refused():
    _add_box()
    spec = positions.LayoutSpec(elevation_min=50, elevation_max=10)
    with pytest.raises(positions.LayoutError, match="elevation range"):
        layout_cameras.create_cameras(bpy.context.scene, spec, 32, 32)


def _monkey_scene(*extras):
    """A 2.7 m monkey standing at the origin, plus ``extras``: "floor" (100 m plane), "small floor"
    (3 m), "dome" (a 200 m sphere around everything), "building" (60 m cube beside it), "table"
    (1 m cube with a 2 cm screw on top, instead of the monkey)."""
    if "table" in extras:
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, 0.5))
        bpy.ops.mesh.primitive_cube_add(size=0.02, location=(0, 0, 1.01))
    else:
        bpy.ops.mesh.primitive_monkey_add(location=(0, 0, 1))
    if "floor" in extras:
        bpy.ops.mesh.primitive_plane_add(size=100.0)
    if "small floor" in extras:
        bpy.ops.mesh.primitive_plane_add(size=3.0)
    if "dome" in extras:
        bpy.ops.mesh.primitive_uv_sphere_add(radius=200.0)
    if "building" in extras:
        bpy.ops.mesh.primitive_cube_add(size=60.0, location=(40, 0, 30))
    return bpy.context.scene


@pytest.mark.parametrize("extras, left_out", [
    (("floor",), ["Plane"]),
    (("floor", "dome"), ["Plane", "Sphere"]),
])
def test_a_floor_or_dome_that_dwarfs_the_subject_is_left_out_of_the_framing(extras, left_out):
    from addon.scene import scene_bounds

    scene = _monkey_scene(*extras)
    spec = positions.LayoutSpec(train=8, val=1, test=1)
    lo, hi, around = notes.framing_bounds(scene, spec)
    assert around == left_out
    assert np.allclose(lo, (-1.37, -0.85, 0.02), atol=0.02) and np.allclose(hi, (1.37, 0.85, 1.98), atol=0.02)
    made = layout_cameras.create_cameras(scene, spec, 100, 100)
    # The monkey fills the frame from about 4.5 m (framed on the 100 m floor: 219 m, 2 px wide).
    assert max(o.matrix_world.translation.length for o in made) < 8.0
    assert "without 'Plane'" in notes.framing_note(scene, spec)
    assert notes.framing_note(scene, positions.LayoutSpec(layout="inside")) is None  # a room keeps its floor
    # The scene box a capture writes: the monkey with a quarter of its diagonal around it, clipped to
    # the scene (without the dome, the floor at z = 0 is its bottom and the monkey's top its top).
    pad = 0.25 * np.linalg.norm(np.subtract(hi, lo))
    s_lo, s_hi = (np.asarray(v) for v in scene_bounds.scene_bounds(scene))
    b_lo, b_hi = scene_bounds.subject_box(scene, lo, hi)
    assert np.allclose(b_lo, np.maximum(np.subtract(lo, pad), s_lo))
    assert b_lo[2] == 0.0 or "dome" in extras
    assert np.allclose(b_hi, np.minimum(np.add(hi, pad), s_hi))


@pytest.mark.parametrize("extras", [(), ("small floor",), ("floor", "building"), ("table",)])
def test_objects_that_are_part_of_the_subject_stay_in_the_framing(extras):
    # A floor little larger than the monkey is its stage; a 60 m building beside it makes the floor
    # under both part of the scene; a table is not the surroundings of the screw on it (the screw
    # pokes out of the table's box).
    from addon.scene import scene_bounds

    scene = _monkey_scene(*extras)
    lo, hi, around = notes.framing_bounds(scene, positions.LayoutSpec())
    s_lo, s_hi = scene_bounds.scene_bounds(scene)
    assert around == [] and tuple(lo) == tuple(s_lo) and tuple(hi) == tuple(s_hi)


def test_a_selection_is_framed_as_selected():
    scene = _monkey_scene("floor")
    for obj in scene.objects:
        obj.select_set(obj.name == "Plane")
    lo, hi, around = notes.framing_bounds(scene, positions.LayoutSpec(target="SELECTION"))
    assert around == [] and hi[0] - lo[0] == pytest.approx(100.0)


def _instance_of(collection_name, location, *, scene):
    """An empty instancing collection ``collection_name`` at ``location`` (as a linked asset arrives)."""
    empty = bpy.data.objects.new(f"{collection_name} instance", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = bpy.data.collections[collection_name]
    empty.location = location
    scene.collection.objects.link(empty)
    return empty


def test_collection_instances_are_bounded_like_the_objects_they_show():
    # A chair that is a collection instance (its source collection excluded from the view layer, as
    # after linking an asset) was missing from the bounds: the scene box and the framing left it out.
    from addon.scene import scene_bounds

    scene = _monkey_scene()
    chairs = bpy.data.collections.new("Chairs")
    scene.collection.children.link(chairs)
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    chair = bpy.context.active_object
    for coll in chair.users_collection:
        coll.objects.unlink(chair)
    chairs.objects.link(chair)
    bpy.context.view_layer.layer_collection.children["Chairs"].exclude = True
    instance = _instance_of("Chairs", (4.0, 0.0, 0.5), scene=scene)
    boxes = dict((name, box) for box, name in scene_bounds.renderable_boxes(scene))
    assert set(boxes) == {"Suzanne", "Chairs instance/Cube"}
    assert np.allclose(boxes["Chairs instance/Cube"], [(3.5, -0.5, 0.0), (4.5, 0.5, 1.0)])
    lo, hi = scene_bounds.scene_bounds(scene)
    assert hi[0] == pytest.approx(4.5) and lo[0] == pytest.approx(-1.37, abs=0.02)
    lo, hi, around = notes.framing_bounds(scene, positions.LayoutSpec())
    assert around == [] and hi[0] == pytest.approx(4.5)
    # A bounce card hidden from camera rays lights the scene but is in no picture: not bounded.
    bpy.ops.mesh.primitive_plane_add(size=8.0, location=(0.0, -9.0, 2.0))
    card = bpy.context.active_object
    assert scene_bounds.scene_bounds(scene)[0][1] == pytest.approx(-13.0)
    card.visible_camera = False
    assert scene_bounds.scene_bounds(scene)[0][1] == pytest.approx(-0.85, abs=0.02)
    # Hidden from renders, the instancer takes its instances with it; selected, it frames them.
    instance.hide_render = True
    assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(1.37, abs=0.02)
    instance.hide_render = False
    for obj in scene.objects:
        obj.select_set(obj is instance)
    lo, hi = scene_bounds.scene_bounds(scene, only_selected=True)
    assert np.allclose(lo, (3.5, -0.5, 0.0)) and np.allclose(hi, (4.5, 0.5, 1.0))


def test_what_renders_nothing_stretches_no_box_and_hair_does():
    # A camera path (a curve without bevel), an empty Grease Pencil object, a text with no body, the
    # second metaball of a family and a mesh of loose edges render nothing, yet each counted as its
    # (padded) control box or as a point at its origin: Suzanne came out 0.2 % of the frame.
    from addon.scene import scene_bounds

    scene = _monkey_scene()
    bpy.ops.curve.primitive_bezier_circle_add(radius=8.0, location=(0, 0, 2))
    bpy.ops.object.grease_pencil_add(type="EMPTY", location=(0, 0, -6))
    bpy.ops.object.text_add(location=(6, 0, 3))
    bpy.context.active_object.data.body = ""
    bpy.ops.object.metaball_add(type="BALL", radius=0.5, location=(0, 0, 1.2))
    bpy.ops.object.metaball_add(type="BALL", radius=0.3, location=(0.9, 0, 1.2))  # its surface is the first's
    guide = bpy.data.meshes.new("guide")
    guide.from_pydata([(0, 0, 0), (0, 30, 0)], [(0, 1)], [])
    scene.collection.objects.link(bpy.data.objects.new("Guide", guide))
    lo, hi = scene_bounds.scene_bounds(scene)
    assert np.allclose(lo, (-1.37, -0.86, 0.01), atol=0.03) and np.allclose(hi, (1.37, 0.86, 1.99), atol=0.03), (lo, hi)
    # A bevelled curve and a text with a body render: their own surfaces bound them, not the cage.
    curve = next(o for o in scene.objects if o.type == "CURVE")
    curve.data.bevel_depth = 0.1
    assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(8.1, abs=0.02)
    assert scene_bounds.scene_bounds(scene)[1][2] == pytest.approx(2.1, abs=0.02)
    # Particle hair renders from the particles, not the mesh: a plane with 4-unit hair is 4 units tall.
    bpy.ops.mesh.primitive_plane_add(size=0.5, location=(0, 5, 0))
    hairy = bpy.context.active_object
    hair = hairy.modifiers.new("hair", "PARTICLE_SYSTEM").particle_system.settings
    hair.type, hair.hair_length, hair.count = "HAIR", 4.0, 50
    boxes = dict((name, box) for box, name in scene_bounds.renderable_boxes(scene))
    assert boxes["Plane (hair)"][1][2] == pytest.approx(4.0, abs=0.01)
    # A selection that spans no space is refused, not framed by cameras standing at one point.
    for obj in scene.objects:
        obj.select_set(obj.type == "GREASEPENCIL")
    with pytest.raises(scene_bounds.BoundsError, match="no selected visible objects"):
        notes.framing_bounds(scene, positions.LayoutSpec(target="SELECTION"))


def test_bounds_follow_the_view_layer_that_renders():
    # A capture renders the active view layer only; the bounds read the first one. With the file's
    # second layer active, an object only it renders fell outside the box (44-60 % of a view's
    # opaque pixels) and out of the masks, and one that only the first renders stretched the box.
    from addon.scene import scene_bounds

    scene = bpy.context.scene
    near, far = (bpy.data.collections.new(n) for n in ("Near", "Far"))
    for coll, x in ((near, 0.0), (far, 6.0)):
        scene.collection.children.link(coll)
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(x, 0.0, 0.0))
        obj = bpy.context.active_object
        for c in obj.users_collection:
            c.objects.unlink(obj)
        coll.objects.link(obj)
    first = scene.view_layers[0]
    first.layer_collection.children["Far"].exclude = True
    assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(0.5)
    second = scene.view_layers.new("Second")
    second.layer_collection.children["Near"].exclude = True
    bpy.context.window.view_layer = second
    assert scene_bounds.render_view_layer(scene) == second
    lo, hi = scene_bounds.scene_bounds(scene)
    assert lo[0] == pytest.approx(5.5) and hi[0] == pytest.approx(6.5)
    assert [o.name for o in scene_bounds.renderable_objects(scene)] == ["Cube.001"]
    assert scene_bounds.scene_bounds(scene, view_layer=first)[1][0] == pytest.approx(0.5)


def test_bounds_follow_what_renders_not_what_the_viewport_shows():
    # Artists hide heavy objects in the viewport (eye or monitor icon); they still render, so they must
    # be inside the box. A collection disabled in renders or excluded from the view layer renders nothing.
    from addon.scene import scene_bounds

    scene = _monkey_scene()
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(6.0, 0.0, 1.0))
    tree = bpy.context.active_object
    for hide in (lambda: tree.hide_set(True), lambda: setattr(tree, "hide_viewport", True)):
        hide()
        assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(7.0)
        assert tree in scene_bounds.renderable_objects(scene)  # so capture's masks see it too
    tree.hide_set(False)
    tree.hide_viewport = False
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    scene.collection.objects.unlink(tree)
    props.objects.link(tree)
    assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(7.0)
    props.hide_render = True
    assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(1.37, abs=0.02)
    props.hide_render = False
    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    assert scene_bounds.scene_bounds(scene)[1][0] == pytest.approx(1.37, abs=0.02)


def test_each_scene_has_its_own_capture_cameras():
    # Collections are shared by name: Generate Cameras in a second scene (the demo scene, say)
    # replaced the first scene's cameras, and Clear Cameras there deleted them.
    _add_box()
    first = bpy.context.scene
    made = layout_cameras.create_cameras(first, positions.LayoutSpec(train=3, val=1, test=1), 32, 32)
    second = bpy.data.scenes.new("Second")
    bpy.ops.mesh.primitive_uv_sphere_add(radius=3.0)
    ball = bpy.context.active_object
    for coll in ball.users_collection:
        coll.objects.unlink(ball)
    second.collection.objects.link(ball)
    with bpy.context.temp_override(scene=second):
        assert not any(collection.capture_cameras(second).values())
        theirs = layout_cameras.create_cameras(second, positions.LayoutSpec(train=2, val=1, test=1), 32, 32)
        assert collection.clear_cameras(second) == len(theirs) == 4
    assert sorted(o.name for split in collection.capture_cameras(first).values() for o in split) == sorted(
        o.name for o in made)
    assert collection.nerf_collection(second).name == positions.COLLECTION_NAME + ".001"
