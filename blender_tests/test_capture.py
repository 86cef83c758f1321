"""End-to-end captures checked only through the exported files.

The scene is a 1.5-unit cube at the origin plus a ball off to one side (so a flipped or mirrored
image cannot pass). Known 3D points are projected with the JSON intrinsics/poses (docs/CONTRACTS.md
formula) and must land on opaque pixels; points whose line of sight misses both objects must land on
transparent ones; depth back-projects onto the objects' surfaces.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import bpy
import numpy as np
import OpenEXR
import pytest
from PIL import Image

from addon.capture.layout import positions as layout_positions
from addon.capture.run import job as run_job
from addon.capture.plan import notes as plan_notes, frame_plan, planning, settings as plan_settings
from addon.capture.layout import collection, cameras

PY = sys.executable
CUBE_HALF = 0.75
BALL_C, BALL_R = np.array([1.3, 0.4, 0.5]), 0.35

# The lowest 8-bit alpha of a fully covered pixel. Blender 4.5's Workbench writes 254 there (and
# everywhere with an opaque film; Cycles and 5.0 write 255); nerf_core reads 0.98 and up as opaque.
OPAQUE_ALPHA = 254



def build_test_scene():
    # Module fixtures run before conftest's per-test reset, so start from an empty file here too.
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_cube_add(size=2 * CUBE_HALF)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=BALL_R, location=tuple(BALL_C), segments=48, ring_count=24)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    bpy.context.scene.collection.objects.link(sun)


def do_capture(out, res, engine, spec, tweak=None, **kw):
    build_test_scene()
    scene = bpy.context.scene
    cameras.create_cameras(scene, spec, *res)
    if tweak:
        for split in collection.capture_cameras(scene).values():
            for cam in split:
                tweak(cam)
    settings = plan_settings.CaptureSettings(out_dir=str(out), engine=engine, samples=1, res_x=res[0], res_y=res[1],
                                       layout=spec.to_dict(), **kw)
    return run_job.CaptureJob(scene, settings).run()


def shifted_vertical_fit(cam):
    cam.data.sensor_fit = "VERTICAL"
    cam.data.sensor_height = 20.0
    cam.data.shift_x, cam.data.shift_y = 0.12, -0.08


@pytest.fixture(scope="module")
def cycles_dataset(tmp_path_factory):
    """Non-square Cycles capture with depth, normals, masks and a point cloud."""
    out = tmp_path_factory.mktemp("cyc") / "ds"
    spec = layout_positions.LayoutSpec(layout="sphere", train=6, val=2, test=3, radius=7.0, seed=4)
    summary = do_capture(out, (48, 32), "cycles", spec, depth=True, normals=True, masks=True, points=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return out, summary


@pytest.fixture(scope="module")
def shifted_dataset(tmp_path_factory):
    """Portrait Workbench capture whose cameras have lens shift and a vertical sensor fit."""
    out = tmp_path_factory.mktemp("shift") / "ds"
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=5, val=1, test=2, radius=8.0, elevation_min=10)
    summary = do_capture(out, (30, 44), "workbench", spec, tweak=shifted_vertical_fit, depth=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return out, summary


def frames(out, split):
    with open(os.path.join(out, f"transforms_{split}.json")) as fh:
        doc = json.load(fh)
    for fr in doc["frames"]:
        intr = {k: fr.get(k, doc.get(k)) for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")}
        yield doc, fr, intr


def project(points, c2w, intr):
    w2c = np.linalg.inv(np.asarray(c2w))
    p = (w2c @ np.c_[points, np.ones(len(points))].T)[:3]
    u = intr["cx"] + intr["fl_x"] * p[0] / -p[2]
    v = intr["cy"] - intr["fl_y"] * p[1] / -p[2]
    return u, v, -p[2]


def ray_misses(cam_pos, point, centre, radius):
    """True when the ray from the camera through ``point`` (and beyond) misses the sphere."""
    d = point - cam_pos
    t = max(0.0, np.dot(centre - cam_pos, d) / np.dot(d, d))
    return np.linalg.norm(cam_pos + t * d - centre) > radius


INSIDE = np.array([[0, 0, 0], *(0.85 * CUBE_HALF * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                                                                  for z in (-1, 1)])), BALL_C])
PROBES = np.array(layout_positions.fibonacci_positions(200, 2.6, (0.3, 0.1, 0.0)))


def check_alpha_geometry(out):
    n_opaque = n_clear = 0
    for split in layout_positions.SPLITS:
        for doc, fr, intr in frames(out, split):
            rgba = np.asarray(Image.open(os.path.join(out, fr["file_path"] + ".png")))
            assert rgba.shape == (intr["h"], intr["w"], 4) and rgba.dtype == np.uint8
            alpha = rgba[..., 3]
            u, v, _ = project(INSIDE, fr["transform_matrix"], intr)
            for k, (uu, vv) in enumerate(zip(u, v)):
                if 0 <= uu < intr["w"] and 0 <= vv < intr["h"]:
                    assert alpha[int(vv), int(uu)] > 200, f"{fr['file_path']}: inner point {k} at ({uu:.1f},{vv:.1f})"
                    n_opaque += 1
            cam_pos = np.asarray(fr["transform_matrix"])[:3, 3]
            u, v, _ = project(PROBES, fr["transform_matrix"], intr)
            for p, uu, vv in zip(PROBES, u, v):
                margin = 1.5  # stay clear of antialiased silhouette pixels
                if not (margin <= uu < intr["w"] - margin and margin <= vv < intr["h"] - margin):
                    continue
                if ray_misses(cam_pos, p, np.zeros(3), CUBE_HALF * np.sqrt(3) * 1.08) and \
                        ray_misses(cam_pos, p, BALL_C, BALL_R * 1.3):
                    assert alpha[int(vv), int(uu)] == 0, f"{out}/{fr['file_path']}: empty point at ({uu:.1f},{vv:.1f})"
                    n_clear += 1
    return n_opaque, n_clear


def on_surface(points, tol):
    cube = np.abs(np.max(np.abs(points), axis=1) - CUBE_HALF) < tol
    ball = np.abs(np.linalg.norm(points - BALL_C, axis=1) - BALL_R) < tol
    return cube | ball


def backprojected(out, fr, intr):
    depth = OpenEXR.File(os.path.join(out, fr["depth_file_path"]), separate_channels=True).parts[0].channels["Z"].pixels
    assert depth.shape == (intr["h"], intr["w"]) and depth.dtype == np.float32
    j, i = np.nonzero(np.isfinite(depth))
    z = depth[j, i]
    cam = np.stack([(i + 0.5 - intr["cx"]) / intr["fl_x"] * z, -(j + 0.5 - intr["cy"]) / intr["fl_y"] * z, -z,
                    np.ones_like(z)], 1)
    return (cam @ np.asarray(fr["transform_matrix"]).T)[:, :3], depth


def test_points_land_on_opaque_pixels_and_empty_space_on_transparent(cycles_dataset, shifted_dataset):
    for out, _ in (cycles_dataset, shifted_dataset):
        n_opaque, n_clear = check_alpha_geometry(out)
        assert n_opaque >= 40 and n_clear >= 40, (out, n_opaque, n_clear)


def test_shifted_vertical_fit_intrinsics_are_exported(shifted_dataset):
    out, _ = shifted_dataset
    doc, fr, intr = next(frames(out, "train"))
    w, h = 30, 44
    fy = 50.0 * h / 20.0  # vertical fit: sensor height spans the image height
    assert doc["w"] == w and doc["h"] == h
    assert doc["fl_y"] == pytest.approx(fy) and doc["fl_x"] == pytest.approx(fy)
    assert doc["cx"] == pytest.approx(w / 2 - 0.12 * h)  # shift is in units of the fitted (vertical) side
    assert doc["cy"] == pytest.approx(h / 2 - 0.08 * h)
    assert doc["camera_angle_x"] == pytest.approx(2 * np.arctan(w / (2 * fy)))


def test_depth_backprojects_onto_the_surfaces(cycles_dataset, shifted_dataset):
    for out, _ in (cycles_dataset, shifted_dataset):
        n = 0
        for split in layout_positions.SPLITS:
            for _doc, fr, intr in frames(out, split):
                pts, depth = backprojected(out, fr, intr)
                alpha = np.asarray(Image.open(os.path.join(out, fr["file_path"] + ".png")))[..., 3]
                hit = np.isfinite(depth)
                # Antialiased silhouette pixels are partly covered: compare only the unambiguous ones.
                assert hit[alpha == 255].all() and not hit[alpha == 0].any(), fr["depth_file_path"]
                ok = on_surface(pts, 0.03)
                assert ok.mean() > 0.97, f"{fr['depth_file_path']}: {ok.mean():.3f} of pixels on a surface"
                n += len(pts)
        assert n > 200


def test_normals_masks_and_point_cloud(cycles_dataset):
    out, _ = cycles_dataset
    for _doc, fr, intr in frames(out, "train"):
        pts, depth = backprojected(out, fr, intr)
        ch = OpenEXR.File(os.path.join(out, fr["normal_file_path"]), separate_channels=True).parts[0].channels
        n = np.stack([ch[c].pixels for c in "XYZ"], -1)
        hit = np.isfinite(depth)
        np.testing.assert_allclose(np.linalg.norm(n[hit], axis=-1), 1.0, atol=0.02)
        cam_pos = np.asarray(fr["transform_matrix"])[:3, 3]
        facing = np.einsum("ij,ij->i", n[hit], cam_pos - pts)
        assert (facing > 0).mean() > 0.97  # world-space normals face the camera
        mask = np.asarray(Image.open(os.path.join(out, fr["mask_path"])))
        assert mask.shape == depth.shape and set(np.unique(mask)) <= {0, 255}
        assert (mask[hit] == 255).mean() > 0.97 and (mask[~hit] == 0).all()
    with open(os.path.join(out, "points3d.ply"), "rb") as fh:
        blob = fh.read()
    head, body = blob.split(b"end_header\n", 1)
    count = int(head.split(b"element vertex ")[1].split(b"\n")[0])
    assert b"property float nx\nproperty float ny\nproperty float nz\nproperty uchar red" in head
    rec = np.frombuffer(body, dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("c", "u1", 3)], count=count)
    assert count > 100 and on_surface(rec["p"].astype(float), 0.03).mean() > 0.97
    with open(os.path.join(out, "nerfstudio", "transforms.json")) as fh:
        assert json.load(fh)["ply_file_path"] == "../points3d.ply"  # relative to nerfstudio/


def test_nerfstudio_gets_millimetre_depth_pngs_and_no_object_masks_on_a_transparent_film(cycles_dataset):
    from nerf_core.data.loading import load_dataset

    out, _ = cycles_dataset
    with open(os.path.join(out, "nerfstudio", "transforms.json")) as fh:
        ns = json.load(fh)
    # nerfstudio reads depth with OpenCV as integers x depth_unit_scale_factor (1e-3 by default).
    assert ns["depth_unit_scale_factor"] == 1e-3
    for fr in ns["frames"]:
        # nerfstudio samples only white mask pixels: object masks would hide the transparent background.
        assert "mask_path" not in fr
        png = Image.open(os.path.join(out, "nerfstudio", fr["depth_file_path"]))
        assert png.mode.startswith("I") and fr["depth_file_path"].endswith(".png")
        mm = np.asarray(png).astype(float)
        exr = os.path.join(out, "depth", fr["file_path"][len("../"):-len(".png")] + ".exr")
        z = OpenEXR.File(exr, separate_channels=True).parts[0].channels["Z"].pixels
        hit = np.isfinite(z)
        assert hit.any() and (~hit).any()
        np.testing.assert_allclose(mm[hit], z[hit] * 1000.0, atol=0.51)
        assert (mm[~hit] == 0).all()  # nerfstudio's depth > 0 marks valid pixels
    # Our own loader reads nerfstudio's file with the same depth as the split files (to a millimetre).
    ours = load_dataset(os.path.join(out, "nerfstudio")).splits["train"].depth
    split = load_dataset(out).splits["train"].depth
    seen = split > 0
    np.testing.assert_allclose(ours[seen].numpy(), split[seen].numpy(), atol=6e-4)


def test_background_depth_of_eevee_is_inf_and_opaque_masks_need_cycles(tmp_path):
    from addon.scene import passes

    # EEVEE writes the far clipping plane (a little more off the axis) where Cycles writes 1e10.
    z = np.array([[2.0, 100.5, 1e10], [0.0, 99.95, 50.0]], np.float32)
    np.testing.assert_array_equal(passes.planar_depth(z, clip_end=100.0),
                                  [[2.0, np.inf, np.inf], [np.inf, np.inf, 50.0]])
    np.testing.assert_array_equal(passes.planar_depth(z), np.array([[2.0, 100.5, np.inf],
                                                                    [np.inf, 99.95, 50.0]], np.float32))
    build_test_scene()
    scene = bpy.context.scene
    spec = layout_positions.LayoutSpec(layout="sphere", train=3, val=0, test=1, radius=7.0)
    cameras.create_cameras(scene, spec, 16, 16)
    for engine in ("workbench", "eevee"):
        settings = plan_settings.CaptureSettings(out_dir=str(tmp_path / engine), engine=engine, res_x=16, res_y=16,
                                           film_transparent=False, masks=True, layout=spec.to_dict())
        with pytest.raises(frame_plan.CaptureError, match="opaque film need Cycles"):
            run_job.CaptureJob(scene, settings)


def test_splits_are_disjoint_and_every_file_exists(cycles_dataset):
    out, summary = cycles_dataset
    assert summary["status"] == "complete" and summary["frames"] == 11
    positions = {}
    for split in layout_positions.SPLITS:
        for doc, fr, _ in frames(out, split):
            assert not fr["file_path"].endswith(".png") and fr["file_path"].startswith(f"./{split}/")
            assert os.path.isfile(os.path.join(out, fr["file_path"] + ".png"))
            for key in ("depth_file_path", "normal_file_path", "mask_path"):
                assert os.path.isfile(os.path.join(out, fr[key]))
            positions[fr["file_path"]] = np.asarray(fr["transform_matrix"])[:3, 3]
            assert {"aabb", "near", "far", "camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h"} <= set(doc)
    train = [p for k, p in positions.items() if "/train/" in k]
    held = [p for k, p in positions.items() if "/train/" not in k]
    assert len(train) == 6 and len(held) == 5
    assert min(np.linalg.norm(a - b) for a in train for b in held) > 1e-3
    with open(os.path.join(out, "nerfstudio", "transforms.json")) as fh:
        ns = json.load(fh)
    assert len(ns["train_filenames"]) == 6 and len(ns["val_filenames"]) == 2 and len(ns["test_filenames"]) == 3
    assert not set(ns["train_filenames"]) & set(ns["test_filenames"] + ns["val_filenames"])
    for fr in ns["frames"]:
        assert fr["file_path"].endswith(".png") and os.path.isfile(os.path.join(out, "nerfstudio", fr["file_path"]))
    doc = json.load(open(os.path.join(out, "transforms_train.json")))
    lo, hi = np.asarray(doc["aabb"])
    np.testing.assert_allclose(lo, [-CUBE_HALF, -CUBE_HALF, -CUBE_HALF], atol=1e-5)
    np.testing.assert_allclose(hi, BALL_C + BALL_R, atol=1e-5)
    assert 0 < doc["near"] < 7 - 1.5 and doc["far"] > 7 + 1.3
    # instant-ngp fits the written aabb to its unit cube; on a transparent film nothing lies beyond it.
    assert doc["aabb_scale"] == 1


def test_ngp_aabb_scale_reaches_twice_the_farthest_camera_when_the_scene_renders_beyond_the_box():
    from addon.dataset.aabb import ngp_aabb_scale

    # Off-centre and large, but all inside the box: instant-ngp's aabb mapping makes it fill the cube.
    assert ngp_aabb_scale((2.8, 2.8, 0), (7.2, 7.2, 3.5), [(15, 0, 2)], beyond_box=False) == 1
    # Box side 2 centred at 0, camera 4 away: the cube must reach 8, i.e. 8 box sides -> 8.
    assert ngp_aabb_scale((-1, -1, -1), (1, 1, 1), [(0, 4, 0), (1, 0, 0)], beyond_box=True) == 8
    assert ngp_aabb_scale((-1, -1, -1), (1, 1, 1), [(0, 4.1, 0)], beyond_box=True) == 16
    assert ngp_aabb_scale((-1, -1, -1), (1, 1, 1), [(0, 0.1, 0)], beyond_box=True) == 1
    assert ngp_aabb_scale((0, 0, 0), (1e-3, 1e-3, 1e-3), [(1e6, 0, 0)], beyond_box=True) == 128


def test_manifest_records_settings_and_no_normalisation(cycles_dataset):
    out, _ = cycles_dataset
    assert not [f for f in os.listdir(out) if f.endswith(".json") and not f.startswith("transforms")]
    # instant-ngp loads every *.json of the folder: the root holds one transforms set, nothing else
    assert sorted(f for f in os.listdir(out) if f.endswith(".json")) == [
        "transforms_test.json", "transforms_train.json", "transforms_val.json"]
    with open(os.path.join(out, "nerf_capture", "manifest.json")) as fh:
        m = json.load(fh)
    assert m["status"] == "complete" and m["blender_version"].startswith("%d.%d" % bpy.app.version[:2])
    assert m["normalization"]["scale"] == 1.0 and m["normalization"]["offset"] == [0.0, 0.0, 0.0]
    assert m["render"]["engine"] == "CYCLES" and m["render"]["resolution"] == [48, 32]
    assert {"view_transform", "look", "exposure", "gamma", "display_device"} <= set(m["render"]["color_management"])
    assert m["layout"]["layout"] == "sphere" and m["seed"] == 0 and m["layout"]["seed"] == 4
    assert len(m["frames"]) == 11 and all(f["done"] and len(f["hash"]) == 16 for f in m["frames"].values())
    assert len({f["hash"] for f in m["frames"].values()}) == 11


def test_nerf_core_check_accepts_the_datasets(cycles_dataset, shifted_dataset):
    for out, _ in (cycles_dataset, shifted_dataset):
        proc = subprocess.run([PY, "-m", "nerf_core", "check", str(out)], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr


def test_scene_cameras_with_different_lenses_get_per_frame_intrinsics(tmp_path):
    build_test_scene()
    scene = bpy.context.scene
    from mathutils import Matrix

    for k, (lens, pos) in enumerate([(35.0, (6, -6, 3)), (50.0, (-7, -5, 2)), (80.0, (0, 9, 4))]):
        cam = bpy.data.objects.new(f"User{k}", bpy.data.cameras.new(f"User{k}"))
        cam.data.lens = lens
        scene.collection.objects.link(cam)
        cam.matrix_world = Matrix(layout_positions.look_at(pos, (0.3, 0.2, 0.0)))
    spec = layout_positions.LayoutSpec(layout="scene-cameras", val=0, test=1, seed=1)
    cameras.create_cameras(scene, spec, 40, 30)
    job = run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), engine="workbench", res_x=40,
                                                            res_y=30, layout=spec.to_dict()))
    job.plan()  # says, before rendering, that one camera_angle_x cannot hold three lenses
    assert any("3 different cameras" in n and "3DGS" in n for n in job.notes), job.notes
    job.run()
    lenses = set()
    for split in ("train", "test"):
        for doc, fr, intr in frames(tmp_path, split):
            assert "fl_x" in fr and "camera_angle_x" in fr  # per frame, since they differ
            lenses.add(round(fr["fl_x"] * 36.0 / 40, 3))
    assert lenses == {35.0, 50.0, 80.0}
    # nerfstudio-data takes a top-level intrinsic for every frame: its file leaves them to the frames.
    with open(os.path.join(tmp_path, "nerfstudio", "transforms.json")) as fh:
        ns = json.load(fh)
    assert not {"fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x"} & set(ns)
    assert {round(fr["fl_x"] * 36.0 / 40, 3) for fr in ns["frames"]} == {35.0, 50.0, 80.0}
    proc = subprocess.run([PY, "-m", "nerf_core", "check", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert "WARNING transforms_train.json: field 'fl_x': the views have 2 different cameras" in proc.stdout, proc.stdout
    for split in ("train", "test"):  # centres are deep inside the silhouettes even at this tiny size
        for _doc, fr, intr in frames(tmp_path, split):
            alpha = np.asarray(Image.open(os.path.join(tmp_path, fr["file_path"] + ".png")))[..., 3]
            u, v, _ = project(np.array([[0.0, 0.0, 0.0], BALL_C]), fr["transform_matrix"], intr)
            assert all(alpha[int(vv), int(uu)] >= OPAQUE_ALPHA for uu, vv in zip(u, v)), fr["file_path"]


def test_depth_of_field_is_off_while_capturing_and_restored_after(tmp_path):
    # A scene camera focused far behind the scene at f/0.1 blurs everything; the capture must render
    # it as the sharp pinhole its transforms describe, and leave the user's camera as it was.
    from mathutils import Matrix

    build_test_scene()
    scene = bpy.context.scene
    cams = []
    for k, pos in enumerate([(6, -6, 3), (-7, -5, 2)]):
        cam = bpy.data.objects.new(f"User{k}", bpy.data.cameras.new(f"User{k}"))
        scene.collection.objects.link(cam)
        cam.matrix_world = Matrix(layout_positions.look_at(pos, (0.3, 0.2, 0.0)))
        cams.append(cam)
    spec = layout_positions.LayoutSpec(layout="scene-cameras", val=0, test=1, seed=1)
    made = cameras.create_cameras(scene, spec, 40, 30)
    settings = dict(engine="cycles", samples=4, res_x=40, res_y=30, layout=spec.to_dict())
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path / "sharp"), **settings)).run()
    for obj in made:
        obj.data.dof.use_dof, obj.data.dof.aperture_fstop, obj.data.dof.focus_distance = True, 0.1, 100.0
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path / "dof"), **settings)).run()
    assert all(obj.data.dof.use_dof for obj in made)  # restored
    for split in ("train", "test"):
        for (_d, fr, _i), (_d2, fr2, _i2) in zip(frames(tmp_path / "sharp", split), frames(tmp_path / "dof", split)):
            a = np.asarray(Image.open(os.path.join(tmp_path / "sharp", fr["file_path"] + ".png")))
            b = np.asarray(Image.open(os.path.join(tmp_path / "dof", fr2["file_path"] + ".png")))
            assert np.array_equal(a, b), fr["file_path"]


def test_a_subject_on_a_vast_floor_gets_a_scene_box_around_the_subject(tmp_path):
    from addon.scene import scene_bounds

    build_test_scene()
    bpy.ops.mesh.primitive_plane_add(size=200.0, location=(0, 0, -CUBE_HALF))
    scene = bpy.context.scene
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=3, val=1, test=1)
    cameras.create_cameras(scene, spec, 40, 30)
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), engine="workbench",
                                                            res_x=40, res_y=30,
                                                      layout=spec.to_dict())).run()
    lo, hi, around = scene_bounds.subject_bounds(scene)
    box = [list(v) for v in scene_bounds.subject_box(scene, lo, hi)]
    doc = json.loads((tmp_path / "transforms_train.json").read_text())
    assert np.allclose(doc["aabb"], box) and doc["aabb"][1][0] - doc["aabb"][0][0] < 10.0  # not the 200 m floor
    manifest = json.loads((tmp_path / "nerf_capture" / "manifest.json").read_text())
    assert manifest["plan"]["bounds"]["surroundings"] == ["Plane"] == around
    assert doc["beyond_box"] == ["Plane"]  # so that train models the floor beyond the box (--unbounded)
    # A room captured from inside keeps the whole scene as its box.
    whole = planning.scene_box(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), layout={"layout": "inside"}))
    assert whole[1] == [] and whole[0][1][0] - whole[0][0][0] == pytest.approx(200.0)


def test_a_flat_subject_gets_a_box_with_thickness_that_train_accepts(tmp_path):
    # A lone plane (a painting, an image imported as a plane) spans no z: its box was 0 thick, and every
    # loader refused the dataset (min < max).
    from addon.scene import scene_bounds
    from nerf_core.data.problems import dataset_problems

    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 0.0, 0.3))
    scene = bpy.context.scene
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=3, val=1, test=1)
    cameras.create_cameras(scene, spec, 40, 30)
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), engine="workbench",
                                                            res_x=40, res_y=30,
                                                      layout=spec.to_dict())).run()
    lo, hi = np.array(json.loads((tmp_path / "transforms_train.json").read_text())["aabb"])
    thick = scene_bounds.MIN_THICKNESS * math.sqrt(8.0)  # of the plane's 2 x 2 x 0 diagonal
    assert np.allclose(lo, [-1.0, -1.0, 0.3 - thick / 2], atol=1e-5)
    assert np.allclose(hi, [1.0, 1.0, 0.3 + thick / 2], atol=1e-5)
    assert dataset_problems(tmp_path) == []
    with pytest.raises(scene_bounds.BoundsError, match="span no space"):
        scene_bounds.with_thickness((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))


@pytest.mark.parametrize("size", [0.02, 2000.0])
def test_a_tiny_or_huge_subject_is_captured_whole(tmp_path, size):
    # Framed from 6 cm, a 2 cm object lay wholly inside Blender's default 10 cm clip_start: every
    # image was empty. A 2 km one is framed from 5.9 km and must not be cut by clip_end either.
    bpy.ops.mesh.primitive_monkey_add(size=size)
    scene = bpy.context.scene
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=3, val=1, test=1)
    made = cameras.create_cameras(scene, spec, 40, 30)
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), engine="workbench",
                                                            res_x=40, res_y=30,
                                                      layout=spec.to_dict())).run()
    for split in ("train", "val", "test"):
        for _doc, fr, _intr in frames(tmp_path, split):
            alpha = np.asarray(Image.open(os.path.join(tmp_path, fr["file_path"] + ".png")))[..., 3]
            # The whole monkey: opaque, and none of it touching the frame's border.
            assert (alpha > 0).mean() > 0.05 and not alpha[[0, -1]].any(), fr["file_path"]
    assert all(o.data.clip_start < 0.5 * o.matrix_world.translation.length for o in made)


def test_masks_of_a_selection_cover_only_it(tmp_path):
    build_test_scene()
    scene = bpy.context.scene
    for obj in scene.objects:
        obj.select_set(obj.name == "Sphere")
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=3, val=0, test=1, radius=7.0, elevation_min=20)
    cameras.create_cameras(scene, spec, 40, 30)
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), engine="cycles", samples=1, res_x=40,
                                                      res_y=30, masks=True, target="SELECTION")).run()
    assert bpy.data.objects["Cube"].pass_index == 0 and bpy.data.objects["Sphere"].pass_index == 0  # restored
    for split in ("train", "test"):
        for _doc, fr, intr in frames(tmp_path, split):
            mask = np.asarray(Image.open(os.path.join(tmp_path, fr["mask_path"]))) > 0
            alpha = np.asarray(Image.open(os.path.join(tmp_path, fr["file_path"] + ".png")))[..., 3]
            u, v, _ = project(np.array([[0.0, 0.0, 0.0], BALL_C]), fr["transform_matrix"], intr)
            cube_px, ball_px = (int(v[0]), int(u[0])), (int(v[1]), int(u[1]))
            assert mask[ball_px] or not alpha[ball_px]  # the ball, unless hidden behind the cube
            assert alpha[cube_px] == 255
            assert mask.sum() < (alpha > 0).sum() * 0.6  # the cube is not in the mask


def test_masks_cover_objects_shown_by_a_collection_instance(tmp_path):
    # A linked asset arrives as an empty instancing a collection excluded from the view layer. Cycles
    # gives an instance the pass index of the object it shows, which capture never set: the masks
    # left the instanced ball out (checked: 80 of 170 opaque pixels of a view unmasked).
    build_test_scene()
    scene = bpy.context.scene
    ball = bpy.data.objects["Sphere"]
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    for coll in ball.users_collection:
        coll.objects.unlink(ball)
    props.objects.link(ball)
    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    ball.pass_index = 7  # the user's own index comes back after the capture
    empty = bpy.data.objects.new("Props instance", None)
    empty.instance_type, empty.instance_collection = "COLLECTION", props
    scene.collection.objects.link(empty)
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=3, val=0, test=0, radius=7.0, elevation_min=20)
    cameras.create_cameras(scene, spec, 40, 30)

    def masks(out, target):
        run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(out), engine="cycles", samples=1, res_x=40,
                                                          res_y=30, masks=True, target=target)).run()
        assert ball.pass_index == 7
        for _doc, fr, intr in frames(out, "train"):
            mask = np.asarray(Image.open(os.path.join(out, fr["mask_path"]))) > 0
            alpha = np.asarray(Image.open(os.path.join(out, fr["file_path"] + ".png")))[..., 3] > 0
            u, v, _ = project(np.array([[0.0, 0.0, 0.0], BALL_C]), fr["transform_matrix"], intr)
            yield mask, alpha, (int(v[0]), int(u[0])), (int(v[1]), int(u[1]))

    for mask, alpha, cube_px, ball_px in masks(tmp_path / "all", "ALL"):
        assert alpha[ball_px] and mask[ball_px] and mask[cube_px]
        assert (mask == alpha).mean() > 0.97  # everything that renders, the edges aside
    for obj in scene.objects:  # only the instancer selected: its ball, not the cube
        obj.select_set(obj is empty)
    for mask, alpha, cube_px, ball_px in masks(tmp_path / "selection", "SELECTION"):
        assert (mask[ball_px] or not alpha[ball_px]) and alpha[cube_px] and not mask[cube_px]
        assert 0 < mask.sum() < (alpha > 0).sum() * 0.6


def test_holdouts_are_named_before_a_capture(tmp_path):
    # A holdout cuts a transparent hole through everything behind it: opaque to what lies behind, yet
    # adding no alpha, which no radiance field can be. The capture names each kind of holdout.
    build_test_scene()
    scene = bpy.context.scene
    spec = layout_positions.LayoutSpec(layout="hemisphere", train=2, val=0, test=0, radius=7.0, elevation_min=20)
    cameras.create_cameras(scene, spec, 40, 30)

    def notes():
        settings = plan_settings.CaptureSettings(out_dir=str(tmp_path / "ds"), engine="cycles", samples=1, res_x=40,
                                           res_y=30, film_transparent=False)
        return run_job.CaptureJob(scene, settings).notes

    assert notes() == []
    ball = bpy.data.objects["Sphere"]
    ball.is_holdout = True
    assert len(notes()) == 1 and "'Sphere' render(s) as holdout" in notes()[0]
    ball.is_holdout = False
    mat = bpy.data.materials.new("Cut-out")
    if mat.node_tree is None:  # Blender < 5.0 creates materials without nodes
        mat.use_nodes = True
    group = bpy.data.node_groups.new("Mask group", "ShaderNodeTree")
    group.nodes.new("ShaderNodeHoldout")
    mat.node_tree.nodes.new("ShaderNodeGroup").node_tree = group  # inside a node group counts too
    bpy.data.objects["Cube"].data.materials.append(mat)
    assert "'Cube' render(s) as holdout" in notes()[0]
    bpy.data.objects["Cube"].data.materials.clear()
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    props.objects.link(ball)
    bpy.context.view_layer.layer_collection.children["Props"].holdout = True
    assert "'Sphere' render(s) as holdout" in notes()[0]
    # What the note is about: on an opaque film, the hole has alpha 0 where the ball is.
    out = tmp_path / "ds"
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(out), engine="cycles", samples=1, res_x=40,
                                                      res_y=30, film_transparent=False)).run()
    _doc, fr, intr = next(iter(frames(out, "train")))
    alpha = np.asarray(Image.open(os.path.join(out, fr["file_path"] + ".png")))[..., 3]
    u, v, _ = project(np.array([BALL_C]), fr["transform_matrix"], intr)
    assert alpha[int(v[0]), int(u[0])] == 0 and alpha[0, 0] == 255


def test_missing_textures_and_libraries_are_named_before_a_capture(tmp_path):
    # Blender renders a missing texture magenta and a missing library's objects not at all, without
    # a word: the capture was "complete" and check said "valid" for a dataset of the wrong scene.
    build_test_scene()
    scene = bpy.context.scene
    cameras.create_cameras(scene, layout_positions.LayoutSpec(layout="hemisphere", train=2, val=0, test=0,
                                                              radius=7.0), 40, 30)

    def notes():
        return run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path / "ds"), res_x=40,
                                                                       res_y=30)).notes

    assert notes() == []
    tex = tmp_path / "wood.png"
    bpy.data.images.new("wood", 4, 4).save(filepath=str(tex))
    mat = bpy.data.materials.new("Wood")
    if mat.node_tree is None:  # Blender < 5.0 creates materials without nodes
        mat.use_nodes = True
    group = bpy.data.node_groups.new("Wood group", "ShaderNodeTree")
    group.nodes.new("ShaderNodeTexImage").image = bpy.data.images.load(str(tex))  # inside a group counts too
    mat.node_tree.nodes.new("ShaderNodeGroup").node_tree = group
    bpy.data.objects["Cube"].data.materials.append(mat)
    assert notes() == []
    tex.unlink()
    assert len(notes()) == 1 and "'wood.png'" in notes()[0] and "magenta" in notes()[0]
    bpy.data.images["wood.png"].pack(data=b"\x89PNG", data_len=4)  # packed: nothing is read from disk
    assert notes() == []
    # a library of linked objects, moved away after the file was saved
    lib_path, main_path = tmp_path / "assets.blend", tmp_path / "main.blend"
    bpy.ops.mesh.primitive_monkey_add(location=(9, 9, 9))
    bpy.data.libraries.write(str(lib_path), {bpy.context.active_object})
    bpy.data.objects.remove(bpy.context.active_object)
    with bpy.data.libraries.load(str(lib_path), link=True) as (_src, dst):
        dst.objects = ["Suzanne"]
    scene.collection.objects.link(dst.objects[0])
    bpy.ops.wm.save_as_mainfile(filepath=str(main_path))
    lib_path.rename(tmp_path / "moved.blend")
    bpy.ops.wm.open_mainfile(filepath=str(main_path))
    scene = bpy.context.scene
    found = notes()
    assert any("'assets.blend'" in n and "'Suzanne' will not render" in n for n in found), found


def test_masks_refuse_what_the_object_index_pass_never_marks(tmp_path):
    # Cycles' object index pass has no value for Grease Pencil (drawn over the render) or volumes:
    # masks called those pixels background, and check then refused the dataset, or passed it with
    # the drawing marked "ignore".
    build_test_scene()
    scene = bpy.context.scene
    cameras.create_cameras(scene, layout_positions.LayoutSpec(layout="hemisphere", train=2, val=0, test=0,
                                                              radius=7.0), 40, 30)
    bpy.ops.object.grease_pencil_add(type="MONKEY", location=(0, 0, 1))

    def job(engine, target="ALL"):
        return run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path / "ds"),
                                                                       engine=engine, res_x=40,
                                                                 res_y=30, masks=True, target=target))

    with pytest.raises(frame_plan.CaptureError, match=r"never marks 'Suzanne \(Grease Pencil\)'.*alpha"):
        job("cycles")
    job("workbench")  # masks from the alpha, which the drawing has
    for obj in scene.objects:
        obj.select_set(obj.name == "Cube")
    job("cycles", "SELECTION")  # the drawing is not masked: nothing to refuse


def test_animation_layout_renders_each_sampled_frame(tmp_path):
    build_test_scene()
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Anim", bpy.data.cameras.new("Anim"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.frame_start, scene.frame_end = 1, 41
    ball = bpy.data.objects["Sphere"]
    for f, x in ((1, -6.0), (41, 6.0)):
        cam.location = (x, -8.0, 2.0)
        cam.keyframe_insert("location", frame=f)
        ball.location = (x, 0.0, 1.2)  # the ball follows the camera: a view of the wrong frame misses it
        ball.keyframe_insert("location", frame=f)
    cam.rotation_euler = (np.radians(80), 0, 0)
    scene.frame_set(5)
    spec = layout_positions.LayoutSpec(layout="animation", frame_step=20, val=0, test=1, seed=0)
    cameras.create_cameras(scene, spec, 40, 30)
    run_job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(tmp_path), engine="workbench", res_x=40,
                                                      res_y=30)).run()
    assert scene.frame_current == 5 and scene.camera == cam
    seen = {}
    for split in ("train", "test"):
        for _doc, fr, intr in frames(tmp_path, split):
            x = {1: -6.0, 21: 0.0, 41: 6.0}[fr["blender_frame"]]
            assert fr["transform_matrix"][0][3] == pytest.approx(x, abs=1e-4)
            alpha = np.asarray(Image.open(os.path.join(tmp_path, fr["file_path"] + ".png")))[..., 3]
            ball_at = np.array([[x, 0.0, 1.2]])
            u, v, _ = project(ball_at, fr["transform_matrix"], intr)
            assert 0 <= u[0] < 40 and 0 <= v[0] < 30
            assert alpha[int(v[0]), int(u[0])] >= OPAQUE_ALPHA, \
                f"ball of frame {fr['blender_frame']} not where expected"
            seen[fr["blender_frame"]] = True
    assert sorted(seen) == [1, 21, 41]


def test_depth_beyond_what_nerfstudio_pngs_hold_is_named():
    # nerfstudio's depth PNGs hold millimetres in 16 bits: a 500-unit scene came out as PNGs of zeros,
    # a 1 mm one as three levels, with nothing said (the EXR depth maps were right).
    def frames_at(distance):
        return [{"transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, distance], [0, 0, 0, 1]]}]

    def box(half):
        return (-half, -half, -half), (half, half, half)

    assert plan_notes.depth_png_notes(frames_at(5.0), box(1.0)) == []
    huge = plan_notes.depth_png_notes(frames_at(900.0), box(250.0))
    assert len(huge) == 1 and "reaches 1150 units" in huge[0] and "written there as 0" in huge[0]
    tiny = plan_notes.depth_png_notes(frames_at(0.004), box(0.001))
    assert len(tiny) == 1 and "at most 5 steps" in tiny[0]


def test_the_film_filter_is_recorded_for_render_and_eval(tmp_path):
    """Every transforms file names the film filter the images went through (nerf_core renders edge
    pixels through it); a filter other than Blender's default is part of the render signature, so a
    changed filter re-renders on resume instead of mixing two films in one dataset."""
    spec = layout_positions.LayoutSpec(layout="sphere", train=2, val=0, test=1, radius=7.0, seed=4)
    default = tmp_path / "default"
    do_capture(default, (16, 12), "cycles", spec)
    gauss = tmp_path / "gauss"
    build_test_scene()
    bpy.context.scene.cycles.pixel_filter_type = "GAUSSIAN"
    bpy.context.scene.cycles.filter_width = 2.25
    scene = bpy.context.scene
    cameras.create_cameras(scene, spec, 16, 12)
    settings = plan_settings.CaptureSettings(out_dir=str(gauss), engine="cycles", samples=1, res_x=16, res_y=12,
                                       layout=spec.to_dict())
    run_job.CaptureJob(scene, settings).run()
    for out, want in ((default, {"type": "BLACKMAN_HARRIS", "width": 1.5}),
                      (gauss, {"type": "GAUSSIAN", "width": 2.25})):
        for name in ("transforms_train.json", "transforms_test.json", "nerfstudio/transforms.json"):
            with open(out / name) as fh:
                assert json.load(fh)["pixel_filter"] == want, (out, name)
        with open(out / "nerf_capture" / "manifest.json") as fh:
            render = json.load(fh)["render"]
        assert render.get("pixel_filter") == (None if out == default else want)
    # Workbench and EEVEE: Film > Filter Size, Blackman-Harris; Workbench without anti-aliasing: none
    scene.render.filter_size = 0.75
    assert plan_settings.film_filter(scene, "BLENDER_EEVEE_NEXT") == {"type": "BLACKMAN_HARRIS", "width": 0.75}
    scene.display.render_aa = "OFF"
    assert plan_settings.film_filter(scene, "BLENDER_WORKBENCH") == {"type": "NONE"}
    # and nerf_core reads it back
    proc = subprocess.run([PY, "-c", "import sys; from nerf_core.data.loading import load_dataset; "
                           "print(load_dataset(sys.argv[1]).pixel_filter)", str(gauss)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "PixelFilter(kind='GAUSSIAN', width=2.25, downscale=1)" in proc.stdout, proc.stderr
