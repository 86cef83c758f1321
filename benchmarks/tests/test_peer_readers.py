"""``benchmarks/peer_readers/nerfstudio_colmap.py``'s comparison, on hand-made nerfstudio outputs (no nerfstudio).

The outputs are made with nerfstudio's own arithmetic (``colmap_dataparser.py`` 1.1.5): poses times the
4x4 dataparser transform, then the translations times the scale, kept in float32 as nerfstudio keeps them.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest

from peer_readers import nerfstudio_colmap as nc

AABB = np.array([[-1.0, -0.5, -0.7], [1.2, 0.5, 0.7]])


def look_at(eye, target=(0.1, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenGL camera-to-world (the camera looks down -z), as our captures write."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(back, right), back, eye
    return c2w


def frames(n=8) -> list:
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n
        eye = (4.5 * math.cos(a), 4.5 * math.sin(a), 0.8 + 0.3 * (k % 3))
        out.append({"name": f"r_{k}.png", "c2w": look_at(eye), "fx": 277.77777777777777, "fy": 277.77777777777777,
                    "cx": 100.0, "cy": 100.5, "w": 200.0, "h": 200.0})
    return out


def rotation(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def nerfstudio_outputs(expected, flip_to_opencv=False) -> dict:
    """What nerfstudio's colmap dataparser returns for ``expected``: applied_transform A (x, z, -y), an
    orientation T, the scale 1 / max |t|; ``dataparser_transform`` = T @ A."""
    a = np.eye(4)[[0, 2, 1, 3]]
    a[2] *= -1
    t = np.eye(4)
    t[:3, :3] = rotation((0.3, -0.2, 0.9), 0.4)
    t[:3, 3] = (0.05, -0.3, 2.4)
    d = t @ a
    poses = np.stack([d @ e["c2w"] for e in expected]).astype(np.float32)
    s = 1.0 / float(np.abs(poses[:, :3, 3]).max())
    poses[:, :3, 3] *= s
    if flip_to_opencv:  # a reader that kept COLMAP's camera axes
        poses[:, :3, 1:3] *= -1
    f32 = [float(np.float32(e["fx"])) for e in expected]
    return {"image_filenames": [e["name"] for e in expected], "fx": f32, "fy": list(f32),
            "cx": [float(np.float32(e["cx"])) for e in expected], "cy": [float(np.float32(e["cy"])) for e in expected],
            "width": [int(e["w"]) for e in expected], "height": [int(e["h"]) for e in expected],
            "camera_to_worlds": poses[:, :3, :4].astype(np.float64).tolist(),
            "dataparser_transform": d[:3].astype(np.float32).astype(np.float64).tolist(), "dataparser_scale": s,
            "num_points3D": 500, "mask_filenames": None}


def test_nerfstudio_outputs_of_our_poses_pass():
    expected = frames()
    summary, failures = nc.compare(nerfstudio_outputs(expected), expected, AABB, points=500)
    assert failures == [] and summary["ok"]
    assert summary["images"] == 8 and summary["cameras_looking_at_box"] == 8 and summary["intrinsics_exact"]
    assert summary["max_rotation_error"] < 1e-6 and summary["max_position_error"] < 1e-5


def test_a_perturbed_pose_fails_and_is_named():
    expected = frames()
    ns = nerfstudio_outputs(expected)
    ns["camera_to_worlds"][3][1][3] += 1e-3  # 1e-3 / scale ~ 5 mm in the scene
    summary, failures = nc.compare(ns, expected, AABB)
    assert not summary["ok"] and summary["worst_camera"] == "r_3.png"
    assert len(failures) == 1 and failures[0].startswith("poses:") and "r_3.png" in failures[0]
    ns = nerfstudio_outputs(expected)
    r = rotation((0, 0, 1), 2e-3)
    c = np.asarray(ns["camera_to_worlds"][5])
    c[:, :3] = r @ c[:, :3]
    ns["camera_to_worlds"][5] = c.tolist()
    _, failures = nc.compare(ns, expected, AABB)
    assert [f.split(":")[0] for f in failures] == ["poses"]


def test_opencv_camera_axes_fail_poses_and_look_away():
    expected = frames()
    summary, failures = nc.compare(nerfstudio_outputs(expected, flip_to_opencv=True), expected, AABB)
    assert [f.split(":")[0] for f in failures] == ["poses", "optical axes"]
    assert summary["max_rotation_error"] > 1.0 and summary["cameras_looking_at_box"] == 0


def test_intrinsics_names_points_and_masks_are_checked(tmp_path):
    expected = frames()
    ns = nerfstudio_outputs(expected)
    ns["cx"][2] = 100.5  # 100.0 in the capture
    ns["image_filenames"][7] = "other.png"
    ns["num_points3D"] = 499
    (tmp_path / "r_0.png").write_bytes(b"")
    ns["mask_filenames"] = [str(tmp_path / "r_0.png"), str(tmp_path / "r_1.png")]
    summary, failures = nc.compare(ns, expected, AABB, points=500)
    assert [f.split(":")[0] for f in failures] == ["images", "intrinsics", "points", "masks"]
    assert "r_7.png" in failures[0] and "other.png" in failures[0] and "r_2.png cx" in failures[1]
    assert summary["cameras_compared"] == 7


@pytest.mark.parametrize("origin, direction, hit", [
    ((5, 0, 0), (-1, 0, 0), True), ((5, 0, 0), (1, 0, 0), False), ((5, 3, 0), (-1, 0, 0), False),
    ((0, 0, 0), (0, 1, 0), True), ((5, 0.2, 0.1), (-1, 0, 0), True), ((5, 0, 0), (-1, 0.5, 0), False)])
def test_axis_hits_box(origin, direction, hit):
    assert nc.axis_hits_box(np.asarray(origin, float), np.asarray(direction, float), AABB) is hit


def test_the_child_imports_nothing_of_ours():
    with open(os.path.join(os.path.dirname(nc.__file__), "_nerfstudio_child.py")) as f:
        text = f.read()
    assert "nerf_core" not in text and "_bootstrap" not in text


def test_expected_frames_are_named_as_the_export_names_its_images(tiny_dataset, tmp_path):
    expected, aabb = nc.expected_frames(str(tiny_dataset(tmp_path / "src")))
    assert [e["name"] for e in expected] == [f"r_{k}.png" for k in range(6)]
    assert (expected[0]["fx"], expected[0]["cy"], expected[0]["w"]) == (5.0, 2.0, 4.0)
    assert aabb.tolist() == [[-1, -1, -1], [1, 1, 1]]


def test_refusals_are_one_line_and_exit_2(tiny_dataset, tmp_path, capsys):
    src = str(tiny_dataset(tmp_path / "src"))
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    with pytest.raises(SystemExit) as exc:
        nc.main(["--dataset", src, "--out", str(tmp_path / "full"), "--python", "python"])
    assert exc.value.code == 2 and "not an empty folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # the export runs; a --python without nerfstudio is named
        nc.main(["--dataset", src, "--out", str(tmp_path / "out"), "--python", "/bin/false"])
    assert exc.value.code == 2 and "nerfstudio's colmap dataparser failed (exit 1)" in capsys.readouterr().err
    assert os.path.isdir(tmp_path / "out" / "colmap" / "sparse" / "0")
