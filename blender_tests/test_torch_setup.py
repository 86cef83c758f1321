"""Set up PyTorch: the operator builds a private environment with pip from a local folder of wheels
(``--no-index``: no network), and the Train panel then trains in it.

The wheel folder is ``.venv/wheelhouse/`` (``scripts/setup_env.sh`` fills it with ``pip download`` at the
pinned versions; nerf_core/tests/test_wheel_install.py installs from it too), or the folder named by
$NERF_WHEELHOUSE. The plan, pip's progress and the failures
are checked without Blender's event loop in test_torch_setup_plan.py.
"""
from __future__ import annotations

import os
import subprocess
import time

import addon_utils
import bpy
import pytest

from addon.bridge import child_process, torch_setup
from addon.common import jobs, prefs, torch_setup_job
from addon.train import train_ui

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WHEELS = os.environ.get("NERF_WHEELHOUSE") or os.path.join(REPO_ROOT, ".venv", "wheelhouse")


def wheel_folder() -> str:
    names = os.listdir(WHEELS) if os.path.isdir(WHEELS) else []
    if not any(n.startswith("torch-") and n.endswith(".whl") for n in names):
        pytest.fail(f"{WHEELS} holds no torch wheel: run `bash scripts/setup_env.sh` (it downloads the wheels "
                    "this test installs offline), or point NERF_WHEELHOUSE at a folder of them")
    return WHEELS


@pytest.fixture
def enabled():
    """The add-on enabled as Blender enables it, so that its preferences exist."""
    addon_utils.enable("addon", default_set=True, handle_error=None)
    yield prefs.get_preferences()
    jobs.cancel_jobs()
    addon_utils.disable("addon", default_set=True)


def drive(job, timeout=240.0):
    """What the modal timer does: update the job until it stops, then run its hooks."""
    deadline = time.monotonic() + timeout
    seen = []
    while job.update() == "running":
        assert time.monotonic() < deadline, f"{job.kind} did not finish in {timeout} s"
        if not seen or seen[-1] != job.status():
            seen.append(job.status())
        time.sleep(0.1)
    job.notify()
    return seen


def test_setup_from_a_wheel_folder_then_train_in_it(enabled, tmp_path):
    from test_full_loop import tiny_capture  # a 32x32 capture of a cube, the loop's own dataset

    wheels = wheel_folder()
    env_dir = str(tmp_path / "torch env")  # a space in the path, as in many user folders
    assert not bpy.app.online_access  # the bpy module runs offline: only a wheel folder may install
    with pytest.raises(RuntimeError, match="online access is off"):
        bpy.ops.nerf.setup_torch(device="CPU", env_dir=env_dir)

    t0 = time.monotonic()
    assert bpy.ops.nerf.setup_torch(device="CPU", wheel_dir=wheels, openexr=False, env_dir=env_dir) == {"FINISHED"}
    job = jobs.get(torch_setup_job.KEY)
    install = next(s for s in job.plan.steps if s.name == "install")
    assert "--no-index" in install.cmd and install.cmd[install.cmd.index("--find-links") + 1] == wheels
    assert install.env["PIP_CONFIG_FILE"] == os.devnull and "PIP_FIND_LINKS" not in install.env
    seen = drive(job)
    assert job.state == "done", job.message
    print(f"setup took {time.monotonic() - t0:.1f} s; steps: {seen}")
    assert any(s.startswith("Installing") for s in seen) and seen[-1].startswith("Checking")
    python = torch_setup.env_python(env_dir)
    assert enabled.python_path == python and torch_setup.is_ready(env_dir)
    # torch comes from the new environment, not from the interpreter running these tests
    where = subprocess.run([python, "-c", "import torch; print(torch.__file__)"], capture_output=True, text=True,
                           env=child_process.child_env(), check=True).stdout.strip()
    assert where.startswith(env_dir), where
    assert child_process.probe_interpreter(python).ok  # the job's own probe, cached: no second torch import

    s = bpy.context.scene.nerf_train
    s.dataset_dir, s.run_dir = tiny_capture(str(tmp_path)), str(tmp_path / "run")
    s.max_seconds, s.max_steps = 0.0, 3
    train = train_ui.start_training(bpy.context)
    assert train.python == python and train.process.cmd[0] == python
    deadline = time.monotonic() + 240
    while train.update() == "running":
        train_ui.sync_train_settings(train)
        assert time.monotonic() < deadline, train.process.log_tail()
        time.sleep(0.1)
    train_ui.sync_train_settings(train)
    assert train.state == "done", train.message
    assert s.step == 3 and s.error == ""


def test_cancel_leaves_no_ready_environment_and_says_so(enabled, tmp_path):
    env_dir = str(tmp_path / "env")
    os.makedirs(env_dir)
    torch_setup.mark_ready(env_dir, "CPU", "torch 0")  # an older setup: a new one must not keep claiming it
    bpy.ops.nerf.setup_torch(device="CPU", wheel_dir=wheel_folder(), openexr=False, env_dir=env_dir)
    job = jobs.get(torch_setup_job.KEY)
    assert not torch_setup.is_ready(env_dir)
    with pytest.raises(RuntimeError, match="already being set up"):
        bpy.ops.nerf.setup_torch(device="CPU", wheel_dir=wheel_folder(), openexr=False, env_dir=env_dir)
    bpy.ops.nerf.setup_torch_cancel()
    drive(job, timeout=30)
    assert job.state == "cancelled" and "press Set up PyTorch to start again" in job.message
    assert not torch_setup.is_ready(env_dir) and enabled.python_path == ""


def test_find_offers_the_checkouts_venv_probed(enabled, monkeypatch, tmp_path):
    fake_venv = tmp_path / "venv"
    os.makedirs(fake_venv / "bin")
    os.symlink("/bin/false", fake_venv / "bin" / "python")  # an interpreter that cannot import torch
    monkeypatch.setenv("VIRTUAL_ENV", str(fake_venv))
    monkeypatch.delenv("CONDA_PREFIX", raising=False)
    bpy.ops.nerf.find_pythons()
    found = {item.label: item for item in enabled.found}
    venv = found["Active virtualenv ($VIRTUAL_ENV)"]
    assert venv.python == str(fake_venv / "bin" / "python") and not venv.ok
    if os.path.isfile(os.path.join(REPO_ROOT, ".venv", "bin", "python")):
        assert "This checkout's .venv" in found
    bpy.ops.nerf.use_python(python=venv.python)
    assert enabled.python_path == venv.python
