"""The capture records its background (film and world) and real scenes capture as they should.

Top level of nerf_capture/manifest.json and of every transforms file: ``film_transparent`` and
``world`` (docs/CONTRACTS.md, dataset folder). Opaque captures hash the world into their frames.
"""
from __future__ import annotations

import json
import os

import bpy
import numpy as np
import pytest
from PIL import Image

from addon.capture.demo import scenes
from addon.capture.layout import positions
from addon.capture.run import job
from addon.capture.plan import frame_plan, settings as plan_settings, world as plan_world
from addon.capture.layout import cameras

TRANSFORMS = ("transforms_train.json", "transforms_val.json", "transforms_test.json", "nerfstudio/transforms.json")

# The lowest 8-bit alpha of a fully covered pixel. Blender 4.5's Workbench writes 254 there (and
# everywhere with an opaque film; Cycles and 5.0 write 255); nerf_core reads 0.98 and up as opaque.
OPAQUE_ALPHA = 254



def _json(path):
    with open(path) as fh:
        return json.load(fh)


def _records(out):
    """(manifest, {transforms file: doc}) of a capture folder."""
    manifest = _json(os.path.join(out, "nerf_capture", "manifest.json"))
    return manifest, {t: _json(os.path.join(out, t)) for t in TRANSFORMS}


def _capture(scene, out, spec, engine="workbench", res=32, **kw):
    cameras.create_cameras(scene, spec, res, res)
    settings = plan_settings.CaptureSettings(out_dir=str(out), engine=engine, samples=kw.pop("samples", 1), res_x=res,
                                       res_y=res, layout=spec.to_dict(), **kw)
    return job.CaptureJob(scene, settings).run()


def _assert_background_recorded(out, film_transparent, world):
    manifest, docs = _records(out)
    assert manifest["film_transparent"] is film_transparent and manifest["world"] == world
    for name, doc in docs.items():
        assert doc["film_transparent"] is film_transparent, name
        assert doc["world"] == world, name


def test_hdri_capture_is_opaque_and_records_the_hdri_world(tmp_path):
    scene = scenes.build("hdri")
    out = tmp_path / "ds"
    spec = positions.LayoutSpec(train=4, val=1, test=1, elevation_min=5, elevation_max=30, seed=1)
    summary = _capture(scene, out, spec, engine="cycles", samples=4, film_transparent=False)
    assert summary["status"] == "complete" and summary["rendered"] == 6
    world = plan_world.world_description(scene.world)
    assert world == {"name": "NeRF Demo HDRI", "kind": "environment_texture", "image": scenes.HDRI_NAME,
                     "color": None, "strength": 1.0}
    _assert_background_recorded(out, False, world)
    assert _records(out)[0]["render"]["world"] == world  # opaque: the world is part of the frames' hash
    for split in ("train", "test"):
        rgba = np.asarray(Image.open(out / split / "r_0.png")).astype(float)
        assert (rgba[..., 3] >= OPAQUE_ALPHA).all()  # an opaque film: the photograph fills the background
        border = np.concatenate([rgba[:3, :, :3].reshape(-1, 3), rgba[-3:, :, :3].reshape(-1, 3)])
        assert border.std(axis=0).max() > 8 and 20 < border.mean() < 235  # structure, neither black nor white


def test_interior_capture_from_inside_the_room(tmp_path):
    scene = scenes.build("interior")
    out = tmp_path / "room"
    spec = positions.LayoutSpec(layout="inside", train=4, val=1, test=1, focal_length=24.0)
    _capture(scene, out, spec, film_transparent=False)
    world = {"name": "NeRF Demo Room World", "kind": "color", "image": None, "color": [0.05, 0.05, 0.05],
             "strength": 1.0}
    _assert_background_recorded(out, False, world)
    doc = _json(out / "nerfstudio" / "transforms.json")
    lo, hi = np.asarray(doc["aabb"])
    sx, sy, sz = scenes.ROOM_SIZE
    np.testing.assert_allclose([lo, hi], [[-sx / 2, -sy / 2, 0], [sx / 2, sy / 2, sz]], atol=1e-5)
    pos = np.array([np.asarray(f["transform_matrix"])[:3, 3] for f in doc["frames"]])
    assert len(pos) == 6 and ((pos > lo) & (pos < hi)).all()  # every camera inside the scene's box
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    farthest = max(np.linalg.norm(corners - p, axis=1).max() for p in pos)
    assert 1e-3 <= doc["near"] < 0.2 and farthest <= doc["far"] < 1.2 * farthest  # every wall within [near, far]
    rgba = np.asarray(Image.open(out / "train" / "r_0.png"))
    assert (rgba[..., 3] >= OPAQUE_ALPHA).all()


def test_transparent_capture_records_its_film_and_world_and_hashes_as_before(tmp_path):
    scene = scenes.build("cube")
    out = tmp_path / "cube"
    _capture(scene, out, positions.LayoutSpec(train=2, val=0, test=0), res=16)
    world = {"name": "NeRF Demo World", "kind": "color", "image": None, "color": [0.35, 0.35, 0.38], "strength": 1.0}
    _assert_background_recorded(out, True, world)
    assert "world" not in _records(out)[0]["render"]  # transparent: frame hashes of older captures still match


def test_switching_the_film_or_an_opaque_world_changes_what_resume_keeps(tmp_path):
    scene = scenes.build("cube")
    out = tmp_path / "ds"
    spec = positions.LayoutSpec(train=2, val=0, test=1)
    assert _capture(scene, out, spec, res=16, film_transparent=False)["rendered"] == 3
    assert _capture(scene, out, spec, res=16, film_transparent=False)["kept"] == 3  # same settings: resumed
    with pytest.raises(frame_plan.CaptureError, match="render settings changed"):
        _capture(scene, out, spec, res=16, film_transparent=True)
    summary = _capture(scene, out, spec, res=16, film_transparent=True, overwrite=True)
    assert summary["rendered"] == 3 and _records(out)[0]["film_transparent"] is True
    _capture(scene, out, spec, res=16, film_transparent=False, overwrite=True)
    scene.world.color = (0.6, 0.2, 0.2)  # what Workbench shows behind the scene (it ignores the nodes)
    with pytest.raises(frame_plan.CaptureError, match="render settings changed"):
        _capture(scene, out, spec, res=16, film_transparent=False)
    assert _capture(scene, out, spec, res=16, film_transparent=False, overwrite=True)["rendered"] == 3
    assert _records(out)[1]["nerfstudio/transforms.json"]["world"]["color"] == pytest.approx([0.6, 0.2, 0.2])
    rgba = np.asarray(Image.open(out / "train" / "r_0.png"))
    r, g, b = map(int, rgba[0, 0, :3])
    assert r > g + 30 and r > b + 30, (r, g, b)  # red, as recorded: the nodes' colour is grey


def _world(name):
    world = bpy.data.worlds.new(name)
    if world.node_tree is None:
        world.use_nodes = True
    tree = world.node_tree
    return world, tree, next(n for n in tree.nodes if n.type == "BACKGROUND"), next(
        n for n in tree.nodes if n.type == "OUTPUT_WORLD")


def test_world_description_of_each_kind_of_world():
    assert plan_world.world_description(None) == {"name": None, "kind": "none", "image": None, "color": None,
                                               "strength": None}
    world, tree, bg, _out = _world("Plain")
    bg.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    bg.inputs["Strength"].default_value = 0.5
    d = plan_world.world_description(world)
    assert d["kind"] == "color" and d["color"] == pytest.approx([0.2, 0.4, 0.6]) and d["strength"] == 0.5
    world.color = (0.9, 0.1, 0.1)  # Workbench ignores the nodes and shows the viewport colour
    d = plan_world.world_description(world, "BLENDER_WORKBENCH")
    assert d["kind"] == "color" and d["color"] == pytest.approx([0.9, 0.1, 0.1])

    world, tree, bg, _out = _world("Sky")
    sky = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(sky.outputs["Color"], bg.inputs["Color"])
    assert plan_world.world_description(world)["kind"] == "sky_texture"

    world, tree, bg, out = _world("Mixed")  # the light-path trick: a Background inside a Mix Shader
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(scenes.hdri_path(), check_existing=True)
    tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    mix = tree.nodes.new("ShaderNodeMixShader")
    tree.links.new(bg.outputs["Background"], mix.inputs[2])
    tree.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    value = tree.nodes.new("ShaderNodeValue")
    tree.links.new(value.outputs["Value"], bg.inputs["Strength"])
    d = plan_world.world_description(world)
    assert d["kind"] == "environment_texture" and d["image"] == scenes.HDRI_NAME and d["strength"] is None

    world, tree, bg, out = _world("Unlinked")
    tree.links.remove(out.inputs["Surface"].links[0])
    assert plan_world.world_description(world)["kind"] == "none"

    world, tree, bg, out = _world("Gradient")
    grad = tree.nodes.new("ShaderNodeTexGradient")
    tree.links.new(grad.outputs["Color"], bg.inputs["Color"])
    assert plan_world.world_description(world)["kind"] == "other"
