"""``python -m nerf_core``: train, render, eval, check (and list methods).

Stable flags are documented in docs/CONTRACTS.md. Expected problems (bad dataset, existing run,
missing checkpoint) end with one ``nerf_core <command>: error: ...`` line on stderr and exit code 2,
never a traceback. Set ``NERF_CORE_PLUGINS=module.a,module.b`` to import modules that register
extra methods before a command runs.
"""
from __future__ import annotations

import argparse
import math
import importlib
import json
import os
import sys
from typing import Dict, List, Optional

from nerf_core.data.backgrounds import BACKGROUNDS

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def _load_plugins() -> None:
    for name in filter(None, (s.strip() for s in os.environ.get("NERF_CORE_PLUGINS", "").split(","))):
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise ValueError(f"NERF_CORE_PLUGINS: cannot import {name!r} ({exc})") from exc


def _seconds_list(text: str) -> list[float]:
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


def _checked_number(cast, noun: str, ok, rule: str):
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


def _folder(text: str) -> str:
    """An argparse ``type`` for output folders: an empty path would mean the current folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty; name a folder (an empty path would write into the current one)")
    return text


_positive_float = _checked_number(float, "a number", lambda v: v > 0, "must be positive")
_positive_int = _checked_number(int, "an integer", lambda v: v > 0, "must be positive")
_nonneg_int = _checked_number(int, "an integer", lambda v: v >= 0, "must be >= 0")


def _add_model_args(p, split_help: str, downscale, chunk_help: str) -> None:
    """The arguments ``render`` and ``eval`` share: the run, which views, and how to run the model.
    ``downscale``: (argparse type, verb for its help)."""
    kind, verb, *rest = downscale
    p.add_argument("run", metavar="RUN", help="run folder written by `train`")
    p.add_argument("--split", default="test", help=split_help)
    if rest:  # no default: the run's own
        p.add_argument("--downscale", type=kind, default=None, metavar="F", help=f"{verb} at 1/F resolution ({rest[0]})")
    else:
        p.add_argument("--downscale", type=kind, default=kind("1"), metavar="F", help=f"{verb} at 1/F resolution")
    p.add_argument("--device", metavar="DEV", help="torch device; default: cuda if available else cpu")
    p.add_argument("--chunk", type=_positive_int, default=8192, help=chunk_help)
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
    from nerf_core.runs.folder import TrainError

    out = {}
    for it in items or []:
        if "=" not in it:
            raise TrainError(f"--set {it!r}: expected KEY=VALUE")
        k, v = it.split("=", 1)
        out[k.strip()] = parse_option_value(v.strip())
    return out


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows a default only when it says something (not None/False/[]) and the help text has not."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if d is None or d is False or d == [] or d is argparse.SUPPRESS or "default" in text:
            return text
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    fmt = _HelpFormatter
    p = argparse.ArgumentParser(
        prog="python -m nerf_core",
        description="Train NeRFs on Blender (or any NeRF-synthetic / nerfstudio) datasets, render novel views, "
                    "evaluate and validate datasets. CPU first; CUDA when available.",
        epilog="examples:\n"
               "  python -m nerf_core check scene_dataset\n"
               "  python -m nerf_core train scene_dataset --out runs/scene --max-seconds 600\n"
               "  python -m nerf_core eval runs/scene --split test\n"
               "  python -m nerf_core render runs/scene --cameras scene_dataset/transforms_test.json --out renders",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    t = sub.add_parser("train", help="train a method on a dataset into a run folder", formatter_class=fmt,
                       description="Train a NeRF. JSON progress events go to stdout and RUN/progress.jsonl; "
                                   "a progress bar with ETA goes to stderr.")
    t.add_argument("dataset", metavar="DATASET", help="dataset folder (transforms_train.json or transforms.json) or a transforms file")
    t.add_argument("--out", required=True, type=_folder, metavar="RUN", help="run folder to create (refused if it exists and is not empty)")
    t.add_argument("--method", metavar="M", help="method name (see `python -m nerf_core methods`); default: the library's default method")
    t.add_argument("--max-steps", type=_positive_int, metavar="N", help="stop after N optimisation steps")
    t.add_argument("--max-seconds", type=_positive_float, metavar="S",
                   help="stop after S seconds of training (previews, checkpoints and evaluation not counted)")
    t.add_argument("--seed", type=int, default=0, metavar="K", help="random seed (same seed + step budget = the same losses on a CPU; on CUDA equal to about "
                        "1e-7, since its atomic adds sum gradients in no fixed order)")
    t.add_argument("--resume", action="store_true",
                   help="continue RUN from RUN/checkpoints/latest.pt (else its newest step_*.pt); DATASET must hold "
                        "the dataset the run was trained on (checked by the hash of its transforms files)")
    t.add_argument("--dataset-moved", action="store_true",
                   help="with --resume: accept a DATASET path other than the recorded one for a run that recorded "
                        "no dataset hash (newer runs accept a moved dataset by its hash without this flag)")
    t.add_argument("--overwrite", action="store_true", help="start RUN again, deleting only files an earlier training wrote")
    t.add_argument("--size", choices=["auto"], help="let nerf_core.methods.sizing choose the model size for this dataset")
    t.add_argument("--contract", action="store_true",
                   help="scene contraction (mip-NeRF 360 style): also model geometry beyond the scene box, such as a "
                        "ground plane running to the horizon (vmgrid; the same as --set contract=true). Without it, "
                        "a cut-out whose opaque pixels look past the box gets it anyway; --set contract=false stops that")
    t.add_argument("--progress", metavar="FILE", help="also append the JSON progress events to FILE")
    t.add_argument("--device", metavar="DEV", help="torch device (cpu, cuda, cuda:1); default: cuda if available else cpu")
    t.add_argument("--lr", type=_positive_float, help="base learning rate (default: the method's)")
    t.add_argument("--batch-rays", type=_positive_int, metavar="N",
                   help="rays per step (default: the method's, 1024 for a method without one; 4x that on CUDA)")
    t.add_argument("--background", choices=list(BACKGROUNDS), default="auto",
                   help="what stands behind the scene while training: environment = a learned world (light from "
                        "infinity, for opaque captures); random = a random colour per ray behind the alpha (cut-outs "
                        "on a transparent film); white-then-random = white for the first 20%% of the budget, then "
                        "random. auto picks environment or random from the dataset's film_transparent and the "
                        "images' alpha, and says why")
    t.add_argument("--downscale", type=_positive_int, default=1, metavar="F", help="train on images downscaled by F")
    t.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="options",
                   help="method option, repeatable (e.g. --set n_samples=64)")
    t.add_argument("--log-every", type=_positive_int, default=50, metavar="N", help="emit a step event every N steps")
    t.add_argument("--preview-every", type=_positive_int, metavar="N", help="preview every N steps (default: every 30 s of training)")
    t.add_argument("--checkpoint-every", type=_positive_int, metavar="N", help="checkpoint every N steps (default: every 5 min)")
    t.add_argument("--eval-views", type=_nonneg_int, metavar="N",
                   help="held-out views to evaluate at the end (0 = none; default: as many as fit in 25%% of the training time)")
    t.add_argument("--eval-at", metavar="S1,S2,...", type=_seconds_list, default=[],
                   help="also evaluate held-out views at these training times (seconds), e.g. 60,120,300")
    t.add_argument("--no-bar", action="store_true", help="no progress bar on stderr")

    r = sub.add_parser("render", help="render novel views of a trained run", formatter_class=fmt,
                       description="Render RGBA PNGs (alpha = opacity), planar depth EXRs and renders.json.")
    _add_model_args(r, split_help="split to render when --cameras is a dataset folder or split transforms.json",
                    downscale=(_positive_float, "render"),
                    chunk_help="most rays per model call (lower it to save memory; CPU calls are smaller)")
    r.add_argument("--cameras", metavar="TRANSFORMS.json",
                   help="dataset folder, transforms file (either layout) or JSON list of cameras; default: the run's dataset")
    r.add_argument("--out", required=True, type=_folder, metavar="DIR", help="output folder")
    r.add_argument("--overwrite", action="store_true", help="replace existing outputs in DIR")

    e = sub.add_parser("eval", help="evaluate a run on held-out views (PSNR, SSIM, depth error)", formatter_class=fmt,
                       description="Prints one line per view, then one JSON object as the last line of stdout.")
    _add_model_args(e, split_help="split to evaluate (test or val)", downscale=(_positive_int, "evaluate", "default: the --downscale the run trained at"),
                    chunk_help="most rays per model call (CPU calls are smaller)")
    e.add_argument("--views", type=_positive_int, metavar="N", help="evaluate N evenly spaced views only")

    c = sub.add_parser("check", help="validate a dataset folder against the dataset conventions", formatter_class=fmt,
                       description="Exit 0 when valid; otherwise exit 1 and list every problem with its file/frame/field.")
    c.add_argument("dataset", metavar="DATASET", help="dataset folder")
    c.add_argument("--json", action="store_true", help="print the report as one JSON object")
    c.add_argument("--for-training", action="store_true",
                   help="errors are only what `train` refuses; the conventions an export keeps for other tools' "
                        "loaders become warnings (a dataset of another tool trains)")
    c.add_argument("--background", default="auto", choices=list(BACKGROUNDS),
                   help="the train --background to check the images against (warns when opaque images meet a mode "
                        "that cannot show their background)")

    from nerf_core.render.server import add_serve_parser

    add_serve_parser(sub, fmt)
    sub.add_parser("methods", help="list the available methods")
    return p


def _cmd_train(a) -> int:
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    cfg = TrainConfig(
        dataset=a.dataset, out=a.out, method=a.method, max_steps=a.max_steps, max_seconds=a.max_seconds, seed=a.seed,
        resume=a.resume, overwrite=a.overwrite, dataset_moved=a.dataset_moved, size=a.size,
        options={**parse_options(a.options), **({"contract": True} if a.contract else {})}, progress=a.progress,
        device=a.device, lr=a.lr, batch_rays=a.batch_rays, background=a.background, downscale=a.downscale,
        log_every=a.log_every, preview_every=a.preview_every, checkpoint_every=a.checkpoint_every,
        eval_views=a.eval_views, eval_at=a.eval_at, show_bar=not a.no_bar,
    )
    train(cfg)
    return 0


def _cmd_render(a) -> int:
    from nerf_core.render.views import render_run

    path = render_run(a.run, a.cameras, a.out, split=a.split, overwrite=a.overwrite, device=a.device,
                      downscale=a.downscale, chunk=a.chunk, checkpoint=a.checkpoint, show_progress=not a.no_bar,
                      pixel_filter=a.pixel_filter)
    print(json.dumps({"renders": str(path.resolve()), "out": str(path.parent.resolve())}))
    return 0


def _cmd_eval(a) -> int:
    from nerf_core.evaluation.evaluate import evaluate_run

    summary = evaluate_run(a.run, split=a.split, device=a.device, max_views=a.views, downscale=a.downscale,
                           chunk=a.chunk, checkpoint=a.checkpoint, show_progress=not a.no_bar,
                           print_fn=lambda line: print(line, flush=True), pixel_filter=a.pixel_filter)
    print(json.dumps(summary, default=lambda o: None))
    return 0


def _cmd_check(a) -> int:
    from nerf_core.check.dataset import check_dataset

    report = check_dataset(a.dataset, background=a.background, for_training=a.for_training)
    if a.json:
        print(json.dumps(report.as_dict()))
    else:
        print(report.format())
    return 0 if report.ok else 1


def _cmd_methods(a) -> int:
    from nerf_core.methods.base import available_methods
    from nerf_core.methods import catalog

    default = getattr(catalog, "DEFAULT_METHOD", None)
    for name in available_methods():
        print(name + ("  (default)" if name == default else ""))
    return 0


COMMANDS = {"train": _cmd_train, "render": _cmd_render, "eval": _cmd_eval, "check": _cmd_check, "methods": _cmd_methods,
            "serve": lambda a: a.handler(a)}


def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from nerf_core.contract.transforms import DatasetError
    from nerf_core.image.io import ImageReadError
    from nerf_core.runs.checkpoints import RunError
    from nerf_core.runs.folder import TrainError

    expected = (DatasetError, RunError, TrainError, ImageReadError, ValueError, OSError)
    try:
        _load_plugins()
        return COMMANDS[args.command](args)
    except expected as exc:
        msg = str(exc) or type(exc).__name__
        if isinstance(exc, OSError) and msg.startswith("[Errno"):  # a bare OSError, not one of our messages
            from nerf_core.runs.folder import os_error_text

            msg = os_error_text(exc)
        print(f"nerf_core {args.command}: error: {msg}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"nerf_core {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
