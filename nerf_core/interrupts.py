"""Stopping a long job cleanly: SIGTERM handled like Ctrl-C.

The add-on's Cancel and most job schedulers send SIGTERM; a trainer that treats it as
``KeyboardInterrupt`` saves a checkpoint on its way out, so the run can be resumed.
"""
from __future__ import annotations

import signal
import threading


def terminate_as_interrupt():
    """Treat SIGTERM (what the add-on's Cancel and most job schedulers send) like Ctrl-C, so the run
    stops with a checkpoint it can resume from. Returns a function restoring the previous handler."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "SIGTERM"):
        return lambda: None

    def handler(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    return lambda: signal.signal(signal.SIGTERM, previous)
