"""The add-on's side of ``python -m nerf_core serve``: one long-lived render process per run.

The render engine (``render_engine.py``) sends cameras here and gets numpy images back. The process
is started the way every nerf_core child is (``child_process``: which interpreter, where nerf_core
is found, its own process group) and is kept alive between frames and renders, so the model loads
once; it is replaced when the run, the checkpoint or the checkpoint file's mtime changes, and shut
down by ``shutdown_all`` (add-on unregister, Blender exit).

Several callers may share a client (the F12 render thread and the viewport's timer): ``poll`` and
``submit`` hold a lock, and results are kept by request id, so no caller steals another's events.

Also here, because the engine and its tests share them: Blender-free pixel conversions
(``display_to_linear``, ``blender_rect``). Imports numpy, the standard library and nerf_core's
contract only (no bpy).
"""
from __future__ import annotations

import atexit
import json
import os
import shutil
import tempfile
import threading
import time
from typing import Callable, Dict, Optional, Tuple

import numpy as np

from . import child_process, runs
from .core_contract import contract

SERVE_START_TIMEOUT_S = 300.0  # importing torch and loading a checkpoint on a cold disk can be slow
# The largest image side ``nerf_core serve`` renders (nerf_core.render.server.MAX_SIDE; that module
# is not importable inside Blender). Checked here first, so the user hears of their Resolution
# setting instead of the request's field 'w'.
MAX_SIDE = 16384


class RenderClientError(RuntimeError):
    """The render process failed or refused a request; the message is for the user."""


def run_problem(run_dir: str, checkpoint: str = "") -> Optional[str]:
    """Why ``run_dir`` cannot be rendered (a message naming the folder or file), else None."""
    if not run_dir:
        return "No NeRF run is chosen: set the run folder in Render Properties > NeRF Run"
    run = os.path.abspath(run_dir)
    if not os.path.isdir(run):
        return f"NeRF run folder {run} does not exist"
    if not os.path.isfile(os.path.join(run, "config.json")):
        return f"{run} is not a NeRF run (no config.json): choose a folder written by `python -m nerf_core train`"
    ckpt = os.path.abspath(checkpoint) if checkpoint else os.path.join(run, "checkpoints", "latest.pt")
    # Without latest.pt (a full disk cost it) nerf_core loads the newest step_*.pt, as --resume does.
    if not os.path.isfile(ckpt) and (checkpoint or not runs.step_checkpoints(run)):
        return f"{ckpt} not found: train the run first (or choose another checkpoint)"
    return None


def serve_command(python: str, run: str, checkpoint: str = "", device: str = "") -> list:
    cmd = [python, "-m", "nerf_core", "serve", run]
    if checkpoint:
        cmd += ["--checkpoint", checkpoint]
    if device:
        cmd += ["--device", device]
    return cmd


def _remove_outputs(event: dict) -> None:
    for p in (event.get("path"), event.get("depth_path")):
        if p:
            try:
                os.remove(p)
            except OSError:
                pass


class RenderClient:
    """One ``nerf_core serve`` process and the requests sent to it."""

    def __init__(self, python: str, run: str, checkpoint: str = "", device: str = "",
                 addon_dir: str = child_process.ADDON_DIR):
        self.run = os.path.abspath(run)
        self.checkpoint = os.path.abspath(checkpoint) if checkpoint else ""
        self.key = client_key(python, run, checkpoint)
        cmd = serve_command(python, self.run, self.checkpoint, device)
        self.process = child_process.BackgroundProcess(cmd, env=child_process.child_env(addon_dir), stdin_pipe=True)
        self.tmpdir = tempfile.mkdtemp(prefix="nerf_render_")
        self.info: Optional[dict] = None  # the ``ready`` event
        self.fatal: Optional[str] = None
        self.results: Dict[int, dict] = {}
        self.errors: Dict[int, str] = {}
        self.skipped: set = set()
        self.progress: Dict[int, float] = {}
        self.abandoned: set = set()  # ids nobody waits for any more: their files are removed on arrival
        self._next_id = 1
        self._lock = threading.RLock()
        self.process.start()

    # -- talking to the process -----------------------------------------------------------------
    def alive(self) -> bool:
        return self.process.running() and self.fatal is None

    def submit(self, camera: dict, depth: bool = False, group: Optional[str] = None) -> int:
        """Send one camera (``c2w`` 4x4 rows, ``fx fy cx cy w h``, optional ``near far``); returns its id."""
        with self._lock:
            rid = self._next_id
            self._next_id += 1
            req = {**camera, "id": rid, "out": os.path.join(self.tmpdir, f"r{rid}.npy"), "depth": bool(depth)}
            if group:
                req["group"] = group
            try:
                self.process.proc.stdin.write((json.dumps(req) + "\n").encode("utf-8"))
                self.process.proc.stdin.flush()
            except (OSError, ValueError) as exc:
                raise RenderClientError(self._death_message(f"the render process stopped ({exc})")) from None
            return rid

    def discard(self, rid: int) -> None:
        """Nobody waits for ``rid`` any more (a viewport moved on): drop its answer when it comes."""
        with self._lock:
            self.abandoned.add(rid)
            ev = self.results.pop(rid, None)
            self.errors.pop(rid, None)
            self.skipped.discard(rid)
            self.progress.pop(rid, None)
        if ev is not None:
            _remove_outputs(ev)

    def poll(self) -> None:
        """Take in what the process printed (never blocks)."""
        with self._lock:
            for ev in self.process.poll():
                kind, rid = ev.get("event"), ev.get("id")
                if rid in self.abandoned and kind in ("result", "skipped", "error"):
                    self.abandoned.discard(rid)
                    if kind == "result":
                        _remove_outputs(ev)
                    continue
                if kind == "ready":
                    self.info = ev
                elif kind == "result" and isinstance(rid, int):
                    self.results[rid] = ev
                    self.progress.pop(rid, None)
                elif kind == "progress" and isinstance(rid, int):
                    self.progress[rid] = float(ev.get("fraction") or 0.0)
                elif kind == "skipped" and isinstance(rid, int):
                    self.skipped.add(rid)
                elif kind == "error":
                    message = str(ev.get("message") or "the render process reported an error")
                    if ev.get("fatal"):
                        self.fatal = message
                    elif isinstance(rid, int):
                        self.errors[rid] = message
                    else:
                        self.errors[0] = message

    def _death_message(self, head: str) -> str:
        if self.fatal:
            return f"Cannot render with NeRF run {self.run}: {self.fatal}"
        failure = self.process.failure_message()
        return f"{head}: {failure}" if failure else head

    def take(self, rid: int) -> Optional[Tuple[np.ndarray, Optional[np.ndarray]]]:
        """(rgba (h, w, 4), depth (h, w) or None) once request ``rid`` is done, else None.

        Raises RenderClientError when the request failed or the process died; the files are removed.
        """
        self.poll()
        with self._lock:
            if rid in self.errors:
                raise RenderClientError(self.errors.pop(rid))
            if rid in self.skipped:
                self.skipped.discard(rid)
                raise RenderClientError(f"request {rid} was replaced by a newer one")
            ev = self.results.pop(rid, None)
        if ev is None:
            if self.fatal or (not self.process.running() and self.process.finished()):
                raise RenderClientError(self._death_message("The NeRF render process exited"))
            return None
        try:
            rgba = np.load(ev["path"])
            depth = np.load(ev["depth_path"]) if ev.get("depth_path") else None
        except (OSError, ValueError, KeyError) as exc:
            raise RenderClientError(f"cannot read the render process's output: {exc}") from None
        finally:
            _remove_outputs(ev)
        return rgba, depth

    def render(self, camera: dict, depth: bool = False, timeout: float = 3600.0,
               on_progress: Optional[Callable[[float, str], None]] = None,
               should_stop: Optional[Callable[[], bool]] = None):
        """Blocking ``submit`` + ``take`` (final renders, headless). None when ``should_stop()`` said so.

        ``on_progress(fraction, message)`` is called while waiting (model loading, then the frame).
        """
        rid = self.submit(camera, depth=depth)
        deadline = time.monotonic() + timeout
        start_deadline = time.monotonic() + SERVE_START_TIMEOUT_S
        while True:
            got = self.take(rid)
            if got is not None:
                return got
            if should_stop is not None and should_stop():
                return None
            now = time.monotonic()
            if self.info is None and now > start_deadline:
                raise RenderClientError(f"the render process did not load {self.run} within "
                                        f"{SERVE_START_TIMEOUT_S:g} s")
            if now > deadline:
                raise RenderClientError(f"rendering took more than {timeout:g} s")
            if on_progress is not None:
                if self.info is None:
                    on_progress(0.0, "NeRF: loading the model")
                else:
                    on_progress(self.progress.get(rid, 0.0), "NeRF: rendering")
            time.sleep(0.02)

    def close(self, grace: float = 3.0) -> None:
        """Ask the process to quit, kill it if it does not, remove the temporary folder."""
        proc = self.process.proc
        if proc is not None and proc.poll() is None:
            try:
                proc.stdin.write(b'{"cmd": "quit"}\n')
                proc.stdin.close()
                proc.wait(timeout=grace)
            except Exception:  # a dead pipe or a slow exit: the kill below settles it
                pass
            if proc.poll() is None:
                self.process.cancel(grace=grace)
        shutil.rmtree(self.tmpdir, ignore_errors=True)


# -- one client per run, shared ---------------------------------------------------------------------
_CLIENTS: Dict[str, RenderClient] = {}
_CLIENTS_LOCK = threading.Lock()


def client_key(python: str, run: str, checkpoint: str = "") -> tuple:
    """What must stay the same for a running process to be reused (a retrained checkpoint changes mtime)."""
    ckpt = os.path.abspath(checkpoint) if checkpoint else os.path.join(os.path.abspath(run), "checkpoints", "latest.pt")
    try:
        mtime = os.path.getmtime(ckpt)
    except OSError:
        mtime = None
    return (python, os.path.abspath(run), ckpt, mtime)


def get_client(python: str, run: str, checkpoint: str = "", device: str = "") -> RenderClient:
    """The live client for (python, run, checkpoint), started when there is none (others are closed)."""
    key = client_key(python, run, checkpoint)
    with _CLIENTS_LOCK:
        client = _CLIENTS.get("current")
        if client is not None and client.key == key and client.alive():
            return client
        if client is not None:
            client.close()
        client = RenderClient(python, run, checkpoint, device)
        _CLIENTS["current"] = client
        return client


def current_client() -> Optional[RenderClient]:
    return _CLIENTS.get("current")


def shutdown_all() -> None:
    with _CLIENTS_LOCK:
        for client in _CLIENTS.values():
            client.close()
        _CLIENTS.clear()


atexit.register(shutdown_all)


# -- pixels -------------------------------------------------------------------------------------------
def display_to_linear(rgb: np.ndarray) -> np.ndarray:
    """sRGB-encoded values (what the NeRF learned from PNGs) -> scene-linear, the inverse of the sRGB
    transfer function that Blender's Standard view transform applies when it saves or shows pixels."""
    rgb = np.clip(rgb, 0.0, 1.0)
    return np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4).astype(np.float32)


def blender_rect(rgba: np.ndarray) -> np.ndarray:
    """(h, w, 4) straight sRGB-encoded RGBA, row 0 at the top -> (h * w, 4) float32 for a Combined pass:
    scene-linear, premultiplied by alpha (Blender's convention), row 0 at the bottom.

    Colours a hair from an 8-bit rounding edge are first moved clear of it
    (``contract.eight_bit.clear_of_8bit_edges``, by at most 2e-5): Blender's colour round trip is
    approximate, and without this its 8-bit files differ from ``nerf_core render``'s by one level
    in about one pixel in a thousand."""
    rgba = np.asarray(rgba, dtype=np.float32)
    out = np.empty_like(rgba)
    alpha = np.clip(rgba[..., 3:4], 0.0, 1.0)
    out[..., :3] = display_to_linear(contract.eight_bit.clear_of_8bit_edges(rgba[..., :3])) * alpha
    out[..., 3:4] = alpha
    return np.ascontiguousarray(out[::-1]).reshape(-1, 4)


def blender_depth_rect(depth: np.ndarray) -> np.ndarray:
    """(h, w) planar depth, row 0 at the top -> (h * w, 1) float32 for the Depth pass, row 0 at the bottom.

    Pixels where nothing was hit (0 from the server) become inf, as in the capture's depth files, so
    that a compositor's Z-combine treats them as infinitely far."""
    d = np.asarray(depth, dtype=np.float32)
    d = np.where(d > 0, d, np.float32(np.inf))
    return np.ascontiguousarray(d[::-1]).reshape(-1, 1)
