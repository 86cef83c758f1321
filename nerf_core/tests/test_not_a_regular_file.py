"""Something that exists but is not a regular file is named for what it is, not reported as missing,
and no reader blocks on a pipe or reads /dev/zero forever (contract/paths.py; RELIABILITY 200-205)."""
import json
import os
import subprocess
import sys
import unicodedata

import numpy as np
import pytest

from nerf_core.contract.paths import file_problem, why_not_a_file

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _run(*args, module=True):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest", OMP_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "nerf_core", *args] if module else [sys.executable, *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=REPO_ROOT, env=env, timeout=60)


def _refused(proc, *words):
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in proc.stderr + proc.stdout, proc.stderr + proc.stdout


def test_file_problem_names_each_kind(tmp_path):
    regular = tmp_path / "a.json"
    regular.write_text("{}")
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    dangling = tmp_path / "link.json"
    dangling.symlink_to(tmp_path / "gone.json")
    assert file_problem(regular) is None
    assert file_problem(tmp_path) == "is a folder, not a file"
    assert file_problem(fifo) == "is a named pipe (FIFO), not a regular file"
    assert file_problem("/dev/zero") == "is a device, not a regular file"
    assert "is a link to" in file_problem(dangling) and "does not exist" in file_problem(dangling)
    assert file_problem(tmp_path / "nowhere" / "x.json").startswith("not found (its folder")


def test_a_name_in_another_unicode_normalisation_is_named(tmp_path):
    nfd = unicodedata.normalize("NFD", "café.png")
    (tmp_path / nfd).write_bytes(b"x")
    nfc = tmp_path / unicodedata.normalize("NFC", "café.png")
    if nfc.exists():  # a file system that normalises names itself (macOS): nothing to report
        pytest.skip("this file system treats both spellings as one name")
    assert "the same name with its accents encoded another way" in why_not_a_file(nfc)


@pytest.mark.parametrize("command", ["train", "check"])
def test_a_pipe_as_transforms_file_is_named_not_waited_on(dataset_factory, tmp_path, command):
    ds = dataset_factory(tmp_path / "ds", layouts=("synthetic",))
    (ds / "transforms_train.json").unlink()
    os.mkfifo(ds / "transforms_train.json")
    args = ["train", str(ds), "--out", str(tmp_path / "run"), "--method", "test-grid", "--max-steps", "2"] \
        if command == "train" else ["check", str(ds)]
    _refused(_run(*args), "transforms_train.json", "is a named pipe (FIFO), not a regular file")
    assert not (tmp_path / "run").exists()


def test_dev_zero_as_transforms_file_is_named(dataset_factory, tmp_path):
    ds = dataset_factory(tmp_path / "ds", layouts=("synthetic",))
    (ds / "transforms_train.json").unlink()
    (ds / "transforms_train.json").symlink_to("/dev/zero")
    _refused(_run("train", str(ds), "--out", str(tmp_path / "run"), "--method", "test-grid", "--max-steps", "2"),
             "is a device, not a regular file")


def test_a_deleted_dataset_folder_and_a_folder_as_checkpoint(trained_run, tmp_path):
    _refused(_run("train", str(tmp_path / "gone"), "--out", str(tmp_path / "run"), "--max-steps", "2"),
             "dataset folder not found")
    _refused(_run("eval", str(trained_run["run"]), "--checkpoint", str(tmp_path)), "is a folder")
    os.mkfifo(tmp_path / "ck.pt")
    _refused(_run("eval", str(trained_run["run"]), "--checkpoint", str(tmp_path / "ck.pt")),
             "is a named pipe (FIFO), not a regular file")


def test_serve_never_writes_through_a_dangling_link(trained_run, tmp_path):
    out = tmp_path / "v.npy"
    out.symlink_to(tmp_path / "elsewhere" / "target.npy")
    c2w = np.eye(4)
    c2w[2, 3] = 3.0
    req = {"id": 1, "c2w": c2w.tolist(), "fx": 22.0, "fy": 20.0, "w": 24, "h": 18, "out": str(out)}
    proc = subprocess.run([sys.executable, "-m", "nerf_core", "serve", str(trained_run["run"])],
                          input=json.dumps(req) + "\n", capture_output=True, text=True, cwd=REPO_ROOT, timeout=60,
                          env=dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest"))
    errors = [json.loads(x) for x in proc.stdout.splitlines() if '"error"' in x]
    assert errors and "is a link to a file that does not exist" in errors[0]["message"], proc.stdout


def test_a_folder_as_blend_is_named(tmp_path):
    proc = _run(os.path.join(REPO_ROOT, "scripts", "capture.py"), "--blend", str(tmp_path), "--out",
                str(tmp_path / "ds"), module=False)
    _refused(proc, "--blend", "is a folder, not a file")
