"""Round four of docs/RELIABILITY.md for the scripts: an output never replaces an input (one rule,
``scripts/_bootstrap.check_output``, comparing files by identity through links and relative paths),
a link loop in ``--out`` is one line, and ``build_addon.py --blender /bin/false`` says what failed.
Every refusal here comes before Blender opens a file, so no test needs a scene."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _script(name, *args, cwd=None):
    return subprocess.run([sys.executable, str(REPO / "scripts" / name), *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd)


def _refused(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    for w in words:
        assert w in last, (w, last)
    return last


@pytest.fixture
def scene(tmp_path):
    blend = tmp_path / "S.blend"
    blend.write_bytes(b"BLENDER-not-really")  # refused before it is opened: its content is never read
    (tmp_path / "t.json").write_text("{}")
    return blend


@pytest.mark.parametrize("script, extra", [
    ("import_cameras.py", ["--transforms", "t.json"]),
    ("import_nerfstudio.py", ["--nerfstudio", ".", "--camera-path", "t.json"]),
])
def test_out_the_scene_itself_through_a_link_or_a_relative_path_is_refused(scene, script, extra):
    link = scene.parent / "link.blend"
    link.symlink_to(scene)
    for out in (scene, link, Path("..") / scene.parent.name / "S.blend"):
        proc = _script(script, "--blend", scene, *extra, "--out", out, "--overwrite", cwd=scene.parent)
        _refused(proc, "same file as --blend", "never replaces an input")
    assert scene.read_bytes() == b"BLENDER-not-really"


def test_render_gallery_and_export_camera_path_refuse_their_input_as_output(scene):
    _refused(_script("render_gallery.py", "--blend", scene, "--out", scene, "--overwrite"), "same file as --blend")
    _refused(_script("export_camera_path.py", "--blend", scene, "--out", scene.parent / "t.json", "--overwrite",
                     "--dataparser-transforms", scene.parent / "t.json"), "same file as --dataparser-transforms")


def test_a_symlink_loop_in_out_is_one_line(scene):
    loop = scene.parent / "loop.blend"
    loop.symlink_to(loop)
    last = _refused(_script("import_cameras.py", "--blend", scene, "--transforms", scene.parent / "t.json",
                            "--out", loop, "--overwrite"), "symbolic link loop")
    assert str(loop) in last


def test_build_addon_with_a_blender_that_is_not_one_says_what_failed(tmp_path):
    proc = _script("build_addon.py", "--blender", "/bin/false", "--out-dir", tmp_path)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "/bin/false exited with status 1" in proc.stderr and "printed nothing" in proc.stderr, proc.stderr
