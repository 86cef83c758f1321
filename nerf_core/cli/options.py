"""The value types and shared arguments of the command line's flags: each bad value is one line
that names the flag (argparse prints it with the usage), never a traceback.
"""
from __future__ import annotations

import argparse
import json
import math
from typing import Dict, List

from nerf_core.errors import TrainError
from nerf_core.render.memory import DEFAULT_CHUNK


def seconds_list(text: str) -> list[float]:
    try:
        parts = text.split(",")
        if any(not v.strip() for v in parts):
            raise ValueError("an empty entry")
        values = [float(v) for v in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated seconds like 60,120,300, got {text!r}") from None
    if any(not (math.isfinite(v) and v > 0) for v in values):
        raise argparse.ArgumentTypeError(f"times must be finite numbers of seconds > 0, got {text}")
    return sorted(values)


def checked_number(cast, noun: str, ok, rule: str):
    """An argparse ``type``: ``cast(text)`` that ``ok`` accepts; otherwise a one-line error saying why."""
    def parse(text: str):
        try:
            v = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if not ok(v):
            raise argparse.ArgumentTypeError(f"{rule}, got {text}")
        return v
    return parse


def folder(text: str) -> str:
    """An argparse ``type`` for output folders: an empty path would mean the current folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty; name a folder (an empty path would write into the current one)")
    return text


positive_float = checked_number(float, "a number", lambda v: v > 0, "must be positive")
nonneg_float = checked_number(float, "a number", lambda v: v >= 0, "must be >= 0")
positive_int = checked_number(int, "an integer", lambda v: v > 0, "must be positive")
nonneg_int = checked_number(int, "an integer", lambda v: v >= 0, "must be >= 0")


def add_model_args(p, split_help: str, downscale, chunk_help: str) -> None:
    """The arguments ``render`` and ``eval`` share: the run, which views, and how to run the model.
    ``downscale``: (argparse type, verb for its help)."""
    kind, verb, *rest = downscale
    p.add_argument("run", metavar="RUN", help="run folder written by `train`")
    p.add_argument("--split", default="test", help=split_help)
    if rest:  # no default: the run's own
        p.add_argument(
            "--downscale", type=kind, default=None, metavar="F", help=f"{verb} at 1/F resolution ({rest[0]})"
        )
    else:
        p.add_argument("--downscale", type=kind, default=kind("1"), metavar="F", help=f"{verb} at 1/F resolution")
    p.add_argument("--device", metavar="DEV", help="torch device; default: cuda if available else cpu")
    p.add_argument("--chunk", type=positive_int, default=DEFAULT_CHUNK, help=chunk_help)
    p.add_argument("--checkpoint", metavar="FILE", help="checkpoint to use instead of RUN/checkpoints/latest.pt")
    p.add_argument("--pixel-filter", choices=["auto", "none"], default="auto",
                   help="auto: render each pixel as the capture's film did, the mean of several rays drawn from its "
                        "pixel filter where the image has an edge (the dataset's `pixel_filter`; Blender's 1.5 px "
                        "Blackman-Harris when it records none); none: one ray through each pixel centre")
    p.add_argument("--no-bar", action="store_true", help="no progress bar on stderr")


def parse_option_value(value: str):
    """One ``--set`` value: an int, a float, true/false, JSON (lists, objects, null), else the string."""
    for cast in (int, float):
        try:
            return cast(value)
        except ValueError:
            pass
    if value.lower() in ("true", "false"):
        return value.lower() == "true"
    try:
        return json.loads(value)
    except ValueError:
        return value


def parse_options(items: List[str]) -> Dict[str, object]:
    """``["n_samples=64", "resolution=[64,128]"]`` -> dict (numbers, booleans and JSON are parsed)."""
    out = {}
    for it in items or []:
        if "=" not in it:
            raise TrainError(f"--set {it!r}: expected KEY=VALUE")
        k, v = it.split("=", 1)
        out[k.strip()] = parse_option_value(v.strip())
    return out


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows a default only when it says something (not None/False/[]) and the help text has not."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if d is None or d is False or d == [] or d is argparse.SUPPRESS or "default" in text:
            return text
        return super()._get_help_string(action)
