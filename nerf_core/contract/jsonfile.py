"""Reading a transforms file's JSON: a key written twice with two values is refused, integers too long
for a float become inf (which every field check refuses by name), and every failure names the file.
"""
from __future__ import annotations

import json
from pathlib import Path

from .errors import DatasetError
from .paths import file_problem


class _DuplicateKey(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _no_conflicting_keys(pairs: list) -> dict:
    """``object_pairs_hook`` for transforms files: a key written twice with two values is refused.

    Python's json keeps the last value silently, so two ``frames`` arrays (a merge gone wrong) would
    train on half the views with nothing said. A key repeated with the same value is harmless.
    """
    out: dict = {}
    for key, value in pairs:
        if key in out and out[key] != value:
            raise _DuplicateKey(key)
        out[key] = value
    return out


# The most digits an integer may have and still fit a float64 (about 1.8e308); beyond, a number in
# a transforms file becomes inf, which every field's check refuses by name. Python's int() would
# instead raise, with no file or field named, past 4300 digits or when converted to float.
_FLOAT_DIGITS = 308


def _parse_int(text: str):
    return int(text) if len(text.lstrip("-")) <= _FLOAT_DIGITS else float(text)


def parse_json_file(path: Path | str):
    """The JSON value in ``path``; DatasetError naming the file when it cannot be read or parsed
    (missing, unreadable, not UTF-8, invalid, nested too deeply for the parser, or a key given
    twice with different values). A UTF-8 byte-order mark, which Windows editors write, is skipped."""
    path = Path(path)
    problem = file_problem(path)
    if problem:  # before open(): a named pipe would block the reader, /dev/zero fill the memory
        raise DatasetError(f"{path}: {problem}")
    try:
        with open(path, encoding="utf-8-sig") as f:
            return json.load(f, object_pairs_hook=_no_conflicting_keys, parse_int=_parse_int)
    except FileNotFoundError as exc:
        raise DatasetError(f"{path}: file not found") from exc
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a folder, not a JSON file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from exc
    except _DuplicateKey as exc:
        raise DatasetError(f"{path}: key {exc.key!r} appears twice in one object with different values; "
                           "JSON readers keep either one, so the file is ambiguous") from None
    except RecursionError:
        raise DatasetError(f"{path}: JSON nested too deeply to read (thousands of levels of [ or {{)") from None


def read_json(path: Path | str) -> dict:
    """A transforms file's top-level object (DatasetError naming the file when it cannot be read)."""
    path = Path(path)
    meta = parse_json_file(path)
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: expected a JSON object with 'frames'")
    return meta
