"""Issue 58, rule 1, for the scripts: outputs never replace inputs or a dataset's files, nothing is
written through a link, and ``--overwrite`` never deletes an input (docs/RELIABILITY.md, "Links").

Each case runs the script as a user would (the ``bpy`` module's Python, tiny scenes); every refusal
comes before anything is rendered or written, so they are fast.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nerf_core.tests.conftest import make_dataset

REPO = Path(__file__).resolve().parents[2]
USER_TEXT = "the user's own file\n"
pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="symbolic links")


def _script(name, *args, cwd=None):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, str(REPO / "scripts" / name), *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd, env=env)


def _refused(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr, proc.stderr[-1500:]
    last = proc.stderr.strip().splitlines()[-1]
    for w in words:
        assert w in last, (w, last)
    return last


def _save_scene(path: Path) -> bytes:
    """A real .blend (the factory scene: a cube, a camera, a light), saved by a child bpy process."""
    path.parent.mkdir(parents=True, exist_ok=True)
    code = ("import bpy, sys; bpy.ops.wm.read_factory_settings(); "
            "bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True, capture_output=True, timeout=300)
    return path.read_bytes()


@pytest.fixture
def fake_run(tmp_path):
    """A folder the scripts take for a trained run (they refuse before loading it)."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"not read")
    (run / "config.json").write_text("{}")
    return run


@pytest.fixture
def user_file(tmp_path):
    p = tmp_path / "precious.txt"
    p.write_text(USER_TEXT)
    return p


TINY_CAPTURE = ("--engine", "workbench", "--count", "2", "--val-count", "1", "--test-count", "1",
                "--resolution", "8", "--quiet")


def test_capture_overwrite_never_deletes_the_scene_it_captures(tmp_path):
    out = tmp_path / "OUT"
    scene = out / "test" / "scene.blend"
    before = _save_scene(scene)
    _refused(_script("capture.py", "--blend", scene, "--out", out, "--overwrite", *TINY_CAPTURE),
             "would delete", "scene.blend", "an input is never deleted")
    assert scene.read_bytes() == before


def test_capture_overwrite_with_a_split_folder_linked_to_a_user_folder_is_one_line(tmp_path, user_file):
    out = tmp_path / "OUT"
    out.mkdir()
    (out / "other.txt").write_text("not a capture")
    (out / "train").symlink_to(tmp_path, target_is_directory=True)
    _refused(_script("capture.py", "--out", out, "--overwrite", *TINY_CAPTURE), "train is a symbolic link")
    assert user_file.read_text() == USER_TEXT and (out / "train").is_symlink()


def test_import_geometry_out_through_a_linked_folder_is_the_scene_and_is_refused(tmp_path, fake_run):
    scene = tmp_path / "scenes" / "scene.blend"
    scene.parent.mkdir()
    scene.write_bytes(b"BLENDER-not-really")
    (tmp_path / "L").symlink_to(scene.parent, target_is_directory=True)
    _refused(_script("import_geometry.py", "--blend", scene, "--run", fake_run, "--kind", "mesh",
                     "--out", tmp_path / "L" / "scene.blend", "--overwrite"), "same file as --blend")
    assert scene.read_bytes() == b"BLENDER-not-really"


def test_import_geometry_keeps_an_existing_vdb_beside_geometry_without_overwrite(tmp_path, fake_run):
    vdb = tmp_path / "X.vdb"
    vdb.write_bytes(b"a user's volume")
    _refused(_script("import_geometry.py", "--run", fake_run, "--kind", "volume", "--geometry", tmp_path / "X.npz",
                     "--out", tmp_path / "out.blend"), "--geometry", "X.vdb", "already exists")
    assert vdb.read_bytes() == b"a user's volume"


def test_import_geometry_refuses_a_vdb_that_is_a_link(tmp_path, fake_run, user_file):
    (tmp_path / "X.vdb").symlink_to(user_file)
    _refused(_script("import_geometry.py", "--run", fake_run, "--kind", "volume", "--geometry", tmp_path / "X.npz",
                     "--out", tmp_path / "out.blend", "--overwrite"), "X.vdb", "symbolic link")
    assert user_file.read_text() == USER_TEXT


def _dataset(tmp_path) -> Path:
    """A small dataset whose first training image is named as render_nerf names frame 1 (0001.png)."""
    ds = make_dataset(tmp_path / "ds", n_train=2, n_val=1, n_test=1, w=8, h=6, layouts=("synthetic",), depth=False)
    (ds / "train" / "r_0.png").rename(ds / "train" / "0001.png")
    meta = json.loads((ds / "transforms_train.json").read_text())
    meta["frames"][0]["file_path"] = "./train/0001"
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    return ds


def test_render_gallery_never_replaces_a_dataset_image(tmp_path):
    ds = _dataset(tmp_path)
    image = ds / "train" / "r_1.png"
    before = image.read_bytes()
    blend = tmp_path / "g.blend"
    blend.write_bytes(b"BLENDER-not-really")
    _refused(_script("render_gallery.py", "--blend", blend, "--out", image, "--overwrite"),
             "dataset's own file", "even with --overwrite")
    assert image.read_bytes() == before


def test_render_nerf_overwrite_never_replaces_a_dataset_image(tmp_path, fake_run):
    ds = _dataset(tmp_path)
    before = (ds / "train" / "0001.png").read_bytes()
    _refused(_script("render_nerf.py", "--run", fake_run, "--out", ds / "train", "--frames", "1:1", "--overwrite",
                     "--python", sys.executable), "dataset's own file", "0001.png")
    assert (ds / "train" / "0001.png").read_bytes() == before


def test_render_nerf_never_writes_through_a_dangling_link_in_out(tmp_path, fake_run):
    out = tmp_path / "frames"
    out.mkdir()
    (out / "0001.png").symlink_to(tmp_path / "elsewhere.png")
    _refused(_script("render_nerf.py", "--run", fake_run, "--out", out, "--frames", "1:1", "--overwrite",
                     "--python", sys.executable), "0001.png", "symbolic link")
    assert not (tmp_path / "elsewhere.png").exists()


def test_a_saved_blend_lands_whole_and_leaves_no_temporary(tmp_path):
    out = tmp_path / "demo.blend"
    proc = _script("make_demo_scene.py", "diffuse", "--out", out)
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert out.stat().st_size > 1000 and sorted(p.name for p in tmp_path.iterdir()) == ["demo.blend"]
    (tmp_path / "link.blend").symlink_to(out)
    _refused(_script("make_demo_scene.py", "diffuse", "--out", tmp_path / "link.blend", "--overwrite"),
             "symbolic link")
