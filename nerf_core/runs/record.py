"""A run's record, RUN/config.json, read and checked once and typed (``RunRecord``): what the
loaders of a trained run (``eval``, ``render``, ``serve``, ``open_run``) take from it.

``train`` writes config.json (``engine.report.run_config``): the ``TrainConfig`` fields plus what the
trainer decided. The fields a loader uses are declared once, here (``RECORD_FIELDS``): the writer checks
what it writes against them (``check_run_config``) and every reader reads through ``read_run_record``,
with the dataset reader's JSON rules (``contract.jsonfile``: a key written twice refused, a number too
long for a float read as inf and refused by name) and its near/far rules. The whole file stays in
``RunRecord.raw``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Sequence, Tuple

from nerf_core import contract
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.jsonfile import parse_json_file
from nerf_core.contract.numbers import is_number, is_whole
from nerf_core.contract.paths import file_problem, not_a_regular_file
from nerf_core.contract.poses import MAX_COORDINATE, coordinate_problem
from nerf_core.data.alpha import DEFAULT_ALPHA_WEIGHT
from nerf_core.data.batcher import DEFAULT_RAY_SAMPLING, RAY_SAMPLING, RECORDED_BEFORE_TRAIN_RAYS, TRAIN_RAYS
from nerf_core.data.depth import DEFAULT_DEPTH_WEIGHT
from nerf_core.data.validation import near_far_problem
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
        aabb: ((xmin, ymin, zmin), (xmax, ymax, zmax)) the scene box trained in, or None.
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
    aabb: Optional[Tuple[Tuple[float, ...], Tuple[float, ...]]]
    raw: dict

    def reach_problem(self, origins: Sequence) -> Optional[str]:
        """Why the recorded near/far keep every camera at ``origins`` (n, 3) from the scene box, or None:
        the dataset reader's rule (``data.validation.near_far_problem``), for the views a loader renders
        (before, ``eval`` scored empty renders with exit 0)."""
        if self.aabb is None:
            return None
        return near_far_problem(self.near, self.far, self.aabb, origins, f"{self.path}")


def _box(v) -> bool:
    return (isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(c, (list, tuple)) and len(c) == 3
                                                        and all(is_number(x) for x in c) for c in v)
            and all(lo < hi for lo, hi in zip(*v)) and coordinate_problem(v, "the box") is None)


def _distance(v) -> bool:
    return is_number(v) and v >= 0 and coordinate_problem([v], "") is None


# The fields of config.json a loader reads: name -> (what it must be, its test, whether null may stand
# for it). ``train`` writes each (``engine.report.run_config`` checks them with ``check_run_config``);
# a file written before a field existed may lack it (``read_run_record`` gives its default).
RECORD_FIELDS: Dict[str, Tuple[str, Callable[[Any], bool], bool]] = {
    "dataset": ("the dataset's path (a string)", lambda v: isinstance(v, str), True),
    # a number or list here would switch change detection off without a word (``runs.folder``)
    "dataset_hash": ("the hash of the dataset's transforms files (a string of hex digits)",
                     lambda v: isinstance(v, str) and bool(v) and all(c in "0123456789abcdef" for c in v), True),
    "method": ("the method's name (a string)", lambda v: isinstance(v, str) and bool(v.strip()), False),
    "downscale": ("a whole number >= 1", lambda v: is_whole(v) and v >= 1, False),
    "eval_background": ("an RGB colour: 3 numbers in [0, 1]",
                        lambda v: (isinstance(v, (list, tuple)) and len(v) == 3
                                   and all(is_number(c) and 0 <= c <= 1 for c in v)),
                        False),
    # the dataset reader's rules (``data.validation.scene_fields``): finite, >= 0, within float32's reach
    "near": (f"a number >= 0 within {MAX_COORDINATE:.0e} units (or null)", _distance, True),
    "far": (f"a number >= 0 within {MAX_COORDINATE:.0e} units (or null)", _distance, True),
    "aabb": ("the scene box: [[xmin, ymin, zmin], [xmax, ymax, zmax]] with each min below its max", _box, False),
}


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
        config = parse_json_file(cfg_path)  # the transforms files' reader: the same JSON rules
    except DatasetError as exc:
        raise RunError(str(exc)) from None
    if not isinstance(config, dict):
        raise RunError(f"{cfg_path}: expected the JSON object that `train` writes, got a {type(config).__name__}; "
                       f"is {run} a run folder?")
    check_run_config(config, cfg_path)
    box = config.get("aabb")
    return RunRecord(path=cfg_path, dataset=config.get("dataset") or None, dataset_hash=config.get("dataset_hash"),
                     method=config.get("method"), near=config.get("near"), far=config.get("far"),
                     eval_background=tuple(float(c) for c in config.get("eval_background", WHITE)),
                     downscale=int(config.get("downscale", 1)),
                     aabb=None if box is None else (tuple(map(float, box[0])), tuple(map(float, box[1]))), raw=config)


def check_run_config(config: dict, where) -> None:
    """Refuse (RunError naming ``where`` and the field) a value of ``RECORD_FIELDS`` that is not what
    ``train`` writes (an edited or damaged file; or, from the writer, a bug), and near/far that leave
    no sample between them."""
    for key, (want, ok, nullable) in RECORD_FIELDS.items():
        if key in config and not ((nullable and config[key] is None) or ok(config[key])):
            raise RunError(f"{where}: field {key!r} must be {want}, got {config[key]!r}")
    near, far = config.get("near"), config.get("far")
    if near is not None and far is not None and far <= near:  # each alone is fine; together no ray has samples
        raise RunError(f"{where}: field 'far' ({far}) must be greater than field 'near' ({near}); every view would "
                       "render empty")


def trained_with(config: dict) -> dict:
    """What a run's training used beyond the colours, from its config.json dict, for every score to
    carry (``eval``'s JSON and metrics.json, the benchmark tables): a score with depth supervision is
    not comparable with a colours-only peer's. Runs from before the flags trained without depth or
    alpha and through the pixel centres.

    Returns:
        {"depth": bool, "depth_weight": float or None (the weight used; None without depth),
         "train_rays": "centre" or "filter", "ray_sampling": "uniform" or "error",
         "alpha_weight": float (``--alpha-weight``; 0.0 = no alpha supervision)}.
    """
    depth = config.get("depth") is True
    weight = config.get("depth_weight")
    if depth and not is_number(weight):
        weight = DEFAULT_DEPTH_WEIGHT  # the flag was left out: the documented default was used
    rays, sampling, alpha = config.get("train_rays"), config.get("ray_sampling"), config.get("alpha_weight")
    return {"depth": depth, "depth_weight": float(weight) if depth else None,
            "train_rays": rays if rays in TRAIN_RAYS else RECORDED_BEFORE_TRAIN_RAYS,
            "ray_sampling": sampling if sampling in RAY_SAMPLING else DEFAULT_RAY_SAMPLING,
            "alpha_weight": float(alpha) if is_number(alpha) else DEFAULT_ALPHA_WEIGHT}
