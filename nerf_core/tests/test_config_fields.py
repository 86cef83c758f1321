"""Each ``TrainConfig`` field declares its kind once (``engine.config.flag``/``setting``); the Python
API's checks (``check_field_types``) and the CLI's parser both follow it."""
from __future__ import annotations

import dataclasses

import pytest

from nerf_core.cli.train import _KINDS
from nerf_core.engine.config import FIELD_KINDS, TrainConfig, check_field_types
from nerf_core.errors import TrainError

FIELDS = dataclasses.fields(TrainConfig)


def test_every_field_declares_a_kind_the_checks_and_the_parser_know():
    assert all(f.metadata.get("kind") in FIELD_KINDS for f in FIELDS), [f.name for f in FIELDS]
    flags = [f for f in FIELDS if "flag" in f.metadata]
    assert all(f.metadata["kind"] in _KINDS for f in flags)  # the parser turns each flag's text into its kind


@pytest.mark.parametrize("name", [f.name for f in FIELDS])
def test_a_value_of_no_kind_is_refused_naming_the_field(name):
    cfg = dataclasses.replace(TrainConfig(dataset="ds", out="run"), **{name: object()})
    with pytest.raises(TrainError, match=rf"^TrainConfig\.{name}\b.* must be .*got <object"):
        check_field_types(cfg)


@pytest.mark.parametrize("name, value, words", [
    ("keep_checkpoints", -1, r"keep_checkpoints must be an integer >= 0"),  # a setting: no flag named
    ("log_every", True, r"log_every \(--log-every\) must be an integer >= 1"),  # a bool is no count
    ("show_bar", 0, r"show_bar \(--no-bar\) must be True or False"),
    ("size", "big", r"size \(--size\) must be None or one of 'auto'"),
    ("background", "grey", r"background \(--background\) must be one of 'auto', "),
    ("eval_seconds", float("inf"), r"eval_seconds must be a finite number of seconds >= 0"),
    ("options", {1: 2}, r"options \(--set\) must be a dict of option name"),
])
def test_the_words_come_from_the_kind(name, value, words):
    cfg = dataclasses.replace(TrainConfig(dataset="ds", out="run"), **{name: value})
    with pytest.raises(TrainError, match=words):
        check_field_types(cfg)


def test_none_passes_only_where_the_field_is_optional():
    check_field_types(TrainConfig(dataset="ds", out="run", max_steps=None, lr=None, progress=None))
    with pytest.raises(TrainError, match="log_every"):
        check_field_types(TrainConfig(dataset="ds", out="run", log_every=None))
