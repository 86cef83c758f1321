"""Round trips with other tools' camera files (addon/capture/layout/camera_import.py, scripts/import_cameras.py,
addon/compare/nerfstudio_results.py): a capture's cameras imported back from every format are the same
cameras; re-capturing them reproduces the images; nerfstudio's re-oriented world comes back exactly.

The capture: the default cube seen by 5 cameras of the scene (Cycles, 2 samples, 30x18 px, pixel aspect
1:1.25), each with its own lens, lens shift and sensor fit (VERTICAL and HORIZONTAL on a non-square image).
"""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys

import bpy
import numpy as np
import pytest
from mathutils import Matrix

from addon.capture.layout import camera_import, cameras, positions
from addon.capture.run import job
from addon.capture.plan import settings as plan_settings
from addon.compare import nerfstudio_results
from addon.dataset import cameras as dataset_cameras
from nerf_core.contract import nerfstudio_frame
from nerf_core.image.io import read_exr

RES = (30, 18)
ASPECT = (1.0, 1.25)
# lens (mm), shift x, shift y, sensor fit, location
CAMERAS = [(50.0, 0.1, -0.05, "VERTICAL", (6, -5, 3)), (35.0, 0.0, 0.0, "HORIZONTAL", (-6, -4, 4)),
           (70.0, -0.08, 0.12, "AUTO", (5, 6, 2)), (42.0, 0.03, 0.0, "VERTICAL", (-5, 5, 5)),
           (60.0, 0.0, 0.07, "HORIZONTAL", (0, -8, 1))]


def _look_at(loc):
    return Matrix(positions.look_at(loc, (0.0, 0.0, 0.0)))


def _build_scene(scene):
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.8, 0.6, 1.2))
    for k, (lens, sx, sy, fit, loc) in enumerate(CAMERAS):
        data = bpy.data.cameras.new(f"Cam{k}")
        data.lens, data.shift_x, data.shift_y, data.sensor_fit = lens, sx, sy, fit
        data.sensor_height = 20.0
        ob = bpy.data.objects.new(f"Cam{k}", data)
        scene.collection.objects.link(ob)
        ob.matrix_world = _look_at(loc)
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = ASPECT


def _capture(scene, out, spec=None):
    spec = spec or positions.LayoutSpec(layout="scene-cameras", train=3, val=1, test=1, seed=3)
    cameras.create_cameras(scene, spec, *RES)
    settings = plan_settings.CaptureSettings(out_dir=str(out), engine="cycles", samples=2, res_x=RES[0],
                                                res_y=RES[1], layout=spec.to_dict(), seed=0,
                                                depth=True, normals=True, masks=True)
    summary = job.CaptureJob(scene, settings).run()
    assert summary["status"] == "complete"


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    """{'blend': the scene without capture cameras, 'dataset': its capture}."""
    root = tmp_path_factory.mktemp("roundtrip")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    _build_scene(scene)
    blend = str(root / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend, copy=True)
    _capture(scene, root / "dataset")
    return {"blend": blend, "dataset": str(root / "dataset"), "root": root}


def _frames(dataset):
    """[(split, frame dict with the file's intrinsics merged in)] of a synthetic capture, in file order."""
    out = []
    for split in ("train", "val", "test"):
        meta = json.load(open(os.path.join(dataset, f"transforms_{split}.json")))
        for fr in meta["frames"]:
            out.append((split, {**{k: meta[k] for k in ("fl_x", "fl_y", "cx", "cy", "w", "h") if k in meta}, **fr}))
    return out


def _ngp_file(dataset, path):
    """instant-ngp's layout of the capture: one transforms.json, per-frame intrinsics, its own fields."""
    frames = []
    for split, fr in _frames(dataset):
        frames.append({"file_path": os.path.join(dataset, fr["file_path"] + ".png"), "sharpness": 50.0,
                       "transform_matrix": fr["transform_matrix"],
                       **{k: fr[k] for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")}})
    json.dump({"aabb_scale": 4, "scale": 0.33, "offset": [0.5, 0.5, 0.5], "frames": frames}, open(path, "w"))
    return path


def _check_cameras(scene, dataset, keep_split=True):
    coll = camera_import.imported_collection(scene, create=False)
    cams = sorted((o for o in coll.objects if camera_import.is_imported(o)),
                  key=lambda o: o[camera_import.IMPORT_INDEX])
    want = _frames(dataset)
    assert len(cams) == len(want)
    for cam, (split, fr) in zip(cams, want):
        got = np.array(cam.matrix_world)
        assert np.abs(got - np.array(fr["transform_matrix"])).max() <= 1e-5, cam.name
        intr = dataset_cameras.camera_intrinsics(cam, scene.render)
        for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            # exact up to Blender's float32 camera properties (lens, sensor, shift: 6e-8 relative each)
            assert intr[key] == pytest.approx(fr[key], rel=1e-6, abs=1e-5), (cam.name, key)
        if keep_split:
            assert cam[camera_import.IMPORT_SPLIT] == split


@pytest.mark.parametrize("source", ["folder", "split_file", "nerfstudio", "instant-ngp"])
def test_every_format_imports_the_capture_cameras_exactly(captured, source, tmp_path):
    ds = captured["dataset"]
    path = {"folder": ds, "split_file": os.path.join(ds, "transforms_val.json"),
            "nerfstudio": os.path.join(ds, "nerfstudio", "transforms.json"),
            "instant-ngp": str(tmp_path / "transforms.json")}[source]
    if source == "instant-ngp":
        _ngp_file(ds, path)
    scene = bpy.context.scene
    summary = camera_import.import_cameras(scene, path)
    assert summary["format"] == {"folder": "synthetic", "split_file": "synthetic"}.get(source, source)
    assert summary["warnings"] == []
    assert (scene.render.resolution_x, scene.render.resolution_y) == RES
    assert (scene.render.pixel_aspect_x, scene.render.pixel_aspect_y) == pytest.approx(ASPECT)
    _check_cameras(scene, ds, keep_split=source != "instant-ngp")


def test_the_script_imports_into_an_empty_blend_and_the_recapture_reproduces_the_images(captured, tmp_path, repo_root):
    out = str(tmp_path / "imported.blend")
    cmd = [sys.executable, os.path.join(repo_root, "scripts", "import_cameras.py"), "--blend", captured["blend"],
           "--transforms", os.path.join(captured["dataset"], "transforms_train.json"), "--out", out]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1])["cameras"] == 5
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "already exists" in again.stderr  # never replaced silently
    bpy.ops.wm.open_mainfile(filepath=out)
    scene = bpy.context.scene
    _check_cameras(scene, captured["dataset"])
    # The scene-cameras layout re-renders exactly these cameras in the file's splits and order.
    _capture(scene, tmp_path / "again", positions.LayoutSpec(layout="scene-cameras", train=1, val=2, test=2, seed=9))
    for split, fr in _frames(captured["dataset"]):
        a = _pixels(os.path.join(captured["dataset"], fr["file_path"] + ".png"))
        b = _pixels(os.path.join(str(tmp_path / "again"), fr["file_path"] + ".png"))
        assert a[..., 3].mean() > 0.05 and np.array_equal(a, b), fr["file_path"]
        # and the other ground truth the capture writes per view. Masks are identical. Depth and normals
        # are floats: an imported camera's matrix is rebuilt from Blender's location/rotation, which can
        # move its last bit, so a sub-sample ray that grazes a silhouette may land on the other side
        # (measured: depth within 2e-6 relative, one normals pixel of 540 off by 0.03).
        for key in ("depth_file_path", "normal_file_path", "mask_path"):
            assert fr.get(key), (fr["file_path"], key)
            a, b = (_file_values(os.path.join(root, fr[key])) for root in (captured["dataset"],
                                                                           str(tmp_path / "again")))
            assert a.keys() == b.keys(), fr[key]
            for c in a:
                if key == "mask_path":
                    assert np.array_equal(a[c], b[c]), fr[key]
                    continue
                same = np.isclose(b[c], a[c], rtol=1e-5, atol=1e-6) | (np.isinf(a[c]) & (a[c] == b[c]))
                assert same.mean() >= 0.99, (fr[key], c, 1 - same.mean())


def _file_values(path):
    """{channel: values} of a depth/normal EXR (read as nerf_core reads it) or a mask PNG."""
    if path.endswith(".exr"):
        return read_exr(path)
    return {"png": _pixels(path)}


def _pixels(path):
    img = bpy.data.images.load(path, check_existing=False)
    try:
        px = np.empty(img.size[0] * img.size[1] * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(-1, 4)
    finally:
        bpy.data.images.remove(img)


def test_distortion_blender_cannot_model_is_named_per_frame(captured, tmp_path):
    path = _ngp_file(captured["dataset"], str(tmp_path / "transforms.json"))
    meta = json.load(open(path))
    meta["frames"][1]["k1"] = -0.05
    meta["frames"][3].update(camera_model="OPENCV_FISHEYE")
    json.dump(meta, open(path, "w"))
    summary = camera_import.import_cameras(bpy.context.scene, path)
    (warning,) = summary["warnings"]
    assert "2 camera(s)" in warning and "r_1" in warning and "r_0" in warning and "OPENCV_FISHEYE" in warning


def _nerfstudio_dataparser(poses):
    """nerfstudio's dataparser transform for camera-to-world ``poses`` (n, 4, 4), by its default rules
    (``auto_orient_and_center_poses`` with method "up" and center "poses", then ``auto_scale_poses``):
    centre = the mean camera position; R turns the mean of the cameras' up axes (+Y columns) onto +Z
    (the rotation about their cross product); transform = [R | -R centre]; scale = 1 / the largest
    absolute coordinate of the oriented camera positions."""
    centre = poses[:, :3, 3].mean(0)
    up = poses[:, :3, 1].mean(0)
    up /= np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(up, z), float(up @ z)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + k + k @ k * (1.0 / (1.0 + c))
    transform = np.concatenate([rot, (-rot @ centre)[:, None]], 1)
    oriented = (rot @ poses[:, :3, 3].T).T - rot @ centre
    return transform, 1.0 / np.abs(oriented).max()


def _write_ply(path, points):
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n"
            "property float x\nproperty float y\nproperty float z\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(head.encode())
        fh.write(np.asarray(points, dtype="<f4").tobytes())


def test_a_point_cloud_and_camera_path_come_back_from_nerfstudios_world(captured, tmp_path):
    poses = np.array([fr["transform_matrix"] for _s, fr in _frames(captured["dataset"])], dtype=np.float64)
    transform, scale = _nerfstudio_dataparser(poses)
    assert not np.allclose(transform[:, :3], np.eye(3)) and abs(scale - 1.0) > 0.05  # a real change of frame
    out = tmp_path / "ns_output"
    out.mkdir()
    json.dump({"transform": transform.tolist(), "scale": scale}, open(out / "dataparser_transforms.json", "w"))
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (200, 3)) + np.array([0.3, -0.2, 0.5])
    moved = (points @ transform[:, :3].T + transform[:, 3]) * scale  # what ns-export writes
    _write_ply(tmp_path / "cloud.ply", moved)
    scene = bpy.context.scene
    (obj,) = nerfstudio_results.import_geometry(scene, str(tmp_path / "cloud.ply"), str(out))
    mw = np.array(obj.matrix_world)
    got = np.array([v.co for v in obj.data.vertices]) @ mw[:3, :3].T + mw[:3, 3]
    assert np.abs(got - points).max() <= 1e-4

    # The viewer's camera path lives in nerfstudio's world too.
    ns_poses = [nerfstudio_frame.to_nerfstudio_pose(p, transform, scale) for p in poses[:2]]
    path = {"camera_type": "perspective", "render_width": 40, "render_height": 30,
            "camera_path": [{"camera_to_world": p.reshape(-1).tolist(), "fov": 40.0,
                             "aspect": 4 / 3} for p in ns_poses]}
    json.dump(path, open(tmp_path / "camera_path.json", "w"))
    summary = camera_import.import_cameras(scene, str(tmp_path / "camera_path.json"), str(out))
    assert summary["format"] == "camera_path" and summary["cameras"] == 2
    cams = sorted((o for o in scene.objects if camera_import.is_imported(o)),
                  key=lambda o: o[camera_import.IMPORT_INDEX])
    for cam, want in zip(cams, poses[:2]):
        assert np.abs(np.array(cam.matrix_world) - want).max() <= 1e-5
        intr = dataset_cameras.camera_intrinsics(cam, scene.render)
        assert intr["fl_y"] == pytest.approx(15.0 / math.tan(math.radians(20.0)), rel=1e-6)


def test_import_errors_name_the_file_and_frame(tmp_path):
    bad = tmp_path / "transforms.json"
    bad.write_text(json.dumps({"frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(camera_import.CameraImportError, match=r"transforms.json: frame 0 \(a.png\).*'w'/'h'"):
        camera_import.import_cameras(bpy.context.scene, str(bad))
    with pytest.raises(camera_import.CameraImportError, match="file not found"):
        camera_import.import_cameras(bpy.context.scene, str(tmp_path / "missing.json"))
    shutil.rmtree(tmp_path)
