"""A run's record, RUN/config.json, read and checked once and typed (``RunRecord``): what the
loaders of a trained run (``eval``, ``render``, ``serve``, ``open_run``) take from it.

``train`` writes config.json (``engine.report.run_config``): the ``TrainConfig`` fields plus what the
trainer decided. The fields a loader uses are typed here; the whole file stays in ``RunRecord.raw``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Tuple

from nerf_core import contract
from nerf_core.contract.paths import file_problem, not_a_regular_file
from nerf_core.data.batcher import DEFAULT_RAY_SAMPLING, RAY_SAMPLING, RECORDED_BEFORE_TRAIN_RAYS, TRAIN_RAYS
from nerf_core.data.depth import DEFAULT_DEPTH_WEIGHT
from nerf_core.errors import RunError

WHITE = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class RunRecord:
    """RUN/config.json, checked: the fields a loader of the trained run uses, typed, and the rest raw.

    Attributes:
        path: the config.json file.
        dataset: the dataset's path as trained, or None (a run folder from elsewhere).
        dataset_hash: the hash of its transforms files (``runs.folder.dataset_hash``), or None.
        method: the method trained.
        near, far: the dataset's ray bounds in scene units, or None.
        eval_background: (3,) RGB the held-out views are scored on.
        downscale: the image downscale the run trained at.
        raw: the whole file as a dict.
    """

    path: Path
    dataset: Optional[str]
    dataset_hash: Optional[str]
    method: Optional[str]
    near: Optional[float]
    far: Optional[float]
    eval_background: Tuple[float, float, float]
    downscale: int
    raw: dict


def read_run_record(run: Path) -> RunRecord:
    """The record of run folder ``run`` (RunError naming the file and field when it is missing,
    unreadable, or holds a value that ``train`` never writes)."""
    cfg_path = Path(contract.config_path(run))
    if not run.is_dir():
        raise RunError(f"{run}: run folder " + (not_a_regular_file(run) or "not found").replace(
            "is not a regular file", "is not a folder"))
    problem = file_problem(cfg_path)
    if problem:
        raise RunError(f"{cfg_path}: {problem}; is {run} a folder written by `python -m nerf_core train`?")
    try:
        config = json.loads(cfg_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise RunError(f"{cfg_path}: invalid JSON ({exc.msg} at line {exc.lineno})") from exc
    except (OSError, UnicodeDecodeError, RecursionError) as exc:
        raise RunError(f"{cfg_path}: cannot read ({exc.__class__.__name__}: {exc})") from exc
    if not isinstance(config, dict):
        raise RunError(f"{cfg_path}: expected the JSON object that `train` writes, got a {type(config).__name__}; "
                       f"is {run} a run folder?")
    _check_run_config(config, cfg_path)
    text = [config.get(k) if isinstance(config.get(k), str) else None for k in ("dataset_hash", "method")]
    return RunRecord(path=cfg_path, dataset=config.get("dataset") or None, dataset_hash=text[0], method=text[1],
                     near=config.get("near"), far=config.get("far"),
                     eval_background=tuple(float(c) for c in config.get("eval_background", WHITE)),
                     downscale=int(config.get("downscale", 1)), raw=config)


def _check_run_config(config: dict, cfg_path: Path) -> None:
    """Refuse (RunError naming the field) the values of a run's config.json that ``eval``, ``render``
    and ``serve`` read, when they are not what ``train`` writes (an edited or damaged file)."""
    def bad(key, want):
        raise RunError(f"{cfg_path}: field {key!r} must be {want}, got {config[key]!r}")

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if "dataset" in config and config["dataset"] is not None and not isinstance(config["dataset"], str):
        bad("dataset", "the dataset's path (a string)")
    if "downscale" in config and not (isinstance(config["downscale"], int) and not isinstance(config["downscale"], bool)
                                      and config["downscale"] >= 1):
        bad("downscale", "a whole number >= 1")
    if "eval_background" in config:
        bg = config["eval_background"]
        if not (isinstance(bg, list) and len(bg) == 3 and all(number(c) and 0 <= c <= 1 for c in bg)):
            bad("eval_background", "an RGB colour: 3 numbers in [0, 1]")
    for key in ("near", "far"):
        if config.get(key) is not None and not (number(config[key]) and config[key] >= 0):
            bad(key, "a number >= 0 (or null)")
    near, far = config.get("near"), config.get("far")
    if near is not None and far is not None and far <= near:  # each alone is fine; together no ray has samples
        raise RunError(f"{cfg_path}: field 'far' ({far}) must be greater than field 'near' ({near}); every view would "
                       "render empty")


def trained_with(config: dict) -> dict:
    """What a run's training used beyond the colours, from its config.json dict, for every score to
    carry (``eval``'s JSON and metrics.json, the benchmark tables): a score with depth supervision is
    not comparable with a colours-only peer's. Runs from before the flags trained without depth and
    through the pixel centres.

    Returns:
        {"depth": bool, "depth_weight": float or None (the weight used; None without depth),
         "train_rays": "centre" or "filter", "ray_sampling": "uniform" or "error"}.
    """
    depth = config.get("depth") is True
    weight = config.get("depth_weight")
    if depth and not (isinstance(weight, (int, float)) and not isinstance(weight, bool)):
        weight = DEFAULT_DEPTH_WEIGHT  # the flag was left out: the documented default was used
    rays, sampling = config.get("train_rays"), config.get("ray_sampling")
    return {"depth": depth, "depth_weight": float(weight) if depth else None,
            "train_rays": rays if rays in TRAIN_RAYS else RECORDED_BEFORE_TRAIN_RAYS,
            "ray_sampling": sampling if sampling in RAY_SAMPLING else DEFAULT_RAY_SAMPLING}
