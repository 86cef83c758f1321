"""scripts/noise_ceiling.py: re-rendering a capture's test views measures its Cycles noise.

One small lit scene is captured at 32 px with Cycles at 4 samples. Re-rendered with the capture's own
seed, the views must match the dataset exactly (so poses, lens, film and colour management are
reproduced); with another seed they must differ by noise only: a finite PSNR well above that of a
wrong pose.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest

PY = sys.executable
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CAPTURE = os.path.join(ROOT, "scripts", "capture.py")
CEILING = os.path.join(ROOT, "scripts", "noise_ceiling.py")


def _run(script, *args, timeout=300):
    return subprocess.run([PY, script, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def capture(tmp_path_factory, cube_and_ball_blend):
    root = tmp_path_factory.mktemp("ceiling")
    blend = cube_and_ball_blend(root / "scene.blend", light="AREA")
    ds = root / "ds"
    proc = _run(CAPTURE, "--blend", blend, "--out", ds, "--count", "3", "--val-count", "1", "--test-count", "3",
                "--resolution", "32", "--engine", "cycles", "--samples", "4", "--layout", "sphere", "--radius", "6",
                "--quiet")
    assert proc.returncode == 0, proc.stderr
    return blend, ds, root


def test_the_capture_seed_reproduces_the_views_and_another_seed_measures_noise(capture):
    blend, ds, root = capture
    same = root / "same.json"
    proc = _run(CEILING, "--blend", blend, "--dataset", ds, "--views", "2", "--seed", "0", "--out", same)
    assert proc.returncode == 0, proc.stderr
    # Rendering the dataset's own views with its own seed gives back its images (8-bit PNGs: equal,
    # or a stray rounding difference at most).
    per_view = json.loads(same.read_text())["per_view"]
    assert [e["view"] for e in per_view] == [0, 2]
    assert all(e["psnr_two_renders"] > 60 for e in per_view), per_view
    other = root / "other.json"
    kept = root / "renders"
    proc = _run(CEILING, "--blend", blend, "--dataset", ds, "--views", "2", "--seed", "5", "--out", other,
                "--keep-renders", kept)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(other.read_text())
    assert sorted(p.name for p in kept.iterdir()) == ["v0.png", "v2.png"]
    assert 15 < res["psnr_two_renders"] < 60, res  # 4 samples: visibly noisy, still the same picture
    assert math.isclose(res["model_ceiling"], res["psnr_two_renders"] + 10 * math.log10(2), abs_tol=2e-3)
    assert "a noise-free model scores about" in proc.stdout


def test_bad_input_is_one_line_naming_the_file(capture, tmp_path):
    blend, ds, root = capture
    proc = _run(CEILING, "--blend", blend, "--dataset", tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert str(tmp_path) in proc.stderr and "manifest.json" in proc.stderr
    kept = root / "kept.json"
    kept.write_text("{}")
    proc = _run(CEILING, "--blend", blend, "--dataset", ds, "--out", kept)
    assert proc.returncode == 2 and "--overwrite" in proc.stderr and kept.read_text() == "{}"
    # --keep-renders never writes into an existing folder.
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "v0.png").write_bytes(b"user data")
    proc = _run(CEILING, "--blend", blend, "--dataset", ds, "--keep-renders", folder)
    assert proc.returncode == 2 and str(folder) in proc.stderr and "Traceback" not in proc.stderr
    assert (folder / "v0.png").read_bytes() == b"user data"
    proc = _run(CEILING, "--blend", blend, "--dataset", ds, "--views", "0")
    assert proc.returncode == 2 and "--views" in proc.stderr and "Traceback" not in proc.stderr


def test_without_blend_the_captured_scene_is_used_not_blenders_default(capture):
    blend, ds, root = capture
    with_blend = root / "with.json"
    without = root / "without.json"
    assert _run(CEILING, "--blend", blend, "--dataset", ds, "--views", "1", "--out", with_blend).returncode == 0
    proc = _run(CEILING, "--dataset", ds, "--views", "1", "--out", without)
    assert proc.returncode == 0, proc.stderr
    assert "using the captured scene" in proc.stderr and str(blend) in proc.stderr
    # The same scene, seed and view: the same number (Blender's default cube would score ~10 dB).
    assert json.loads(without.read_text())["psnr_two_renders"] == json.loads(with_blend.read_text())["psnr_two_renders"]
