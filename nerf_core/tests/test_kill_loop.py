"""Crash safety of a run folder: ``train`` killed with SIGKILL at many points (while a checkpoint's
temporary file exists, between it and the rename, mid-``progress.jsonl``, mid-preview, at random
times), then ``train --resume``. Every time the run must resume, or say the truth (exit 2, one line,
no traceback), and then start again with the flag the message names.

The iterations are seeded, one test each; ``NERF_KILL_LOOP=N`` runs N of them (CI: 6, about 15 s each).
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ITERATIONS = int(os.environ.get("NERF_KILL_LOOP", "6"))
# "_later": only once a complete checkpoint exists, so that the kill lands between a later
# checkpoint's temporary file and its rename (or mid-preview) of a run that has something to resume
TRIGGERS = ("checkpoint_tmp_later", "preview_tmp_later", "progress_bytes", "checkpoint_tmp", "random_time",
            "preview_tmp")


def _env():
    return dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest", OMP_NUM_THREADS="1")


def _train(ds, run, *flags):
    return [sys.executable, "-m", "nerf_core", "train", str(ds), "--out", str(run), "--method", "test-grid",
            "--batch-rays", "64", "--checkpoint-every", "3", "--preview-every", "2", "--eval-views", "0",
            "--no-bar", *flags]


def _triggered(run: Path, trigger: str, threshold: int) -> bool:
    if trigger.endswith("_later"):
        if not (run / "checkpoints" / "latest.pt").is_file():
            return False
        trigger = trigger[:-len("_later")]
    if trigger == "checkpoint_tmp":
        return any((run / "checkpoints").glob("*.tmp")) if (run / "checkpoints").is_dir() else False
    if trigger == "preview_tmp":
        return any((run / "previews").glob(".*.tmp*")) if (run / "previews").is_dir() else False
    if trigger == "progress_bytes":
        p = run / "progress.jsonl"
        return p.is_file() and p.stat().st_size >= threshold
    return False


def _kill_somewhere(ds, run, trigger, rng) -> str:
    """Start a trainer and SIGKILL it when ``trigger`` fires (or at a random time); returns what fired."""
    proc = subprocess.Popen(_train(ds, run, "--max-steps", "100000"), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=_env(), cwd=REPO_ROOT)
    started = time.monotonic()
    deadline = started + (rng.uniform(1.0, 6.0) if trigger == "random_time" else 25.0)
    threshold = rng.randint(200, 4000)
    fired = "timeout"
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if _triggered(run, trigger, threshold):
                fired = trigger
                break
            time.sleep(0.0005)
        else:
            fired = "random_time" if trigger == "random_time" else "timeout"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    return fired


def _clear_error(proc) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-1500:])
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("nerf_core train: error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.mark.slow
@pytest.mark.parametrize("k", range(ITERATIONS))
def test_a_killed_run_resumes_or_tells_the_truth(dataset_factory, tmp_path, k):
    """Iteration ``k`` of the loop (one test each, so that parallel workers share them): its trigger is
    ``TRIGGERS[k % len(TRIGGERS)]``, its random kill time and byte threshold come from a seed of ``k``."""
    ds = dataset_factory(tmp_path / "ds", n_train=6, n_test=1, w=16, h=12)
    rng = random.Random(k)
    trigger = TRIGGERS[k % len(TRIGGERS)]
    run = tmp_path / "run"
    fired = _kill_somewhere(ds, run, trigger, rng)
    resumed = subprocess.run(_train(ds, run, "--resume", "--max-steps", "100000", "--max-seconds", "1.5"),
                             capture_output=True, text=True, env=_env(), cwd=REPO_ROOT, timeout=120)
    if resumed.returncode == 0:
        outcome = "resumed"
        events = [json.loads(x) for x in (run / "progress.jsonl").read_text().splitlines()
                  if x.startswith("{") and x.endswith("}")]
        assert events[-1]["event"] == "done", events[-3:]
    else:
        # The truth: nothing to resume from (killed before the first checkpoint), and what to do:
        # --overwrite when the trainer left files, or no --resume when it was killed before it
        # wrote any (a slow start on a loaded machine).
        message = _clear_error(resumed)
        flag = "--overwrite" if "--overwrite" in message else None
        assert flag or "drop --resume" in message, message
        again = subprocess.run(_train(ds, run, *([flag] if flag else []), "--max-steps", "5"),
                               capture_output=True, text=True, env=_env(), cwd=REPO_ROOT, timeout=120)
        assert again.returncode == 0, again.stderr[-1500:]
        outcome = f"told, then {flag or 'a new run'}"
    print(f"kill loop {k}: {fired}: {outcome}")


def _stop_after_first_checkpoint(ds, run, how: str) -> subprocess.CompletedProcess:
    """Start a trainer and, once its first checkpoint exists, stop it ``how``: "SIGHUP" (a closed
    terminal or ssh connection) or "closed stdout" (``train ... | head``: the reader goes away)."""
    # the trainer starts as from a terminal: SIGHUP at its default, whatever the test worker inherited
    # (an ignored SIGHUP, as nohup leaves it, is rightly kept ignored by the trainer)
    proc = subprocess.Popen(_train(ds, run, "--max-steps", "100000", "--log-every", "1"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=_env(), cwd=REPO_ROOT,
                            preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        while not (run / "checkpoints" / "latest.pt").is_file() and time.monotonic() < deadline:
            time.sleep(0.01)
        if how == "SIGHUP":
            proc.send_signal(signal.SIGHUP)
        else:
            proc.stdout.close()
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, "", err.decode())


@pytest.mark.parametrize("how", ["SIGHUP", "closed stdout"])
def test_sighup_and_a_closed_stdout_save_a_checkpoint_that_resumes(dataset_factory, tmp_path, how):
    ds = dataset_factory(tmp_path / "ds", n_train=4, n_test=1, w=16, h=12)
    run = tmp_path / "run"
    stopped = _stop_after_first_checkpoint(ds, run, how)
    assert stopped.returncode == 130, stopped.stderr[-1500:]
    assert "Traceback" not in stopped.stderr and "interrupted" in stopped.stderr
    events = [json.loads(x) for x in (run / "progress.jsonl").read_text().splitlines() if x.startswith("{")]
    assert events[-1]["event"] == "error" and "checkpoint saved" in events[-1]["message"], events[-2:]
    saved = [e["step"] for e in events if e["event"] == "checkpoint"][-1]
    resumed = subprocess.run(_train(ds, run, "--resume", "--max-steps", str(saved + 3)), capture_output=True,
                             text=True, env=_env(), cwd=REPO_ROOT, timeout=120)
    assert resumed.returncode == 0, resumed.stderr[-1500:]
    events = [json.loads(x) for x in (run / "progress.jsonl").read_text().splitlines() if x.startswith("{")]
    start = [e for e in events if e["event"] == "start"][-1]
    assert start["resumed_from"] == saved and events[-1]["event"] == "done"
