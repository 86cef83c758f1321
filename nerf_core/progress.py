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

from . import contract


class EventLog:
    """Writes events to stdout (optional) and to any number of append-only files."""

    def __init__(self, paths: Iterable[Path | str] = (), stdout: bool = True, stream: Optional[IO[str]] = None):
        self.stream = stream if stream is not None else (sys.stdout if stdout else None)
        self._files: List[IO[str]] = []
        seen = set()
        for p in paths:
            p = Path(p).resolve()
            if p in seen:
                continue
            seen.add(p)
            p.parent.mkdir(parents=True, exist_ok=True)
            self._files.append(open(p, "a", encoding="utf-8"))
        self.events: List[dict] = []  # kept for callers (tests, the trainer's summary)

    def emit(self, event: str, **fields) -> dict:
        record = {"event": event, "time": time.time(), **contract.json_safe(fields)}
        line = json.dumps(record, allow_nan=False)
        for f in ([self.stream] if self.stream is not None else []) + self._files:
            f.write(line + "\n")
            f.flush()
        self.events.append(record)
        return record

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
