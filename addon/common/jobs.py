"""Background jobs (capture, training, rendering) and the one modal timer operator that advances them.

Modelled on Blender's ``operator_modal_timer.py`` template: the operators that start work only
create a job and return; ``NERF_OT_follow_jobs`` gets a timer event a few times a second and calls
each running job's ``update()``, which never waits (a training child is polled, a capture renders
one frame), so Blender stays responsive. Other events pass through; Esc stops a capture.

Jobs live in a registry keyed by what they do ('capture', 'train', 'render'): Python objects cannot
live in scene properties. A job mirrors its state into the scene's settings through its
``on_update`` hook (set by the UI module that started it) and runs ``on_end`` once when it stops.
Running children are stopped when a file is loaded and when Blender's Python exits: they live in
their own process group, so nothing else would take them down.
"""
from __future__ import annotations

import atexit
import sys
import time
import traceback
from typing import Callable, Dict, List, Optional, Sequence

import bpy

from ..bridge import child_process
from .ui_common import status_bar, tag_redraw

TICK = 0.05  # seconds between timer events; each job says how often it wants updating
STALE_FOLLOWER = 5.0  # a follower silent this long has lost its window: start another


class Job:
    """Something running in the background. ``update()`` advances it without blocking and returns its
    state, 'running', 'done', 'failed' or 'cancelled'; ``message`` says what happened for the last three."""

    kind = "job"
    interval = 0.25  # seconds between updates: a child's output does not need more
    esc_cancels = False  # Esc in the viewport stops it (capture: the user is watching it render)
    keeps_timer_event = False  # capture renders on the timer event, so it keeps it, as Blender's own jobs do
    cancel_report = "INFO"

    def __init__(self, scene_name: str):
        self.scene_name = scene_name
        self.state = "running"
        self.message = ""
        self.warnings: List[str] = []  # reported beside the message when the job is done
        self.on_update: Optional[Callable[["Job"], None]] = None
        self.on_end: Optional[Callable[["Job"], None]] = None
        self.ended = False  # on_end has run
        self.last_update = 0.0

    @property
    def scene(self):
        return bpy.data.scenes.get(self.scene_name)

    def update(self) -> str:
        raise NotImplementedError

    def cancel(self, wait: bool = True) -> None:
        raise NotImplementedError

    def fail(self, message: str) -> str:
        self.state, self.message = "failed", message
        return self.state

    def status_bar_text(self) -> Optional[str]:
        """A line for Blender's status bar while running, or None."""
        return None

    def notify(self) -> None:
        """Mirror the state into the scene (``on_update``) and, once it has stopped, run ``on_end``."""
        if self.on_update is not None:
            self.on_update(self)
        if self.state != "running" and not self.ended:
            self.ended = True
            if self.on_end is not None:
                self.on_end(self)


class ProcessJob(Job):
    """A job whose work happens in a nerf_core child process (``child_process.BackgroundProcess``)."""

    def __init__(self, scene_name: str):
        super().__init__(scene_name)
        self.process: Optional[child_process.BackgroundProcess] = None

    def cancel(self, wait: bool = True) -> None:
        """Stop the child. ``wait=False`` (the Cancel button) only asks it to stop, so Blender never
        waits; ``update()`` then finishes the cancel, killing the group if it does not exit in time."""
        if self.process is None or self.state != "running":
            return
        if wait:
            self.process.cancel()
            self._cancelled()
        else:
            self.process.request_stop()

    def _cancelled(self) -> str:
        p = self.process.progress
        self.state = "cancelled"
        self.message = f"{self.kind.capitalize()} cancelled"
        if p.step is not None:
            self.message += f" at step {p.step}"
        if p.error and "checkpoint saved" in p.error:
            self.message += "; checkpoint saved: Resume continues from it"
        return self.state

    def _check_cancel(self) -> Optional[str]:
        """While a requested stop is under way: None to keep going, else the final state."""
        if self.process.stop_requested_at is None:
            return None
        self.process.poll()
        if self.process.finished():
            return self._cancelled()
        self.process.kill_if_overdue()
        return self.state

    def update(self) -> str:
        """Finish a requested stop, else poll the child; once it has exited, ``child_exited``."""
        if self.state != "running":
            return self.state
        stopping = self._check_cancel()
        if stopping is not None:
            return stopping
        self.process.poll()
        if not self.process.finished():
            return self.state
        return self.child_exited()

    def child_exited(self) -> str:
        """The child has exited: fail with its error (``Training stopped: ...``), else ``succeeded()``."""
        failure = self.process.failure_message()
        if failure:
            return self.fail(f"{self.kind.capitalize()} stopped: {failure}")
        return self.succeeded()

    def succeeded(self) -> str:
        """The child exited cleanly: finish the job's own work, set ``done`` and say what was done."""
        raise NotImplementedError


# -- the registry ------------------------------------------------------------------------------------
_JOBS: Dict[str, Job] = {}
_FOLLOWER = {"active": False, "last_tick": 0.0, "status_text": None}
_HOOKED = {"atexit": False}


def add(key: str, job: Job) -> Job:
    """Track ``job`` under ``key`` (replacing a finished one); it is stopped on file load and exit."""
    if key in _JOBS and _JOBS[key] is not job and _JOBS[key].state == "running":
        raise child_process.SetupError(f"A {_JOBS[key].kind} job is already running: cancel it first.")
    _JOBS[key] = job
    _hook()
    return job


def get(key: str) -> Optional[Job]:
    return _JOBS.get(key)


def is_running(key: str) -> bool:
    job = _JOBS.get(key)
    return job is not None and job.state == "running"


def running(keys: Optional[Sequence[str]] = None) -> List[Job]:
    return [job for key, job in _JOBS.items() if job.state == "running" and (keys is None or key in keys)]


def cancel_jobs(wait: bool = True, keys: Optional[Sequence[str]] = None) -> None:
    """Stop every running job (or those under ``keys``). The Cancel button passes ``wait=False`` (the
    follower finishes the cancel); file loads and exit wait, since nothing polls afterwards."""
    for job in running(keys):
        job.cancel(wait=wait)


def forget(keys: Sequence[str]) -> None:
    """Stop and drop the jobs under ``keys`` (a UI module unregistering)."""
    cancel_jobs(keys=keys)
    for key in keys:
        _JOBS.pop(key, None)


def _stop_children() -> None:
    """At exit: stop the child processes (they live in their own session, so quitting Blender would
    not take them down). A capture is left alone: it renders in Blender itself, which is going away."""
    for job in running():
        if isinstance(job, ProcessJob):
            job.cancel()


@bpy.app.handlers.persistent
def _cancel_on_load(_dummy=None):
    # A new file drops the modal follower; the jobs must not outlive it.
    cancel_jobs()
    _FOLLOWER["active"] = False


def _hook() -> None:
    """Stop the jobs on file load and at exit; hooked as soon as a job exists, whoever started it."""
    if not _HOOKED["atexit"]:
        atexit.register(_stop_children)
        _HOOKED["atexit"] = True
    if _cancel_on_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_cancel_on_load)


# -- the follower ------------------------------------------------------------------------------------
def follow(context) -> bool:
    """Start the follower unless one runs; False when there is no window to run it in (scripts and
    tests then call ``update()`` themselves, or wait)."""
    if context.window is None or bpy.app.background:
        return False
    if _FOLLOWER["active"] and time.monotonic() - _FOLLOWER["last_tick"] < STALE_FOLLOWER:
        return True
    _FOLLOWER["active"] = False
    return "RUNNING_MODAL" in bpy.ops.nerf.follow_jobs("INVOKE_DEFAULT")


def _report(op, job: Job) -> None:
    if job.state == "failed":
        print(f"NeRF Bridge: {job.message}", file=sys.stderr)  # the whole log tail, for the console
        op.report({"ERROR"}, job.message.splitlines()[0])
    elif job.state == "cancelled":
        op.report({job.cancel_report}, job.message)
    else:
        op.report({"INFO"}, job.message)
        for warning in job.warnings:
            op.report({"WARNING"}, warning)


class NERF_OT_follow_jobs(bpy.types.Operator):
    """Advance the NeRF background jobs (capture, training, rendering) a few times a second"""

    bl_idname = "nerf.follow_jobs"
    bl_label = "Follow NeRF Jobs"
    bl_options = {"INTERNAL"}

    _timer = None

    def invoke(self, context, event):
        if context.window is None:
            return {"CANCELLED"}
        self._timer = context.window_manager.event_timer_add(TICK, window=context.window)
        context.window_manager.modal_handler_add(self)
        _FOLLOWER["active"], _FOLLOWER["last_tick"] = True, time.monotonic()
        return {"RUNNING_MODAL"}

    def execute(self, context):  # without an event loop there is nothing to follow with
        return {"CANCELLED"}

    def modal(self, context, event):
        if event.type == "ESC":
            esc = [job for job in running() if job.esc_cancels]
            if not esc:
                return {"PASS_THROUGH"}
            for job in esc:
                job.cancel()
        elif event.type != "TIMER":
            return {"PASS_THROUGH"}
        now = time.monotonic()
        ended = []
        for job in [j for j in _JOBS.values() if not j.ended]:
            if job.state == "running":
                if now - job.last_update < job.interval:
                    continue
                try:
                    job.update()
                except Exception as exc:  # noqa: BLE001  (a bug or unreadable output must end the job)
                    # Left running, the job would block every later Render or Train click with "already
                    # running", with nothing to cancel. The traceback goes to the console for a report.
                    traceback.print_exc()
                    if isinstance(job, ProcessJob) and job.process is not None and not job.process.finished():
                        job.cancel()
                    job.fail(f"{job.kind.capitalize()} failed: {type(exc).__name__}: {exc}")
                job.last_update = time.monotonic()
            job.notify()
            if job.ended:
                ended.append(job)
        for job in ended:
            _report(self, job)
        live = running()
        text = next((t for t in (job.status_bar_text() for job in live) if t), None)
        if text or _FOLLOWER["status_text"]:
            status_bar(context, text)
            _FOLLOWER["status_text"] = text
        tag_redraw(context)
        _FOLLOWER["last_tick"] = time.monotonic()
        if live:
            return {"RUNNING_MODAL"} if any(job.keeps_timer_event for job in live) else {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        _FOLLOWER["active"] = False
        return {"CANCELLED"} if ended and ended[-1].state in ("failed", "cancelled") else {"FINISHED"}


classes = (NERF_OT_follow_jobs,)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    _hook()


def unregister():
    cancel_jobs()
    _JOBS.clear()
    _FOLLOWER.update(active=False, status_text=None)
    if _HOOKED["atexit"]:
        atexit.unregister(_stop_children)
        _HOOKED["atexit"] = False
    if _cancel_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_load)
    _unregister_classes()
