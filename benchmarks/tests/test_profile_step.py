"""benchmarks/profile_step.py on a run trained for a few steps: it times steps, names the kernel taken,
and refuses what it cannot profile with one line."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _run(*args, timeout=300):
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=REPO)


def test_profiles_a_trained_vmgrid_run(tmp_path, tiny_dataset):
    data = tiny_dataset(tmp_path / "data", n_train=6)
    train = _run("-m", "nerf_core", "train", data, "--out", tmp_path / "run", "--max-steps", "3", "--no-bar",
                 "--eval-views", "0")
    assert train.returncode == 0, train.stderr
    proc = _run(REPO / "benchmarks" / "profile_step.py", tmp_path / "run", data, "--steps", "2", "--rays", "64",
                "--res", "20", "--table", "3")
    assert proc.returncode == 0, proc.stderr
    assert "profile_step: vmgrid, grids 20, 64 rays, cpu" in proc.stdout and "median step" in proc.stdout
    assert "vm_products" in proc.stdout and "Self CPU" in proc.stdout


def test_a_missing_run_is_one_line(tmp_path):
    proc = _run(REPO / "benchmarks" / "profile_step.py", tmp_path / "nothing", tmp_path)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr and "run folder not found" in proc.stderr


def test_train_mode_prints_operators_syncs_and_time(tmp_path, tiny_dataset):
    data = tiny_dataset(tmp_path / "data", n_train=6)
    proc = _run(REPO / "benchmarks" / "profile_step.py", "--train", data, "--steps", "3", "--batch-rays", "16")
    assert proc.returncode == 0, proc.stderr
    assert "16 rays, cpu, 1 thread(s), 3 steps from the first on" in proc.stdout
    assert "wall per step:" in proc.stdout and "ATen operators / step:" in proc.stdout
    assert "host syncs / step:" in proc.stdout


def test_train_mode_refuses_a_missing_dataset_in_one_line(tmp_path):
    proc = _run(REPO / "benchmarks" / "profile_step.py", "--train", tmp_path / "nothing", "--steps", "2")
    assert proc.returncode != 0 and "Traceback" not in proc.stderr and "profile_step: --train" in proc.stderr


def test_step_counts_counts_top_level_ops_and_each_sync_once():
    """Boolean-mask indexing (nonzero inside index) and .item() are one sync each; the ops that an
    operator calls internally are not counted again."""
    import torch
    from torch.profiler import ProfilerActivity, profile, record_function

    from bench.step_counts import STEP_MARK, count_steps

    x = torch.arange(10.0) - 4.0
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(2):
            with record_function(STEP_MARK):
                y = x[x > 0]  # gt, index (nonzero inside): one sync
                z = (y * 2).sum()  # mul, sum: no sync
                z.item()  # one sync
    counts = count_steps(prof.events())
    assert counts.syncs == [2, 2]
    assert counts.ops[0] == counts.ops[1] and 5 <= counts.ops[0] <= 6  # gt, index, mul, sum, item (+ a view)
    kinds = counts.summary()["sync_kinds"]
    assert kinds["aten::index (aten::nonzero)"] == 1.0


def test_sync_sources_names_the_lines_that_sync(tmp_path, tiny_dataset):
    data = tiny_dataset(tmp_path / "data", n_train=6)
    proc = _run(REPO / "benchmarks" / "bench" / "sync_sources.py", data, "--steps", "3", "--batch-rays", "16")
    assert proc.returncode == 0, proc.stderr
    rows = proc.stdout.splitlines()[1:]
    assert rows and all(".py:" in r for r in rows), proc.stdout  # each row names a source line
    assert any("aten._fused_adam_" in r and "engine/trainer.py" in r for r in rows), proc.stdout


def test_profiles_a_run_of_a_capture_in_the_original_synthetic_layout(tmp_path, tiny_dataset):
    """Only ``camera_angle_x`` and the frames, as the original NeRF scenes have them: no w, fl_x or aabb
    (the profile once read the JSON by hand and failed with KeyError 'w')."""
    import json

    data = tiny_dataset(tmp_path / "data", n_train=6)
    for split in ("train", "test"):
        path = data / f"transforms_{split}.json"
        meta = json.loads(path.read_text())
        path.write_text(json.dumps({"camera_angle_x": meta["camera_angle_x"], "frames": meta["frames"]}))
    train = _run("-m", "nerf_core", "train", data, "--out", tmp_path / "run", "--max-steps", "2", "--no-bar",
                 "--eval-views", "0")
    assert train.returncode == 0, train.stderr
    proc = _run(REPO / "benchmarks" / "profile_step.py", tmp_path / "run", data, "--steps", "1", "--rays", "16",
                "--table", "0")
    assert proc.returncode == 0, proc.stderr
    assert "median step" in proc.stdout
