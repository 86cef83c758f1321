"""Stopping a long job cleanly: SIGTERM and SIGHUP handled like Ctrl-C.

The add-on's Cancel and most job schedulers send SIGTERM, a closed terminal or ssh connection
SIGHUP; a trainer that treats them as ``KeyboardInterrupt`` saves a checkpoint on its way out, so
the run can be resumed. (A SIGHUP left ignored by the parent, as ``nohup`` does, stays ignored.)
A file-size limit (``ulimit -f``) would kill the process with SIGXFSZ in the middle of a write;
ignored, the write fails with EFBIG instead and the trainer names the file and keeps the previous
checkpoint.
Under ``torchrun`` the ranks record the signal instead (``DeferredInterrupts``) and stop together.
"""
from __future__ import annotations

import signal
import threading


def honour_interrupts() -> None:
    """Make Ctrl-C (SIGINT) and SIGTERM reach this process even if its parent left them ignored or
    blocked (and SIGHUP if it was blocked): both are inherited across exec, and a parent such as
    Blender, a farm manager or a test runner may have either in force when it starts us. Without
    this, Cancel could only end the trainer with SIGKILL, after the add-on's grace period, and no
    checkpoint would be saved."""
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if hasattr(signal, "pthread_sigmask"):  # POSIX
        # SIGHUP too: a blocked hangup is no ``nohup`` (which ignores it, and an ignored SIGHUP stays
        # ignored: ``_stop_signals``); blocked, a closed terminal would leave the trainer running unseen
        wanted = {getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)}
        signal.pthread_sigmask(signal.SIG_UNBLOCK, wanted)


def _stop_signals() -> list:
    """The signals that stop a run with a checkpoint besides SIGINT: SIGTERM, and SIGHUP unless ignored."""
    names = ["SIGTERM"] + (["SIGHUP"] if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) != signal.SIG_IGN
                           else [])
    return [getattr(signal, n) for n in names if hasattr(signal, n)]


def terminate_as_interrupt():
    """Treat SIGTERM (what the add-on's Cancel and most job schedulers send) and SIGHUP (a closed
    terminal) like Ctrl-C, so the run stops with a checkpoint it can resume from, and ignore SIGXFSZ
    so that a file-size limit fails a write (EFBIG, named) instead of killing the process. Returns a
    function restoring the previous handlers."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def handler(signum, frame):
        raise KeyboardInterrupt(f"{signal.Signals(signum).name}")

    previous = {sig: signal.signal(sig, handler) for sig in _stop_signals()}
    if hasattr(signal, "SIGXFSZ"):
        previous[signal.SIGXFSZ] = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    def restore() -> None:
        for sig, old in previous.items():
            signal.signal(sig, old)

    return restore


class DeferredInterrupts:
    """SIGINT and SIGTERM recorded rather than raised, while the ranks of a ``torchrun`` job train.

    A rank that raised ``KeyboardInterrupt`` the moment the signal came would leave the others
    waiting in a collective, at another step. Recorded, the request travels in the next step's
    reduce (``nerf_core.engine.replicas``), and every rank stops after the same step, with rank 0 saving
    the checkpoint. ``torchrun`` forwards a Ctrl-C (SIGINT) and SIGTERM to every rank.

        with DeferredInterrupts(enabled) as stop:
            ... stop.requested() ...
    Leaving the block restores the previous handlers, then (``reraise``) raises ``KeyboardInterrupt``
    if a signal came after the last check and the block is not already leaving with an exception.
    With ``reraise=False`` the block simply shields what it runs (an interrupted run's checkpoint).
    """

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self, enabled: bool = True, reraise: bool = True):
        self.enabled = enabled and threading.current_thread() is threading.main_thread()
        self.reraise = reraise
        self.signal = None  # name of the first signal received
        self._checked = False
        self._previous = {}

    def requested(self) -> bool:
        """True once a signal came (checked by the step's reduce)."""
        self._checked = self.signal is not None
        return self._checked

    def __enter__(self) -> "DeferredInterrupts":
        if self.enabled:
            def handler(signum, frame):
                self.signal = self.signal or signal.Signals(signum).name

            for name in self.SIGNALS:
                if hasattr(signal, name) and signal.getsignal(getattr(signal, name)) != signal.SIG_IGN:
                    self._previous[name] = signal.signal(getattr(signal, name), handler)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        for name, previous in self._previous.items():
            signal.signal(getattr(signal, name), previous)
        self._previous = {}
        if self.reraise and exc_type is None and self.signal is not None and not self._checked:
            raise KeyboardInterrupt
