"""docs/CONTRACTS.md in code: the rules that nerf_core, the add-on and the scripts must share.

Only the standard library and numpy: the Blender add-on imports this module (from the repository
or from the add-on's vendored copy of nerf_core) without torch, and a test imports it with torch
blocked. One home for each rule; nothing else spells these names out.

Sections:
- run folder paths (``RUN/config.json``, ``RUN/checkpoints/latest.pt``, ...);
- the training budget fraction;
- progress events (one JSON object per line) and strict JSON (``json_safe``: no NaN/inf).
Submodules (re-exported here, so ``contract.resolve_intrinsics`` works like ``contract.latest_checkpoint``):
- ``transforms``: reading transforms files (frames, the dataset path rule, splits);
- ``jsonfile``: the JSON of a transforms file; ``poses``: the one camera-matrix parser and its rules;
- ``errors``: ``DatasetError`` and ``PoseError``; ``paths``: why a path is not a readable file;
- ``intrinsics``: the one focal-length rule, ``resolve_intrinsics``;
- ``lens``: the lens models read (OPENCV, OPENCV_FISHEYE) and their fields, ``parse_lens``;
- ``naming``: the names of render outputs (de-duplicated) and evenly spaced view indices;
- ``film``: the ``pixel_filter`` field (the film filter a dataset's images were rendered through);
- ``camera_path``: nerfstudio's camera_path.json, read and written; ``camera_files``: the cameras of any
  transforms file (imported into Blender); ``nerfstudio_frame``: nerfstudio's dataparser transform;
- ``colmap_model``: COLMAP's sparse model files, read and written (``colmap_poses``: its pose rule);
  ``colmap_dataset``: a COLMAP folder as frames (the ``colmap`` layout) and our cameras as COLMAP's;
- ``eight_bit``: how a float colour becomes an 8-bit level, for both ways of rendering a run;
- ``world_file``: the world export's PNG and the text chunks it carries (read without Pillow);
- ``outputs``: the output rule (no link written through, no input replaced or deleted, no dataset file written).
"""
from __future__ import annotations

import json
import math
import os
import re
from typing import Any, Dict, Optional

# the add-on reaches them as contract.X; importing colmap_dataset registers the COLMAP layout
from . import (  # noqa: F401
    camera_files,
    camera_path,
    colmap_dataset,
    colmap_model,
    eight_bit,
    exports,
    nerfstudio_frame,
    outputs,
    world_file,
)
from .errors import DatasetError, PoseError  # noqa: F401
from .film import (  # noqa: F401
    DEFAULT_FILTER_KIND,
    DEFAULT_FILTER_WIDTH,
    FILTER_KINDS,
    film_filter_field,
    parse_film_filter,
)
from .intrinsics import (  # noqa: F401
    ANGLE_ONLY_LOADERS,
    angle_only_caveats,
    focal_from_fov,
    fov_from_focal,
    resolve_intrinsics,
)
from .jsonfile import read_json  # noqa: F401
from .lens import DISTORTION_KEYS, LENS_MODELS, Lens, parse_lens  # noqa: F401 (re-exported)
from .naming import (  # noqa: F401
    ERRORS_DIR,
    MAX_STEM_BYTES,
    MAX_STEM_CHARS,
    evenly_spaced,
    file_safe,
    frame_stem,
    output_stems,
    path_stem,
    render_files,
    unique_stems,
)
from .numbers import is_number
from .paths import IMAGE_EXTS, file_problem, why_not_a_file  # noqa: F401
from .poses import check_pose, parse_pose  # noqa: F401
from .transforms import (  # noqa: F401
    EXTRA_FIELDS,
    HOLDOUT_EVERY,
    INTRINSIC_KEYS,
    SPLITS,
    FrameInfo,
    depth_coverage,
    detect_layout,
    frame_infos,
    parse_intrinsics,
    read_frames,
    read_transforms,
    resolve_dataset_path,
    resolve_image,
)

# -- run folder -----------------------------------------------------------------------------------
CONFIG = "config.json"
PROGRESS = "progress.jsonl"
METRICS = "metrics.json"
CHECKPOINTS_DIR = "checkpoints"
LATEST_CHECKPOINT = "latest.pt"
PREVIEWS_DIR = "previews"
LOCK = ".lock"
WRITTEN_LIST = ".written.json"  # every file (relative path) the run's trainers wrote


def step_name(step: int, suffix: str) -> str:
    """``step_0001234.pt`` / ``step_0001234.png``: the one naming rule for per-step files."""
    return f"step_{int(step):07d}{suffix}"


def step_glob(suffix: str) -> str:
    """``step_*.pt``: the glob that lists per-step files (``pathlib.Path.glob``)."""
    return f"step_*{suffix}"


def step_name_pattern(suffix: str) -> str:
    """Regular expression (for ``re.fullmatch``) of exactly the names ``step_name(..., suffix)`` makes."""
    return r"step_\d{7}" + re.escape(suffix)


def config_path(run) -> str:
    return os.path.join(os.fspath(run), CONFIG)


def progress_path(run) -> str:
    return os.path.join(os.fspath(run), PROGRESS)


def metrics_path(run) -> str:
    return os.path.join(os.fspath(run), METRICS)


def checkpoints_dir(run) -> str:
    return os.path.join(os.fspath(run), CHECKPOINTS_DIR)


def latest_checkpoint(run) -> str:
    """``RUN/checkpoints/latest.pt`` (it may not exist)."""
    return os.path.join(os.fspath(run), CHECKPOINTS_DIR, LATEST_CHECKPOINT)


def step_checkpoint(run, step: int) -> str:
    return os.path.join(os.fspath(run), CHECKPOINTS_DIR, step_name(step, ".pt"))


def previews_dir(run) -> str:
    return os.path.join(os.fspath(run), PREVIEWS_DIR)


def preview_path(run, step: int) -> str:
    return os.path.join(os.fspath(run), PREVIEWS_DIR, step_name(step, ".png"))


# -- training budget ------------------------------------------------------------------------------
def budget_fraction(step: Optional[float], elapsed: Optional[float], max_steps: Optional[float],
                    max_seconds: Optional[float]) -> Optional[float]:
    """How much of the training budget is spent, in [0, 1]: the step or the time budget, whichever
    runs out first (the trainer stops at that one). None when no budget is known."""
    parts = []
    if max_steps and step is not None:
        parts.append(step / max_steps)
    if max_seconds and elapsed is not None:
        parts.append(elapsed / max_seconds)
    if not parts:
        return None
    value = max(parts)
    return min(1.0, max(0.0, value)) if math.isfinite(value) else None


# -- progress events ------------------------------------------------------------------------------
# (``progress``: an export's stages, nerf_core/cli/export.py; EventLog refuses a name not listed here)
EVENTS = ("start", "step", "preview", "rollback", "checkpoint", "eval", "done", "error", "note", "progress")


def parse_json_line(line: str) -> Optional[Dict[str, Any]]:
    """The JSON object on one line of a nerf_core command's stdout, or None for anything else (blank
    lines, library warnings, truncated JSON, a JSON value that is not an object). Events are such
    objects; so is the summary ``eval``/``render``/``check`` print as their last line."""
    line = line.strip()
    if not line.startswith("{"):
        return None
    try:
        obj = json.loads(line)
    except ValueError:
        return None
    return obj if isinstance(obj, dict) else None


def parse_event_line(line: str) -> Optional[Dict[str, Any]]:
    """The event object on one line of the trainer's stream, or None for anything else (what
    ``parse_json_line`` refuses, and JSON without a string ``event``)."""
    obj = parse_json_line(line)
    if obj is None or not isinstance(obj.get("event"), str):
        return None
    return obj


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, inf) inside dicts, lists and tuples replaced by None:
    ``json.dumps`` would write NaN/Infinity, which strict JSON readers (and JavaScript) reject."""
    if isinstance(value, float) and not is_number(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value
