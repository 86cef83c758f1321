"""Named stage marks in a training step, for the benchmark's step profile; free when nothing records.

Methods and library code mark where the stages of a step begin and end::

    from nerf_core.utils import profiling
    with profiling.stage("sampling"):
        t0, t1, ridx = sampling.occupied_samples(...)

Nothing is timed unless a ``StageRecorder`` is active (``with recorder:``): then each mark on the
thread that activated it adds its *exclusive* wall time to ``recorder.totals[name]`` (time spent in a
stage nested inside another is charged to the inner one, so the totals add up to the time covered).
Inactive, ``stage`` is one global read returning a shared do-nothing context manager, so the marks
can stay in the trainer's hot path. Stage names in use: ``sampling`` (ray marching, sample placement,
occupancy-grid updates), ``field`` (density/colour queries of the network or grid), ``rendering``
(volume-rendering compositing); ``benchmarks/bench/profiler.py`` adds ``other_forward``, ``backward``
and ``optimizer`` around the rest of its step.

Standard library only: the addon and the contract tests may import this without torch.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Optional

_active: Optional["StageRecorder"] = None  # the recorder being fed, or None (the usual case)
_activate_lock = threading.Lock()


class _NoStage:
    """The do-nothing context manager every mark returns while nothing records (one shared instance)."""

    __slots__ = ()

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc) -> bool:
        return False


_NO_STAGE = _NoStage()


def stage(name: str):
    """Context manager marking stage ``name``; timed only inside an active ``StageRecorder``'s thread."""
    rec = _active
    if rec is None or rec.thread != threading.get_ident():
        return _NO_STAGE
    return _Stage(rec, name)


class _Stage:
    __slots__ = ("rec", "name")

    def __init__(self, rec: "StageRecorder", name: str):
        self.rec, self.name = rec, name

    def __enter__(self) -> None:
        self.rec.enter(self.name)

    def __exit__(self, *exc) -> bool:
        self.rec.exit()
        return False


class StageRecorder:
    """Exclusive wall time per stage name: a stage nested in another is charged to the inner one.

    ``sync`` runs before every clock read (``torch.cuda.synchronize`` on a GPU, where kernels run
    asynchronously and the clock would otherwise measure only their launch). ``clock`` is injectable
    for tests. Use as ``with recorder:`` to receive the library's marks; ``recorder.stage(name)``
    marks a stage of the caller's own (the profiler's driver loop) in the same accounting.
    Single-threaded by design: marks from other threads are ignored, and only one recorder may be
    active at a time.
    """

    def __init__(self, sync: Optional[Callable[[], None]] = None, clock: Callable[[], float] = time.perf_counter):
        self.totals: dict[str, float] = {}
        self.stack: list[list] = []  # [name, start, time spent in nested stages]
        self.sync = sync or (lambda: None)
        self.clock = clock
        self.thread: Optional[int] = None

    def enter(self, name: str) -> None:
        self.sync()
        self.stack.append([name, self.clock(), 0.0])

    def exit(self) -> None:
        self.sync()
        name, start, nested = self.stack.pop()
        spent = self.clock() - start
        self.totals[name] = self.totals.get(name, 0.0) + spent - nested
        if self.stack:
            self.stack[-1][2] += spent

    def stage(self, name: str) -> _Stage:
        return _Stage(self, name)

    def reset(self) -> None:
        """Forget the totals (after warm-up steps); stages still open keep running."""
        self.totals.clear()

    def __enter__(self) -> "StageRecorder":
        global _active
        with _activate_lock:
            if _active is not None:
                raise RuntimeError("profiling: another StageRecorder is already recording")
            self.thread = threading.get_ident()
            _active = self
        return self

    def __exit__(self, *exc) -> bool:
        global _active
        with _activate_lock:
            _active = None
            self.thread = None
        return False
