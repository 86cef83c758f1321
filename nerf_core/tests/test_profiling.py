"""Stage marks (``nerf_core.utils.profiling``): exclusive time per stage, and nothing recorded when inactive."""
from __future__ import annotations

import threading

import pytest

from nerf_core.utils import profiling


def test_stage_recorder_charges_nested_time_to_the_inner_stage():
    clock = {"t": 0.0}
    rec = profiling.StageRecorder(clock=lambda: clock["t"])

    def field(pts):
        with profiling.stage("field"):
            clock["t"] += 2.0  # 2 s inside the field
            return pts

    def sampling(x):
        with profiling.stage("sampling"):
            clock["t"] += 1.0  # 1 s of sampling's own work ...
            field(x)  # ... plus a nested field call
            clock["t"] += 0.5
            return x

    with rec:
        assert sampling(3) == 3
        field(1)
    assert rec.totals == {"field": 4.0, "sampling": 1.5}
    assert rec.stack == []


def test_driver_stages_wrap_the_library_marks_and_sync_at_every_boundary():
    clock = {"t": 0.0}
    syncs = []
    rec = profiling.StageRecorder(sync=lambda: syncs.append(clock["t"]), clock=lambda: clock["t"])
    with rec:
        with rec.stage("other_forward"):
            clock["t"] += 0.25
            with profiling.stage("rendering"):
                clock["t"] += 1.0
        with rec.stage("backward"):
            clock["t"] += 3.0
    assert rec.totals == {"other_forward": 0.25, "rendering": 1.0, "backward": 3.0}
    assert syncs == [0.0, 0.25, 1.25, 1.25, 1.25, 4.25]  # before every clock read: 3 stages x (enter, exit)


def test_marks_are_free_and_unrecorded_without_an_active_recorder():
    rec = profiling.StageRecorder(clock=lambda: 1 / 0)  # any clock read would raise
    # One shared do-nothing object: an inactive mark allocates nothing.
    assert profiling.stage("sampling") is profiling.stage("field")
    with profiling.stage("sampling"):
        pass
    assert rec.totals == {}
    with rec:
        pass
    with profiling.stage("sampling"):  # after the recorder closed
        pass
    assert rec.totals == {}


def test_marks_from_other_threads_are_ignored_and_recorders_do_not_nest():
    clock = {"t": 0.0}
    rec = profiling.StageRecorder(clock=lambda: clock["t"])

    def worker():
        with profiling.stage("field"):
            clock["t"] += 5.0

    with rec:
        t = threading.Thread(target=worker)
        t.start()
        t.join()
        with pytest.raises(RuntimeError, match="already recording"):
            with profiling.StageRecorder():
                pass
        with profiling.stage("sampling"):
            clock["t"] += 1.0
    assert rec.totals == {"sampling": 1.0}
