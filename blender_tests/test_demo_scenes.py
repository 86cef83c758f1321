"""Demo scenes: each builds quickly and deterministically, fits in about +-1.5 units (the interior: its
room), and is lit; the real-scene demos have their world and capture flags."""
from __future__ import annotations

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
from PIL import Image

from addon.capture.demo import capture_flags, scenes
from addon.capture.layout import positions
from addon.capture.run import job
from addon.capture.plan import settings as plan_settings, world
from addon.capture.layout import collection, cameras
from addon.scene import scene_bounds

PY = sys.executable
SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "make_demo_scene.py")


def fingerprint(scene):
    out = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        n = len(ev.data.vertices) if obj.type == "MESH" else 0
        out.append((obj.name, obj.type, n, tuple(round(v, 6) for v in obj.matrix_world.translation)))
    return out


@pytest.mark.parametrize("name", sorted(scenes.SCENES))
def test_scene_builds_within_bounds_lit_and_deterministic(name):
    scene = scenes.build(name)
    lo, hi = scene_bounds.scene_bounds(scene)
    if name == "interior":  # the room is the scene: its box is the bounds
        sx, sy, sz = scenes.ROOM_SIZE
        np.testing.assert_allclose([list(lo), list(hi)], [[-sx / 2, -sy / 2, 0], [sx / 2, sy / 2, sz]], atol=1e-5)
    elif name == "ground":  # the floor runs on: the framing leaves it out, and the subject fits the usual box
        lo, hi, around = scene_bounds.subject_bounds(scene)
        assert around == ["Ground"] and max(map(abs, list(lo) + list(hi))) <= 1.6, (lo, hi, around)
    else:
        assert max(map(abs, list(lo) + list(hi))) <= 1.6, (name, lo, hi)
        assert scene_bounds.subject_bounds(scene)[2] == []  # nothing dwarfs the subject
    assert any(o.type == "LIGHT" for o in scene.objects) and scene.world is not None
    meshes = [o for o in scene.objects if o.type == "MESH"]
    assert meshes and all(o.material_slots and o.material_slots[0].material for o in meshes)
    first = fingerprint(scene)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert fingerprint(scenes.build(name)) == first


def test_unknown_scene_is_named():
    with pytest.raises(scenes.DemoSceneError, match="unknown demo scene 'lego'.*cube"):
        scenes.build("lego")


def test_workbench_render_of_the_flat_cube_shows_it_lit(tmp_path):
    scene = scenes.build("cube")
    cameras.create_cameras(scene, positions.LayoutSpec(train=1, val=0, test=0, elevation_min=30,
                                                       elevation_max=30), 32, 32)
    job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path / "ds"), engine="workbench",
                                                      res_x=32, res_y=32)).run()
    rgba = np.asarray(Image.open(tmp_path / "ds" / "train" / "r_0.png")).astype(float)
    obj = rgba[..., 3] == 255
    assert 0.1 < obj.mean() < 0.9
    red = rgba[obj][:, :3]
    assert (red[:, 0] > red[:, 1] + 40).mean() > 0.9 and red[:, 0].mean() > 60  # red and not black


def test_make_demo_scene_script_writes_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "thin.blend"
    proc = subprocess.run([PY, SCRIPT, "thin", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and out.is_file(), proc.stderr
    size = out.stat().st_size
    proc = subprocess.run([PY, SCRIPT, "cube", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "exists" in proc.stderr and out.stat().st_size == size
    bpy.ops.wm.open_mainfile(filepath=str(out))
    assert "Wire lattice" in bpy.data.objects


# ---------------------------------------------------------------- real scenes: hdri and interior


def _world_nodes(scene):
    tree = scene.world.node_tree
    out = next(n for n in tree.nodes if n.type == "OUTPUT_WORLD" and n.is_active_output)
    bg = out.inputs["Surface"].links[0].from_node
    return bg, (bg.inputs["Color"].links[0].from_node if bg.inputs["Color"].is_linked else None)


def test_hdri_scene_shows_one_of_blenders_studio_light_photographs():
    scene = scenes.build("hdri")
    assert scene.render.film_transparent is False
    bg, env = _world_nodes(scene)
    assert bg.type == "BACKGROUND" and env is not None and env.type == "TEX_ENVIRONMENT"
    path = bpy.path.abspath(env.image.filepath)
    assert os.path.basename(path) == scenes.HDRI_NAME and os.path.isfile(path)
    assert os.path.dirname(path) == os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world")
    assert env.image.packed_file is not None  # the saved .blend does not depend on this bpy's install path
    assert tuple(env.image.size) == (1024, 512)  # it loads: a real equirectangular photo, not a pink placeholder
    assert world.world_description(scene.world) == {
        "name": scene.world.name, "kind": "environment_texture", "image": scenes.HDRI_NAME, "color": None,
        "strength": pytest.approx(1.0)}
    names = {o.name for o in scene.objects if o.type == "MESH"}
    assert {"Sphere", "Pedestal", "Checker cube", "Platform"} <= names


def test_hdri_scene_without_its_image_says_which_file_and_keeps_the_scene(monkeypatch):
    scenes.build("diffuse")
    before = sorted(o.name for o in bpy.context.scene.objects)
    monkeypatch.setattr(scenes, "HDRI_NAME", "no_such_world.exr")
    with pytest.raises(scenes.DemoSceneError, match=r"no_such_world\.exr.*forest\.exr"):
        scenes.build("hdri")
    assert sorted(o.name for o in bpy.context.scene.objects) == before


def test_interior_is_a_closed_lit_room_with_furniture():
    scene = scenes.build("interior")
    assert scene.render.film_transparent is False
    names = {o.name for o in scene.objects}
    assert {"Floor", "Ceiling", "Wall -X", "Wall +X", "Wall -Y", "Wall +Y", "Table", "Shelf", "Lamp shade"} <= names
    lo, hi = scene_bounds.scene_bounds(scene)
    lights = [o for o in scene.objects if o.type == "LIGHT"]
    assert lights and all(o.data.type == "AREA" for o in lights)
    for light in lights:  # inside the room, under the ceiling
        p = light.matrix_world.translation
        assert all(lo[k] < p[k] < hi[k] for k in range(3)), (light.name, p)
    bg, src = _world_nodes(scene)
    assert src is None and world.world_description(scene.world)["kind"] == "color"
    # Floor and walls are textured (something to reconstruct), in metres (object coordinates).
    for obj_name in ("Floor", "Wall -X", "Wall +Y"):
        nodes = bpy.data.objects[obj_name].material_slots[0].material.node_tree.nodes
        assert any(n.type in ("TEX_CHECKER", "TEX_NOISE", "TEX_WAVE") for n in nodes)
        assert any(n.type == "TEX_COORD" for n in nodes)


def _inside_cameras(scene, **kw):
    spec = positions.LayoutSpec(**{"layout": "inside", "train": 40, "val": 4, "test": 6, "seed": 3, **kw})
    cameras.create_cameras(scene, spec, 32, 32)
    cams = collection.capture_cameras(scene)
    return {s: [np.asarray(o.matrix_world) for o in cams[s]] for s in positions.SPLITS}, cams


def test_inside_layout_stands_every_camera_in_the_room_apart_from_the_furniture():
    scene = scenes.build("interior")
    lo, hi = (np.asarray(v) for v in scene_bounds.scene_bounds(scene))
    mats, cams = _inside_cameras(scene)
    assert [len(mats[s]) for s in positions.SPLITS] == [40, 4, 6]
    allm = [m for s in positions.SPLITS for m in mats[s]]
    pos = np.array([m[:3, 3] for m in allm])
    fwd = np.array([-m[:3, 2] for m in allm])
    # strictly inside the room, away from walls, floor and ceiling
    assert (pos > lo + 0.1).all() and (pos < hi - 0.1).all()
    # no two poses coincide (so train, val and test never share a camera)
    for i in range(len(allm)):
        for j in range(i + 1, len(allm)):
            assert np.linalg.norm(pos[i] - pos[j]) > 1e-3 or np.dot(fwd[i], fwd[j]) < 0.9999, (i, j)
    # looking outward all around the horizontal circle, within the default elevation range
    elev = np.degrees(np.arcsin(fwd[:, 2]))
    lo_e, hi_e = positions.INSIDE_ELEVATION
    assert (elev >= lo_e - 1e-6).all() and (elev <= hi_e + 1e-6).all()
    az = np.degrees(np.arctan2(fwd[:, 1], fwd[:, 0])) % 360
    assert np.histogram(az, bins=8, range=(0, 360))[0].min() >= 3  # every 45-degree sector is used
    # upright cameras (no roll), unit scale, a near clip for a room
    for m in allm:
        assert abs(m[2, 0]) < 1e-6  # camera +X stays horizontal
        np.testing.assert_allclose(np.linalg.norm(m[:3, :3], axis=0), 1.0, atol=1e-6)
    assert all(o.data.clip_start <= positions.INSIDE_CLIP_START + 1e-9 for s in positions.SPLITS for o in cams[s])
    # none inside a piece of furniture's bounding box (the room's planes have no volume)
    room = {"Floor", "Ceiling", "Wall -X", "Wall +X", "Wall -Y", "Wall +Y", "Rug", "Painting"}
    for obj in scene_bounds.renderable_objects(scene):
        if obj.name in room:
            continue
        b_lo, b_hi = (np.asarray(v) for v in scene_bounds.object_bounds([obj]))
        inside = ((pos >= b_lo) & (pos <= b_hi)).all(axis=1)
        assert not inside.any(), obj.name
    # deterministic from the seed; another seed moves them
    again, _ = _inside_cameras(scene)
    for s in positions.SPLITS:
        np.testing.assert_allclose(np.array(again[s]), np.array(mats[s]))
    other, _ = _inside_cameras(scene, seed=4)
    assert not np.allclose(np.array(other["train"]), np.array(mats["train"]))


def test_inside_layout_honours_an_elevation_override():
    scene = scenes.build("interior")
    mats, _ = _inside_cameras(scene, train=12, val=0, test=0, elevation_min=-5.0, elevation_max=5.0)
    elev = np.degrees(np.arcsin(np.array([-m[2, 2] for m in mats["train"]])))
    assert (np.abs(elev) <= 5.0 + 1e-6).all()


def test_inside_poses_avoid_obstacles_ignore_the_enclosure_and_refuse_a_flat_box():
    lo, hi = (-3.0, -2.0, 0.0), (3.0, 2.0, 3.0)
    block = ((-3.0, -2.0, 0.0), (0.0, 2.0, 3.0))  # the whole -x half of the room
    shell = ((-3.05, -2.05, -0.05), (3.05, 2.05, 3.05))  # one mesh for all walls: holds everything
    poses = positions.inside_poses(60, lo, hi, seed=1, obstacles=[block, shell])
    pos = np.array([p for p, _d in poses])
    assert len(poses) == 60 and (pos[:, 0] > 0.0).all()
    assert (pos[:, 2] >= 1.2 - 1e-9).all() and (pos[:, 2] <= 1.8 + 1e-9).all()  # the middle height band
    dirs = np.array([d for _p, d in poses])
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
    assert poses == positions.inside_poses(60, lo, hi, seed=1, obstacles=[block, shell])
    with pytest.raises(positions.LayoutError, match="no volume"):
        positions.inside_poses(4, (0, 0, 0), (1, 1, 0))
    with pytest.raises(positions.LayoutError, match="inside an object's bounding box"):
        positions.inside_poses(4, lo, hi, obstacles=[((-3, -2, 0), (0.01, 2, 3)), ((0, -2, 0), (3, 2, 3))], attempts=50)


def test_capture_flags_of_each_scene_parse_as_capture_options(monkeypatch):
    monkeypatch.syspath_prepend(os.path.dirname(SCRIPT))
    import capture as capture_script

    assert set(capture_flags.CAPTURE_DEFAULTS) <= set(scenes.SCENES)
    for name in ("cube", "diffuse", "highfreq", "glossy", "thin", "multi"):
        assert scenes.capture_flags(name) == []  # object scenes: transparent film, hemisphere
    hdri = capture_script.build_parser().parse_args(["--out", "x", *scenes.capture_flags("hdri")])
    assert hdri.opaque and hdri.layout == "hemisphere"
    ground = capture_script.build_parser().parse_args(["--out", "x", *scenes.capture_flags("ground")])
    assert ground.opaque and ground.layout == "hemisphere"
    room = capture_script.build_parser().parse_args(["--out", "x", *scenes.capture_flags("interior")])
    assert room.opaque and room.layout == "inside" and room.focal_length == 24.0


def test_benchmark_and_demo_capture_real_scenes_with_their_flags(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(os.path.dirname(SCRIPT))
    monkeypatch.syspath_prepend(os.path.join(os.path.dirname(os.path.dirname(SCRIPT)), "benchmarks"))
    import demo
    from bench import datasets, runner

    assert demo.scene_capture_flags("interior") == scenes.capture_flags("interior")
    assert demo.scene_capture_flags("diffuse") == []
    calls = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        out = cmd[cmd.index("--out") + 1]
        if cmd[1].endswith("make_demo_scene.py"):
            open(out, "w").close()
        else:
            os.makedirs(out, exist_ok=True)
            for split in ("train", "test"):
                open(os.path.join(out, f"transforms_{split}.json"), "w").write("{}")
        return runner.CliResult(args=cmd, returncode=0)

    monkeypatch.setattr(datasets, "run_cli", fake_run)
    settings = {"resolution": 32, "count": 4}
    ds_room, _ = datasets.ensure_dataset("interior", str(tmp_path), dict(settings))
    ds_obj, _ = datasets.ensure_dataset("diffuse", str(tmp_path), dict(settings))
    room_cmd, obj_cmd = calls[1], calls[3]
    assert room_cmd[room_cmd.index("--layout") + 1] == "inside" and "--opaque" in room_cmd
    assert "--opaque" not in obj_cmd and "--layout" not in obj_cmd
    # the flags are in the cache key; an object scene's key is what it always was
    assert ds_room.endswith("interior-" + datasets.settings_key({"scene": "interior",
                                                                 **capture_flags.capture_defaults("interior"),
                                                                 **settings}))
    assert ds_obj.endswith("diffuse-" + datasets.settings_key({"scene": "diffuse", **settings}))
