"""Checkpoints of a run: writing them (atomic, keep-N), reading them safely, and loading a model.

* ``save_checkpoint`` writes ``RUN/checkpoints/step_XXXXXXX.pt`` then ``latest.pt``, each through a
  ``.tmp`` file and a rename, lists both in ``RUN/.written.json`` first, and keeps the newest
  ``keep`` step files.
* ``read_checkpoint`` loads with ``torch.load(weights_only=True)``: a checkpoint holds only tensors
  and plain Python data, and anything else is refused (``CheckpointRefused``) rather than run.
* ``load_run`` rebuilds the trained model for ``render`` and ``eval`` (``runs.weights``);
  ``read_resume_checkpoint`` picks what ``train --resume`` continues from.

File names come from ``nerf_core.contract``; the run folder's rules live in ``nerf_core.runs.folder``.
"""
from __future__ import annotations

import os
import pickle
import platform
import re
import sys
from pathlib import Path
from typing import Optional, Tuple

import numpy as np
import torch

from nerf_core import __version__, contract
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.jsonfile import parse_json_file
from nerf_core.contract.paths import file_problem
from nerf_core.errors import CheckpointRefused, RunError, TrainError
from nerf_core.methods.base import RadianceModel
from nerf_core.runs.checkpoint_checks import check_entries, nonfinite_weight
from nerf_core.runs.folder import (
    WRITTEN_LIST,
    os_reason,
    record_written,
    resume_candidates,
)
from nerf_core.runs.record import RunRecord, read_run_record
from nerf_core.runs.weights import first_line, model_from_checkpoint
from nerf_core.utils import arguments
from nerf_core.utils.atomic import atomic_file

# ----------------------------------------------------------------------------------------------
# reading


def _legacy_checkpoint_globals() -> list:
    """The only non-tensor globals a checkpoint written before checkpoints became weights-only may hold.

    Older trainers saved ``np.random.get_state()`` (a numpy array) and ``torch.__version__`` (a
    ``TorchVersion``, a ``str`` subclass). Unpickling those needs numpy's array and dtype
    reconstruction and that string class: data-only constructors that run no user code, so
    allowing them keeps old runs resumable without opening the door to arbitrary pickles.
    """
    from torch.torch_version import TorchVersion

    try:
        from numpy._core.multiarray import (
            _reconstruct as reconstruct,  # numpy 2 (and the alias in 1.26)
        )
    except ImportError:
        from numpy.core.multiarray import _reconstruct as reconstruct
    allowed = [np.ndarray, np.dtype, TorchVersion, reconstruct]
    if TorchVersion(torch.__version__) >= (2, 6):
        # numpy 1.x writes numpy.core..., numpy 2.x numpy._core...: one function under either name.
        # torch 2.5 takes no (function, name) pairs; there the function counts under its own name only.
        allowed += [(reconstruct, "numpy.core.multiarray._reconstruct"),
                    (reconstruct, "numpy._core.multiarray._reconstruct")]
    dtypes = getattr(np, "dtypes", None)  # numpy >= 1.25 pickles a dtype through its class (UInt32DType...)
    if dtypes is not None:
        allowed += [c for c in vars(dtypes).values() if isinstance(c, type) and issubclass(c, np.dtype)]
    return allowed


# What torch's weights-only unpickler says when a file needs something it will not build; any other
# unpickling error is a damaged file rather than a refused one.
_REFUSED = re.compile(r"GLOBAL (\S+) was not an allowed global|unsupported GLOBAL (\S+) whose module|"
                      r"reduce for unrecognized function (.+)|Can only create new object.* but got (.+)")


def read_checkpoint(path: Path) -> dict:
    """The checkpoint at ``path``, loaded so that it cannot run code (raises RunError naming the file).

    A ``.pt`` file is a pickle, and an unrestricted unpickle executes whatever the file asks for, so
    a crafted ``latest.pt`` would run code on ``eval``, ``render`` or ``train --resume``. The trainer
    writes only tensors and plain Python data, which ``torch.load(weights_only=True)`` accepts; the
    numpy state of older checkpoints is admitted through ``_legacy_checkpoint_globals`` and nothing else.
    """
    if path.is_dir():
        raise RunError(f"{path}: is a folder; give a checkpoint file such as "
                       f"{contract.CHECKPOINTS_DIR}/{contract.LATEST_CHECKPOINT}")
    problem = file_problem(path)
    if problem:
        raise RunError(f"{path}: checkpoint {problem}")
    kind = _file_kind(path)
    if kind is not None:
        raise RunError(f"{path}: not a checkpoint ({kind}); `python -m nerf_core train` writes "
                       f"{contract.CHECKPOINTS_DIR}/{contract.LATEST_CHECKPOINT}")
    try:
        with torch.serialization.safe_globals(_legacy_checkpoint_globals()):
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = _REFUSED.search(str(exc))
        if found is None:
            raise RunError(
                f"{path}: cannot read checkpoint (damaged or not a checkpoint: {_unpickler_detail(exc)})"
            ) from None
        what = next((g.strip() for g in found.groups() if g), "")
        raise CheckpointRefused(
            f"{path}: refused: the checkpoint contains code or objects that are not plain tensors and data"
            + (f" ({what})" if what else "")
            + "; it will not be loaded, because loading it could run that code. "
            "Use a checkpoint written by `python -m nerf_core train`."
        ) from None  # the unpickler's long advice to reload with weights_only=False must not reach the user
    except Exception as exc:  # truncated or foreign file
        raise RunError(f"{path}: cannot read checkpoint ({type(exc).__name__}: {first_line(exc)})") from exc
    if not isinstance(ckpt, dict):
        raise RunError(f"{path}: not a nerf_core checkpoint (holds a {type(ckpt).__name__}, not a dict)")
    return ckpt


def _unpickler_detail(exc: BaseException) -> str:
    """The unpickler's own complaint, without torch's advice around it (which suggests weights_only=False)."""
    text = str(exc).split("\n\nCheck the documentation")[0]
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else type(exc).__name__


# The first bytes of what ``torch.save`` writes: a zip archive (the default since torch 1.6), or the
# legacy format, which starts with a pickle protocol opcode.
_TORCH_MAGIC = (b"PK\x03\x04", b"\x80")


def _file_kind(path: Path) -> Optional[str]:
    """None when ``path`` starts like a file ``torch.save`` writes, else what it looks like instead
    (an empty file, text, another kind of file): a plainer message than torch's ``KeyError: 101``."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return None  # torch.load reports it, with the reason
    if not head:
        return "the file is empty"
    if head.startswith(_TORCH_MAGIC):
        return None
    try:
        head.decode("utf-8")
        return "it holds text"
    except UnicodeDecodeError:
        return "it is not a file written by torch.save"


def load_trained(run: Path | str, device: torch.device, checkpoint: Optional[Path | str] = None
                 ) -> Tuple[RadianceModel, RunRecord, dict]:
    """(model in eval mode, the run's typed record, checkpoint dict) of a run folder: what ``eval``,
    ``render``, ``serve`` and ``open_run`` start from.

    The record is RUN/config.json, checked (``runs.record``). The checkpoint is read safely
    (``torch.load(weights_only=True)``) and must belong to the run (same method, same dataset hash);
    the model is rebuilt from the checkpoint's method, options and scene box (``runs.weights``).

    Raises:
        RunError: a missing or unreadable run folder, config.json or checkpoint, a checkpoint of another
            run, or one whose model does not build.
        CheckpointRefused: a checkpoint that would need code to load (a crafted pickle).
    """
    run = Path(arguments.path("load_run", "run", run))
    if not isinstance(device, (torch.device, str)):
        raise TypeError(f"load_run: device must be a torch.device (or 'cpu', 'cuda'), got {device!r}")
    if checkpoint is not None:
        arguments.path("load_run", "checkpoint", checkpoint)
    record = read_run_record(run)
    ck = Path(checkpoint) if checkpoint else newest_checkpoint(run)
    ckpt = read_checkpoint(ck)
    _check_checkpoint_of_run(ckpt, record.raw, ck, run)
    return model_from_checkpoint(ckpt, device, str(ck)), record, ckpt


def load_run(run: Path | str, device: torch.device, checkpoint: Optional[Path | str] = None):
    """The older form of ``nerf_core.open_run``, kept for compatibility: (model in eval mode, config
    dict, checkpoint dict) of a run folder. New code uses ``open_run``, whose ``Run`` also renders
    views with the run's own near, far and background.

    Args:
        run: a run folder written by ``train`` (holds ``config.json`` and ``checkpoints/``).
        device: where the model goes, e.g. ``torch.device("cpu")``.
        checkpoint: a checkpoint file to load instead of ``RUN/checkpoints/latest.pt``.

    Returns:
        model: the trained ``RadianceModel`` in eval mode on ``device`` (``model.aabb``: (2, 3) float32).
        config: RUN/config.json as a dict: the ``TrainConfig`` fields plus what training decided
            (``near``, ``far``, ``eval_background``, ``aabb``, ...).
        ckpt: the checkpoint dict (``step``, ``method``, ``options``, ``aabb``, ``model`` weights, ``config``...).

    Raises:
        RunError: a missing or unreadable run folder, config.json or checkpoint, a checkpoint of another
            run, or one whose model does not build.
        CheckpointRefused: a checkpoint that would need code to load (a crafted pickle).
    """
    model, record, ckpt = load_trained(run, device, checkpoint)
    return model, record.raw, ckpt


def check_checkpoint_of_run(ckpt: dict, ck: Path, run: Path) -> None:
    """Refuse (RunError) a checkpoint that another run wrote, judged by RUN/config.json when the run has
    one: ``train --resume`` must not continue (and rewrite config.json to) another run's method."""
    cfg_path = Path(contract.config_path(run))
    if not cfg_path.exists():
        return  # no config.json: the checkpoint's own record is all there is
    try:
        config = parse_json_file(cfg_path)  # the record's reader (``runs.record``): the same JSON rules
    except DatasetError as exc:
        raise RunError(str(exc)) from None
    if isinstance(config, dict):
        _check_checkpoint_of_run(ckpt, config, ck, run)


def newest_checkpoint(run: Path) -> Path:
    """RUN/checkpoints/latest.pt, or, when it is gone (a full disk cost it) but a complete step file is
    there, the newest step_*.pt, as ``train --resume`` would take (a note says so on stderr)."""
    latest = Path(contract.latest_checkpoint(run))
    if os.path.lexists(latest):
        return latest
    steps = [p for p in resume_candidates(run) if p != latest]
    if not steps:
        return latest  # read_checkpoint names it as missing
    print(f"note: {latest} is missing; using the newest complete checkpoint, {steps[0].name}", file=sys.stderr)
    return steps[0]


def _check_checkpoint_of_run(ckpt: dict, config: dict, ck: Path, run: Path) -> None:
    """Refuse (RunError) a checkpoint that another run wrote: another method, or another dataset.

    ``eval RUN --checkpoint C`` and ``render RUN --checkpoint C`` apply RUN's config.json to C (near
    and far, the evaluation background, the dataset) and ``eval`` writes C's scores into RUN's
    metrics.json, so a checkpoint of another run would be scored against the wrong data and filed
    under the wrong run. An older checkpoint of the same run, or one of a moved run folder, passes.
    """
    record = ckpt.get("config") if isinstance(ckpt.get("config"), dict) else {}
    mine, theirs = config.get("method"), ckpt.get("method")
    problems = []
    if isinstance(mine, str) and isinstance(theirs, str) and mine != theirs:
        problems.append(f"method {theirs!r}, where {run} trained {mine!r}")
    want, have = config.get("dataset_hash"), record.get("dataset_hash")
    if isinstance(want, str) and isinstance(have, str) and want != have:
        problems.append(f"another dataset ({record.get('dataset', 'unknown')})")
    if problems:
        origin = record.get("out")
        raise RunError(f"{ck}: this checkpoint belongs to another run" + (f" ({origin})" if origin else "")
                       + ": " + "; ".join(problems) + f". {run}'s settings and metrics would be applied to it; "
                       "evaluate or render it through its own run folder")


def read_resume_checkpoint(run: Path) -> tuple[Path, dict]:
    """(path, checkpoint) that ``--resume`` continues from: latest.pt, else the newest step_*.pt that
    loads (a full disk may have cost latest.pt). A refused checkpoint stops the search (RunError)."""
    failures = []
    for path in resume_candidates(run):
        try:
            ckpt = read_checkpoint(path)
        except CheckpointRefused:
            raise  # a crafted checkpoint is an alarm, not damage to route around
        except RunError as exc:
            failures.append(str(exc))
            continue
        try:
            check_entries(ckpt, str(path), for_resume=True)
            check_checkpoint_of_run(ckpt, path, run)
        except RunError as exc:
            failures.append(str(exc))
            continue
        if failures or path.name != contract.LATEST_CHECKPOINT:
            latest = f"{contract.CHECKPOINTS_DIR}/{contract.LATEST_CHECKPOINT}"
            print(f"train: resuming from {path}" + (f" ({failures[0]})" if failures else f" ({latest} is missing)"),
                  file=sys.stderr)
        return path, ckpt
    raise RunError(failures[0] if len(failures) == 1 else
                   f"{contract.checkpoints_dir(run)}: no checkpoint loads: " + "; ".join(failures))


# ----------------------------------------------------------------------------------------------
# writing


def versions() -> dict:
    """Library versions recorded in config.json and in every checkpoint, as plain ``str``."""
    # str(): torch.__version__ is a TorchVersion, a class the weights-only checkpoint loader refuses.
    return {"nerf_core": str(__version__), "torch": str(torch.__version__), "numpy": str(np.__version__),
            "python": platform.python_version()}


def atomic_torch_save(obj, path: Path) -> None:
    """Write ``path`` through a new temporary file and a rename (``utils.atomic``: never through a
    link). On failure (a full disk) the temporary file is removed, ``path`` keeps its previous content,
    and TrainError names the file and the cause."""
    try:
        with atomic_file(path) as fh:
            torch.save(obj, fh)
    except (OSError, RuntimeError) as exc:  # torch.save reports a failed write as RuntimeError too
        raise TrainError(f"{path}: cannot write checkpoint: {os_reason(exc)}") from None


def save_checkpoint(run: Path, state: dict, step: int, keep: int) -> Path:
    """Write ``state`` as ``RUN/checkpoints/step_XXXXXXX.pt`` and ``latest.pt``; returns latest's path.

    Both names are recorded in ``RUN/.written.json`` before either is written. The step file goes
    first: when ``latest.pt`` cannot be written, a complete step file still is (``--resume`` uses it).
    Only the newest ``keep`` step files are kept. Raises TrainError naming the file that failed.
    """
    bad = nonfinite_weight(state.get("model", {}))
    if bad is not None:  # a damaged model must not replace the last good checkpoint, nor end as "done"
        raise TrainError(f"the model's weight {bad!r} turned NaN or infinite by step {step}; nothing was saved "
                         f"over the last good checkpoint. The method's options (--set) or --lr are beyond what "
                         "float32 holds: lower them and start again")
    ck = Path(contract.checkpoints_dir(run))
    ck.mkdir(parents=True, exist_ok=True)
    step_path = Path(contract.step_checkpoint(run, step))
    latest = Path(contract.latest_checkpoint(run))
    try:
        record_written(run, step_path, latest)
    except OSError as exc:
        raise TrainError(f"{run / WRITTEN_LIST}: cannot write: {os_reason(exc)}") from None
    atomic_torch_save(state, step_path)
    atomic_torch_save(state, latest)
    olds = sorted(ck.glob(contract.step_glob(".pt")))
    for p in olds[: max(0, len(olds) - keep)]:
        p.unlink()
    return latest
