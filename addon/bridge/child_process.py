"""Run ``python -m nerf_core ...`` as a separate process without ever blocking Blender.

torch never loads inside Blender's Python: training, rendering and dataset checks run in a child
interpreter (an add-on preference, default ``sys.executable`` when it can import torch). The child
gets its own session/process group so that Cancel kills the whole tree, and its stdout/stderr are
read by daemon threads into a queue that the UI drains from a modal timer (``BackgroundProcess.poll``).

Imports only the standard library, ``.progress`` and ``.core_path`` (never torch, never bpy):
scripts and tests use it without bpy.
"""
from __future__ import annotations

import errno
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

from ..file_writes import write_atomic
from .core_path import ADDON_DIR, nerf_core_search_path  # noqa: F401 (nerf_core_search_path: re-exported)
from .progress import LOG_TAIL_LINES, ProgressParser

PREFS_HINT = "Edit > Preferences > Add-ons > NeRF Bridge > Python with torch"


class SetupError(Exception):
    """A problem the user fixes in their setup (interpreter, dataset, run folder); message is for them."""


class DiskFullError(OSError):
    """Writing a file failed because the disk is full; the message names the file."""


# -- finding nerf_core and an interpreter ------------------------------------------------------
def child_env(addon_dir: str = ADDON_DIR, base: Optional[Dict[str, str]] = None) -> Dict[str, str]:
    """Environment for a nerf_core child: nerf_core importable, unbuffered output, UTF-8."""
    env = dict(os.environ if base is None else base)
    # Blender sets PYTHONHOME/PYTHONPATH for its own bundled Python; an external interpreter must not
    # inherit them or it would load Blender's standard library.
    env.pop("PYTHONHOME", None)
    path = nerf_core_search_path(addon_dir)
    env["PYTHONPATH"] = path or ""
    if not env["PYTHONPATH"]:
        del env["PYTHONPATH"]
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONIOENCODING"] = "utf-8"
    return env


@dataclass
class ProbeResult:
    python: str
    ok: bool
    message: str
    slow: bool = False  # it did not answer in time: busy, not broken (never cached)


_PROBE_CACHE: Dict[tuple, ProbeResult] = {}
_PROBE_CODE = "import torch, nerf_core; print('torch', torch.__version__)"


def probe_interpreter(python: str, timeout: float = 60.0, addon_dir: str = ADDON_DIR) -> ProbeResult:
    """Can ``python`` import torch and nerf_core? Cached per (path, mtime, search path)."""
    if not python:
        return ProbeResult(python, False, "no interpreter given")
    if not (os.path.isfile(python) and os.access(python, os.X_OK)):
        return ProbeResult(python, False, f"{python} is not an executable file")
    key = _probe_key(python, addon_dir)
    if key in _PROBE_CACHE:
        return _PROBE_CACHE[key]
    try:
        proc = subprocess.run(
            probe_command(python), capture_output=True, text=True, timeout=timeout,
            env=child_env(addon_dir), stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        # Not cached: a cold disk cache can make the first torch import slow.
        return ProbeResult(python, False, f"{python} is still importing torch after {timeout:g} s (a busy machine "
                           "or a cold disk); it is slow, not broken: try again in a moment", slow=True)
    except OSError as exc:
        return ProbeResult(python, False, f"{python} could not be started: {exc}")
    return remember_probe(python, proc.returncode, (proc.stdout if proc.returncode == 0 else
                                                    proc.stderr or proc.stdout).splitlines(), addon_dir)


def _probe_key(python: str, addon_dir: str) -> tuple:
    return os.path.realpath(python), os.path.getmtime(python), nerf_core_search_path(addon_dir)


def probe_command(python: str) -> List[str]:
    """The command ``probe_interpreter`` runs (with ``child_env``): a background job may run it too
    and hand the outcome to ``remember_probe``, so that Blender never waits on a torch import."""
    return [python, "-c", _PROBE_CODE]


def remember_probe(python: str, returncode: int, lines: Sequence[str], addon_dir: str = ADDON_DIR) -> ProbeResult:
    """The result of a finished probe command (its exit code and output lines: stdout on success, the
    error output otherwise), cached as ``probe_interpreter`` would have cached it."""
    lines = [ln.strip() for ln in lines if ln.strip()]
    if returncode == 0:
        result = ProbeResult(python, True, next((ln for ln in reversed(lines) if ln.startswith("torch ")),
                                                "\n".join(lines)))
    else:
        result = ProbeResult(python, False, lines[-1] if lines else f"exit code {returncode}")
    _PROBE_CACHE[_probe_key(python, addon_dir)] = result
    return result


def _venv_suggestion(addon_dir: str) -> str:
    venv = os.path.join(os.path.dirname(addon_dir), ".venv", "bin", "python")
    return venv if os.path.isfile(venv) else "the project's .venv/bin/python"


def resolve_interpreter(preference: str = "", addon_dir: str = ADDON_DIR) -> str:
    """The interpreter to run nerf_core with, or SetupError saying exactly what to set."""
    if preference:
        python = os.path.abspath(os.path.expanduser(preference))
        result = probe_interpreter(python, addon_dir=addon_dir)
        if result.slow:
            raise SetupError(f"The interpreter set in {PREFS_HINT}: {result.message}.")
        if not result.ok:
            raise SetupError(
                f"The interpreter set in {PREFS_HINT} ({python}) cannot run NeRF training: "
                f"{result.message}. Point it at a Python that has torch installed, e.g. "
                f"{_venv_suggestion(addon_dir)}."
            )
        return python
    result = probe_interpreter(sys.executable, addon_dir=addon_dir)
    if result.ok:
        return sys.executable
    if result.slow:
        raise SetupError(f"Blender's Python: {result.message}.")
    raise SetupError(
        f"Blender's Python ({sys.executable}) cannot import torch ({result.message}). Set {PREFS_HINT} "
        f"to a Python that has torch installed, e.g. {_venv_suggestion(addon_dir)}."
    )


# -- commands ------------------------------------------------------------------------------------
def train_command(
    python: str, dataset: str, run: str, method: str = "", max_seconds: float = 0.0,
    max_steps: int = 0, seed: Optional[int] = None, resume: bool = False, overwrite: bool = False,
    extra: Sequence[str] = (),
) -> List[str]:
    """``python -m nerf_core train`` with the contract's flags; 0/empty means "trainer default"."""
    cmd = [python, "-m", "nerf_core", "train", dataset, "--out", run]
    if method:
        cmd += ["--method", method]
    if max_seconds and max_seconds > 0:
        cmd += ["--max-seconds", f"{max_seconds:g}"]
    if max_steps and max_steps > 0:
        cmd += ["--max-steps", str(int(max_steps))]
    if seed is not None and not resume:  # a resumed run keeps its own seed (another one is refused)
        cmd += ["--seed", str(int(seed))]
    if resume:
        cmd.append("--resume")
    if overwrite:
        cmd.append("--overwrite")
    return cmd + list(extra)


def render_command(python: str, run: str, cameras: str, out: str, split: str = "", checkpoint: str = "") -> List[str]:
    """``nerf_core render``; ``checkpoint`` (a step_*.pt) when latest.pt is gone: render loads only
    latest.pt unless told which file (nerf_core.runs.checkpoints.load_run)."""
    cmd = [python, "-m", "nerf_core", "render", run, "--cameras", cameras, "--out", out]
    if split:
        cmd += ["--split", split]
    if checkpoint:
        cmd += ["--checkpoint", checkpoint]
    return cmd


def export_command(python: str, kind: str, run: str, out: str, checkpoint: str = "") -> List[str]:
    """``nerf_core export KIND RUN --out FILE`` (``kind``: a format of ``contract.exports``: "mesh", "volume",
    "world")."""
    cmd = [python, "-m", "nerf_core", "export", kind, run, "--out", out]
    return cmd + (["--checkpoint", checkpoint] if checkpoint else [])


def check_dataset(python: str, dataset: str, timeout: float = 300.0, addon_dir: str = ADDON_DIR) -> None:
    """Run ``python -m nerf_core check DATASET``; SetupError carrying its message when invalid."""
    if not dataset:
        raise SetupError("No dataset folder is set: capture a dataset first or choose its folder.")
    if not os.path.isdir(dataset):
        raise SetupError(f"Dataset folder {dataset} does not exist: capture a dataset first.")
    try:
        proc = subprocess.run(
            [python, "-m", "nerf_core", "check", dataset], capture_output=True, text=True,
            timeout=timeout, env=child_env(addon_dir), stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        raise SetupError(f"Checking dataset {dataset} took more than {timeout:g} s.") from None
    if proc.returncode != 0:
        lines = [ln.strip() for ln in (proc.stderr + "\n" + proc.stdout).splitlines() if ln.strip()]
        detail = "\n".join(lines[-5:]) or f"exit code {proc.returncode}"
        raise SetupError(f"Dataset {dataset} is not usable:\n{detail}")


# -- writing files safely ------------------------------------------------------------------------
def describe_os_error(exc: OSError, path: str, what: str = "writing") -> str:
    if exc.errno == errno.ENOSPC:
        return f"Disk full while {what} {path}: free some space and try again (nothing was overwritten)."
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"No permission for {what} {path}: choose a folder you can write to."
    return f"Could not finish {what} {path}: {exc.strerror or exc}"


def write_json_atomic(path: str, obj) -> None:
    """Write JSON through a temporary file so a full disk never leaves a truncated file behind."""
    try:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        write_atomic(path, lambda fh: json.dump(obj, fh, indent=2), tmp=f"{path}.tmp{os.getpid()}")
    except OSError as exc:
        if exc.errno == errno.ENOSPC:
            raise DiskFullError(exc.errno, describe_os_error(exc, path)) from exc
        raise


# -- the background process ------------------------------------------------------------------------
class BackgroundProcess:
    """A nerf_core child process whose output is parsed without blocking the caller.

    ``poll()`` never blocks: it drains what the reader threads queued, feeds stdout to a
    ``ProgressParser`` (``.progress``) and returns the new JSON events. stderr lines join the same
    log tail, so ``failure_message()`` can show the end of the log when the child dies.
    """

    def __init__(self, cmd: Sequence[str], env: Optional[Dict[str, str]] = None, cwd: Optional[str] = None,
                 tail_lines: int = LOG_TAIL_LINES, stdin_pipe: bool = False, parser_class=ProgressParser):
        self.cmd = list(cmd)
        self.stdin_pipe = stdin_pipe  # a request/response child (nerf_core serve) reads its stdin
        self.env = env if env is not None else child_env()
        self.cwd = cwd
        self.tail: deque = deque(maxlen=tail_lines)
        # parser_class: a ProgressParser subclass that also reads a foreign stdout (torch_setup: pip's)
        self.progress = parser_class(tail_lines)
        self.progress.log_tail = self.tail  # stdout and stderr lines share one tail, in arrival order
        self._stderr = ProgressParser(tail_lines)
        self._stderr.log_tail = self.tail
        self._queue: "queue.Queue[tuple]" = queue.Queue()
        self._open_streams = 0
        self.proc: Optional[subprocess.Popen] = None
        self.cancelled = False
        self.stop_requested_at: Optional[float] = None
        self.started_at: Optional[float] = None

    # lifecycle
    def start(self) -> "BackgroundProcess":
        kwargs = {}
        if os.name == "posix":
            kwargs["start_new_session"] = True  # own process group: cancel kills the whole tree
        else:
            kwargs["creationflags"] = getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0)
        try:
            self.proc = subprocess.Popen(
                self.cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                stdin=subprocess.PIPE if self.stdin_pipe else subprocess.DEVNULL,
                env=self.env, cwd=self.cwd, bufsize=0, **kwargs,
            )
        except OSError as exc:
            raise SetupError(f"Could not start {self.cmd[0]}: {exc.strerror or exc}") from exc
        self.started_at = time.monotonic()
        for name, stream in (("out", self.proc.stdout), ("err", self.proc.stderr)):
            self._open_streams += 1
            threading.Thread(target=self._reader, args=(name, stream), daemon=True,
                             name=f"nerf-{name}-{self.proc.pid}").start()
        return self

    def _reader(self, name: str, stream) -> None:
        try:
            while True:
                chunk = stream.read1(65536) if hasattr(stream, "read1") else stream.read(65536)
                if not chunk:
                    break
                self._queue.put((name, chunk))
        except (OSError, ValueError):
            pass
        finally:
            self._queue.put((name, None))

    @property
    def pid(self) -> Optional[int]:
        return self.proc.pid if self.proc else None

    @property
    def returncode(self) -> Optional[int]:
        return self.proc.poll() if self.proc else None

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def finished(self) -> bool:
        """Exited and every byte of its output has been parsed."""
        return self.proc is not None and self.proc.poll() is not None and self._open_streams == 0

    def poll(self) -> List[dict]:
        """Drain queued output (never blocks); return the new progress events."""
        events: List[dict] = []
        while True:
            try:
                name, chunk = self._queue.get_nowait()
            except queue.Empty:
                break
            parser = self.progress if name == "out" else self._stderr
            if chunk is None:
                self._open_streams -= 1
                found = parser.finish()
            else:
                found = parser.feed(chunk)
            if name == "out":
                events.extend(found)
            elif found:
                # A JSON event on stderr (e.g. an error printed by a crashing trainer) still counts.
                for ev in found:
                    self.progress.apply(ev)
                events.extend(found)
        return events

    def wait(self, timeout: Optional[float] = None, on_events=None, interval: float = 0.05) -> Optional[int]:
        """Block until finished (headless use); ``on_events(list)`` sees events as they come."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.finished():
            events = self.poll()
            if events and on_events:
                on_events(events)
            if deadline is not None and time.monotonic() > deadline:
                return None
            time.sleep(interval)
        events = self.poll()
        if events and on_events:
            on_events(events)
        return self.returncode

    def request_stop(self) -> None:
        """Ask the child to stop without waiting: SIGINT to its group, which nerf_core's trainer turns
        into "save a checkpoint, then exit" so Resume can continue. ``kill_if_overdue`` escalates."""
        if self.proc is None or self.stop_requested_at is not None:
            return
        self.cancelled = True
        self.stop_requested_at = time.monotonic()
        if self.proc.poll() is None:
            self._signal_group(signal.SIGINT if os.name == "posix" else None)

    def kill_if_overdue(self, grace: float = 15.0) -> bool:
        """After ``request_stop``: kill the group once ``grace`` s have passed; True if it killed."""
        if self.stop_requested_at is None or time.monotonic() - self.stop_requested_at < grace:
            return False
        self._signal_group(getattr(signal, "SIGKILL", None))
        return True

    def cancel(self, grace: float = 5.0) -> None:
        """Stop the child and everything it started, blocking: SIGINT (graceful: the trainer saves a
        checkpoint), then SIGKILL to the whole group after ``grace`` s."""
        if self.proc is None:
            return
        self.request_stop()
        try:
            self.proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            pass
        # The leader may be gone while its children linger in the group: kill the group regardless.
        self._signal_group(getattr(signal, "SIGKILL", None))
        try:
            self.proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            pass
        self.poll()

    def _signal_group(self, sig) -> None:
        if os.name == "posix":
            try:
                os.killpg(self.proc.pid, sig)
            except (ProcessLookupError, PermissionError):
                pass  # the group is already gone
        else:  # Windows: no process groups to signal; taskkill /T walks the tree.
            subprocess.run(["taskkill", "/F", "/T", "/PID", str(self.proc.pid)], capture_output=True)

    # reporting
    def log_tail(self) -> str:
        return "\n".join(self.tail)

    def failure_message(self) -> Optional[str]:
        """None while running, after success or after a cancel; else what went wrong plus the log tail."""
        code = self.returncode
        if code is None or self.cancelled or (code == 0 and self.progress.error is None):
            return None
        head = self.progress.error or f"{os.path.basename(self.cmd[0])} exited with code {code}"
        if code < 0 and os.name == "posix":
            try:
                head += f" (killed by {signal.Signals(-code).name})"
            except ValueError:
                pass
        tail = self.log_tail()
        return f"{head}\n--- last lines of the log ---\n{tail}" if tail else head


def pid_alive(pid: int) -> bool:
    """True when a process with ``pid`` exists and is not a zombie (POSIX)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    stat = f"/proc/{pid}/stat"
    if os.path.exists(stat):
        try:
            with open(stat) as fh:
                return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False
    return True


def group_pids(pgid: int) -> List[int]:
    """Live pids in process group ``pgid`` (Linux /proc; empty elsewhere)."""
    pids = []
    if not os.path.isdir("/proc"):
        return pids
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            pids.append(int(entry))
    return pids

