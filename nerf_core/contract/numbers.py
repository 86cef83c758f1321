"""What counts as a number and as a whole number, in one place, for every reader and checker.

A JSON file, a checkpoint, a ``--set`` value and a Python caller all hand over values whose kind must
be told apart the same way: ``True`` is an ``int`` to Python but never a count or a length here, NaN
and inf are floats but never a measurement, and numpy's scalars (``np.int64(32)``, ``np.float32(0.5)``)
are numbers like Python's (numpy registers them with ``numbers.Integral``/``numbers.Real``). The
modules that check values (``contract`` readers, ``utils.arguments``, ``methods.options``,
``engine.config``, ``runs.record``, ``runs.checkpoint_checks``) ask these; they do not spell the test
again (``nerf_core/tests/test_architecture.py`` refuses a new copy).
"""
from __future__ import annotations

import math
import numbers as _numbers


def is_bool(value) -> bool:
    """True for ``True``/``False`` and numpy's booleans (which are no ``bool`` subclass)."""
    return isinstance(value, bool) or type(value).__name__ == "bool_"


def is_whole(value) -> bool:
    """A whole number: a Python or numpy integer, not a bool (``1.0`` is not one: a JSON writer that
    writes a count as a float has a bug worth naming)."""
    return isinstance(value, _numbers.Integral) and not is_bool(value)


def is_real(value) -> bool:
    """A real number of any size (a Python or numpy int or float, not a bool), NaN and inf included."""
    return isinstance(value, _numbers.Real) and not is_bool(value)


def is_number(value) -> bool:
    """A finite real number (an int or float, Python's or numpy's), not a bool, NaN or inf."""
    if not is_real(value):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int too large for a float is no measurement either
        return False


def plain(value):
    """``value`` with numpy's scalars (at any depth of lists, tuples and dicts) as Python's own, so that
    JSON can hold it: a config built with ``np.int64(4)`` must not fail when config.json is written."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if is_bool(value):
        return bool(value)
    if is_whole(value):
        return int(value)
    if is_real(value) and not isinstance(value, float):
        return float(value)
    return value
