"""Captured and derived datasets (``bench.datasets``); no Blender: the capture commands are faked."""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from bench import datasets, runner


def test_subset_views_keeps_spread_frames_and_leaves_source(tmp_path, tiny_dataset):
    src = tiny_dataset(tmp_path / "src", n_train=8)
    before = (src / "transforms_train.json").read_text()
    dst = datasets.subset_views(str(src), str(tmp_path / "sub"), 4)
    meta = json.loads(open(os.path.join(dst, "transforms_train.json")).read())
    assert [f["file_path"] for f in meta["frames"]] == ["./train/r_0", "./train/r_2", "./train/r_4", "./train/r_6"]
    assert datasets.count_frames(dst, "test") == 2
    assert not os.path.exists(os.path.join(dst, "transforms.json"))  # would list the unedited cameras
    assert not os.path.exists(os.path.join(dst, "nerfstudio"))  # the same file where captures now write it
    assert os.path.isfile(os.path.join(dst, "train", "r_7.png"))
    assert (src / "transforms_train.json").read_text() == before
    with pytest.raises(runner.BenchError, match="transforms_train.json has 8"):
        datasets.subset_views(str(src), str(tmp_path / "sub2"), 9)


def test_perturb_poses_rotates_and_moves_by_the_asked_amount(tmp_path, tiny_dataset):
    src = tiny_dataset(tmp_path / "src")
    dst = datasets.perturb_poses(str(src), str(tmp_path / "noisy"), rot_deg=3.0, trans_frac=0.05, seed=1)
    a = json.loads((src / "transforms_train.json").read_text())["frames"]
    b = json.loads(open(os.path.join(dst, "transforms_train.json")).read())["frames"]
    for fa, fb in zip(a, b):
        pa, pb = np.asarray(fa["transform_matrix"]), np.asarray(fb["transform_matrix"])
        # Rotation angle between the two orientations, and the centre's shift (radius 4 -> 0.2).
        r = pa[:3, :3].T @ pb[:3, :3]
        angle = math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(3.0, abs=1e-6)
        assert np.linalg.norm(pb[:3, 3] - pa[:3, 3]) == pytest.approx(0.2, abs=1e-9)
        assert np.allclose(pb[:3, :3] @ pb[:3, :3].T, np.eye(3), atol=1e-9)  # still a rotation
    test_a = json.loads((src / "transforms_test.json").read_text())
    test_b = json.loads(open(os.path.join(dst, "transforms_test.json")).read())
    assert test_a == test_b


def test_ensure_dataset_reuses_matching_capture_only(tmp_path, monkeypatch):
    calls = []

    def fake_run(cmd, **kw):
        calls.append(os.path.basename(cmd[1]))
        if cmd[1].endswith("make_demo_scene.py"):
            open(cmd[cmd.index("--out") + 1], "w").close()
        else:
            out = cmd[cmd.index("--out") + 1]
            os.makedirs(out, exist_ok=True)
            for split in ("train", "test"):
                open(os.path.join(out, f"transforms_{split}.json"), "w").write("{}")
        return runner.CliResult(args=cmd, returncode=0)

    monkeypatch.setattr(datasets, "run_cli", fake_run)
    ds1, reused1 = datasets.ensure_dataset("diffuse", str(tmp_path), {"resolution": 64, "count": 10})
    ds2, reused2 = datasets.ensure_dataset("diffuse", str(tmp_path), {"resolution": 64, "count": 10})
    ds3, reused3 = datasets.ensure_dataset("diffuse", str(tmp_path), {"resolution": 32, "count": 10})
    assert (reused1, reused2, reused3) == (False, True, False)
    assert ds1 == ds2 != ds3
    assert calls == ["make_demo_scene.py", "capture.py", "make_demo_scene.py", "capture.py"]
    assert datasets.default_capture_args("s.blend", "o", {"val_count": 1, "depth": True, "x": None}) == [
        "--blend", "s.blend", "--out", "o", "--val-count", "1", "--depth"]
