"""Incremental parser for the trainer's JSON-line progress stream (docs/CONTRACTS.md, "Progress events").

The trainer's stdout arrives in arbitrary chunks from a reader thread: a chunk may end mid-line or
even mid-UTF-8 character, and libraries print warnings that are not JSON. ``ProgressParser.feed``
accepts bytes or str, keeps the unfinished tail for the next call, turns complete JSON lines into
state (latest step, loss, PSNR, ETA, preview...) and keeps every other line as a log line, so a
crash can be reported with the end of the log. What counts as an event line, and how the budget
fraction is computed, are ``nerf_core.contract``'s rules (loaded torch-free by ``.core_contract``).
Imports only the standard library and that module (no bpy, no torch).
"""
from __future__ import annotations

import codecs
import math
from collections import deque
from typing import Any, Deque, Dict, List, Optional, Union

from .core_contract import contract

LOG_TAIL_LINES = 30


def _number(value: Any) -> Optional[float]:
    """``value`` as a finite-or-inf float, None when it is missing or not a number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


_COUNTS = ("step", "max_steps", "n_params")  # fields that are whole numbers (JSON may write 12.0)


def _field_number(ev: Dict[str, Any], name: str) -> Optional[Union[int, float]]:
    """``ev[name]`` as a number (an int for ``_COUNTS``), None when missing or not a number."""
    value = _number(ev.get(name))
    if name in _COUNTS:  # a count of inf/NaN (JSON "Infinity" from a foreign writer) is no count
        return int(value) if value is not None and math.isfinite(value) else None
    return value


class ProgressParser:
    """State of one training run, built from its progress stream.

    Attributes (None until an event says otherwise):
        method, device, run (str), max_steps, n_params (int), max_seconds: from the ``start`` event.
        background, background_reason: what stands behind the scene (``environment``: a learned
            world for opaque captures; ``random``: cut-outs on a transparent film) and why.
        notes: messages of ``note`` events (e.g. how the learned world was fitted).
        step (int), loss, psnr, lr, elapsed, eta, samples_per_s (float): from the latest ``step`` event.
        frac: the training-budget fraction in [0, 1] the latest ``step`` event reported (trainers
            before the ``frac`` field: None, and ``fraction()`` computes it from the budgets).
        preview_path: absolute path of the latest preview PNG.
        checkpoint_path: the latest checkpoint written.
        rollbacks: list of ``rollback`` events (NaN/divergence recoveries), oldest first.
        evals: list of ``eval`` events.
        done: True after the ``done`` event; ``metrics`` then holds its metrics dict.
        error: the message of an ``error`` event.
        unknown_events: count of JSON objects whose ``event`` this parser does not know.
        last_event: the latest event object.
        log_tail: the last ``LOG_TAIL_LINES`` raw lines (JSON or not), for crash reports.
    """

    KNOWN = contract.EVENTS
    # The attributes that hold the latest value an event gave (what each holds: the docstring above);
    # each is None until an event sets it.
    LATEST = ("method", "device", "run", "max_steps", "max_seconds", "n_params", "background",
              "background_reason", "step", "loss", "psnr", "lr", "elapsed", "eta", "samples_per_s", "frac",
              "preview_path", "checkpoint_path", "error", "last_event")

    def __init__(self, tail_lines: int = LOG_TAIL_LINES):
        self._decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
        self._pending = ""
        self.log_tail: Deque[str] = deque(maxlen=tail_lines)
        self.n_lines = 0
        for name in self.LATEST:
            setattr(self, name, None)
        self.notes: List[str] = []
        self.rollbacks: List[Dict[str, Any]] = []
        self.evals: List[Dict[str, Any]] = []
        self.done = False
        self.metrics: Dict[str, Any] = {}
        self.unknown_events = 0

    # -- feeding -----------------------------------------------------------------------------
    def feed(self, chunk: Union[bytes, bytearray, str]) -> List[Dict[str, Any]]:
        """Consume a chunk; return the JSON events completed by it (in order)."""
        text = self._decoder.decode(bytes(chunk)) if isinstance(chunk, (bytes, bytearray)) else chunk
        self._pending += text
        events = []
        # \r also ends a line: progress bars from libraries redraw with carriage returns.
        normalised = self._pending.replace("\r\n", "\n").replace("\r", "\n")
        *complete, self._pending = normalised.split("\n")
        for line in complete:
            event = self.feed_line(line)
            if event is not None:
                events.append(event)
        return events

    def finish(self) -> List[Dict[str, Any]]:
        """End of stream: parse a last line that had no newline."""
        rest = self._pending + self._decoder.decode(b"", final=True)
        self._pending = ""
        event = self.feed_line(rest) if rest.strip() else None
        return [event] if event is not None else []

    def feed_line(self, line: str) -> Optional[Dict[str, Any]]:
        """Parse one complete line; return it as an event dict when it is a JSON event."""
        line = line.strip()
        if not line:
            return None
        self.n_lines += 1
        self.log_tail.append(line)
        obj = contract.parse_event_line(line)
        if obj is None:
            return None
        self.apply(obj)
        self.last_event = obj
        return obj

    # -- state -------------------------------------------------------------------------------
    def apply(self, ev: Dict[str, Any]) -> None:
        """Update the state from one event object (also used for JSON events that arrive on stderr)."""
        kind = ev["event"]
        if kind == "start":
            self._take_strings(ev, ("method", "device", "run", "background", "background_reason"))
            # The budgets are the run's: a start event without them means none (not "as before").
            for name in ("max_steps", "max_seconds", "n_params"):
                setattr(self, name, _field_number(ev, name))
        elif kind == "note":
            if isinstance(ev.get("message"), str):
                self.notes.append(ev["message"])
        elif kind == "step":
            self._take_numbers(ev, ("step", "loss", "psnr", "lr", "elapsed", "samples_per_s"))
            # eta may legitimately be null ("unknown"), which must clear a stale estimate.
            self.eta = _number(ev.get("eta"))
            frac = _number(ev.get("frac"))
            self.frac = min(1.0, max(0.0, frac)) if frac is not None and frac == frac else None
        elif kind == "preview":
            if isinstance(ev.get("path"), str):
                self.preview_path = ev["path"]
        elif kind == "checkpoint":
            if isinstance(ev.get("path"), str):
                self.checkpoint_path = ev["path"]
        elif kind == "rollback":
            self.rollbacks.append(ev)
            self._take_numbers(ev, ("step", "lr"))
        elif kind == "eval":
            self.evals.append(ev)
        elif kind == "done":
            self.done = True
            self._take_numbers(ev, ("step", "elapsed"))
            self.eta = 0.0
            if isinstance(ev.get("checkpoint"), str):
                self.checkpoint_path = ev["checkpoint"]
            if isinstance(ev.get("metrics"), dict):
                self.metrics = dict(ev["metrics"])
        elif kind == "error":
            message = ev.get("message")
            self.error = message if isinstance(message, str) and message else "trainer reported an error"
        else:
            self.unknown_events += 1

    def _take_numbers(self, ev: Dict[str, Any], names) -> None:
        """Each field of ``names`` that ``ev`` carries as a number; a missing one keeps the last value."""
        for name in names:
            value = _field_number(ev, name)
            if value is not None:
                setattr(self, name, value)

    def _take_strings(self, ev: Dict[str, Any], names) -> None:
        for name in names:
            if isinstance(ev.get(name), str):
                setattr(self, name, ev[name])

    def fraction(self) -> Optional[float]:
        """Progress in [0, 1]: the latest step event's ``frac`` (the trainer knows its budget best),
        else, from trainers that do not send it, the step or time budget, whichever is further
        (``contract.budget_fraction``); None if unknown."""
        if self.done:
            return 1.0
        if self.frac is not None:
            return self.frac
        return contract.budget_fraction(self.step, self.elapsed, self.max_steps, self.max_seconds)

    def tail_text(self, n: int = LOG_TAIL_LINES) -> str:
        """The last ``n`` log lines joined, for error reports."""
        return "\n".join(list(self.log_tail)[-n:])
