"""The JSON-line progress parser (addon/bridge/progress.py) fed the way a pipe delivers output."""
from __future__ import annotations

import json

from addon.bridge.progress import ProgressParser

STREAM = [
    {"event": "start", "time": 1.0, "run": "/r", "method": "nerf", "max_steps": 200, "max_seconds": None,
     "device": "cpu", "n_params": 1234},
    {"event": "step", "time": 2.0, "step": 50, "loss": 0.05, "psnr": 13.0, "lr": 0.01, "elapsed": 5.0,
     "eta": 15.0, "samples_per_s": 1000.0},
    {"event": "preview", "time": 2.5, "step": 50, "path": "/r/previews/step_0000050.png"},
    {"event": "rollback", "time": 3.0, "step": 40, "reason": "loss is NaN", "lr": 0.005},
    {"event": "step", "time": 4.0, "step": 100, "loss": 0.02, "psnr": 17.0, "lr": 0.005, "elapsed": 10.0,
     "eta": None, "samples_per_s": 1000.0},
    {"event": "shiny_new_event", "time": 4.5, "whatever": [1, 2]},
    {"event": "checkpoint", "time": 5.0, "step": 100, "path": "/r/checkpoints/latest.pt"},
    {"event": "done", "time": 6.0, "step": 200, "elapsed": 20.0, "checkpoint": "/r/checkpoints/latest.pt",
     "metrics": {"psnr": 21.5, "ssim": 0.8}},
]


def _text() -> str:
    lines = []
    for i, ev in enumerate(STREAM):
        lines.append(json.dumps(ev))
        if i == 1:
            lines.append("UserWarning: some library warning {not json")
            lines.append("")
            lines.append("[1, 2, 3]")  # JSON, but not an event object
    return "\n".join(lines) + "\n"


def test_byte_by_byte_feed_gives_the_same_state_as_one_chunk():
    whole = ProgressParser()
    events_whole = whole.feed(_text())
    split = ProgressParser()
    events_split = []
    data = _text().encode("utf-8")
    for i in range(len(data)):  # worst case: every line arrives in 1-byte pieces
        events_split += split.feed(data[i : i + 1])
    assert [e["event"] for e in events_split] == [e["event"] for e in events_whole]
    assert len(events_whole) == len(STREAM)
    for p in (whole, split):
        assert (p.method, p.device, p.max_steps, p.n_params) == ("nerf", "cpu", 200, 1234)
        assert p.step == 200 and p.done and p.error is None
        assert p.loss == 0.02 and p.psnr == 17.0 and p.elapsed == 20.0 and p.eta == 0.0
        assert p.preview_path == "/r/previews/step_0000050.png"
        assert p.checkpoint_path == "/r/checkpoints/latest.pt"
        assert [r["reason"] for r in p.rollbacks] == ["loss is NaN"]
        assert p.metrics == {"psnr": 21.5, "ssim": 0.8}
        assert p.unknown_events == 1
        assert "UserWarning: some library warning {not json" in p.log_tail
        assert p.fraction() == 1.0


def test_partial_line_waits_for_its_end_and_null_eta_clears_estimate():
    p = ProgressParser()
    p.feed(json.dumps(STREAM[0]) + "\n")
    first, second = json.dumps(STREAM[1])[:30], json.dumps(STREAM[1])[30:]
    assert p.feed(first) == [] and p.step is None
    assert [e["step"] for e in p.feed(second + "\n")] == [50]
    assert p.eta == 15.0 and p.fraction() == 0.25
    p.feed(json.dumps(STREAM[4]) + "\n")
    assert p.eta is None and p.step == 100 and p.fraction() == 0.5


def test_split_multibyte_utf8_and_carriage_returns():
    p = ProgressParser()
    data = "progress ▕██▏ 50%\rprogress ▕████▏ 100%\n".encode("utf-8")
    cut = data.index("█".encode("utf-8")) + 1  # in the middle of a 3-byte character
    p.feed(data[:cut])
    p.feed(data[cut:])
    assert list(p.log_tail) == ["progress ▕██▏ 50%", "progress ▕████▏ 100%"]


def test_error_event_truncated_json_and_unterminated_last_line():
    p = ProgressParser()
    p.feed('{"event": "step", "step": 3, "loss": 0.1, "psnr"\n')  # cut-off JSON: a log line
    assert p.step is None and p.log_tail[-1].startswith('{"event": "step"')
    p.feed('{"event": "error", "time": 1, "message": "dataset train/r_3.png is missing"}')
    assert p.error is None  # no newline yet
    events = p.finish()
    assert [e["event"] for e in events] == ["error"]
    assert p.error == "dataset train/r_3.png is missing" and not p.done


def test_log_tail_keeps_only_the_last_lines():
    p = ProgressParser(tail_lines=30)
    p.feed("".join(f"line {i}\n" for i in range(100)))
    assert len(p.log_tail) == 30 and p.log_tail[0] == "line 70" and p.tail_text(2) == "line 98\nline 99"


def test_start_event_background_and_note_events_are_kept():
    p = ProgressParser()
    p.feed(json.dumps({"event": "start", "time": 1.0, "method": "vmgrid", "background": "environment",
                       "background_reason": "the images have no alpha channel (RGB)"}) + "\n")
    p.feed(json.dumps({"event": "note", "time": 1.5,
                       "message": "environment: 58 % of the train rays miss the box"}) + "\n")
    assert p.background == "environment"
    assert "alpha" in p.background_reason
    assert p.notes == ["environment: 58 % of the train rays miss the box"]
    assert p.unknown_events == 0


def _step(step, elapsed, **extra):
    return json.dumps({"event": "step", "time": 0.0, "step": step, "loss": 0.1, "psnr": 10.0, "lr": 0.01,
                       "elapsed": elapsed, "eta": None, "samples_per_s": 1.0, **extra}) + "\n"


def test_fraction_prefers_the_trainers_frac():
    p = ProgressParser()
    p.feed(json.dumps({"event": "start", "time": 0.0, "max_steps": 100, "max_seconds": 40.0}) + "\n")
    # The trainer knows its budget best (a resumed run, a budget it changed): 0.3, not 50/100 or 10/40.
    p.feed(_step(50, 10.0, frac=0.3))
    assert p.frac == 0.3 and p.fraction() == 0.3
    p.feed(_step(60, 12.0, frac=1.7))  # out of range: clamped, like the budget rule
    assert p.fraction() == 1.0
    p.feed(_step(70, 30.0, frac=None))  # no usable frac: the budget rule, whichever budget is further
    assert p.frac is None and p.fraction() == 30.0 / 40.0
    p.feed(_step(80, 31.0, frac="half"))
    assert p.fraction() == 0.8


def test_fraction_of_a_trainer_without_frac_uses_the_budgets():
    p = ProgressParser()
    p.feed(json.dumps({"event": "start", "time": 0.0, "max_steps": 200, "max_seconds": None}) + "\n")
    assert p.fraction() is None  # no step yet
    p.feed(_step(50, 5.0))
    assert p.frac is None and p.fraction() == 0.25
    p.feed(json.dumps({"event": "done", "time": 1.0, "step": 60, "elapsed": 6.0}) + "\n")
    assert p.fraction() == 1.0  # stopped early, but done is done


def test_non_finite_counts_are_ignored_not_a_crash():
    # Python's json reads "Infinity"/"NaN"; a foreign writer may send them. int(inf) would raise inside
    # Blender's timer and stop the panel updating.
    p = ProgressParser()
    p.feed('{"event": "start", "max_steps": Infinity}\n{"event": "step", "step": 5, "loss": 0.1}\n')
    p.feed('{"event": "step", "step": NaN, "loss": 0.2}\n{"event": "step", "step": Infinity}\n')
    assert p.max_steps is None
    assert p.step == 5 and p.loss == 0.2
