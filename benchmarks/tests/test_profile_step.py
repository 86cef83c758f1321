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
