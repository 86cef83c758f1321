"""Keeping the model copies of a ``torchrun`` job identical, step after step.

Every rank holds a full copy of the model and its optimiser. They stay bitwise equal because every
input to every update is equal on all ranks:

* gradients: averaged over the ranks (``distributed.average_gradients``);
* the training hook (occupancy-grid updates, coarse-to-fine growth): a deterministic function of
  the parameters, the step and the budget fraction, plus random jitter (the occupancy grid's cell
  samples). The jitter is drawn from a torch RNG seeded identically on every rank for that step
  (``seed_shared``), so every rank computes the same grid and grows at the same step;
* statistics a method keeps from its own training batches (``RadianceModel.replica_stats``, e.g.
  vmgrid's running opacity that decides when geometry counts as "formed"): averaged over the
  ranks every step. Being running means (EMAs), the average of the ranks' means is the mean over
  all ranks' rays;
* the decisions the trainer takes from the loss or the clock: the loss (and PSNR) reported and
  compared against its running average is the mean over the ranks; the elapsed training time is
  the largest of the ranks' (so a time budget stops every rank at the same step); a stop request
  (SIGINT/SIGTERM on any rank) and rank 0's wall-clock checkpoint timer travel in the same reduce.
  A NaN on one rank makes the averaged loss or gradient NaN on all, so every rank rolls back
  together.

Each rank draws its own rays: the batch generator and torch's global RNG (render jitter) are
re-seeded every step from (seed, rank, step, rollbacks) (``seed_rank``). A run is therefore
deterministic for a step budget and ``--resume`` continues the same streams without storing
per-rank RNG states: they follow from the step counter the checkpoint holds.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import torch

from nerf_core.engine import distributed
from nerf_core.engine.distributed import Context


@dataclass
class Shared:
    """What one step's reduce agreed on (equal on every rank)."""

    loss: float  # mean of the ranks' losses
    mse: float  # mean of the ranks' photometric MSE
    n_samples: int  # samples evaluated by all ranks together
    seconds: float  # training time of this step (the slowest rank's)
    stop: bool  # some rank was asked to stop (SIGINT/SIGTERM)
    checkpoint_due: bool  # rank 0's wall-clock checkpoint timer ran out


class Replicas:
    """The per-step agreement between the ranks of an active ``Context`` (see the module docstring)."""

    def __init__(self, ctx: Context, seed: int):
        self.ctx, self.seed = ctx, int(seed)
        self._tail = 0.0  # local seconds after the last reduce (optimiser step), counted at the next one
        self._t_reduce = time.perf_counter()

    def start(self, model: torch.nn.Module, elapsed: float) -> float:
        """Make every rank's model equal to rank 0's; returns the elapsed training time to continue
        from (the largest of the ranks': setup such as the environment prefit counts as training)."""
        distributed.broadcast_module(model)
        return distributed.max_over_ranks(elapsed)

    def seed_shared(self, step: int, rollbacks: int) -> None:
        """Seed torch's global RNG identically on every rank (before the training hook)."""
        torch.manual_seed(distributed.stream_seed(self.seed, "shared", step, rollbacks))

    def seed_rank(self, gen: torch.Generator, step: int, rollbacks: int) -> None:
        """Seed the batch generator and torch's global RNG with this rank's streams for ``step``."""
        rank = self.ctx.rank
        gen.manual_seed(distributed.stream_seed(self.seed, "batches", rank, step, rollbacks))
        torch.manual_seed(distributed.stream_seed(self.seed, "render", rank, step, rollbacks))

    def reduce(self, params: Sequence[torch.Tensor], model, loss: torch.Tensor, mse: torch.Tensor,
               n_samples: int, t0: float, stop: bool, checkpoint_due: bool) -> Shared:
        """Average the gradients of ``params`` after ``loss.backward()`` and agree on the step's
        scalars. ``t0``: ``time.perf_counter()`` when this rank started the step; ``stop``: this rank
        was asked to stop; ``checkpoint_due``: rank 0's wall-clock checkpoint timer ran out."""
        ctx = self.ctx
        stats = model.replica_stats()
        names = sorted(stats)
        seconds = [0.0] * ctx.world_size
        seconds[ctx.rank] = time.perf_counter() - t0 + self._tail
        extra = [float(loss.detach()), float(mse.detach()), float(n_samples), float(stop),
                 float(checkpoint_due and ctx.is_main)] + seconds + [float(stats[n]) for n in names]
        self._t_reduce = time.perf_counter()
        summed = distributed.average_gradients(params, ctx.world_size, extra)
        masks = model.replica_masks()
        if masks:  # the cells any rank touched: every rank steps them all (``RadianceModel.replica_masks``)
            union = distributed.all_reduce(torch.cat([m.reshape(-1).float() for m in masks]))
            at = 0
            for m in masks:
                m.copy_(union[at:at + m.numel()].reshape(m.shape) > 0)
                at += m.numel()
        w = ctx.world_size
        if names:
            model.set_replica_stats({n: v / w for n, v in zip(names, summed[5 + w:])})
        return Shared(loss=summed[0] / w, mse=summed[1] / w, n_samples=int(round(summed[2])),
                      seconds=max(summed[5:5 + w]), stop=summed[3] > 0, checkpoint_due=summed[4] > 0)

    def end_step(self) -> None:
        """Mark the end of this rank's step: the time since the reduce is counted at the next one."""
        self._tail = time.perf_counter() - self._t_reduce

    def after_side_work(self, preview_cost: float) -> float:
        """Wait for rank 0's previews, checkpoints and evaluations (not training time, so every rank
        leaves this together and no rank counts the wait); returns rank 0's last preview cost, which
        times the next preview on every rank."""
        t = torch.tensor([preview_cost if self.ctx.is_main else 0.0], dtype=torch.float64)
        distributed.all_reduce(t)
        return float(t.item())
