"""Image planes (addon/compare/planes.py): placement in the camera frustum, gallery, re-import, camera files."""
from __future__ import annotations

import json
import math
import os

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Euler, Matrix, Vector

from addon.dataset import cameras
from addon import file_writes
from addon.compare import planes
from nerf_core.image import metrics

W, H = 40, 30


def write_png(path, rgba):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    file_writes.write_png(path, rgba)


def fake_render(tmp_path, n=2, intr=None):
    """A render folder as `nerf_core render` writes it, plus the dataset split it came from."""
    intr = intr or {"fl_x": 50.0, "fl_y": 50.0, "cx": 23.5, "cy": 12.0, "w": W, "h": H}
    rng = np.random.default_rng(0)
    render, data = tmp_path / "render", tmp_path / "data"
    frames = []
    for i in range(n):
        img = np.concatenate([rng.random((H, W, 3)), np.ones((H, W, 1))], axis=2)
        write_png(str(render / f"r_{i}.png"), img)
        write_png(str(data / "test" / f"r_{i}.png"), np.clip(img + 0.02 * (i + 1), 0, 1))
        c2w = Matrix.Translation((i, -4.0, 0.5)) @ Euler((math.radians(85), 0.0,
                                                          math.radians(10 * i))).to_matrix().to_4x4()
        frames.append({"file_path": f"./test/r_{i}", "transform_matrix": [list(r) for r in c2w]})
    meta = dict(intr, near=0.5, far=8.0, frames=frames)
    (data / "transforms_test.json").write_text(json.dumps(meta))
    # What `nerf_core render` adds for views with ground truth: nerf_core's metrics and heat-maps.
    rendered = []
    for i, fr in enumerate(frames):
        pred = metrics.composite(planes.load_image_array(str(render / f"r_{i}.png")))
        gt = metrics.composite(planes.load_image_array(str(data / "test" / f"r_{i}.png")))
        write_png(str(render / "errors" / f"r_{i}.png"), metrics.error_heatmap(pred, gt))
        rendered.append(dict(fr, file_path=f"r_{i}.png", psnr=metrics.psnr(pred, gt), ssim=metrics.ssim(pred, gt),
                             error_map=f"errors/r_{i}.png"))
    (render / "renders.json").write_text(json.dumps(dict(meta, frames=rendered, error_map_vmax=metrics.HEATMAP_VMAX)))
    return str(render), str(data / "transforms_test.json")


def project(c2w, intr, point):
    x, y, z = Matrix(c2w).inverted() @ Vector(point)
    return intr["cx"] + intr["fx"] * x / -z, intr["cy"] - intr["fy"] * y / -z


def corner_errors(ob, view):
    """Pixel distance between each vertex's projection and the image corner its UV says it shows."""
    uv = ob.data.uv_layers.active.data
    errs = []
    for loop in ob.data.loops:
        u_tex, v_tex = uv[loop.index].uv
        want = (u_tex * view.intrinsics["w"], (1.0 - v_tex) * view.intrinsics["h"])
        got = project(view.c2w, view.intrinsics, ob.matrix_world @ ob.data.vertices[loop.vertex_index].co)
        errs.append(math.dist(want, got))
    return errs


def counts():
    return {k: len(getattr(bpy.data, k)) for k in ("objects", "meshes", "materials", "images", "curves")}


def test_camera_aligned_planes_cover_the_image_through_their_camera(tmp_path):
    render, cams = fake_render(tmp_path)
    views = planes.views_from_render(render, cams)
    assert [v.name for v in views] == ["r_0", "r_1"] and views[0].ground_truth.endswith("test/r_0.png")
    obs = planes.import_camera_aligned(views, distance=2.5)
    assert [o.name for o in obs] == ["NeRF r_0", "NeRF r_1"]
    assert {o.name for o in bpy.data.collections[planes.VIEWS_COLLECTION].objects} == {"NeRF r_0", "NeRF r_1"}
    for ob, view in zip(obs, views):
        assert planes.plane_image_path(ob) == view.image
        assert max(corner_errors(ob, view)) < 1e-3
        depth = -(Matrix(view.c2w).inverted() @ ob.matrix_world.translation).z
        assert depth == pytest.approx(2.5, abs=1e-5)
        assert tuple(ob.scale) == pytest.approx((1, 1, 1))


def test_views_rendered_through_a_distorted_lens_are_named_in_a_warning(tmp_path):
    render, cams = fake_render(tmp_path, n=3)
    assert planes.lens_note(planes.views_from_render(render, cams)) == ""  # pinholes: nothing to say
    listing = os.path.join(render, "renders.json")
    meta = json.loads(open(listing).read())
    meta["frames"][1].update(camera_model="OPENCV", k1=-0.12, k2=0.01, p1=0.0, p2=0.0)  # what render writes
    meta["frames"][2].update(camera_model="OPENCV", k1=0.0, k2=0.0, p1=0.0, p2=0.0)  # all zero: a pinhole
    open(listing, "w").write(json.dumps(meta))
    views = planes.views_from_render(render, cams)
    assert [v.lens for v in views] == [None, "OPENCV", None]
    note = planes.lens_note(views)
    assert note.startswith("1 of 3 views were rendered through a distorted OPENCV lens") and "pinhole" in note


def test_reimport_replaces_instead_of_piling_up_and_spares_user_objects(tmp_path):
    render, cams = fake_render(tmp_path)
    views = planes.views_from_render(render, cams)
    planes.import_camera_aligned(views, 2.0)
    planes.import_gallery(views, render)
    user = bpy.data.objects.new("my empty", None)
    bpy.data.collections[planes.GALLERY_COLLECTION].objects.link(user)
    first = counts()
    for _ in range(2):
        planes.import_gallery(planes.views_from_render(render, cams), render)
        planes.import_camera_aligned(planes.views_from_render(render, cams), 3.0)
        assert counts() == first
    assert bpy.data.objects.get("my empty") is not None
    gallery = bpy.data.collections[planes.GALLERY_COLLECTION]
    assert len([o for o in gallery.objects if o.type == "MESH"]) == 6  # 2 rows x NeRF | Blender | error
    planes.clear_collection(planes.GALLERY_COLLECTION)
    planes.clear_collection(planes.VIEWS_COLLECTION)
    assert len(bpy.data.images) == 0 and len(bpy.data.materials) == 0 and len(bpy.data.meshes) == 0


def test_looking_through_a_view_camera_survives_reimport_and_clear(tmp_path):
    # The README suggests looking through "NeRF Cam r_0"; a re-import or Clear Views left the scene
    # with no camera, and F12 then failed.
    scene = bpy.context.scene
    mine = bpy.data.objects.new("My camera", bpy.data.cameras.new("My camera"))
    scene.collection.objects.link(mine)
    render, cams = fake_render(tmp_path)
    planes.import_camera_aligned(planes.views_from_render(render, cams), 2.0)
    scene.camera = bpy.data.objects["NeRF Cam r_1"]
    planes.import_camera_aligned(planes.views_from_render(render, cams), 3.0)
    assert scene.camera is not None and scene.camera.name.startswith("NeRF Cam r_1")
    planes.clear_collection(planes.VIEWS_COLLECTION)
    assert scene.camera == mine


def test_a_damaged_renders_file_is_named_not_a_traceback(tmp_path):
    render, cams = fake_render(tmp_path)
    path = os.path.join(render, "renders.json")
    meta = json.loads(open(path).read())
    meta["error_map_vmax"] = "big"  # unreadable: the heat-map legend goes without a scale
    meta["frames"][1]["ground_truth"] = ["a"]  # was a TypeError inside the Render job
    with open(path, "w") as fh:
        json.dump(meta, fh)
    with pytest.raises(ValueError, match=r"frame 1 \(r_1\): field 'ground_truth' must be an image path"):
        planes.views_from_render(render, cams)
    meta["frames"][1].pop("ground_truth")
    with open(path, "w") as fh:
        json.dump(meta, fh)
    assert all(v.error_vmax is None for v in planes.views_from_render(render, cams))


def test_gallery_rows_have_metrics_heatmaps_and_labels(tmp_path):
    render, cams = fake_render(tmp_path)
    views = planes.import_gallery(planes.views_from_render(render, cams), render)
    for i, view in enumerate(views):
        # ground truth = render + 0.02 (i+1) on every channel, so MSE and PSNR are known exactly
        offset = round(0.02 * (i + 1) * 255) / 255
        assert view.metrics["psnr"] == pytest.approx(-10 * math.log10(offset ** 2), abs=0.5)
        assert 0.9 < view.metrics["ssim"] <= 1.0
        heat = os.path.join(render, "errors", f"{view.name}.png")
        assert os.path.isfile(heat)
        ob = bpy.data.objects[f"Gallery Error {view.name}"]
        assert planes.plane_image_path(ob) == heat
        assert planes.plane_image_path(bpy.data.objects[f"Gallery Blender {view.name}"]) == view.ground_truth
        label = bpy.data.objects[f"Label {view.name}"]
        assert f"PSNR {view.metrics['psnr']:.2f} dB" in label.data.body and "SSIM" in label.data.body


def test_missing_render_names_the_frame(tmp_path):
    render, cams = fake_render(tmp_path)
    os.remove(os.path.join(render, "r_1.png"))
    with pytest.raises(ValueError, match=r"frame 1 \(r_1\).*r_1.png is missing"):
        planes.views_from_render(render, cams)


def test_selected_camera_file_matches_blenders_projection_including_shift(tmp_path):
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 320, 240
    cam = bpy.data.objects.new("Shifted Cam", bpy.data.cameras.new("Shifted Cam"))
    scene.collection.objects.link(cam)
    cam.data.lens, cam.data.shift_x, cam.data.shift_y = 40.0, 0.15, -0.1
    cam.matrix_world = Matrix.Translation((1.0, -5.0, 2.0)) @ Euler((math.radians(70), 0,
                                                                     math.radians(15))).to_matrix().to_4x4()
    data = cameras.cameras_transforms([cam], scene, (160, 120), base={"near": 0.1, "far": 9,
                                                                      "aabb": [[-1] * 3, [1] * 3]})
    assert data["near"] == 0.1 and data["w"] == 160 and len(data["frames"]) == 1
    frame = data["frames"][0]
    intr = planes.intrinsics_from(data, frame)
    for point in ((0, 0, 0), (0.5, 0.3, -0.2), (-0.7, 1.0, 0.4)):
        ndc = world_to_camera_view(scene, cam, Vector(point))
        assert project(frame["transform_matrix"], intr, point) == pytest.approx((ndc.x * 160,
                                                                                 (1 - ndc.y) * 120), abs=1e-3)


def test_fly_through_writes_one_view_per_frame(tmp_path):
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 100, 100
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    scene.frame_start, scene.frame_end, scene.frame_current = 1, 3, 2
    for f, x in ((1, 0.0), (3, 2.0)):
        cam.location = (x, -5, 0)
        cam.keyframe_insert("location", frame=f)
    data = cameras.cameras_transforms([cam], scene, (50, 50), frames=[1, 2, 3], prefix="flythrough")
    xs = [fr["transform_matrix"][0][3] for fr in data["frames"]]
    assert [fr["file_path"] for fr in data["frames"]] == [f"./flythrough/frame_{i:04d}" for i in (1, 2, 3)]
    assert xs[0] == pytest.approx(0.0) and xs[2] == pytest.approx(2.0) and 0 < xs[1] < 2
    assert scene.frame_current == 2  # restored


def test_camera_with_another_aspect_is_refused(tmp_path):
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
    cam = bpy.data.objects.new("Wide", bpy.data.cameras.new("Wide"))
    scene.collection.objects.link(cam)
    with pytest.raises(ValueError, match=r"'Wide' renders at 1920x1080.*aspect 1.778.*trained on 100x100"):
        cameras.cameras_transforms([cam], scene, (100, 100))


def test_image_metrics_against_hand_computed_values(tmp_path):
    a = np.zeros((16, 16, 3))
    b = np.full((16, 16, 3), 0.1)
    assert metrics.psnr(a, b) == pytest.approx(20.0)
    assert metrics.psnr(a, a) == float("inf")
    assert metrics.ssim(b, b) == pytest.approx(1.0)
    rgba = np.zeros((2, 2, 4))
    rgba[..., 3] = 0.25
    assert metrics.composite(rgba, (1, 1, 1))[0, 0] == pytest.approx([0.75] * 3)
    heat = metrics.error_heatmap(a, b, vmax=0.1)
    assert heat.shape == (16, 16, 3) and heat[0, 0] == pytest.approx([0.988, 0.998, 0.645], abs=1e-3)
    path = str(tmp_path / "x.png")
    file_writes.write_png(path, np.dstack([b, np.ones((16, 16))]))
    back = planes.load_image_array(path)
    assert back.shape == (16, 16, 4) and back[0, 0, 0] == pytest.approx(round(0.1 * 255) / 255, abs=1e-6)


def test_a_sibling_run_with_infinite_budgets_is_listed(tmp_path):
    # json reads Infinity; int() of it raised OverflowError and stopped Refresh Runs (and the refresh
    # after every job) at that run.
    from addon.bridge import runs

    for name, steps in (("a_run", float("inf")), ("b_run", 200)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "config.json").write_text(json.dumps({"method": "vmgrid", "max_steps": steps, "seed": 0}))
    listed = runs.list_runs(str(tmp_path))
    assert sorted(os.path.basename(r.path) for r in listed) == ["a_run", "b_run"]
    summaries = {os.path.basename(r.path): r.settings_summary() for r in listed}
    assert summaries["a_run"] == "seed 0" and summaries["b_run"] == "200 steps, seed 0"
