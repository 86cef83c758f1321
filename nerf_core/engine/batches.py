"""What a run's steps train on, as its flags say: the batcher (``RadianceModel.make_batcher`` with the
``BatchOptions`` of ``--train-rays``, ``--depth``, ``--ray-sampling`` and ``--alpha-weight``), the checks
the dataset must pass for them before the run folder is made (``check_supervision``), what they add to
a step's loss (``with_supervision``), and for ``--depth`` the occupancy grid told at the start of the
run (and on ``--resume``, since the mark is not saved) which cells the capture's depth shows empty
(``data.carving.free_cells``)."""
from __future__ import annotations

import sys

import torch

from nerf_core.data.alpha import check_alpha, with_alpha_term
from nerf_core.data.batcher import Batcher, BatchOptions, RayBatch, footprint
from nerf_core.data.carving import free_cells
from nerf_core.data.depth import check_depth, depth_targets, with_depth_term
from nerf_core.data.split import Dataset, Split
from nerf_core.engine.config import TrainConfig
from nerf_core.errors import RunError
from nerf_core.methods.base import RadianceModel, ray_weights
from nerf_core.runs.events import EventLog


def check_supervision(dataset: Dataset, cfg: TrainConfig) -> None:
    """Refuse (DatasetError naming the flag) a dataset that cannot give what ``cfg``'s supervision
    flags ask for: missing, damaged or mis-scaled depth for ``--depth`` (``data.depth.check_depth``), no
    transparent film for ``--alpha-weight`` (``data.alpha.check_alpha``)."""
    if cfg.depth:
        check_depth(dataset, dataset.split("train"))
    if cfg.alpha_weight:
        check_alpha(dataset)


def training_batcher(model: RadianceModel, dataset: Dataset, cfg: TrainConfig, background: str,
                     gen: torch.Generator, device: torch.device, log: EventLog, is_main: bool, method: str) -> Batcher:
    """The batcher of a run over ``dataset``'s train split, as ``cfg`` says (``train_rays``, ``depth``,
    ``ray_sampling``, ``alpha_weight``); with ``--depth`` the model's occupancy grid is carved first
    (``carve_free_space``)."""
    train = dataset.split("train")
    if cfg.depth:
        carve_free_space(model, train, method, log, is_main)
    options = BatchOptions(footprint=footprint(dataset.pixel_filter, cfg.train_rays),
                           depth=depth_targets(train, model.aabb) if cfg.depth else None, sampling=cfg.ray_sampling,
                           alpha=bool(cfg.alpha_weight))
    return model.make_batcher(train, background, gen, device, options)


def with_supervision(loss: torch.Tensor, out: dict, batch: RayBatch, cfg: TrainConfig) -> torch.Tensor:
    """A step's ``loss`` () (the method's, from the colours) with the terms of ``--depth`` and
    ``--alpha-weight`` for ``batch`` and what the step rendered (``out``), each ray weighted as in the
    colour loss (``batch.weight``); ``loss`` itself for a colours-only run, so that it runs no op more.

    Raises RunError when the run asks for a term that the batch does not carry: a method's own batcher
    (``RadianceModel.make_batcher``) that ignores ``BatchOptions.depth`` or ``.alpha`` would otherwise
    train on colours alone while config.json says otherwise."""
    for flag, asked, carried in (("--depth", cfg.depth, batch.depth),
                                 ("--alpha-weight", cfg.alpha_weight, batch.alpha)):
        if asked and carried is None:
            raise RunError(f"{flag}: the method's batcher (make_batcher) gave a batch without it; the method "
                           "does not support the flag, so train without it")
    weight = ray_weights(out, batch.weight)
    loss = with_depth_term(loss, out, batch.depth, weight, cfg.depth_weight)
    return with_alpha_term(loss, out, batch.alpha, weight, cfg.alpha_weight)


def carve_free_space(model: RadianceModel, train: Split, method: str, log: EventLog, is_main: bool) -> None:
    """Mark the cells of ``model``'s occupancy grid that ``train``'s depth (v, h, w) shows empty, and
    say how much of the box that was (stderr on the main process, and a ``note`` event on ``log``)."""
    grid = model.occupancy_grid()
    if grid is None:
        msg = (f"--depth: method {method!r} has no occupancy grid over the scene box here (an unbounded run's "
               "grid spans the contracted world); the depth is used by the loss only, which on the ground demo "
               "scene made 0.42x the steps and cost 3.0 dB at 60 s")
    else:
        free = free_cells(grid.aabb, grid.resolution, train, train.depth)
        grid.mark_known_free(free)
        msg = (f"--depth: the occupancy grid starts with {float(free.float().mean()):.0%} of the box empty, "
               "as the train views' depth shows it")
    if is_main:
        print(f"train: {msg}", file=sys.stderr)
    log.emit("note", message=msg)
