"""COLMAP in Blender: ``capture.py --colmap`` writes DATASET/colmap by the library's export, and
``import_cameras.py --colmap`` puts a sparse model's cameras (intrinsics, lens shift) and points into a
.blend. One small capture (cube + ball, 4+1+1 views at 32 px, Cycles at 2 samples)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from addon.dataset.cameras import camera_intrinsics
from nerf_core.contract import colmap_model as cm
from nerf_core.contract.transforms import frame_infos

PY = sys.executable
SCRIPTS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts")
ARGS = ["--count", "4", "--val-count", "1", "--test-count", "1", "--resolution", "32", "--engine", "cycles",
        "--samples", "2", "--seed", "3", "--layout", "sphere", "--radius", "7", "--depth", "--points", "--quiet"]


def _run(script, *args, timeout=300):
    return subprocess.run([PY, os.path.join(SCRIPTS, script), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def capture(tmp_path_factory, cube_and_ball_blend):
    root = tmp_path_factory.mktemp("colmap")
    blend = cube_and_ball_blend(root / "scene.blend")
    out = root / "ds"
    proc = _run("capture.py", "--blend", blend, "--out", out, *ARGS, "--colmap", "--colmap-splits", "train,test")
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout.strip().splitlines()[-1])


def test_capture_writes_colmap_with_points_seen_by_train_images(capture):
    out, summary = capture
    col = summary["colmap"]
    assert col["images"] == {"train": 4, "test": 1} and col["points"] > 0
    model = cm.read_model(out / "colmap" / "sparse" / "0")
    train = {i for i, im in model.images.items() if im.name.startswith("train_")}
    assert all(len(t) and set(t[:, 0]) <= train for t in model.points.tracks)
    _, _, src, _ = frame_infos(out)
    _, _, back, _ = frame_infos(out / "colmap")
    for split in ("train", "test"):
        for a, b in zip(src[split], back[split]):
            assert np.abs(a.c2w - b.c2w).max() < 1e-6
            assert all(b.intrinsics[k] == pytest.approx(a.intrinsics[k], abs=1e-9) for k in ("fl_x", "cx", "cy"))
    # the capture's own dataset still loads as before (the colmap folder is beside, not inside, its files)
    assert len(src["train"]) == 4


def test_colmap_splits_are_checked_before_rendering(tmp_path, cube_and_ball_blend):
    blend = cube_and_ball_blend(tmp_path / "scene.blend")
    proc = _run("capture.py", "--blend", blend, "--out", tmp_path / "ds", *ARGS, "--colmap", "--colmap-splits", "tr")
    assert proc.returncode == 2 and "--colmap-splits 'tr'" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "ds").exists()


def _shifted_model(folder):
    """A sparse model whose two cameras have lens shift and non-square pixels, and three points."""
    folder.mkdir(parents=True)
    (folder.parent.parent / "images").mkdir()
    cams = {1: cm.Camera(1, "PINHOLE", 64, 48, np.array([70.0, 70.0, 35.5, 21.25])),
            2: cm.Camera(2, "PINHOLE", 64, 48, np.array([55.0, 60.5, 30.0, 26.0]))}
    images = {}
    for k in (1, 2, 3):
        c2w = np.eye(4)
        a = 0.7 * k
        c2w[:3, :3] = cm.qvec_to_rotmat([np.cos(a / 2), np.sin(a / 2) * 0.6, np.sin(a / 2) * 0.8, 0.0])
        c2w[:3, 3] = [k, -2.0 * k, 0.5]
        q, t = cm.pose_to_colmap(c2w)
        images[k] = cm.Image(k, q, t, 1 + k % 2, f"img_{k}.png")
    pts = cm.Points(np.array([1, 2, 3]), np.array([[0, 0, 0], [1, 0, 0], [0, 1, 2.0]]),
                    np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8), np.zeros(3),
                    [np.zeros((0, 2), np.int64)] * 3)
    for name, data in cm.model_files_bytes(cm.Model(cams, images, pts), (".bin",)).items():
        (folder / name).write_bytes(data)
    return cams, images


def test_import_cameras_colmap_keeps_poses_intrinsics_and_points(tmp_path):
    sparse = tmp_path / "rec" / "sparse" / "0"
    cams, images = _shifted_model(sparse)
    out = tmp_path / "cams.blend"
    proc = _run("import_cameras.py", "--colmap", sparse, "--points", "--out", out)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["format"] == "colmap" and summary["cameras"] == 3 and summary["points"]["count"] == 3
    bpy.ops.wm.open_mainfile(filepath=str(out))
    scene = bpy.context.scene
    obs = {o.name: o for o in bpy.data.objects if o.type == "CAMERA"}
    checked = 0
    for k, im in images.items():
        ob = obs[f"img_{k}"]
        c2w = np.array(ob.matrix_world)
        assert np.abs(c2w - cm.pose_from_colmap(im.qvec, im.tvec)).max() < 1e-6
        if (cams[im.camera_id].width, cams[im.camera_id].height) == (scene.render.resolution_x,
                                                                       scene.render.resolution_y):
            fx, fy, cx, cy = cams[im.camera_id].params
            got = camera_intrinsics(ob, scene.render)
            # the scene holds the first view's pixel aspect, as a float32 (1.1 is 1.100000024): fl_y and cy
            # of non-square pixels are exact to that float32, 2e-8 of their value
            if abs(fx / fy - got["fl_x"] / got["fl_y"]) < 1e-6:
                assert got["fl_x"] == pytest.approx(fx, abs=1e-9) and got["cx"] == pytest.approx(cx, abs=1e-9)
                assert got["fl_y"] == pytest.approx(fy, rel=1e-7) and got["cy"] == pytest.approx(cy, rel=1e-7)
                checked += 1
    assert checked == 2  # images 1 and 3 (camera 2, whose pixel aspect the scene took from the first view)
    pts = bpy.data.objects["Imported Points"]
    assert len(pts.data.vertices) == 3 and "Col" in pts.data.color_attributes
    assert np.allclose(pts.data.vertices[2].co, (0, 1, 2))


def test_import_cameras_colmap_errors_are_one_line(tmp_path):
    proc = _run("import_cameras.py", "--colmap", tmp_path, "--out", tmp_path / "x.blend")
    assert proc.returncode == 2 and "no COLMAP model there" in proc.stderr and "Traceback" not in proc.stderr
    sparse = tmp_path / "rec" / "sparse" / "0"
    _shifted_model(sparse)
    raw = (sparse / "cameras.bin").read_bytes()
    (sparse / "cameras.bin").write_bytes(raw[:-5])
    proc = _run("import_cameras.py", "--colmap", sparse, "--out", tmp_path / "y.blend")
    assert proc.returncode == 2 and "cameras.bin: the file is truncated" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "y.blend").exists()
    proc = _run("import_cameras.py", "--transforms", tmp_path, "--points", "--out", tmp_path / "z.blend")
    assert proc.returncode == 2 and "--points needs --colmap" in proc.stderr
