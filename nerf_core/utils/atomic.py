"""Atomic file writes: the one home of write-to-a-temporary-file-then-rename.

A reader (another process, a crash, a full disk) never sees a half-written file: the content goes
to a temporary file beside the target, which replaces the target only once it is complete. On
failure the temporary file is removed and the target keeps its previous content.

    with atomic_path(out / "renders.json") as tmp:
        tmp.write_text(text)
    write_json_atomic(run / "config.json", config)
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any, Iterator, Optional


def hidden_temp(path: Path) -> Path:
    """``DIR/.NAME.tmp``: the default temporary name, hidden from a folder listing."""
    return path.with_name(f".{path.name}.tmp")


@contextlib.contextmanager
def atomic_path(path: Path | str, tmp: Optional[Path] = None) -> Iterator[Path]:
    """Yield a temporary path to write; on a clean exit it replaces ``path`` (``os.replace``).

    Args:
        path: the file to write.
        tmp: the temporary file (default ``hidden_temp(path)``); it must be on the same file system.
    Raises:
        whatever the body raised, after removing the temporary file.
    """
    path = Path(path)
    tmp = hidden_temp(path) if tmp is None else Path(tmp)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text_atomic(path: Path | str, text: str, tmp: Optional[Path] = None) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path, tmp) as t:
        t.write_text(text, encoding="utf-8")


def write_json_atomic(path: Path | str, data: Any, **dumps_kwargs) -> None:
    """Write ``data`` as indented JSON to ``path`` atomically; ``dumps_kwargs`` go to ``json.dumps``."""
    write_text_atomic(path, json.dumps(data, indent=2, **dumps_kwargs))
