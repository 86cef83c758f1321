"""Issue 58, rule 6, for the scripts: a flag's bad value is one line naming the flag, exit 2, before
anything is rendered or written (``_bootstrap.whole_number``, ``_bootstrap.out_blend``)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _script(name, *args, cwd):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, str(REPO / "scripts" / name), *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd, env=env)


def _refused(proc, *words) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr, proc.stderr[-1500:]
    last = proc.stderr.strip().splitlines()[-1]
    assert all(w in last for w in words), last
    return last


@pytest.mark.parametrize("flag, value, words", [
    ("--percent", "0", ("argument --percent: must lie in 1..1000", "got 0")),
    ("--percent", "-50", ("argument --percent: must lie in 1..1000",)),
    ("--percent", "half", ("argument --percent: expected a whole number, got 'half'",)),
    ("--samples", "0", ("argument --samples: must lie in 1..",)),
])
def test_render_gallery_refuses_a_percent_or_samples_out_of_range(tmp_path, flag, value, words):
    # --percent 0: Blender clamped it to 1 % and the script reported a 0x0 image
    _refused(_script("render_gallery.py", "--out", tmp_path / "g.png", flag, value, cwd=tmp_path), *words)
    assert not (tmp_path / "g.png").exists()


@pytest.mark.parametrize("value", ["nan", "inf", "-3", "1.5", "grey"])
def test_render_gallery_refuses_a_background_that_is_not_a_colour(tmp_path, value):
    # argparse's float took nan and inf, and Blender drew a black or white world from them
    _refused(_script("render_gallery.py", "--out", tmp_path / "g.png", "--background", "0.1", value, "0.1",
                     cwd=tmp_path), "argument --background:", "[0, 1]")
    assert not (tmp_path / "g.png").exists()


def test_make_demo_scene_refuses_an_out_that_is_not_a_blend(tmp_path):
    last = _refused(_script("make_demo_scene.py", "cube", "--out", "scene.png", cwd=tmp_path),
                    "--out", "scene.png", "writes a .blend file")
    assert "ending in .blend" in last and list(tmp_path.iterdir()) == []
