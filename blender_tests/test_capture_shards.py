"""Sharded capture (render farm): shards as separate processes, the merge, and what must refuse.

One small scene (cube + ball) is captured whole and as 2 concurrent shards + merge, 6 frames at
32 px with Cycles at 2 samples; the merged dataset must equal the whole one.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import bpy
import numpy as np
import pytest
from PIL import Image

from addon.capture.plan import frame_plan

PY = sys.executable
SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "capture.py")
ARGS = ["--count", "4", "--val-count", "1", "--test-count", "1", "--resolution", "32", "--engine", "cycles",
        "--samples", "2", "--seed", "3", "--layout", "sphere", "--radius", "7", "--depth", "--points", "--quiet"]
SPLIT_FILES = ("transforms_train.json", "transforms_val.json", "transforms_test.json")


def _files(root) -> list[str]:
    return sorted(os.path.relpath(os.path.join(d, f), root) for d, _, fs in os.walk(root) for f in fs)


def _run(*args, timeout=300):
    return subprocess.run([PY, SCRIPT, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def captures(tmp_path_factory, cube_and_ball_blend):
    """(whole, merged, unmerged copy of the shards' folder, blend) of one scene and one command line."""
    root = tmp_path_factory.mktemp("shards")
    blend = cube_and_ball_blend(root / "scene.blend")
    whole, sharded = root / "whole", root / "sharded"
    proc = _run("--blend", blend, "--out", whole, *ARGS)
    assert proc.returncode == 0, proc.stderr
    # The two shards run at the same time, as two processes, into one folder.
    procs = [subprocess.Popen([PY, SCRIPT, "--blend", str(blend), "--out", str(sharded), *ARGS, "--shard", f"{k}/2"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in (1, 2)]
    results = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, results):
        assert p.returncode == 0, err
    summaries = [json.loads(out.strip().splitlines()[-1]) for out, _ in results]
    unmerged = root / "unmerged"
    shutil.copytree(sharded, unmerged)
    proc = _run("--out", sharded, "--merge")
    assert proc.returncode == 0, proc.stderr
    return whole, sharded, unmerged, blend, summaries


def test_shards_split_the_plan_and_write_no_shared_file(captures):
    whole, sharded, unmerged, _, summaries = captures
    assert [(s["shard"], s["frames"], s["planned"]) for s in summaries] == [("1/2", 3, 6), ("2/2", 3, 6)]
    assert summaries[0]["plan_hash"] == summaries[1]["plan_hash"]
    # Before the merge: frames and per-shard states only; the dataset's shared files are the merge's.
    names = _files(unmerged)
    assert not [n for n in names if n.endswith(".json") and "shards" not in n]
    assert "points3d.ply" not in names and not [n for n in names if "partial" in n]
    states = {n: json.loads((unmerged / n).read_text()) for n in names if n.startswith("nerf_capture/shards/")}
    assert set(states) == {"nerf_capture/shards/shard-1-of-2.json", "nerf_capture/shards/shard-2-of-2.json"}
    plan = states["nerf_capture/shards/shard-1-of-2.json"]["plan"]
    keys = [fr["key"] for fr in plan["frames"]]
    assert keys == ["train/r_0", "train/r_1", "train/r_2", "train/r_3", "val/r_0", "test/r_0"]
    # round robin: frame i belongs to shard i mod 2 + 1
    assert sorted(states["nerf_capture/shards/shard-1-of-2.json"]["done"]) == sorted(keys[0::2])
    assert sorted(states["nerf_capture/shards/shard-2-of-2.json"]["done"]) == sorted(keys[1::2])


def test_merged_capture_equals_the_whole_capture(captures):
    whole, sharded, _, _, _ = captures
    data = [n for n in _files(whole) if not n.startswith("nerf_capture/")]
    assert data == [n for n in _files(sharded) if not n.startswith("nerf_capture/")]
    assert "points3d.ply" in data and len([n for n in data if n.endswith(".png") and "depth/" not in n]) == 6
    assert len([n for n in data if n.startswith("nerfstudio/depth/")]) == 6  # the merge writes them too
    for name in data:
        a, b = (whole / name).read_bytes(), (sharded / name).read_bytes()
        if name.endswith(".png") and not name.startswith("nerfstudio/depth/"):
            # Cycles is deterministic here (fixed seed, no adaptive sampling, no denoiser): the pixels
            # agree exactly. The files differ only in Blender's PNG text chunks (Date, render times).
            pa, pb = np.asarray(Image.open(whole / name)), np.asarray(Image.open(sharded / name))
            assert pa.shape == (32, 32, 4) and np.array_equal(pa, pb), name
        else:  # transforms files, depth EXRs and nerfstudio's depth PNGs, point cloud: byte for byte
            assert a == b, name
    mw, ms = (json.loads((d / "nerf_capture" / "manifest.json").read_text()) for d in (whole, sharded))
    assert mw["status"] == ms["status"] == "complete"
    assert mw["plan_hash"] == ms["plan_hash"] == frame_plan.plan_hash(ms["plan"])
    assert mw["plan"] == ms["plan"] and len(ms["plan"]["frames"]) == 6
    assert mw["shards"] is None and ms["shards"]["count"] == 2
    assert {k: v["hash"] for k, v in mw["frames"].items()} == {k: v["hash"] for k, v in ms["frames"].items()}
    assert all(v["done"] and set(v["sha256"]) >= {"image", "depth_file_path"} for v in ms["frames"].values())


def test_nerf_core_check_accepts_the_merged_capture(captures):
    _, sharded, _, _, _ = captures
    proc = subprocess.run([PY, "-m", "nerf_core", "check", str(sharded)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_merge_with_missing_frames_names_them_and_writes_nothing(captures, tmp_path):
    _, _, unmerged, _, _ = captures
    ds = tmp_path / "ds"
    shutil.copytree(unmerged, ds)
    (ds / "train" / "r_2.png").unlink()  # shard 1's (frame 2)
    (ds / "nerf_capture" / "shards" / "shard-2-of-2.json").unlink()  # shard 2 never reported
    proc = _run("--out", ds, "--merge")
    assert proc.returncode == 2
    err = proc.stderr
    assert "4 of 6 planned frames" in err
    assert "train r_2 (train/r_2.png, shard 1/2): train/r_2.png is missing" in err
    for line in ("train r_1 (train/r_1.png, shard 2/2)", "train r_3 (train/r_3.png, shard 2/2)",
                 "test r_0 (test/r_0.png, shard 2/2)"):
        assert line + ": not rendered (no shard recorded it)" in err
    assert "train r_0" not in err and "val r_0" not in err  # shard 1's intact frames
    assert not [n for n in _files(ds) if n.endswith(".json") and "shards" not in n]


def test_merge_refuses_a_frame_changed_after_its_shard_wrote_it(captures, tmp_path):
    _, _, unmerged, _, _ = captures
    ds = tmp_path / "ds"
    shutil.copytree(unmerged, ds)
    (ds / "val" / "r_0.png").write_bytes((ds / "train" / "r_0.png").read_bytes())  # decodes, but another view
    proc = _run("--out", ds, "--merge")
    assert proc.returncode == 2
    assert "1 of 6 planned frames" in proc.stderr and "val r_0 (val/r_0.png, shard 1/2)" in proc.stderr
    assert "differs from the file written" in proc.stderr


def test_a_shard_with_other_settings_or_shard_count_is_refused(captures, tmp_path):
    _, _, unmerged, blend, _ = captures
    ds = tmp_path / "ds"
    shutil.copytree(unmerged, ds)
    before = {n: (ds / n).read_bytes() for n in _files(ds)}
    other = ["3" if ARGS[i - 1] == "--samples" else a for i, a in enumerate(ARGS)]  # 3 samples, not 2
    assert other != ARGS
    proc = _run("--blend", blend, "--out", ds, *other, "--shard", "1/2")
    assert proc.returncode == 2
    assert "planned with other settings" in proc.stderr and "render" in proc.stderr
    assert "shard-1-of-2.json" in proc.stderr
    proc = _run("--blend", blend, "--out", ds, *ARGS, "--shard", "1/3")
    assert proc.returncode == 2 and "captured in 2 shards" in proc.stderr and "not 3" in proc.stderr
    assert {n: (ds / n).read_bytes() for n in _files(ds)} == before


def test_a_shard_run_again_resumes_and_renders_nothing(captures, tmp_path):
    _, _, unmerged, blend, _ = captures
    ds = tmp_path / "ds"
    shutil.copytree(unmerged, ds)
    proc = _run("--blend", blend, "--out", ds, *ARGS, "--shard", "2/2")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert (summary["rendered"], summary["kept"], summary["frames"]) == (0, 3, 3)


@pytest.mark.parametrize("value, words", [
    ("0/2", "K must lie in 1..2"), ("3/2", "K must lie in 1..2"), ("1/0", "at least 1"),
    ("two", "expected K/N"), ("1/2/3", "expected K/N"), ("1.5/2", "expected K/N"),
])
def test_bad_shard_values_are_refused_before_anything_runs(tmp_path, value, words):
    out = tmp_path / "ds"
    proc = _run("--out", out, "--quiet", "--shard", value, timeout=120)
    assert proc.returncode == 2
    assert f"--shard {value!r}" in proc.stderr and words in proc.stderr
    assert not out.exists()


def test_shard_with_merge_or_overwrite_is_refused(tmp_path):
    out = tmp_path / "ds"
    for extra, words in ((["--merge"], "--merge joins the shards"), (["--overwrite"], "--overwrite cannot go")):
        proc = _run("--out", out, "--quiet", "--shard", "1/2", *extra, timeout=120)
        assert proc.returncode == 2 and words in proc.stderr
    assert not out.exists()


def test_merge_without_shards_says_so(tmp_path):
    proc = _run("--out", tmp_path, "--merge", timeout=120)
    assert proc.returncode == 2 and "holds no shard states" in proc.stderr


def test_parse_shard_and_round_robin():
    assert frame_plan.parse_shard("2/5") == (2, 5) and frame_plan.parse_shard(" 1 / 1 ") == (1, 1)
    frames = [{"key": i} for i in range(7)]
    shares = [[f["key"] for f in frame_plan.shard_frames(frames, k, 3)] for k in (1, 2, 3)]
    assert shares == [[0, 3, 6], [1, 4], [2, 5]]


def test_more_shards_than_frames_leaves_some_empty_and_still_merges(tmp_path):
    """In-process shards (CaptureJob with settings.shard): 2 frames over 3 shards; shard 3 has none."""
    from addon.capture.run import merge
    from addon.capture.layout import positions
    from addon.capture.run import job
    from addon.capture.plan import frame_plan, settings
    from addon.capture.layout import cameras

    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    cameras.create_cameras(scene, positions.LayoutSpec(train=1, val=0, test=1), 16, 16)
    out = tmp_path / "ds"

    def shard(k):
        return job.CaptureJob(scene, settings.CaptureSettings(out_dir=str(out), engine="workbench", res_x=16,
                                                                 res_y=16, shard=(k, 3))).run()

    empty = shard(3)
    assert (empty["frames"], empty["rendered"], empty["status"], empty["planned"]) == (0, 0, "done", 2)
    with pytest.raises(frame_plan.CaptureError, match="2 of 2 planned frames"):
        merge.merge(str(out))
    assert [shard(k)["rendered"] for k in (1, 2)] == [1, 1]
    merged = merge.merge(str(out))
    assert (merged["status"], merged["frames"], merged["shards"]) == ("complete", 2, 3)
    assert json.loads((out / "transforms_test.json").read_text())["frames"][0]["file_path"] == "./test/r_0"


def test_a_whole_capture_keeps_the_frames_shards_finished(tmp_path):
    """Switching from the farm to one machine midway: the whole run keeps every frame a shard recorded."""
    from addon.capture.layout import positions
    from addon.capture.run import job
    from addon.capture.plan import settings
    from addon.capture.layout import cameras

    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    cameras.create_cameras(scene, positions.LayoutSpec(train=3, val=0, test=1), 16, 16)
    out = tmp_path / "ds"
    base = dict(out_dir=str(out), engine="workbench", res_x=16, res_y=16, depth=True)
    first = job.CaptureJob(scene, settings.CaptureSettings(**base, shard=(1, 2))).run()
    assert first["rendered"] == 2  # frames 0 and 2 of 4
    whole = job.CaptureJob(scene, settings.CaptureSettings(**base)).run()
    assert (whole["kept"], whole["rendered"], whole["status"]) == (2, 2, "complete")
    manifest = json.loads((out / "nerf_capture" / "manifest.json").read_text())
    assert all(f["done"] and "sha256" in f for f in manifest["frames"].values())
