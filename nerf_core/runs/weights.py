"""Loading a checkpoint's weights into a model: one ``load_weights`` for every loader (``eval``,
``render``, ``serve``, ``open_run``) and for ``train --resume``, and the checks before it.

The order is the same everywhere: upgrade an older version's layout, take back the run state (the
grown grid's size), check every weight against the model, resize what grew, load.
"""
from __future__ import annotations

from typing import Dict, Optional

import torch

from nerf_core.errors import RunError
from nerf_core.methods.base import RadianceModel
from nerf_core.methods.registry import build_model, saved_options, saved_run_state
from nerf_core.runs.checkpoint_checks import check_entries, check_weights


def load_state_resizing(model: torch.nn.Module, state: Dict[str, torch.Tensor]) -> None:
    """``load_state_dict`` that copes with parameters whose saved shape differs from a fresh build.

    Methods that grow during training (coarse-to-fine grids) are rebuilt at their initial size by
    ``build_model``. A method may handle that in its own ``load_state_dict``; otherwise the
    mismatched tensors are resized to the saved shapes before loading.
    """
    try:
        model.load_state_dict(state)
        return
    except RuntimeError as exc:
        if "size mismatch" not in str(exc):
            raise
    own = dict(model.named_parameters())
    own.update(dict(model.named_buffers()))
    for key, value in state.items():
        cur = own.get(key)
        if cur is not None and cur.shape != value.shape:
            cur.data = torch.empty(value.shape, dtype=cur.dtype, device=cur.device)
    model.load_state_dict(state)


def load_weights(model: RadianceModel, ckpt: dict, where: str = "checkpoint") -> Optional[dict]:
    """Load a checkpoint's weights into ``model``, a fresh build of the checkpoint's method and options.

    Upgrades an older layout (``model.upgrade_checkpoint``), takes back the run state
    (``model.restore_run_state``), checks names, shapes, dtypes and values (``check_weights``), then
    loads, resizing what grew.

    Args:
        model: the model built from the checkpoint's ``method``, ``options`` and ``aabb``.
        ckpt: the checkpoint dict (``model``: name -> tensor; optional ``optimizer``, ``method_state``).
        where: the file, for messages.

    Returns:
        the checkpoint's optimiser state in this version's layout, or None when it holds none.

    Raises:
        RunError: weights that are not a dict of tensors, or that do not fit the model.
    """
    weights = checked_weights(ckpt, where)
    weights, opt_state = model.upgrade_checkpoint(weights, ckpt.get("optimizer"))
    try:
        model.restore_run_state(saved_run_state(model.method_name, ckpt))
    except ValueError as exc:
        raise RunError(f"{where}: entry 'method_state': {exc}") from exc
    check_weights(model, weights, where)  # nothing mis-shaped or NaN reaches the model
    load_state_resizing(model, weights)
    return opt_state


def checked_weights(ckpt: dict, where: str) -> dict:
    """The checkpoint's ``model`` entry when it is a dict of tensors (RunError naming ``where`` otherwise)."""
    weights = ckpt.get("model")
    if not (isinstance(weights, dict) and all(isinstance(v, torch.Tensor) for v in weights.values())):
        raise RunError(f"{where}: entry 'model' must be the model's weights (a dict of tensors), "
                       f"got a {type(weights).__name__}")
    return weights


def model_from_checkpoint(ckpt: dict, device: torch.device, where: str = "checkpoint") -> RadianceModel:
    """The checkpoint's model, rebuilt with ``build_model`` and its weights (``load_weights``), in eval
    mode on ``device`` (raises RunError naming ``where`` when the checkpoint does not describe a model
    that builds)."""
    for key in ("method", "options", "aabb", "model"):
        if key not in ckpt:
            raise RunError(f"{where}: missing entry {key!r} (not a nerf_core checkpoint?)")
    method, options, aabb = ckpt["method"], ckpt["options"], ckpt["aabb"]
    # A foreign or edited checkpoint must fail here, by name, not deep inside torch with a TypeError.
    if not isinstance(method, str):
        raise RunError(f"{where}: entry 'method' must be a method name, got a {type(method).__name__}")
    if not (isinstance(options, dict) and all(isinstance(k, str) for k in options)):
        raise RunError(f"{where}: entry 'options' must be a dict of the method's options, "
                       f"got a {type(options).__name__}")
    try:
        box = torch.as_tensor(aabb, dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError, OverflowError):
        box = None
    if box is None or box.shape != (2, 3) or not bool(torch.isfinite(box).all()):
        raise RunError(f"{where}: entry 'aabb' must be the scene box, 2 x 3 finite numbers (min, max)")
    checked_weights(ckpt, where)  # before the build: a foreign file fails by name, with no work done
    check_entries(ckpt, where)
    try:
        model = build_model(method, box, **saved_options(method, options))
        load_weights(model, ckpt, where)
    except ValueError as exc:  # unknown method name, or an option value the method refuses
        raise RunError(f"{where}: {exc}") from exc
    except TypeError as exc:  # an option the method does not take
        raise RunError(f"{where}: entry 'options' does not fit method {method!r}: {first_line(exc)}") from exc
    except (RuntimeError, KeyError) as exc:
        raise RunError(f"{where}: the saved weights do not fit method {method!r}: {first_line(exc)}") from exc
    return model.to(device).eval()


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, without torch's advice paragraph after it."""
    lines = [ln for ln in str(exc).splitlines() if ln.strip()]
    line = lines[0] if lines else type(exc).__name__
    return line.split(". This is an internal miniz error")[0]  # torch's paragraph on corrupted zips
