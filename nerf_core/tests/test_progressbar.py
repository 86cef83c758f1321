"""The terminal progress bar: line contents, ETA arithmetic and throttled non-terminal output."""
import io

import pytest

from nerf_core.utils import progressbar
from nerf_core.utils.progressbar import ProgressBar, format_seconds


def test_format_seconds():
    assert format_seconds(75.2) == "1:15"
    assert format_seconds(3725) == "1:02:05"
    assert format_seconds(None) == "?" and format_seconds(float("nan")) == "?"


def test_eta_and_line_from_a_fake_clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(progressbar.time, "monotonic", lambda: now[0])
    stream = io.StringIO()
    bar = ProgressBar(total=40, label="train", stream=stream, width=8, log_every=5.0)
    assert bar.eta() is None
    now[0] = 110.0
    bar.update(10, info="step 10")  # 10 units in 10 s -> 30 left -> 30 s
    assert bar.eta() == pytest.approx(30.0)
    line = bar.line()
    assert line.startswith("train [##------]  25.0% 10/40") and "eta 0:30" in line and line.endswith("step 10")
    now[0] = 111.0
    bar.update(1)  # within log_every of the last print: not written again
    assert stream.getvalue().count("\n") == 1
    bar.close()
    assert stream.getvalue().count("\n") == 2 and "11/40" in stream.getvalue().splitlines()[-1]


def test_open_ended_and_disabled():
    stream = io.StringIO()
    bar = ProgressBar(total=None, label="scan", stream=stream)
    bar.update(3)
    assert "scan 3" in bar.line() and "eta" not in bar.line()
    quiet = io.StringIO()
    with ProgressBar(total=5, stream=quiet, enabled=False) as b:
        b.update(5)
    assert quiet.getvalue() == ""


def test_long_bars_count_whole_units():
    bar = ProgressBar(total=750, label="benchmark", stream=io.StringIO())
    bar.set(241.179)
    assert "241/750" in bar.line()
    short = ProgressBar(total=4, stream=io.StringIO())
    short.set(2.5)
    assert "2.5/4" in short.line()
