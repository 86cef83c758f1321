"""``python -m nerf_core train DATASET --out RUN``: its flags, and the run they start.

Each flag is a ``TrainConfig`` field declared with ``engine.config.flag``: its name, help and default
are written once, there. This module only turns each field's ``kind`` into an argparse type.
"""
from __future__ import annotations

import argparse
import dataclasses

from nerf_core.cli.options import (
    folder,
    nonneg_float,
    nonneg_int,
    parse_options,
    positive_float,
    positive_int,
    seconds_list,
)
from nerf_core.engine.config import TrainConfig, default_method
from nerf_core.engine.trainer import train
from nerf_core.errors import TrainError
from nerf_core.methods.registry import current_option_names, method_class

# A flag's ``kind`` (``engine.config.flag``) -> argparse keyword arguments.
_KINDS = {
    "str": {}, "path": {}, "int": {"type": int}, "positive_int": {"type": positive_int},
    "nonneg_int": {"type": nonneg_int}, "nonneg_float": {"type": nonneg_float},
    "positive_float": {"type": positive_float}, "folder": {"type": folder}, "seconds_list": {"type": seconds_list},
    "options": {"action": "append"}, "switch": {"action": "store_true"}, "switch_off": {"action": "store_false"},
}


def flag_fields() -> list:
    """The ``TrainConfig`` fields that are flags, with their ``flag`` metadata."""
    return [(f, f.metadata["flag"]) for f in dataclasses.fields(TrainConfig) if "flag" in f.metadata]


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    t = sub.add_parser("train", help="train a method on a dataset into a run folder", formatter_class=fmt,
                       description="Train a NeRF. JSON progress events go to stdout and RUN/progress.jsonl; "
                                   "a progress bar with ETA goes to stderr.")
    for f, spec in flag_fields():
        kind, choices = f.metadata["kind"], f.metadata["choices"]
        kwargs = dict(_KINDS[kind], help=spec["help"])
        if spec["metavar"] is not None:
            kwargs["metavar"] = spec["metavar"]
        if choices is not None:
            kwargs["choices"] = list(choices)
        name = spec["name"] or "--" + f.name.replace("_", "-")
        if not name.startswith("-"):  # a positional argument: the field's own name
            t.add_argument(f.name, **kwargs)
            continue
        if spec["required"]:
            kwargs["required"] = True
        elif f.default is not dataclasses.MISSING:
            kwargs["default"] = f.default
        elif kind == "options":
            kwargs["default"] = []  # --set KEY=VALUE items; parse_options makes the dict
        else:
            kwargs["default"] = f.default_factory()
        t.add_argument(name, dest=f.name, **kwargs)
    t.add_argument("--unbounded", "--contract", dest="unbounded", action="store_true",  # --contract: its old name
                   help="scene contraction (mip-NeRF 360 style): also model geometry beyond the scene box, such as "
                        "a ground plane running to the horizon (vmgrid; the same as --set unbounded=true). Without "
                        "it, a cut-out whose opaque pixels look past the box gets it anyway; --set unbounded=false "
                        "stops that")
    t.set_defaults(handler=run)


def config_from_args(a: argparse.Namespace) -> TrainConfig:
    """The ``TrainConfig`` the parsed flags ask for."""
    values = {f.name: getattr(a, f.name) for f, _ in flag_fields()}
    values["options"] = _options(a)
    return TrainConfig(**values)


def run(a) -> int:
    train(config_from_args(a))
    return 0


def _options(a) -> dict:
    """``--set`` options (old option names mapped to today's), with ``--unbounded`` as ``unbounded=true``;
    the two flags must not disagree."""
    try:
        cls = method_class(a.method or default_method())  # an unknown method: ``TrainConfig.check`` says so
        known = (cls.Options.declared() or None) if cls is not None else None
        options = current_option_names(parse_options(a.options), known)
    except ValueError as exc:
        raise TrainError(f"--set: {exc}") from None
    if a.unbounded:
        if options.get("unbounded", True) is not True:
            raise TrainError(f"--unbounded and --set unbounded={options['unbounded']} disagree; give one of them")
        options["unbounded"] = True
    return options
