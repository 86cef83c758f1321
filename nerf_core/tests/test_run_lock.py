"""One writer per run folder: a second trainer into a busy run stops at once and names the first's PID."""
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest

from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.errors import TrainError
from nerf_core.runs.events import read_events
from nerf_core.runs.folder import RUN_LOCK, check_run_folder, lock_run_folder

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="the run lock uses flock (POSIX only)")


def _cfg(ds, run, **kw):
    base = dict(dataset=str(ds), out=str(run), method="test-grid", max_steps=3, batch_rays=64, seed=0,
                stdout_events=False, show_bar=False, eval_views=0)
    base.update(kw)
    return TrainConfig(**base)


def test_the_lock_names_its_holder_and_is_gone_once_released(tmp_path):
    release = lock_run_folder(tmp_path)
    assert (tmp_path / RUN_LOCK).read_text().strip() == str(os.getpid())
    # flock locks belong to an open file, so a second lock fails even inside the same process.
    with pytest.raises(TrainError, match=f"another trainer \\(PID {os.getpid()}\\)") as err:
        lock_run_folder(tmp_path)
    assert str(err.value).startswith(f"{tmp_path}: ")
    release()
    assert not (tmp_path / RUN_LOCK).exists()
    lock_run_folder(tmp_path)()  # free again


def test_a_left_over_lock_file_does_not_make_a_folder_busy_or_non_empty(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / RUN_LOCK).write_text("999999\n")  # what a trainer killed with SIGKILL leaves: a file nobody locks
    check_run_folder(run, resume=False, overwrite=False)
    assert train(_cfg(sphere_dataset, run))["step"] == 3
    assert not (run / RUN_LOCK).exists()


def test_overwrite_and_resume_of_a_held_run_are_refused_and_change_nothing(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run))
    before = {p.relative_to(run): p.stat().st_mtime_ns for p in run.rglob("*")}
    release = lock_run_folder(run)  # stands in for a trainer still writing the run
    try:
        for kw in ({"overwrite": True}, {"resume": True, "max_steps": 6}, {}):
            with pytest.raises(TrainError, match=f"{run}: another trainer \\(PID {os.getpid()}\\)"):
                train(_cfg(sphere_dataset, run, **kw))
        assert (run / RUN_LOCK).read_text().strip() == str(os.getpid())  # --overwrite left the holder's lock
    finally:
        release()
    assert {p.relative_to(run): p.stat().st_mtime_ns for p in run.rglob("*")} == before


def test_a_new_run_is_checked_again_once_locked(sphere_dataset, tmp_path, monkeypatch):
    """Two trainers into a folder that does not exist yet both pass the first check; the one that
    gets the lock second must find the folder filled by the first and stop."""
    import nerf_core.engine.trainer as train_mod

    run = tmp_path / "run"
    real_load = train_mod.load_dataset

    def load_while_another_trainer_starts(*a, **kw):
        run.mkdir()
        (run / "config.json").write_text("{}")
        return real_load(*a, **kw)

    monkeypatch.setattr(train_mod, "load_dataset", load_while_another_trainer_starts)
    with pytest.raises(TrainError, match="not empty"):
        train(_cfg(sphere_dataset, run))
    assert sorted(p.name for p in run.iterdir()) == ["config.json"]


def _start_trainer(args, stderr_path):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest", OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "nerf_core", *args], stdout=subprocess.PIPE,
                            stderr=open(stderr_path, "w"), text=True, cwd=REPO_ROOT, env=env)


def test_a_second_trainer_into_a_busy_run_exits_at_once_naming_the_first(sphere_dataset, tmp_path):
    run = (tmp_path / "run").resolve()
    common = ["--method", "test-grid", "--batch-rays", "64", "--no-bar", "--eval-views", "0"]
    first = _start_trainer(["train", str(sphere_dataset), "--out", str(run), "--max-steps", "10000000",
                            "--log-every", "1000000", *common], tmp_path / "first.err")
    lines: "queue.Queue[str]" = queue.Queue()
    threading.Thread(target=lambda: [lines.put(ln) for ln in first.stdout], daemon=True).start()
    try:
        deadline = time.monotonic() + 120
        while True:
            assert first.poll() is None, (tmp_path / "first.err").read_text()[-2000:]
            try:
                if json.loads(lines.get(timeout=1)).get("event") == "start":
                    break
            except queue.Empty:
                assert time.monotonic() < deadline, "the first trainer never started"
            except ValueError:
                pass
        for extra in ([], ["--resume"], ["--overwrite"]):
            env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest")
            t0 = time.monotonic()
            second = subprocess.run([sys.executable, "-m", "nerf_core", "train", str(sphere_dataset), "--out", str(run),
                                     "--max-steps", "5", *common, *extra],
                                    capture_output=True, text=True, cwd=REPO_ROOT, env=env, timeout=120)
            assert second.returncode == 2, (extra, second.stderr[-2000:])
            assert time.monotonic() - t0 < 60
            assert "Traceback" not in second.stderr + second.stdout
            last = second.stderr.strip().splitlines()[-1]
            assert last.startswith(f"nerf_core train: error: {run}: another trainer (PID {first.pid})"), last
            events = [json.loads(ln) for ln in second.stdout.splitlines() if ln.startswith("{")]
            assert [e["event"] for e in events] == ["error"] and f"PID {first.pid}" in events[0]["message"]
        assert first.poll() is None  # the first trainer is unharmed
        first.send_signal(signal.SIGTERM)
        assert first.wait(timeout=120) == 130
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    events = read_events(run / "progress.jsonl")
    assert [e["event"] for e in events].count("start") == 1
    assert events[-1]["event"] == "error" and "checkpoint saved" in events[-1]["message"]
    assert not any("another trainer" in e.get("message", "") for e in events)
    assert (run / "checkpoints" / "latest.pt").is_file() and (run / "config.json").is_file()
    assert not (run / RUN_LOCK).exists()  # released on the way out
