"""A dependency-free terminal progress bar with an ETA, for capture, training, rendering and benchmarks.

Imports only the standard library, so scripts running inside Blender's Python can use it too.

    bar = ProgressBar(total=120, label="capture")
    for i in range(120):
        ...
        bar.update(1, info="train/r_7")
    bar.close()

On a terminal it redraws one line; when stderr is not a terminal (CI logs, pipes) it prints a plain
line at most every ``log_every`` seconds, so logs stay readable.
"""
from __future__ import annotations

import sys
import time
from typing import Optional, TextIO


def format_seconds(seconds: Optional[float]) -> str:
    """``75.2`` -> ``'1:15'``; ``None`` -> ``'?'``."""
    if seconds is None or seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class ProgressBar:
    """Progress over ``total`` units (or open-ended when ``total`` is None)."""

    def __init__(
        self,
        total: Optional[float],
        label: str = "",
        stream: Optional[TextIO] = None,
        width: int = 28,
        log_every: float = 5.0,
        enabled: bool = True,
    ):
        self.total = total
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.width = width
        self.log_every = log_every
        self.enabled = enabled
        self.done = 0.0
        self.info = ""
        self.start = time.monotonic()
        self._last_draw = 0.0
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def eta(self) -> Optional[float]:
        """Seconds left, extrapolated from the mean rate so far; None until something is done."""
        if not self.total or self.done <= 0:
            return None
        elapsed = time.monotonic() - self.start
        return max(0.0, elapsed * (self.total - self.done) / self.done)

    def set(self, done: float, info: str = "") -> None:
        self.done = done
        if info:
            self.info = info
        self._draw()

    def update(self, n: float = 1, info: str = "") -> None:
        self.set(self.done + n, info)

    def line(self) -> str:
        elapsed = time.monotonic() - self.start
        if self.total:
            frac = min(1.0, self.done / self.total)
            filled = int(round(frac * self.width))
            bar = "#" * filled + "-" * (self.width - filled)
            # Whole units for long bars (seconds of work, frames); fractions only where they say something.
            count = f"{self.done:.0f}/{self.total:.0f}" if self.total >= 20 else f"{self.done:g}/{self.total:g}"
            head = f"{self.label} [{bar}] {100 * frac:5.1f}% {count}"
            tail = f"elapsed {format_seconds(elapsed)} eta {format_seconds(self.eta())}"
        else:
            head = f"{self.label} {self.done:g}"
            tail = f"elapsed {format_seconds(elapsed)}"
        return f"{head} {tail} {self.info}".rstrip()

    def _draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self._tty:
            if force or now - self._last_draw > 0.1:
                self.stream.write("\r\033[K" + self.line())
                self.stream.flush()
                self._last_draw = now
        elif force or now - self._last_draw >= self.log_every:
            self.stream.write(self.line() + "\n")
            self.stream.flush()
            self._last_draw = now

    def close(self, info: str = "") -> None:
        if info:
            self.info = info
        self._draw(force=True)
        if self.enabled and self._tty:
            self.stream.write("\n")
            self.stream.flush()

    def __enter__(self) -> "ProgressBar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
