"""What a training checkpoint holds and how it is written, apart from the trainer: ``RunFacts`` (what
a run records of itself in config.json and in every checkpoint) and ``write_checkpoint``. The
schedule (when to write one) belongs to ``callbacks.CheckpointEvery``; an interrupted run writes its
last one through the same callback.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch

from nerf_core.data.split import Dataset
from nerf_core.engine.report import run_config
from nerf_core.engine.state import RunDecisions, TrainState
from nerf_core.methods.base import RadianceModel
from nerf_core.optim import TrainingOptimizer
from nerf_core.runs.checkpoints import save_checkpoint, versions
from nerf_core.utils.seeding import rng_state


@dataclass(frozen=True)
class RunFacts:
    """What a run is, fixed once it starts: its config, decisions, dataset and where it runs.

    ``config(model)`` is RUN/config.json's content (``report.run_config``) for the model as it is now
    (its size grows while training, so every checkpoint asks again)."""

    cfg: object  # the run's TrainConfig (after --resume's merge)
    decisions: RunDecisions
    dataset: Dataset
    run: Path
    device: torch.device
    world_size: int
    dataset_hash: Optional[str]
    dataset_images: Optional[dict]

    def config(self, model: RadianceModel) -> dict:
        return run_config(self.cfg, self.decisions, model, self.dataset, self.run, self.device, self.world_size,
                          self.dataset_hash, self.dataset_images)


def write_checkpoint(facts: RunFacts, model: RadianceModel, opt: TrainingOptimizer, state: TrainState,
                     gen: torch.Generator, log) -> Path:
    """Write RUN/checkpoints/step_*.pt and latest.pt (``runs.checkpoints.save_checkpoint``) with
    everything ``--resume`` continues from, and emit a ``checkpoint`` event on ``log``; returns latest.pt."""
    record = {
        "format": 1, "method": facts.decisions.method, "options": model.options,
        "method_state": model.run_state(), "aabb": model.aabb.detach().cpu(),
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "optimizer": opt.state_dict(), **state.checkpoint_entries(),
        "rng": rng_state(gen), "config": facts.config(model), "size_reasons": facts.decisions.size_reasons,
        "versions": versions(),
    }
    latest = save_checkpoint(facts.run, record, state.step, facts.cfg.keep_checkpoints)
    log.emit("checkpoint", step=state.step, path=str(latest))
    return latest
