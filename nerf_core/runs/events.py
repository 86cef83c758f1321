"""Progress events: one JSON object per line, on stdout and in ``RUN/progress.jsonl``.

The event vocabulary is fixed by docs/CONTRACTS.md (``start``, ``step``, ``preview``, ``rollback``,
``checkpoint``, ``eval``, ``done``, ``error``). The Blender add-on reads these lines from the
training subprocess, so every line must be a complete JSON object flushed at once.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import IO, Iterable, Iterator, List, Optional

from nerf_core import contract
from nerf_core.utils.stdout import StdoutClosed, stdout_failure


def _ends_mid_line(path: Path) -> bool:
    """Whether the regular file ``path`` is non-empty and its last byte is not a newline."""
    try:
        if not path.is_file() or path.stat().st_size == 0:
            return False
        with open(path, "rb") as fh:
            fh.seek(-1, 2)
            return fh.read(1) != b"\n"
    except OSError:
        return False


class EventLog:
    """Writes events to stdout (optional) and to any number of append-only files."""

    def __init__(self, paths: Iterable[Path | str] = (), stdout: bool = True, stream: Optional[IO[str]] = None):
        self.stream = stream if stream is not None else (sys.stdout if stdout else None)
        self._files: List[IO[str]] = []
        seen = set()
        for p in paths:
            p = Path(p).absolute()
            key = p.resolve()
            if key in seen:
                continue
            seen.add(key)
            p.parent.mkdir(parents=True, exist_ok=True)
            # Open the path as given, not as resolved: /dev/stdout resolves to /proc/PID/fd/pipe:[N]
            # when stdout is a pipe, a name that cannot be opened.
            f = open(p, "a", encoding="utf-8")
            if _ends_mid_line(p):  # a log cut mid-line (a killed trainer): the next event starts a line
                f.write("\n")
            self._files.append(f)
        self.events: List[dict] = []  # kept for callers (tests, the trainer's summary)

    def emit(self, event: str, **fields) -> dict:
        """Write one event (a name of ``contract.EVENTS``: the readers know no other) to every stream."""
        if event not in contract.EVENTS:
            raise ValueError(f"event {event!r} is not one of contract.EVENTS {contract.EVENTS}: declare it there")
        record = {"event": event, "time": time.time(), **contract.json_safe(fields)}
        line = json.dumps(record, allow_nan=False)
        # The files first: a closed stdout stops the run, and this event must still reach the log.
        for f in list(self._files) + ([self.stream] if self.stream is not None else []):
            try:
                f.write(line + "\n")
                f.flush()
            except (OSError, StdoutClosed) as exc:
                if f is self.stream and f in (sys.stdout, sys.__stdout__):
                    self.stream = None  # never again: the failure below stops the run or names stdout
                    self.events.append(record)
                    raise (exc if isinstance(exc, StdoutClosed) else stdout_failure(exc)) from None
                if isinstance(exc, StdoutClosed):
                    raise
                if f is not self.stream:
                    self._drop(f)  # its buffer still holds the line: closing it later would fail again
                if exc.filename is None and getattr(f, "name", None):
                    # A failed write does not say which file: the trainer names this one, not RUN.
                    raise OSError(exc.errno, exc.strerror, str(f.name)) from None
                raise
        self.events.append(record)
        return record

    def _drop(self, f: IO[str]) -> None:
        self._files.remove(f)
        try:
            f.close()
        except OSError:
            pass  # the write that failed has been reported

    def close(self) -> None:
        for f in self._files:
            f.close()
        self._files = []

    def __enter__(self) -> "EventLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def parse_events(lines: Iterable[str]) -> Iterator[dict]:
    """Yield the event objects among ``lines`` (``contract.parse_event_line``), skipping anything else."""
    for line in lines:
        event = contract.parse_event_line(line)
        if event is not None:
            yield event


def read_events(path: Path | str) -> List[dict]:
    """All events in a ``progress.jsonl`` file (tolerates partial or foreign lines)."""
    with open(path, encoding="utf-8") as f:
        return list(parse_events(f))
