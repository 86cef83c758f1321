"""Property-based tests (hypothesis) of round five's rules 3 and 4: every generated set of method
options is either refused by name (``OptionError`` naming an option that was given) or within every
declared bound and cross-field rule; every generated RUN/config.json is either refused naming the file
or read into a record whose typed fields are what ``RECORD_FIELDS`` declares.

The "ci" profile of test_fuzz.py (derandomised, a small budget); ``HYPOTHESIS_PROFILE=long`` hunts longer.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerf_core.contract.numbers import is_number, is_whole
from nerf_core.errors import RunError
from nerf_core.methods.environment_options import EnvironmentOptions
from nerf_core.methods.nerf_options import NeRFOptions
from nerf_core.methods.options import OptionError
from nerf_core.methods.vmgrid_options import VMGridOptions
from nerf_core.runs.record import RECORD_FIELDS, read_run_record

settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.register_profile("long", max_examples=3000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

OPTION_CLASSES = (VMGridOptions, NeRFOptions, EnvironmentOptions)
ODD = st.one_of(st.none(), st.booleans(), st.text(max_size=6), st.integers(-2 ** 70, 2 ** 70),
                st.floats(), st.sampled_from([1e-300, 1e300, 2 ** 64, -0.0, 0.5, 1, 2]))


def _near_bounds(f: dataclasses.Field):
    """Values of field ``f`` around its bounds (just inside and outside them), numpy's numbers among them,
    and anything else JSON can hold."""
    low, high = f.metadata.get("low"), f.metadata.get("high")
    edges = [v for b in (low, high) if b is not None for v in (b, b * (1 - 1e-9), b * (1 + 1e-9), b - 1, b + 1)]
    edges = [v for v in edges if abs(v) < 2 ** 62] + [b for b in (low, high) if b is not None]
    inside = st.floats(float(low) if low is not None else -1e6, float(high) if high is not None else 1e6)
    number = st.one_of(st.sampled_from(edges or [0]), inside, inside.map(round), st.integers(-10, 5000))
    return st.one_of(number, number.map(np.float32), number.map(lambda v: np.int64(int(v)) if abs(v) < 2 ** 62 else v),
                     st.lists(number, max_size=5), st.sampled_from(list(f.metadata.get("choices") or ["x"])), ODD)


@st.composite
def option_sets(draw):
    cls = draw(st.sampled_from(OPTION_CLASSES))
    fields = cls.declared()
    names = draw(st.lists(st.sampled_from(sorted(fields)), max_size=4, unique=True))
    values = {n: draw(_near_bounds(fields[n])) for n in names}
    if draw(st.booleans()):
        values[draw(st.sampled_from(["bogus", "resolution", "contract"]))] = 1
    return cls, values


def _within(value, f: dataclasses.Field) -> bool:
    m = f.metadata
    if m.get("choices") is not None:
        return any(value is c or (type(value) is type(c) and value == c) for c in m["choices"])
    entries = value if isinstance(value, list) else [value]
    for v in entries:
        if isinstance(v, bool):
            continue
        if not is_number(v):
            return False
        low, high = m.get("low"), m.get("high")
        if low is not None and (v < low or (m.get("open_low") and v == low)):
            return False
        if high is not None and (v > high or (m.get("open_high") and v == high)):
            return False
    return True


@given(option_sets())
def test_options_are_refused_by_name_or_within_every_bound(case):
    cls, values = case
    try:
        opts = cls.parse("m", values)
    except OptionError as exc:
        assert exc.option in values or exc.option in ("res_init", "upsample_at", "skip", "environment"), exc
        assert "\n" not in str(exc) and str(exc).startswith("m: ")
        return
    out = opts.to_dict()
    json.dumps(out)  # numpy's numbers came back as Python's: a checkpoint can hold them
    for name, f in cls.declared().items():
        assert _within(out[name], f), (name, out[name])
        if isinstance(f.default, int) and not isinstance(f.default, bool) and f.metadata.get("choices") is None:
            assert is_whole(out[name]) and type(out[name]) is int
    if cls is VMGridOptions:
        assert out["res_init"] <= out["res_final"]
        assert all(a < b for a, b in zip(out["upsample_at"], out["upsample_at"][1:]))
    if cls is NeRFOptions:
        assert out["skip"] <= out["depth"]
    if cls is EnvironmentOptions:
        assert out["width"] % 2 == 0


GOOD = {"dataset": "/data/ds", "dataset_hash": "ab" * 32, "method": "vmgrid", "downscale": 1,
        "eval_background": [1.0, 1.0, 1.0], "near": 0.5, "far": 6.0, "aabb": [[-1, -1, -1], [1, 1, 1]]}
FIELD_VALUES = st.one_of(ODD, st.lists(ODD, max_size=4), st.lists(st.lists(st.floats(-2, 2), min_size=3, max_size=3),
                                                                  min_size=2, max_size=2))


@given(st.dictionaries(st.sampled_from(sorted(RECORD_FIELDS)), FIELD_VALUES, max_size=3), st.booleans())
def test_a_run_record_is_refused_naming_the_file_or_typed_as_declared(changes, twice):
    config = {**GOOD, **changes}
    text = json.dumps(config, allow_nan=True)
    if twice and changes:  # a key written twice: once with the good value, once with the drawn one
        key = sorted(changes)[0]
        text = "{" + json.dumps(key) + ": " + json.dumps(GOOD[key]) + ", " + text[1:]
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp)
        (run / "config.json").write_text(text, encoding="utf-8")
        try:
            record = read_run_record(run)
        except RunError as exc:
            assert str(exc).startswith(str(run / "config.json")) and "\n" not in str(exc), exc
            return
    assert not twice or not changes or changes[sorted(changes)[0]] == GOOD[sorted(changes)[0]]
    assert record.dataset_hash is None or isinstance(record.dataset_hash, str)
    assert isinstance(record.method, str) and record.downscale >= 1
    for v in (record.near, record.far):
        assert v is None or (is_number(v) and 0 <= v <= 1e6)
    if record.near is not None and record.far is not None:
        assert record.far > record.near
    assert all(0 <= c <= 1 for c in record.eval_background)
    assert record.aabb is None or all(lo < hi and math.isfinite(lo) for lo, hi in zip(*record.aabb))
