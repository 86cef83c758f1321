"""Running the command-line tools a study measures: subprocesses, their JSON-line events, parallel jobs.

The studies drive the same command lines users run (``scripts/make_demo_scene.py``,
``scripts/capture.py``, ``python -m nerf_core train/eval/render``) as subprocesses, so what they
measure is what users get. This module owns starting them (``run_cli``, ``nerf_core_cmd``,
``script_cmd``), reading their progress events (``parse_events``, ``CliResult``) and a run's final
test metrics (``final_test_metrics``), sharing the
cores between parallel runs (``thread_env``, ``run_parallel``, ``SharedProgress``) and describing
the machine the numbers came from (``machine_info``).

Standard library and ``nerf_core.contract`` (standard library + numpy) only: importing it must not
start torch.
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Iterable, Optional, Sequence

from _bootstrap import REPO_ROOT  # scripts/ is on sys.path wherever ``bench`` is importable (entry scripts, conftest)
from nerf_core import contract  # standard library + numpy: no torch

PYTHON = sys.executable


class BenchError(RuntimeError):
    """A step of a study failed; the message names the command, scene or file."""


def parse_events(lines: Iterable[str]) -> list[dict]:
    """The JSON objects among ``lines``: events, and the summary ``eval`` prints last
    (``nerf_core.contract.parse_json_line``); library warnings and partial lines are skipped."""
    return [ev for ev in map(contract.parse_json_line, lines) if ev is not None]


@dataclass
class CliResult:
    """What a finished subprocess left behind."""

    args: list[str]
    returncode: int
    events: list[dict] = field(default_factory=list)
    stdout_tail: list[str] = field(default_factory=list)
    stderr_tail: list[str] = field(default_factory=list)
    wall: float = 0.0

    @property
    def ok(self) -> bool:
        return self.returncode == 0

    def last_json(self) -> Optional[dict]:
        """The last JSON object printed (``eval`` prints its metrics as the last line)."""
        return self.events[-1] if self.events else None

    def error_message(self) -> str:
        """The best one-line explanation of a failure: the ``error`` event, else stderr's last line."""
        for ev in reversed(self.events):
            if ev.get("event") == "error":
                return str(ev.get("message", "error"))
        for line in reversed(self.stderr_tail + self.stdout_tail):
            if line.strip():
                return line.strip()
        return f"exit code {self.returncode}"


def nerf_core_cmd(*args: str) -> list[str]:
    return [PYTHON, "-m", "nerf_core", *[str(a) for a in args]]


def thread_env(jobs: int) -> dict:
    """Environment that gives each of ``jobs`` parallel children an equal share of the CPU cores.

    torch (and numpy's BLAS) start one thread per core by default; ``jobs`` runs that each start
    ``cpu_count`` threads would fight over the cores and every timing would measure the contention.
    With ``jobs`` <= 1 nothing is set, so a single run uses the machine as a user's run does.
    """
    if jobs <= 1:
        return {}
    threads = str(max(1, (os.cpu_count() or 1) // jobs))
    return {"OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads, "OPENBLAS_NUM_THREADS": threads}


def run_parallel(tasks: Sequence[Callable[[], object]], jobs: int) -> list:
    """Run the zero-argument callables ``tasks``, ``jobs`` at a time; results in the order given.

    The tasks start subprocesses and wait on them, so threads are enough. A task that raises
    re-raises here after the others have finished: a study never loses the runs that worked.
    """
    if jobs <= 1 or len(tasks) <= 1:
        return [t() for t in tasks]
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(t) for t in tasks]
        return [f.result() for f in futures]


class SharedProgress:
    """One progress bar fed by several parallel runs: the bar shows finished work plus each live run's.

    ``advance(key, seconds)`` records how far run ``key`` is; ``finish(key, cost, info)`` books its
    full planned cost. Thread-safe, so parallel runs' event callbacks can call it directly.
    """

    def __init__(self, bar):
        self.bar = bar
        self.finished = bar.done
        self.live: dict = {}
        self.lock = threading.Lock()

    def _draw(self, info: str) -> None:
        self.bar.set(self.finished + sum(self.live.values()), info=info)

    def advance(self, key, seconds: float, info: str = "") -> None:
        with self.lock:
            self.live[key] = seconds
            self._draw(info)

    def finish(self, key, cost: float, info: str = "") -> None:
        with self.lock:
            self.live.pop(key, None)
            self.finished += cost
            self._draw(info)


def script_cmd(script: str, *args: str) -> list[str]:
    return [PYTHON, os.path.join(REPO_ROOT, "scripts", script), *[str(a) for a in args]]


def run_cli(
    cmd: Sequence[str],
    on_event: Optional[Callable[[dict], None]] = None,
    log_path: Optional[str] = None,
    timeout: Optional[float] = None,
    tail: int = 40,
    env_extra: Optional[dict] = None,
) -> CliResult:
    """Run ``cmd``, streaming stdout so ``on_event`` sees progress events as they happen.

    stderr goes to a temporary file (not a pipe) so a chatty child can never block on a full pipe.
    ``log_path`` receives both streams for post-mortems. A timeout kills the child and is reported as
    return code 124, like coreutils' ``timeout``. ``env_extra`` is merged into the child's
    environment (``thread_env`` for parallel jobs).
    """
    start = time.monotonic()
    env = dict(os.environ)
    env.update(env_extra or {})
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONPATH"] = REPO_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    log = open(log_path, "a", encoding="utf-8") if log_path else None
    err_path = (log_path or os.path.join(tempfile.gettempdir(), f"bench_{os.getpid()}")) + ".stderr"
    result = CliResult(args=list(cmd), returncode=-1)
    try:
        if log:
            log.write("$ " + " ".join(cmd) + "\n")
            log.flush()
        with open(err_path, "w+", encoding="utf-8", errors="replace") as err:
            proc = subprocess.Popen(
                list(cmd), stdout=subprocess.PIPE, stderr=err, text=True, errors="replace",
                cwd=REPO_ROOT, env=env, bufsize=1,
            )
            try:
                assert proc.stdout is not None
                for line in proc.stdout:
                    if log:
                        log.write(line)
                        log.flush()  # the log is what one reads while a long run is still going
                    ev = contract.parse_json_line(line)
                    if ev is not None:
                        result.events.append(ev)
                        if on_event:
                            on_event(ev)
                    else:
                        result.stdout_tail.append(line.rstrip("\n"))
                        del result.stdout_tail[:-tail]
                    if timeout is not None and time.monotonic() - start > timeout:
                        proc.kill()
                        break
                proc.wait(timeout=None if timeout is None else max(1.0, timeout - (time.monotonic() - start)))
                result.returncode = proc.returncode
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                result.returncode = 124
            if timeout is not None and time.monotonic() - start > timeout and result.returncode != 0:
                result.returncode = 124
            err.seek(0)
            err_text = err.read()
        result.stderr_tail = err_text.splitlines()[-tail:]
        if log:
            log.write(err_text)
    finally:
        if log:
            log.close()
        try:
            os.remove(err_path)
        except OSError:
            pass
    result.wall = time.monotonic() - start
    return result


def final_test_metrics(train: CliResult, run_dir: str, log_path: Optional[str] = None,
                       env_extra: Optional[dict] = None) -> tuple[Optional[dict], Optional[str]]:
    """A finished training run's test PSNR/SSIM: ``(metrics, None)``, or ``(None, why)``.

    The trainer's own final ``eval`` event on the test split when it sent one (saves a process; the
    ``--eval-at`` evaluations during training carry ``eval_wall`` and are not final), else the last
    JSON line of a separate ``nerf_core eval RUN --split test``.
    """
    final = [e for e in train.events if e.get("event") == "eval" and e.get("split") == "test" and "eval_wall" not in e]
    if final:
        return final[-1], None
    ev = run_cli(nerf_core_cmd("eval", run_dir, "--split", "test", "--no-bar"), log_path=log_path, env_extra=env_extra)
    metrics = ev.last_json() if ev.ok else None
    if not metrics or "psnr" not in metrics:
        return None, ev.error_message()
    return metrics, None


def _run_cli(args) -> Optional[subprocess.CompletedProcess]:
    """Run a short CLI command from the checkout (None when it cannot start or hangs)."""
    try:
        return subprocess.run(list(args), capture_output=True, text=True, cwd=REPO_ROOT, timeout=120,
                              env={**os.environ, "PYTHONPATH": REPO_ROOT})
    except (OSError, subprocess.TimeoutExpired):
        return None


def method_names() -> list[str]:
    """The methods ``python -m nerf_core methods`` lists, plugins included ([] when it cannot run)."""
    out = _run_cli(nerf_core_cmd("methods"))
    if out is None or out.returncode != 0:
        return []
    return [line.split()[0] for line in out.stdout.splitlines() if line.strip()]


def cli_help(*args: str) -> str:
    """``--help`` text of a CLI (empty when it cannot run), used to detect optional trainer flags."""
    out = _run_cli([*args, "--help"])
    return "" if out is None else out.stdout + out.stderr


# --------------------------------------------------------------------------------------------
# Machine description
# --------------------------------------------------------------------------------------------


def contended(load_before, load_after, own_threads: int) -> bool:
    """Whether other jobs shared the machine with a timing run, from the 1-minute load averages.

    The run's own threads raise the load average to about ``own_threads`` by its end, so only more
    than that (plus half a core of slack) counts; at the start anything above half the cores does.
    A value of None (no load average on this system) says nothing.
    """
    cores = os.cpu_count() or 1
    return ((load_before is not None and load_before > cores / 2)
            or (load_after is not None and load_after > own_threads + 0.5))


CONTENDED_NOTE = ("**Contended machine**: the load average says that other jobs ran beside this benchmark "
                  "(above half the cores at the start, or above its own threads + 0.5 at the end), so these "
                  "timings are not speed claims; re-run on a quiet machine.")


def git_commit(tree: str = REPO_ROOT) -> str:
    """Short commit of the checkout at ``tree``, with "+uncommitted changes" when tracked files differ
    from it; "unknown" outside git."""
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             cwd=tree, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, cwd=tree).stdout.strip()
        return out + ("+uncommitted changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def machine_info() -> dict:
    """Where the numbers came from: CPU model, cores, load, Python/torch versions."""
    info = {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        info["load_avg"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    try:
        import importlib.metadata as md

        info["torch"] = md.version("torch")
    except Exception:  # noqa: BLE001 (any metadata problem just leaves the field out)
        pass
    return info
