"""What a run's steps train on, as its flags say: the batcher (``RadianceModel.make_batcher`` with the
``BatchOptions`` of ``--train-rays``, ``--depth`` and ``--ray-sampling``), and for ``--depth`` the
occupancy grid told at the start of the run (and on ``--resume``, since the mark is not saved) which
cells the capture's depth shows empty (``data.carving.free_cells``)."""
from __future__ import annotations

import sys

import torch

from nerf_core.data.batcher import Batcher, BatchOptions, footprint
from nerf_core.data.carving import free_cells
from nerf_core.data.depth import depth_targets
from nerf_core.data.split import Dataset, Split
from nerf_core.engine.config import TrainConfig
from nerf_core.methods.base import RadianceModel
from nerf_core.runs.events import EventLog


def training_batcher(model: RadianceModel, dataset: Dataset, cfg: TrainConfig, background: str,
                     gen: torch.Generator, device: torch.device, log: EventLog, is_main: bool, method: str) -> Batcher:
    """The batcher of a run over ``dataset``'s train split, as ``cfg`` says (``train_rays``, ``depth``,
    ``ray_sampling``); with ``--depth`` the model's occupancy grid is carved first (``carve_free_space``)."""
    train = dataset.split("train")
    if cfg.depth:
        carve_free_space(model, train, method, log, is_main)
    options = BatchOptions(footprint=footprint(dataset.pixel_filter, cfg.train_rays),
                           depth=depth_targets(train) if cfg.depth else None, sampling=cfg.ray_sampling)
    return model.make_batcher(train, background, gen, device, options)


def carve_free_space(model: RadianceModel, train: Split, method: str, log: EventLog, is_main: bool) -> None:
    """Mark the cells of ``model``'s occupancy grid that ``train``'s depth (v, h, w) shows empty, and
    say how much of the box that was (stderr on the main process, and a ``note`` event on ``log``)."""
    grid = model.occupancy_grid()
    if grid is None:
        msg = (f"--depth: method {method!r} has no occupancy grid over the scene box here; "
               "the depth is used by the loss only")
    else:
        free = free_cells(grid.aabb, grid.resolution, train, train.depth)
        grid.mark_known_free(free)
        msg = (f"--depth: the occupancy grid starts with {float(free.float().mean()):.0%} of the box empty, "
               "as the train views' depth shows it")
    if is_main:
        print(f"train: {msg}", file=sys.stderr)
    log.emit("note", message=msg)
