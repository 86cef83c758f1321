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
from collections import deque
from typing import Any, Deque, Dict, List, Optional, Union

from .core_contract import contract

LOG_TAIL_LINES = 30


def _number(value: Any) -> Optional[float]:
    """``value`` as a finite-or-inf float, None when it is missing or not a number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


class ProgressParser:
    """State of one training run, built from its progress stream.

    Attributes (None until an event says otherwise):
        method, device, max_steps, max_seconds, n_params: from the ``start`` event.
        background, background_reason: what stands behind the scene (``environment``: a learned
            world for opaque captures; ``random``: cut-outs on a transparent film) and why.
        notes: messages of ``note`` events (e.g. how the learned world was fitted).
        step, loss, psnr, lr, elapsed, eta, samples_per_s: from the latest ``step`` event.
        frac: the training-budget fraction in [0, 1] the latest ``step`` event reported (trainers
            before the ``frac`` field: None, and ``fraction()`` computes it from the budgets).
        preview_path: absolute path of the latest preview PNG.
        checkpoint_path: the latest checkpoint written.
        rollbacks: list of ``rollback`` events (NaN/divergence recoveries), oldest first.
        evals: list of ``eval`` events.
        done: True after the ``done`` event; ``metrics`` then holds its metrics dict.
        error: the message of an ``error`` event.
        unknown_events: count of JSON objects whose ``event`` this parser does not know.
        log_tail: the last ``LOG_TAIL_LINES`` raw lines (JSON or not), for crash reports.
    """

    KNOWN = contract.EVENTS

    def __init__(self, tail_lines: int = LOG_TAIL_LINES):
        self._decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
        self._pending = ""
        self.log_tail: Deque[str] = deque(maxlen=tail_lines)
        self.n_lines = 0
        self.method: Optional[str] = None
        self.device: Optional[str] = None
        self.run: Optional[str] = None
        self.max_steps: Optional[int] = None
        self.max_seconds: Optional[float] = None
        self.n_params: Optional[int] = None
        self.background: Optional[str] = None
        self.background_reason: Optional[str] = None
        self.notes: List[str] = []
        self.step: Optional[int] = None
        self.loss: Optional[float] = None
        self.psnr: Optional[float] = None
        self.lr: Optional[float] = None
        self.elapsed: Optional[float] = None
        self.eta: Optional[float] = None
        self.samples_per_s: Optional[float] = None
        self.frac: Optional[float] = None
        self.preview_path: Optional[str] = None
        self.checkpoint_path: Optional[str] = None
        self.rollbacks: List[Dict[str, Any]] = []
        self.evals: List[Dict[str, Any]] = []
        self.done = False
        self.metrics: Dict[str, Any] = {}
        self.error: Optional[str] = None
        self.unknown_events = 0
        self.last_event: Optional[Dict[str, Any]] = None

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
            self.method = ev.get("method") if isinstance(ev.get("method"), str) else self.method
            self.device = ev.get("device") if isinstance(ev.get("device"), str) else self.device
            self.run = ev.get("run") if isinstance(ev.get("run"), str) else self.run
            max_steps = _number(ev.get("max_steps"))
            self.max_steps = int(max_steps) if max_steps is not None else None
            self.max_seconds = _number(ev.get("max_seconds"))
            n_params = _number(ev.get("n_params"))
            self.n_params = int(n_params) if n_params is not None else None
            for name in ("background", "background_reason"):
                if isinstance(ev.get(name), str):
                    setattr(self, name, ev[name])
        elif kind == "note":
            if isinstance(ev.get("message"), str):
                self.notes.append(ev["message"])
        elif kind == "step":
            step = _number(ev.get("step"))
            if step is not None:
                self.step = int(step)
            for name in ("loss", "psnr", "lr", "elapsed", "samples_per_s"):
                value = _number(ev.get(name))
                if value is not None:
                    setattr(self, name, value)
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
            step = _number(ev.get("step"))
            if step is not None:
                self.step = int(step)
            lr = _number(ev.get("lr"))
            if lr is not None:
                self.lr = lr
        elif kind == "eval":
            self.evals.append(ev)
        elif kind == "done":
            self.done = True
            step = _number(ev.get("step"))
            if step is not None:
                self.step = int(step)
            elapsed = _number(ev.get("elapsed"))
            if elapsed is not None:
                self.elapsed = elapsed
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
