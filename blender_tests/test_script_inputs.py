"""Scripts and long-lived readers follow the shared rules (issue 41, part F; RELIABILITY 210-214):
a frame range Blender cannot hold, a file as --out-dir, a run whose latest.pt is gone but whose
step file is complete."""
import os
import shutil
import sys
from types import SimpleNamespace

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "scripts"))

import build_addon  # noqa: E402
import render_nerf  # noqa: E402

from addon.bridge import render_client  # noqa: E402


def test_a_frame_range_beyond_blender_is_refused_not_a_memory_error(capsys):
    scene = SimpleNamespace(frame_start=1, frame_end=10, frame_step=1)
    with pytest.raises(SystemExit):
        render_nerf.frame_range("1:2000000000", scene)
    err = capsys.readouterr().err
    assert "--frames '1:2000000000': Blender's frames run from -1048574 to 1048574" in err
    assert render_nerf.frame_range("3:5", scene) == [3, 4, 5]


def test_a_file_as_out_dir_is_named(tmp_path, capsys):
    target = tmp_path / "dist"
    target.write_text("not a folder")
    assert build_addon.main(["--out-dir", str(target)]) == 2
    assert "--out-dir" in capsys.readouterr().err and target.read_text() == "not a folder"


def test_a_run_with_only_a_step_checkpoint_can_be_rendered(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.json").write_text("{}")
    assert "not found" in render_client.run_problem(str(run))
    (run / "checkpoints" / "step_0000030.pt").write_bytes(b"PK")
    assert render_client.run_problem(str(run)) is None  # nerf_core loads the newest step file
    assert "not found" in render_client.run_problem(str(run), str(run / "checkpoints" / "other.pt"))
    shutil.rmtree(run)


def test_a_slow_interpreter_is_called_slow_not_broken(tmp_path):
    from addon.bridge import child_process

    slow = tmp_path / "python"
    slow.write_text("#!/bin/sh\nsleep 5\n")
    slow.chmod(0o755)
    result = child_process.probe_interpreter(str(slow), timeout=0.5)
    assert not result.ok and result.slow and "slow, not broken" in result.message


def test_resolve_interpreter_says_slow_without_suggesting_the_same_python(tmp_path, monkeypatch):
    from addon.bridge import child_process

    monkeypatch.setattr(child_process, "probe_interpreter", lambda python, **k: child_process.ProbeResult(
        python, False, f"{python} is still importing torch after 60 s (a busy machine or a cold disk); it is slow, "
        "not broken: try again in a moment", slow=True))
    with pytest.raises(child_process.SetupError, match="slow, not broken") as err:
        child_process.resolve_interpreter(str(tmp_path / "py"))
    assert "Point it at a Python that has torch" not in str(err.value)
