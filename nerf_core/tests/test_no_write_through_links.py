"""Rule 1 of issue 58: nothing is ever written through a link (docs/RELIABILITY.md, "Links").

A link or a hard link planted where a writer used to put its temporary file (``RUN/.lock``,
``latest.pt.tmp``, ``.config.json.tmp``, ``.mesh.ply.tmp``) must leave the user's file it points to
untouched: every temporary is created new (``utils.atomic``), and the lock file is never opened
through a link nor truncated.
"""
import os
import sys

import pytest

from nerf_core.cli.main import main
from nerf_core.errors import TrainError
from nerf_core.tests.conftest import use_model
from nerf_core.runs.folder import RUN_LOCK, lock_run_folder, trainer_written
from nerf_core.tests.test_export_mesh import SphereModel
from nerf_core.utils import atomic

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="links and flock are POSIX here")

USER_TEXT = "the user's own file\n"


@pytest.fixture
def user_file(tmp_path):
    p = tmp_path / "precious.txt"
    p.write_text(USER_TEXT)
    return p


def _train(ds, run, *flags):
    return main(["train", str(ds), "--out", str(run), "--method", "test-grid", "--max-steps", "3",
                 "--batch-rays", "64", "--eval-views", "0", "--no-bar", *flags])


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


# ------------------------------------------------------------------------------------------------ the run lock


def test_a_lock_file_linked_to_a_user_file_is_refused_before_anything_is_written(sphere_dataset, tmp_path,
                                                                                 user_file, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / RUN_LOCK).symlink_to(user_file)
    assert _train(sphere_dataset, run) == 2
    line = _one_line(capsys)
    assert RUN_LOCK in line and "symbolic link" in line
    assert user_file.read_text() == USER_TEXT


@pytest.mark.parametrize("kind", ["symlink", "hardlink", "dangling"])
def test_the_lock_itself_never_opens_a_link_nor_truncates(tmp_path, user_file, kind):
    lock = tmp_path / RUN_LOCK
    if kind == "symlink":
        lock.symlink_to(user_file)
    elif kind == "hardlink":
        os.link(user_file, lock)
    else:
        lock.symlink_to(tmp_path / "nowhere")
    with pytest.raises(TrainError, match=f"{RUN_LOCK}: is a (symbolic|hard) link"):
        lock_run_folder(tmp_path)
    assert user_file.read_text() == USER_TEXT and not (tmp_path / "nowhere").exists()


def test_a_large_file_at_the_lock_name_is_not_a_lock_and_is_left_whole(tmp_path):
    (tmp_path / RUN_LOCK).write_text("x" * 100)
    with pytest.raises(TrainError, match="more than a trainer's lock file"):
        lock_run_folder(tmp_path)
    assert (tmp_path / RUN_LOCK).read_text() == "x" * 100


def test_a_stale_lock_with_a_longer_pid_is_rewritten_without_truncation(tmp_path):
    (tmp_path / RUN_LOCK).write_text("123456789012\n")
    release = lock_run_folder(tmp_path)
    assert (tmp_path / RUN_LOCK).read_text().strip() == str(os.getpid())
    release()


# ------------------------------------------------------------------------------------- checkpoints and config


def test_resume_past_a_checkpoint_temporary_linked_to_a_user_file(sphere_dataset, tmp_path, user_file, capsys):
    run = tmp_path / "run"
    assert _train(sphere_dataset, run) == 0
    ck = run / "checkpoints"
    for name in ("latest.pt.tmp", ".latest.pt.tmp"):  # the fixed names older trainers used
        (ck / name).symlink_to(user_file)
    (run / ".config.json.tmp").symlink_to(user_file)
    os.link(user_file, run / ".written.json.tmp")
    capsys.readouterr()
    assert _train(sphere_dataset, run, "--resume", "--max-steps", "6") == 0
    assert user_file.read_text() == USER_TEXT
    assert not (ck / "latest.pt").is_symlink() and (ck / "latest.pt").is_file()
    assert not (run / "config.json").is_symlink()


def test_a_checkpoint_that_is_a_link_is_refused_naming_it(sphere_dataset, tmp_path, user_file, capsys):
    run = tmp_path / "run"
    assert _train(sphere_dataset, run) == 0
    latest = run / "checkpoints" / "latest.pt"
    latest.unlink()
    latest.symlink_to(user_file)
    capsys.readouterr()
    assert _train(sphere_dataset, run, "--resume", "--max-steps", "6") == 2
    assert "latest.pt" in _one_line(capsys) and user_file.read_text() == USER_TEXT


def test_a_killed_writers_temporary_is_the_runs_own_for_overwrite(sphere_dataset, tmp_path, user_file):
    run = tmp_path / "run"
    assert _train(sphere_dataset, run) == 0
    leftover = run / "checkpoints" / ".latest.pt.0123456789abcdef.tmp"  # what SIGKILL mid-save leaves
    leftover.write_bytes(b"PK half")
    planted = run / "checkpoints" / ".latest.pt.fedcba9876543210.tmp"
    planted.symlink_to(user_file)  # a link is never the run's own: --overwrite leaves it
    assert leftover in trainer_written(run) and planted not in trainer_written(run)
    assert _train(sphere_dataset, run, "--overwrite") == 0
    assert not leftover.exists() and user_file.read_text() == USER_TEXT


# ------------------------------------------------------------------------------------------------ utils.atomic


@pytest.mark.parametrize("planted", ["symlink", "hardlink"])
def test_no_temporary_name_is_ever_reused(tmp_path, user_file, planted, monkeypatch):
    target = tmp_path / "out.json"
    fixed = tmp_path / ".out.json.0000000000000000.tmp"
    if planted == "symlink":
        fixed.symlink_to(user_file)
    else:
        os.link(user_file, fixed)
    names = iter(["0000000000000000", "1111111111111111"])  # the first random name is the planted one
    monkeypatch.setattr(atomic.secrets, "token_hex", lambda n: next(names))
    atomic.write_json_atomic(target, {"a": 1})
    assert target.read_text().strip().startswith("{") and user_file.read_text() == USER_TEXT
    assert fixed.exists() and not (tmp_path / ".out.json.1111111111111111.tmp").exists()


@pytest.mark.parametrize("dangling", [False, True])
def test_a_target_that_is_a_link_is_refused_in_one_line(tmp_path, user_file, dangling):
    target = tmp_path / "mesh.ply"
    target.symlink_to(tmp_path / "nowhere" if dangling else user_file)
    for write in (lambda: atomic.write_bytes_atomic(target, b"x", flag="--out"),
                  lambda: atomic.atomic_path(target, flag="--out").__enter__()):
        with pytest.raises(atomic.LinkRefused, match=r"--out .*mesh\.ply: is a symbolic link") as err:
            write()
        assert "\n" not in str(err.value)
    assert user_file.read_text() == USER_TEXT and not (tmp_path / "nowhere").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_atomic_path_gives_a_private_fresh_name_and_leaves_nothing(tmp_path):
    target = tmp_path / "scene.blend"
    with atomic.atomic_path(target) as tmp:
        assert tmp.name == "scene.blend" and tmp.parent != tmp_path and not tmp.exists()
        tmp.write_bytes(b"blend")
        (tmp.parent / "scene.blend1").write_bytes(b"a writer's backup")  # stays in the private folder
    assert target.read_bytes() == b"blend" and sorted(p.name for p in tmp_path.iterdir()) == ["scene.blend"]
    with pytest.raises(RuntimeError), atomic.atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("the writer failed")
    assert target.read_bytes() == b"blend" and sorted(p.name for p in tmp_path.iterdir()) == ["scene.blend"]


def test_a_killed_writers_temporaries_are_recognised():
    assert atomic.is_leftover_temp(".latest.pt.0123456789abcdef.tmp")
    assert atomic.is_leftover_temp(".scene.blend.k2j_9xq1.tmpdir")
    assert not atomic.is_leftover_temp("latest.pt.tmp") and not atomic.is_leftover_temp(".hidden.tmp")


# ------------------------------------------------------------------------------------------------ export


@pytest.fixture
def sphere_run(monkeypatch, tmp_path):
    """``export`` on a run whose model is the analytic sphere (as test_export_mesh's ``fake_run``)."""
    use_model(monkeypatch, SphereModel())
    return tmp_path / "run"


@pytest.mark.parametrize("kind, name", [("mesh", "mesh.ply"), ("volume", "volume.npz")])
@pytest.mark.parametrize("planted", ["symlink", "hardlink"])
def test_a_stale_temporary_beside_an_export_is_never_written_through(sphere_run, tmp_path, user_file, capsys,
                                                                     kind, name, planted):
    out = tmp_path / name
    for stale in (tmp_path / f".{name}.tmp", tmp_path / f"{name}.tmp"):  # the fixed names writers used
        stale.symlink_to(user_file) if planted == "symlink" else os.link(user_file, stale)
    assert main(["export", kind, str(sphere_run), "--out", str(out), "--resolution", "16"]) == 0
    assert user_file.read_text() == USER_TEXT and out.is_file() and not out.is_symlink()


@pytest.mark.parametrize("kind, name", [("mesh", "mesh.ply"), ("volume", "volume.npz")])
def test_an_export_out_that_is_a_link_is_refused_before_the_work(sphere_run, tmp_path, user_file, capsys, kind, name):
    out = tmp_path / name
    out.symlink_to(user_file)
    assert main(["export", kind, str(sphere_run), "--out", str(out), "--resolution", "16", "--overwrite"]) == 2
    assert "symbolic link" in _one_line(capsys) and user_file.read_text() == USER_TEXT


def test_render_never_writes_through_a_dangling_link_in_out(trained_run, tmp_path, capsys):
    run, ds, out = trained_run["run"], trained_run["dataset"], tmp_path / "views"
    render = ["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out), "--no-bar"]
    assert main(render) == 0
    image = sorted(out.glob("*.png"))[0]
    image.unlink()
    image.symlink_to(tmp_path / "elsewhere.png")
    capsys.readouterr()
    assert main([*render, "--overwrite"]) == 2
    line = _one_line(capsys)
    assert image.name in line and "symbolic link" in line and not (tmp_path / "elsewhere.png").exists()
