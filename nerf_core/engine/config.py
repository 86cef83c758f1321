"""``TrainConfig``: everything that decides a training run, and what ``--resume`` may change in it.

A run's config is saved in ``RUN/config.json`` and in every checkpoint; ``merge_resumed_config``
rebuilds it on ``--resume`` from the saved one and the few settings a user may change then.
"""
from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, fields
from typing import Dict, List, Optional, Sequence

from nerf_core import contract
from nerf_core.contract.numbers import is_number, is_real, is_whole, plain
from nerf_core.data.alpha import DEFAULT_ALPHA_WEIGHT
from nerf_core.data.backgrounds import BACKGROUNDS
from nerf_core.data.batcher import (
    DEFAULT_RAY_SAMPLING,
    DEFAULT_TRAIN_RAYS,
    RAY_SAMPLING,
    RECORDED_BEFORE_TRAIN_RAYS,
    TRAIN_RAYS,
)
from nerf_core.data.depth import DEFAULT_DEPTH_WEIGHT
from nerf_core.errors import TrainError
from nerf_core.methods import catalog
from nerf_core.methods.options import OptionError
from nerf_core.methods.registry import available_methods, method_class
from nerf_core.render.memory import DEFAULT_CHUNK
from nerf_core.runs.folder import resume_dataset

MAX_BATCH_RAYS = 1 << 22  # rays a step; more would need tens of GB for the samples alone
MAX_DEPTH_WEIGHT = 100.0  # the depth loss at 100x the colour error would teach geometry without colour
MAX_ALPHA_WEIGHT = 100.0  # likewise: opacity without colour


def flag(default, help: str, *, name: Optional[str] = None, kind: str = "str", metavar: Optional[str] = None,
         choices: Optional[Sequence[str]] = None, required: bool = False):
    """A ``TrainConfig`` field that is also a flag of ``python -m nerf_core train``: the flag, its help
    and its default are declared once, here (``cli.train`` builds the parser from these fields).

    Args:
        default: the field's default (a list or dict is copied per instance); ``None`` with
            ``required``/a positional ``name`` for fields without one.
        help: the flag's help text (argparse's: ``%%`` for a percent sign).
        name: the flag ("--no-bar", "--set") or, without dashes, a positional argument; default:
            ``--`` and the field's name with dashes.
        kind: what the value is, which decides both how the command line's text becomes the value
            (``cli.train``) and what ``check_field_types`` accepts from Python (``FIELD_KINDS``): "str",
            "path", "int", "positive_int", "nonneg_int", "positive_float", "nonneg_float", "folder", "seconds_list",
            "options" (repeatable KEY=VALUE), "switch" (a flag that sets True) or "switch_off" (a flag
            that sets False).
        metavar, choices, required: as argparse's.
    """
    # "kind" and "choices" belong to the value (``check_field_types`` reads them for every field);
    # "flag" holds only what the command line adds.
    meta = {"kind": kind, "choices": tuple(choices) if choices is not None else None,
            "flag": {"name": name, "help": help, "metavar": metavar, "required": required}}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: type(default)(default), metadata=meta)
    if default is None and (required or (name is not None and not name.startswith("-"))):
        return field(metadata=meta)  # no default: the caller must give it
    return field(default=default, metadata=meta)


def setting(default, kind: str):
    """A ``TrainConfig`` field that is no flag of ``train`` (set from Python or kept from the run's
    config), with its ``kind`` (see ``flag``) for ``check_field_types``."""
    return field(default=default, metadata={"kind": kind, "choices": None})


@dataclass
class TrainConfig:
    """Everything that decides a run (saved in RUN/config.json and in checkpoints); ``train(cfg)`` runs it.

    The fields mirror ``python -m nerf_core train``'s flags (``max_steps`` is ``--max-steps``). Only
    ``dataset`` and ``out`` are required; ``check()`` refuses values no run can use (TrainError).

    Attributes:
        dataset: dataset folder (``transforms_train.json`` or ``transforms.json``) or a transforms file.
        out: run folder to create (refused when it exists and is not empty, unless ``resume`` or
            ``overwrite``).
        method: a registered method name; None: the library's default method (vmgrid).
        max_steps: stop after this many optimisation steps (> 0), or None.
        max_seconds: stop after this many seconds of training (previews, checkpoints and evaluation
            not counted), or None. With both budgets training stops at the first spent; with neither,
            at the method's ``default_max_steps`` (``train`` writes it into ``max_steps``).
        seed: random seed in 0..2^63-1 (same seed and step budget: the same losses on a CPU).
        resume: continue ``out`` from its latest checkpoint; only the fields in ``RESUME_MAY_CHANGE``
            may differ from the run's own.
        overwrite: delete the files an earlier run wrote into ``out`` and start anew.
        dataset_moved: with ``resume``, accept a ``dataset`` path other than the recorded one (the
            dataset's hash is checked when recorded).
        size: "auto": ``nerf_core.methods.sizing`` picks the model size for the dataset; None: the
            method's defaults.
        options: explicit method options (``--set key=value``), over the method's defaults.
        progress: an extra JSON-lines file to append the progress events to, or None.
        device: "cpu", "cuda", "cuda:1"...; None or "auto": CUDA when there is one, else the CPU.
        lr: base learning rate; None: the method's ``default_lr``.
        batch_rays: rays per step in 1..2^22; None: the method's default (4x on CUDA).
        background: "auto" (``nerf_core.data.backgrounds.choose``: environment for opaque images,
            random for cut-outs), "environment", "random", "white", "black" or "white-then-random".
        downscale: integer image downscale factor the dataset is loaded at.
        log_every: emit a ``step`` event every this many steps.
        preview_every: steps between preview images; None: every ``preview_seconds`` of training time.
        preview_seconds: training seconds between previews (when ``preview_every`` is None).
        preview_size: longest side of preview images, in pixels.
        checkpoint_every: steps between checkpoints; None: every ``checkpoint_seconds`` of wall time.
        checkpoint_seconds: wall seconds between checkpoints (when ``checkpoint_every`` is None).
        keep_checkpoints: ``step_XXXXXXX.pt`` files kept besides ``latest.pt``.
        max_rollbacks: divergence rollbacks (each halving the learning rate) before training stops
            with a TrainError.
        eval_views: held-out views evaluated at the end; None: as many as fit in ``eval_seconds``;
            0: skip evaluation.
        eval_seconds: time for the final evaluation; None: max(30 s, 25 % of the training time).
        eval_at: training seconds (> 0) at which to also evaluate held-out views.
        chunk: most rays per model call when rendering previews and evaluations.
        stdout_events: print the JSON progress events on stdout (they go to RUN/progress.jsonl anyway).
        show_bar: show a progress bar on stderr.
    """

    dataset: str = flag(None, "dataset folder (transforms_train.json or transforms.json) or a transforms file",
                        name="dataset", kind="path", metavar="DATASET")
    out: str = flag(None, "run folder to create (refused if it exists and is not empty)", kind="folder",
                    metavar="RUN", required=True)
    method: Optional[str] = flag(None, "method name (see `python -m nerf_core methods`); default: the library's "
                                       "default method", metavar="M")
    max_steps: Optional[int] = flag(None, "stop after N optimisation steps", kind="positive_int", metavar="N")
    max_seconds: Optional[float] = flag(None, "stop after S seconds of training (previews, checkpoints and "
                                              "evaluation not counted)", kind="positive_float", metavar="S")
    seed: int = flag(0, "random seed (same seed + step budget = the same losses on a CPU; on CUDA equal to about "
                        "1e-7, since its atomic adds sum gradients in no fixed order)", kind="int", metavar="K")
    resume: bool = flag(False, "continue RUN from RUN/checkpoints/latest.pt (else its newest step_*.pt); DATASET "
                               "must hold the dataset the run was trained on (checked by the hash of its "
                               "transforms files)", kind="switch")
    overwrite: bool = flag(False, "start RUN again, deleting only files an earlier training wrote", kind="switch")
    dataset_moved: bool = flag(False, "with --resume: accept a DATASET path other than the recorded one for a run "
                                      "that recorded no dataset hash (newer runs accept a moved dataset by its hash "
                                      "without this flag)", kind="switch")
    size: Optional[str] = flag(None, "let nerf_core.methods.sizing choose the model size for this dataset",
                               choices=("auto",))
    options: Dict[str, object] = flag({}, "method option, repeatable (e.g. --set res_final=128; "
                                          "`python -m nerf_core methods vmgrid` lists them)",
                                      name="--set", kind="options", metavar="KEY=VALUE")
    progress: Optional[str] = flag(None, "also append the JSON progress events to FILE", kind="path", metavar="FILE")
    device: Optional[str] = flag(None, "torch device (cpu, cuda, cuda:1); default: cuda if available else cpu",
                                 metavar="DEV")
    lr: Optional[float] = flag(None, "base learning rate (default: the method's)", kind="positive_float")
    batch_rays: Optional[int] = flag(None, "rays per step (default: the method's, 1024 for a method without one; "
                                           "4x that on CUDA)", kind="positive_int", metavar="N")
    background: str = flag("auto", "what stands behind the scene while training: environment = a learned world "
                                   "(light from infinity, for opaque captures); random = a random colour per ray "
                                   "behind the alpha (cut-outs on a transparent film); white-then-random = white for "
                                   "the first 20%% of the budget, then random. auto picks environment or random from "
                                   "the dataset's film_transparent and the images' alpha, and says why",
                           choices=BACKGROUNDS)
    train_rays: str = flag(DEFAULT_TRAIN_RAYS, "where a training ray goes through its pixel: filter = at an offset "
                                               "drawn from the capture's pixel filter (its `pixel_filter`; Blender's "
                                               "1.5 px Blackman-Harris when it records none), so one ray a pixel has "
                                               "the rendered pixel as its expected colour; centre = through the "
                                               "pixel's centre", choices=TRAIN_RAYS)
    ray_sampling: str = flag(DEFAULT_RAY_SAMPLING, "which pixels a step trains on: uniform = every pixel alike; "
                                                   "error = in proportion to a running estimate of their error "
                                                   "(half of each batch stays uniform), with the loss weighted so "
                                                   "that it still estimates the uniform one", choices=RAY_SAMPLING)
    depth: bool = flag(False, "also supervise with the capture's depth maps (every train frame needs one): a loss "
                              "on the rendered depth, and the occupancy grid starts with the space the depth shows "
                              "empty. Off by default, so that scores compare with colours-only tools", kind="switch")
    depth_weight: Optional[float] = flag(None, f"with --depth: the depth loss's weight against the colour error "
                                               f"(default {DEFAULT_DEPTH_WEIGHT:g})", kind="positive_float",
                                         metavar="W")
    alpha_weight: float = flag(DEFAULT_ALPHA_WEIGHT, "also supervise the rendered opacity with the images' alpha "
                                                     "(a capture on a transparent film): the squared error, at W "
                                                     "times the colour error's weight. 0 (the default) = off, so "
                                                     "that scores compare with colours-only tools",
                               kind="nonneg_float", metavar="W")
    downscale: int = flag(1, "train on images downscaled by F", kind="positive_int", metavar="F")
    log_every: int = flag(50, "emit a step event every N steps", kind="positive_int", metavar="N")
    preview_every: Optional[int] = flag(None, "preview every N steps (default: every 30 s of training)",
                                        kind="positive_int", metavar="N")
    preview_seconds: float = setting(30.0, "seconds")  # training seconds between previews (preview_every None)
    preview_size: int = setting(256, "positive_int")  # longest side of preview images
    checkpoint_every: Optional[int] = flag(None, "checkpoint every N steps (default: every 5 min)",
                                           kind="positive_int", metavar="N")
    checkpoint_seconds: float = setting(300.0, "seconds")
    keep_checkpoints: int = setting(3, "nonneg_int")  # step_XXXXXXX.pt files kept besides latest.pt
    max_rollbacks: int = setting(8, "nonneg_int")
    eval_views: Optional[int] = flag(None, "held-out views to evaluate at the end (0 = none; default: as many as "
                                           "fit in 25%% of the training time)", kind="nonneg_int", metavar="N")
    eval_seconds: Optional[float] = setting(None, "seconds")  # None: max(30 s, 25 % of the training time)
    eval_at: List[float] = flag([], "also evaluate held-out views at these training times (seconds), e.g. "
                                    "60,120,300", kind="seconds_list", metavar="S1,S2,...")
    chunk: int = setting(DEFAULT_CHUNK, "positive_int")
    stdout_events: bool = setting(True, "switch")
    show_bar: bool = flag(True, "no progress bar on stderr", name="--no-bar", kind="switch_off")

    def budget_fraction(self, step: int, elapsed: float) -> float:
        """Share of the budget spent, in [0, 1] (``contract.budget_fraction``; 0 without a budget)."""
        frac = contract.budget_fraction(step, elapsed, self.max_steps, self.max_seconds)
        return 0.0 if frac is None else frac

    def finished(self, step: int, elapsed: float) -> bool:
        return (self.max_steps is not None and step >= self.max_steps) or (
            self.max_seconds is not None and elapsed >= self.max_seconds
        )

    def spent_budgets(self, step: int, elapsed: float) -> List[str]:
        """The budgets (as flags) that ``step`` and ``elapsed`` already meet, e.g. ["--max-steps 100"]."""
        return ([f"--max-steps {self.max_steps}"] if self.max_steps is not None and step >= self.max_steps
                else []) + ([f"--max-seconds {self.max_seconds:g}"] if self.max_seconds is not None
                            and elapsed >= self.max_seconds else [])

    def eta(self, step: int, elapsed: float) -> Optional[float]:
        """Training seconds left: to the step budget at the mean step time so far, or to the time budget."""
        etas = []
        if self.max_steps and step > 0:
            etas.append(elapsed / step * max(0, self.max_steps - step))
        if self.max_seconds:
            etas.append(max(0.0, self.max_seconds - elapsed))
        return min(etas) if etas else None

    def bar_total(self) -> tuple[float, str]:
        """(total, unit) of the progress bar: steps or seconds for one budget, percent for both."""
        if self.max_steps and not self.max_seconds:
            return self.max_steps, "steps"
        if self.max_seconds and not self.max_steps:
            return round(self.max_seconds), "seconds"
        return 100, "percent"

    def bar_done(self, unit: str, step: int, elapsed: float) -> float:
        """Progress in the bar's ``unit`` (see ``bar_total``)."""
        if unit == "steps":
            return step
        if unit == "seconds":
            return round(elapsed, 1)
        return round(100 * self.budget_fraction(step, elapsed), 1)

    def check(self) -> None:
        """Refuse settings no run can use (TrainError naming the flag)."""
        check_field_types(self)
        for name in ("max_steps", "max_seconds", "lr"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):  # NaN and inf are refused too
                raise TrainError(f"--{name.replace('_', '-')} must be a finite number > 0, got {v}")
        if self.batch_rays is not None and not 1 <= self.batch_rays <= MAX_BATCH_RAYS:
            raise TrainError(f"--batch-rays must lie in 1..{MAX_BATCH_RAYS}, got {self.batch_rays}")
        if not 0 <= self.seed < 2 ** 63:
            raise TrainError(f"--seed must lie in 0..2^63-1, got {self.seed}")
        bad = [t for t in self.eval_at if not (math.isfinite(t) and t > 0)]
        if bad:
            raise TrainError(f"--eval-at: training times must be finite numbers of seconds > 0, got {bad[0]}")
        beyond = [t for t in self.eval_at if self.max_seconds is not None and t > self.max_seconds]
        if beyond:
            raise TrainError(f"--eval-at {beyond[0]:g} lies beyond --max-seconds {self.max_seconds:g}: training stops "
                             "first, so nothing would be evaluated there. Lower the mark or raise the budget")
        if self.depth_weight is not None:
            if not self.depth:
                raise TrainError("--depth-weight weighs the depth loss that --depth adds: pass --depth too, or "
                                 "leave --depth-weight out")
            if not (math.isfinite(self.depth_weight) and 0 < self.depth_weight <= MAX_DEPTH_WEIGHT):
                raise TrainError(f"--depth-weight must be a finite number in (0, {MAX_DEPTH_WEIGHT:g}], got "
                                 f"{self.depth_weight}")
        if not (math.isfinite(self.alpha_weight) and 0 <= self.alpha_weight <= MAX_ALPHA_WEIGHT):
            raise TrainError(f"--alpha-weight must be a finite number in [0, {MAX_ALPHA_WEIGHT:g}] (0 = off), got "
                             f"{self.alpha_weight}")
        if self.method is not None and not self.method.strip():
            raise TrainError("--method is empty; leave it out for the default method, or name one")

        cls = method_class(self.method or default_method())
        if cls is None:
            raise TrainError(f"unknown method {self.method!r}; choose one of {', '.join(available_methods())}")
        try:
            cls.parse_options(self.options)  # the method's typed options: the same rules as build_model
        except OptionError as exc:
            raise TrainError(f"--set {exc.option}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise TrainError(f"--set: {exc}") from None


# ------------------------------------------------------------------------------------------------
# What a field of each kind (``flag``/``setting``) must hold when the config comes from Python: the
# words of the error, and the test. A wrong type or a zero would otherwise fail deep inside the run
# (log_every=0: ZeroDivisionError), after the run folder is made; ``TrainConfig.check`` runs these
# first, before anything is written. Ranges beyond a kind's (seed < 2^63, ...) are ``check``'s.
def _path(v) -> bool:
    return isinstance(v, (str, os.PathLike)) and bool(str(v).strip())


FIELD_KINDS = {
    "str": ("a string", lambda v: isinstance(v, str)),
    "path": ("a non-empty path (str)", _path),
    "folder": ("a non-empty path (str)", _path),
    "int": ("an integer >= 0", lambda v: is_whole(v) and v >= 0),
    "positive_int": ("an integer >= 1", lambda v: is_whole(v) and v >= 1),
    "nonneg_int": ("an integer >= 0", lambda v: is_whole(v) and v >= 0),
    "positive_float": ("a finite number > 0", lambda v: is_number(v) and v > 0),
    "nonneg_float": ("a finite number >= 0", lambda v: is_number(v) and v >= 0),
    "seconds": ("a finite number of seconds >= 0", lambda v: is_number(v) and v >= 0),  # 0: "none at all"
    "seconds_list": ("a list of training times in seconds",
                     # NaN or a time past the budget: ``check`` says so in its own words
                     lambda v: isinstance(v, (list, tuple)) and all(is_real(t) for t in v)),
    "options": ("a dict of option name (str) -> value ({} for the method's defaults)",
                lambda v: isinstance(v, dict) and all(isinstance(k, str) for k in v)),
    "switch": ("True or False", lambda v: isinstance(v, bool)),
    "switch_off": ("True or False", lambda v: isinstance(v, bool)),
}
_PATH_KINDS = ("path", "folder")
MAX_PREVIEW_SIZE = 1 << 14  # pixels on the longest side; a preview is a thumbnail
MAX_CHUNK = 1 << 24  # rays per model call


def _field_error(name: str, want: str, value) -> TrainError:
    """TrainConfig.NAME (and its flag, where it has one) must be WANT, got VALUE."""
    spec = {f.name: f.metadata.get("flag") for f in fields(TrainConfig)}.get(name)
    if spec is None or (spec["name"] and not spec["name"].startswith("-")):
        where = ""  # no flag of its own (a setting, or the positional DATASET)
    else:
        where = f" ({spec['name'] or '--' + name.replace('_', '-')})"
    return TrainError(f"TrainConfig.{name}{where} must be {want}, got {value!r}")


def check_field_types(cfg: "TrainConfig") -> None:
    """Refuse a field of the wrong type or out of range (TrainError naming the field and what it must be);
    TypeError when ``cfg`` is no TrainConfig at all. A numpy number is a number: it is stored back as
    Python's (``contract.numbers.plain``), so that config.json and checkpoints can hold it.

    Each field's rule comes from its declared ``kind`` (``FIELD_KINDS``), its ``choices`` and, for
    ``Optional[...]`` fields, None; the CLI's argparse types check the same kinds for its flags.
    """
    if not isinstance(cfg, TrainConfig):
        raise TypeError(f"train(cfg): cfg must be a nerf_core.TrainConfig, got {type(cfg).__name__}")
    for f in fields(TrainConfig):
        v = getattr(cfg, f.name)
        if v is None and str(f.type).startswith("Optional["):
            continue
        want, ok = FIELD_KINDS[f.metadata["kind"]]
        if not ok(v):
            raise _field_error(f.name, want, v)
        setattr(cfg, f.name, plain(v))  # numpy's numbers as Python's: config.json must hold them
        if f.metadata["kind"] in _PATH_KINDS:
            try:
                os.fsencode(v)
            except UnicodeError:
                raise _field_error(f.name, "a path the file system can encode (it holds a lone surrogate)", v) from None
        choices = f.metadata["choices"]
        if choices is not None and v not in choices:
            nothing = "None or " if str(f.type).startswith("Optional[") else ""
            raise _field_error(f.name, nothing + "one of " + ", ".join(map(repr, choices)), v)
    if cfg.preview_size > MAX_PREVIEW_SIZE:
        raise _field_error("preview_size", f"at most {MAX_PREVIEW_SIZE} pixels", cfg.preview_size)
    if cfg.chunk > MAX_CHUNK:
        raise _field_error("chunk", f"at most {MAX_CHUNK} rays", cfg.chunk)


# What the user may change when resuming: budgets, device, output plumbing; the rest is the run's.
RESUME_MAY_CHANGE = {"max_steps", "max_seconds", "device", "progress", "stdout_events", "show_bar", "resume", "out",
                     "eval_views", "eval_seconds", "log_every", "checkpoint_every", "checkpoint_seconds", "chunk",
                     "preview_every", "preview_seconds", "preview_size", "keep_checkpoints", "max_rollbacks", "eval_at"}
# Not settings of the run, or checked on their own (method, dataset) by ``merge_resumed_config``.
_RESUME_BOOKKEEPING = {"dataset", "dataset_moved", "overwrite", "method"}


def _resume_conflicts(cli: TrainConfig, saved: dict) -> list:
    """'--flag VALUE (the run's: SAVED)' for each setting the command line gives (other than its
    default) that differs from the run's: ``--resume`` would silently train with the run's own."""
    defaults = TrainConfig(dataset="", out="")
    out = []
    for key, value in asdict(cli).items():
        if key in RESUME_MAY_CHANGE or key in _RESUME_BOOKKEEPING or key not in saved:
            continue
        if value != getattr(defaults, key) and value != saved[key]:
            flag = "--set" if key == "options" else "--" + key.replace("_", "-")
            shown = " ".join(f"{k}={v}" for k, v in value.items()) if key == "options" else value
            out.append(f"{flag} {shown} (the run's: {saved[key] if saved[key] is not None else 'the default'})")
    return out


def merge_resumed_config(cli: TrainConfig, ckpt: dict) -> TrainConfig:
    """The config to continue a run with: the checkpoint's, with the settings in ``RESUME_MAY_CHANGE``
    taken from ``cli`` (the command line), and the dataset checked by ``runs.dataset_identity.resume_dataset``.
    Raises TrainError when the command line names another method or another dataset."""
    saved = dict(ckpt.get("config") or {})
    if cli.method and saved.get("method") and cli.method != saved["method"]:
        raise TrainError(f"--resume: the run was trained with method {saved['method']!r}, not {cli.method!r}")
    conflicts = _resume_conflicts(cli, saved)
    if conflicts:
        raise TrainError("--resume continues a run with the settings it started with; " + "; ".join(conflicts)
                         + ". Leave them out to resume, or train a new run (another --out) with them")
    dataset = resume_dataset(saved, cli.dataset, cli.dataset_moved)
    merged = asdict(cli)
    for k, v in saved.items():
        if k in merged and k not in RESUME_MAY_CHANGE:
            merged[k] = v
    if cli.max_steps is None and cli.max_seconds is None:
        merged["max_steps"], merged["max_seconds"] = saved.get("max_steps"), saved.get("max_seconds")
    if "train_rays" not in saved:  # a run from before the flag: it trained through the pixel centres
        merged["train_rays"] = RECORDED_BEFORE_TRAIN_RAYS
    if "ray_sampling" not in saved:  # ... and drew its pixels uniformly
        merged["ray_sampling"] = DEFAULT_RAY_SAMPLING
    if "alpha_weight" not in saved:  # ... and without alpha supervision
        merged["alpha_weight"] = DEFAULT_ALPHA_WEIGHT
    merged["resume"], merged["overwrite"] = True, False
    merged["dataset"], merged["dataset_moved"] = dataset, cli.dataset_moved
    return TrainConfig(**merged)


def default_method() -> str:
    """The catalog's DEFAULT_METHOD, else the first registered method (TrainError when none is)."""

    names = available_methods()
    name = catalog.DEFAULT_METHOD
    if name in names:
        return name
    if not names:
        raise TrainError("no NeRF methods are registered (nerf_core/methods/catalog.py registers none)")
    return names[0]
