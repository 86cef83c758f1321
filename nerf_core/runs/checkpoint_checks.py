"""The one validator of what a checkpoint holds, against what it loads into.

``torch.load(weights_only=True)`` (``checkpoints.read_checkpoint``) guarantees that a file runs no
code; it says nothing about whether its tensors fit. A mis-shaped Adam moment reaches the fused
optimiser, which writes out of bounds (a segfault or heap corruption); mis-shaped or NaN weights end
in a matmul traceback or in scores of a broken model. So every reader (``load_run`` for ``render``,
``eval`` and ``serve``; the resume reader and the trainer for ``train --resume``) passes through here:

- ``check_entries``: every scalar entry (step, elapsed, learning-rate scale, rollbacks, the loss
  average, the RNG state, the optimiser's layout) is of the kind and range the trainer writes;
- ``check_weights``: every weight has the name, dtype and shape of the model it loads into (shapes
  may differ only where the method declares growth, ``RadianceModel.growing``), and is finite;
- the optimiser's state is checked by the optimiser itself (``nerf_core.optim.TrainingOptimizer.check_state``),
  which alone knows its layout.

Each problem is a RunError naming the file and the entry.
"""
from __future__ import annotations

from typing import Dict

import torch

from nerf_core.contract.numbers import is_number, is_whole
from nerf_core.errors import RunError
from nerf_core.methods.base import MAX_GRID_RES, RadianceModel

RNG_KEYS = ("python", "numpy", "torch", "batches")


def _whole(value, least: int) -> bool:
    return is_whole(value) and value >= least


def _finite(value, least: float = 0.0, inclusive: bool = True) -> bool:
    if not is_number(value):
        return False
    return value >= least if inclusive else value > least


def _byte_state(value) -> bool:
    return isinstance(value, torch.Tensor) and value.dtype == torch.uint8 and value.dim() == 1


def check_rng(rng, where: str) -> None:
    """The RNG state ``seeding.rng_state`` writes: python's tuple, numpy's dict, torch's byte tensors."""
    if not isinstance(rng, dict) or any(k not in rng for k in RNG_KEYS):
        missing = [k for k in RNG_KEYS if not isinstance(rng, dict) or k not in rng]
        raise RunError(f"{where}: entry 'rng' must hold the random states {list(RNG_KEYS)}; missing {missing}")
    py = rng["python"]
    if not (isinstance(py, tuple) and len(py) == 3 and isinstance(py[1], tuple)
            and all(isinstance(v, int) for v in py[1])):
        raise RunError(f"{where}: entry 'rng' field 'python' is not the state of python's random module")
    nps = rng["numpy"]
    if isinstance(nps, dict):
        key = nps.get("key")
        if not (isinstance(key, torch.Tensor) and key.shape == (624,) and not key.is_floating_point()
                and isinstance(nps.get("bit_generator"), str) and _whole(nps.get("pos"), 0) and nps["pos"] <= 624
                and isinstance(nps.get("has_gauss"), int) and isinstance(nps.get("cached_gaussian"), float)):
            raise RunError(f"{where}: entry 'rng' field 'numpy' is not the state of numpy's random generator")
    elif not isinstance(nps, tuple):  # checkpoints older than the weights-only format kept numpy's tuple
        raise RunError(f"{where}: entry 'rng' field 'numpy' is not the state of numpy's random generator")
    for key in ("torch", "batches"):
        if not _byte_state(rng[key]):
            raise RunError(f"{where}: entry 'rng' field {key!r} must be a generator state (a 1-D uint8 tensor)")


def check_entries(ckpt: dict, where: str, for_resume: bool = False) -> None:
    """Refuse (RunError naming ``where`` and the entry) scalar entries the trainer would not write.

    Args:
        ckpt: the checkpoint dict (from ``read_checkpoint``).
        where: the file, for messages.
        for_resume: also require what ``train --resume`` continues from (step, elapsed, the RNG state,
            the optimiser's state).
    """
    def bad(key, want):
        raise RunError(f"{where}: entry {key!r} must be {want}, got {ckpt[key]!r:.80}")

    needed = ("step", "elapsed", "rng", "optimizer") if for_resume else ()
    missing = [k for k in needed if k not in ckpt]
    if missing:
        raise RunError(f"{where}: missing entries {missing}; `train --resume` needs a checkpoint written by `train`")
    if "format" in ckpt and not (_whole(ckpt["format"], 1) and ckpt["format"] == 1):
        bad("format", "1 (the only checkpoint format there is)")
    if "step" in ckpt and not _whole(ckpt["step"], 0):
        bad("step", "a whole number >= 0")
    if "elapsed" in ckpt and not _finite(ckpt["elapsed"]):
        bad("elapsed", "a finite number of seconds >= 0")
    if "lr_scale" in ckpt and not (_finite(ckpt["lr_scale"], 0.0, inclusive=False) and ckpt["lr_scale"] <= 1):
        bad("lr_scale", "a number in (0, 1]")
    if "rollbacks" in ckpt and not _whole(ckpt["rollbacks"], 0):
        bad("rollbacks", "a whole number >= 0")
    if ckpt.get("loss_ema") is not None and not _finite(ckpt["loss_ema"]):
        bad("loss_ema", "a finite number >= 0 or null")
    if "config" in ckpt and not isinstance(ckpt["config"], dict):
        bad("config", "the run's config (a dict)")
    if "rng" in ckpt:
        check_rng(ckpt["rng"], where)
    if "optimizer" in ckpt:
        opt = ckpt["optimizer"]
        if not (isinstance(opt, dict) and isinstance(opt.get("state"), dict)
                and isinstance(opt.get("param_groups"), list)
                and all(isinstance(g, dict) and isinstance(g.get("params"), list) for g in opt["param_groups"])):
            raise RunError(f"{where}: entry 'optimizer' must be an optimiser's state_dict "
                           "({'state': {...}, 'param_groups': [...]})")


def _fits_growth(saved: torch.Size, fresh: torch.Size, grid_dims) -> bool:
    """A grown grid: the same number of dimensions, the same sizes outside ``grid_dims`` (channels), and
    each size along ``grid_dims`` within the grid limits."""
    return (len(saved) == len(fresh)
            and all(s == f for d, (s, f) in enumerate(zip(saved, fresh)) if d not in grid_dims)
            and all(1 <= saved[d] <= MAX_GRID_RES + 1 for d in grid_dims))  # +1: grids store their corners


def _growing(model) -> dict:
    """The model's ``growing`` as name -> grid dimensions (a plain tuple of names: all dims after the
    first two, as (3, C, H, W) planes grow)."""
    growing = model.growing
    if isinstance(growing, dict):
        return {k: tuple(v) for k, v in growing.items()}
    return {name: None for name in growing}


def nonfinite_weight(weights: Dict[str, torch.Tensor]) -> str | None:
    """The name of the first floating-point tensor of ``weights`` holding NaN or inf, else None: what
    a checkpoint must never be written with (the loaders refuse it as damaged)."""
    for name, value in weights.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(torch.isfinite(value).all()):
            return name
    return None


def check_weights(model: RadianceModel, weights: Dict[str, torch.Tensor], where: str) -> None:
    """Refuse (RunError) weights that do not fit ``model``: names, dtypes, shapes, finite values.

    Args:
        model: a freshly built model of the checkpoint's method and options.
        weights: the checkpoint's ``model`` entry, name -> tensor.
        where: the file, for messages.
    """
    own = model.state_dict()
    missing = sorted(set(own) - set(weights))
    unexpected = sorted(set(weights) - set(own))
    if missing or unexpected:
        raise RunError(f"{where}: the saved weights do not fit method {model.method_name!r}: "
                       + (f"missing {missing[:4]}" if missing else "")
                       + ("; " if missing and unexpected else "")
                       + (f"unexpected {unexpected[:4]}" if unexpected else ""))
    growing = _growing(model)
    for name, value in weights.items():
        fresh = own[name]
        if value.dtype != fresh.dtype:
            raise RunError(f"{where}: weight {name!r} is {value.dtype}, the model holds {fresh.dtype}")
        dims = growing.get(name) or tuple(range(2, fresh.dim()))
        if value.shape != fresh.shape and not (name in growing and _fits_growth(value.shape, fresh.shape, dims)):
            raise RunError(f"{where}: weight {name!r} has shape {tuple(value.shape)}; the model holds "
                           f"{tuple(fresh.shape)}" + (" (a grid may grow, but not so)" if name in growing else ""))
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise RunError(f"{where}: weight {name!r} holds NaN or infinite values; the model would render "
                           "nothing meaningful (a damaged checkpoint, or training that diverged)")
    # The grids of a model grow together (one resolution): every growing dimension of every grown weight
    # has the same size. A checkpoint with non-square planes, or planes and lines of two sizes, is refused
    # here rather than indexed out of bounds later.
    sizes = {(name, d): int(weights[name].shape[d]) for name, dims in growing.items() if name in weights
             for d in (dims or range(2, weights[name].dim())) if d < weights[name].dim()}
    if len(set(sizes.values())) > 1:
        shown = ", ".join(f"{name} dim {d}: {n}" for (name, d), n in list(sizes.items())[:6])
        raise RunError(f"{where}: the grids must all have one resolution, got {shown}")
