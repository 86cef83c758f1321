"""Process management of the training child (addon/bridge/child_process.py), with a fake trainer that
speaks the JSON-line protocol of docs/CONTRACTS.md: this tests the plumbing, not NeRF training."""
from __future__ import annotations

import os
import signal
import sys
import textwrap
import time

import pytest

from addon.bridge import child_process, runs
from addon.bridge.child_process import BackgroundProcess, group_pids, pid_alive

FAKE_TRAINER = textwrap.dedent('''
    import json, subprocess, sys, time
    # as nerf_core's CLI does (utils.interrupts.honour_interrupts): Ctrl-C reaches us whatever the
    # test runner's process left ignored or blocked
    import signal
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    mode = sys.argv[1]
    if mode == "stubborn":  # ignores the polite SIGINT (inherited by its children): needs SIGKILL
        import signal
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        mode = "hang"
    def emit(**ev):
        ev.setdefault("time", time.time())
        sys.stdout.write(json.dumps(ev) + "\\n"); sys.stdout.flush()
    emit(event="start", run="fake", method="fake", max_steps=3, max_seconds=None, device="cpu", n_params=1)
    sys.stderr.write("a warning on stderr\\n"); sys.stderr.flush()
    if mode == "hang":
        # A grandchild, as a DataLoader worker would be: cancel must take it down too.
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
        emit(event="grandchild", pid=child.pid)
        for step in range(1, 10**6):
            emit(event="step", step=step, loss=0.1, psnr=10.0, lr=0.01, elapsed=step * 0.05, eta=None,
                 samples_per_s=1.0)
            time.sleep(0.05)
    if mode == "crash":
        for i in range(40):
            print(f"traceback line {i}", file=sys.stderr)
        sys.exit(3)
    if mode == "error":
        emit(event="error", message="Disk full while writing checkpoints/latest.pt")
        sys.exit(1)
    # "ok": a partial line written in two pieces, garbage, then the normal end
    sys.stdout.write('{"event": "step", "step": 1, '); sys.stdout.flush(); time.sleep(0.05)
    sys.stdout.write('"loss": 0.5, "psnr": 3.0, "lr": 0.01, "elapsed": 0.1, "eta": 0.2, "samples_per_s": 1}\\n')
    print("not json at all")
    emit(event="done", step=3, elapsed=0.3, checkpoint="fake.pt", metrics={"psnr": 30.0})
''')


@pytest.fixture
def fake(tmp_path):
    path = tmp_path / "fake_trainer.py"
    path.write_text(FAKE_TRAINER)
    return lambda mode: [sys.executable, str(path), mode]


def _wait(proc: BackgroundProcess, timeout: float = 60.0):
    assert proc.wait(timeout=timeout) is not None, "fake trainer did not finish"


def test_successful_run_is_parsed_from_partial_and_garbage_output(fake):
    proc = BackgroundProcess(fake("ok")).start()
    seen = []
    assert proc.wait(timeout=60, on_events=seen.extend) == 0
    assert proc.returncode == 0 and proc.finished()
    assert [e["event"] for e in seen] == ["start", "step", "done"]
    assert proc.progress.done and proc.progress.metrics == {"psnr": 30.0}
    assert proc.failure_message() is None
    assert "not json at all" in proc.log_tail() and "a warning on stderr" in proc.log_tail()


def test_crash_reports_exit_code_and_the_end_of_the_log(fake):
    proc = BackgroundProcess(fake("crash")).start()
    _wait(proc)
    message = proc.failure_message()
    assert "exited with code 3" in message
    # stdout and stderr are separate pipes, so their relative order may vary by a line or two
    assert "traceback line 39" in message and "traceback line 20" in message
    assert "traceback line 5\n" not in message  # only the last 30 lines are kept


def test_error_event_becomes_the_headline(fake):
    proc = BackgroundProcess(fake("error")).start()
    _wait(proc)
    assert proc.failure_message().startswith("Disk full while writing checkpoints/latest.pt")


@pytest.mark.skipif(os.name != "posix", reason="process groups are POSIX; Windows uses taskkill /T")
@pytest.mark.parametrize("mode", ["hang", "stubborn"])
def test_cancel_kills_the_child_and_its_children(fake, mode):
    proc = BackgroundProcess(fake(mode)).start()
    grandchild = None
    deadline = time.monotonic() + 60
    while (grandchild is None or (proc.progress.step or 0) < 2) and time.monotonic() < deadline:
        for ev in proc.poll():
            if ev["event"] == "grandchild":
                grandchild = ev["pid"]
        time.sleep(0.05)
    assert grandchild is not None and pid_alive(grandchild) and pid_alive(proc.pid)
    pgid = proc.pid
    proc.cancel(grace=1.0)
    assert not pid_alive(proc.pid)
    deadline = time.monotonic() + 10  # the grandchild is reparented and reaped by init
    while pid_alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not pid_alive(grandchild), "grandchild survived the cancel"
    assert group_pids(pgid) == []
    assert proc.failure_message() is None  # a cancel is not a crash
    # SIGKILL for the stubborn one; Python dies of the SIGINT it did not catch otherwise
    assert proc.returncode == (-signal.SIGKILL if mode == "stubborn" else -signal.SIGINT)


def test_child_env_finds_vendored_copy_first_then_checkout(tmp_path, repo_root):
    addon_dir = tmp_path / "nerf_bridge"
    (addon_dir / "vendor" / "nerf_core").mkdir(parents=True)
    assert child_process.nerf_core_search_path(str(addon_dir)) is None  # no __init__.py: not a package
    (addon_dir / "vendor" / "nerf_core" / "__init__.py").write_text("")
    assert child_process.nerf_core_search_path(str(addon_dir)) == str(addon_dir / "vendor")
    env = child_process.child_env(str(addon_dir), base={"PYTHONHOME": "/blender/python", "PATH": "/bin"})
    assert env["PYTHONPATH"] == str(addon_dir / "vendor") and "PYTHONHOME" not in env
    assert env["PYTHONUNBUFFERED"] == "1"
    assert child_process.nerf_core_search_path(os.path.join(repo_root, "addon")) == repo_root


def test_commands_follow_the_cli_contract():
    cmd = child_process.train_command("py", "/d", "/r", method="nerf", max_seconds=5, max_steps=0, seed=1)
    assert cmd == ["py", "-m", "nerf_core", "train", "/d", "--out", "/r", "--method", "nerf",
                   "--max-seconds", "5", "--seed", "1"]
    # A resumed run keeps its seed: train refuses a different one rather than ignore it.
    cmd = child_process.train_command("py", "/d", "/r", method="nerf", max_seconds=5, max_steps=0, seed=1,
                                        resume=True)
    assert cmd == ["py", "-m", "nerf_core", "train", "/d", "--out", "/r", "--method", "nerf",
                   "--max-seconds", "5", "--resume"]
    assert child_process.render_command("py", "/r", "/t.json", "/o") == [
        "py", "-m", "nerf_core", "render", "/r", "--cameras", "/t.json", "--out", "/o"]


def test_run_folder_states_and_new_names(tmp_path):
    run = tmp_path / "run"
    assert runs.run_folder_state(str(run)) == "new"
    run.mkdir()
    assert runs.run_folder_state(str(run)) == "empty"
    assert runs.suggest_run_name(str(run)) == str(run)
    (run / "config.json").write_text("{}")
    assert runs.run_folder_state(str(run)) == "occupied"
    (run / "checkpoints").mkdir()
    (run / "checkpoints" / "step_0000010.pt").write_bytes(b"x")  # what --resume falls back to
    assert runs.run_folder_state(str(run)) == "resumable"
    (run / "checkpoints" / "latest.pt").write_bytes(b"x")
    assert runs.run_folder_state(str(run)) == "resumable"
    (tmp_path / "notes.txt").write_text("mine")
    assert runs.run_folder_state(str(tmp_path / "notes.txt")) == "file"
    (tmp_path / "run_2").mkdir()
    assert runs.suggest_run_name(str(run)) == str(tmp_path / "run_3")
