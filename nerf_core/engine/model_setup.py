"""The model a training run starts from: its options (``--set``, ``--size auto``, a resumed
checkpoint's, ``unbounded`` when the scene reaches past its box, a learned world for opaque images),
the seeded build, and the rays per step.
"""
from __future__ import annotations

import time
from typing import List, Optional, Tuple

import torch

from nerf_core.data.scene_box import beyond_box_reason
from nerf_core.data.split import Dataset, Split
from nerf_core.errors import TrainError
from nerf_core.fields.environment import prefit_from_split, size_for_focal
from nerf_core.methods.base import RadianceModel
from nerf_core.methods.registry import build_model, has_option, saved_options
from nerf_core.methods.sizing import auto_size_dataset
from nerf_core.runs.weights import load_weights
from nerf_core.utils.seeding import seed_everything

# A CPU step costs in proportion to its rays; a GPU step at these sizes mostly costs kernel launches,
# so 4x the rays cost few steps. 30 s on an H100 (multi, 200 px, 5 test views): vmgrid 2048 rays
# 38.31 dB (2998 steps) against 8192 rays 38.78 dB (2504); nerf 1024 rays 31.90 dB (3101) against
# 4096 rays 32.63 dB (2272).
CUDA_BATCH_SCALE = 4


def model_options(cfg, method: str, dataset: Dataset, ckpt: Optional[dict],
                  bg_mode: str) -> Tuple[dict, torch.Tensor, List[str]]:
    """The options and scene box to build ``method`` with, and the reasons for the sizes chosen.

    Args:
        cfg: the run's ``TrainConfig`` (``size``, ``options``, ``background``).
        method: the method's registered name.
        dataset: the loaded dataset (its ``aabb`` (2, 3) and train split).
        ckpt: a checkpoint to resume (its options and box win), or None.
        bg_mode: the background training uses ("environment" adds a learned world).
    Returns:
        (options, aabb (2, 3) float32, size reasons: one line each, for the ``start`` event).
    Raises:
        TrainError for a ``--size`` other than auto.
    """
    if ckpt is not None:
        return saved_options(method, ckpt["options"]), torch.as_tensor(ckpt["aabb"]), list(ckpt.get("size_reasons", []))
    reasons: List[str] = []
    options: dict = {}
    if cfg.size == "auto":
        black = [0.0, 0.0, 0.0] if cfg.background == "black" else [1.0, 1.0, 1.0]
        options, reasons = auto_size_dataset(method, dataset, black)
    elif cfg.size not in (None, "", "default"):
        raise TrainError(f"--size {cfg.size!r}: only 'auto' is supported")
    options.update(cfg.options)
    unbounded_if_beyond_box(method, dataset, bg_mode, options, reasons)
    if bg_mode == "environment" and "environment" not in options:
        options["environment"] = {"width": size_for_focal(float(dataset.split("train").cameras.fx.median()))}
    return options, dataset.aabb, reasons


def unbounded_if_beyond_box(method: str, dataset: Dataset, bg_mode: str, options: dict, reasons: List[str]) -> None:
    """Turn on ``unbounded`` for a method that has it (and was not told) when the scene reaches past
    its box (``scene_box.beyond_box_reason``: the dataset says so, or a cut-out's opaque pixels look
    past the box). On the capture's floor scene, 3 minutes of vmgrid: 15.7 dB without and 28.7 dB
    with on a transparent film; 24.8 and 28.0 dB on an opaque one (the learned environment cannot
    hold a floor). Adds to ``options`` and ``reasons`` in place."""
    if "unbounded" in options or not has_option(method, "unbounded"):
        return
    why = beyond_box_reason(dataset, bg_mode)
    if why:
        options["unbounded"] = True
        reasons.append(f"unbounded=true: {why}, so the world beyond the box is modelled too "
                       "(--set unbounded=false turns it off)")


def build_seeded(method: str, aabb: torch.Tensor, options: dict, seed: int, ckpt: Optional[dict],
                 where: str = "checkpoint") -> Tuple[RadianceModel, Optional[dict]]:
    """Seed every generator with ``seed``, build ``method`` and load a resumed checkpoint's weights
    (``runs.weights.load_weights``, the loaders' own).

    Returns:
        (the model, on the CPU; the checkpoint's optimiser state in this version's layout, or None).
        Raises TrainError naming options the method refuses.
    """
    seed_everything(seed)
    try:
        model = build_model(method, aabb, **options)
    except TypeError as exc:
        raise TrainError(f"method {method!r} does not accept these options {sorted(options)}: {exc}") from exc
    except ValueError as exc:  # unknown method or option values the method rejects
        raise TrainError(str(exc)) from exc
    opt_state = load_weights(model, ckpt, where) if ckpt is not None else None
    return model, opt_state


def default_batch_rays(model: RadianceModel, device: torch.device) -> int:
    """Rays per step when ``--batch-rays`` is not given: the method's ``default_batch_rays``,
    ``CUDA_BATCH_SCALE`` times that on a CUDA device."""
    base = int(model.default_batch_rays)
    return base * CUDA_BATCH_SCALE if device.type == "cuda" else base


def prefit_environment(model: RadianceModel, train: Split, near, far, gen: torch.Generator,
                       device: torch.device) -> Tuple[str, float, float]:
    """Fit the model's learned world to the train rays that miss the scene box, before the first step.

    Returns:
        (a note saying how many rays missed, their share, the seconds it took: training time)."""
    started = time.perf_counter()
    msg, share = prefit_from_split(model, train, near, far, gen, device)
    return msg, share, time.perf_counter() - started
