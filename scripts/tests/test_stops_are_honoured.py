"""Issue 58, rule 7, end to end: ``import_geometry.py`` started with SIGINT ignored (as a farm manager
starts jobs) stops on Ctrl-C while its export runs, stops the export, and saves nothing.

The export is held in its start-up by a plugin (``NERF_CORE_PLUGINS``, imported by the CLI before a
command runs) that records its PID and sleeps, so the interrupt lands while the script waits on it.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.skipif(os.name != "posix", reason="signals")

PLUGIN = """import os, pathlib, time
pathlib.Path(os.environ["HOLD_MARKER"]).write_text(str(os.getpid()))
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its parent) counts as gone
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def test_import_geometry_started_with_sigint_ignored_stops_on_ctrl_c_and_saves_nothing(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"never loaded: the export is stopped first")
    (tmp_path / "hold_export.py").write_text(PLUGIN)
    marker, out = tmp_path / "export.pid", tmp_path / "out.blend"
    env = dict(os.environ, OMP_NUM_THREADS="1", NERF_CORE_PLUGINS="hold_export", HOLD_MARKER=str(marker),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, str(REPO / "scripts" / "import_geometry.py"), "--run", str(run),
                             "--kind", "mesh", "--out", str(out), "--geometry", str(tmp_path / "mesh.ply"),
                             "--python", sys.executable], env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        deadline = time.monotonic() + 120
        while not marker.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert marker.exists(), proc.communicate(timeout=30)
        time.sleep(0.3)  # the script is in its wait loop
        child = int(marker.read_text())
        started = time.monotonic()
        proc.send_signal(signal.SIGINT)  # Ctrl-C, to the script alone
        _, err = proc.communicate(timeout=60)
        assert time.monotonic() - started < 30  # not the export's 120 s
        assert proc.returncode == 2 and "interrupted; nothing was imported" in err.strip().splitlines()[-1], err
        assert "Traceback" not in err and not out.exists() and not (tmp_path / "mesh.ply").exists()
        deadline = time.monotonic() + 15
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(child), "the export was left running"
    finally:  # whatever failed, leave no process of ours behind
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        if marker.exists() and marker.read_text() and _alive(int(marker.read_text())):
            os.kill(int(marker.read_text()), signal.SIGKILL)
