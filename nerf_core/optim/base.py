"""``TrainingOptimizer``: what the trainer asks of an optimiser beyond ``torch.optim.Optimizer``.

The trainer never looks inside an optimiser's state: the optimiser checks a checkpoint's state
against itself (``check_state``) before ``load_state_dict`` sees it, and decides which of an old
optimiser's state a rebuilt one keeps (``carry_state_from``). An optimiser with another state layout
(a step count per grid cell, say) overrides ``state_shape``, and the loader follows.
"""
from __future__ import annotations

import math

import torch

from nerf_core.contract.numbers import is_whole
from nerf_core.errors import RunError


def _whole(value) -> bool:
    return is_whole(value) and value >= 0


class TrainingOptimizer(torch.optim.Optimizer):
    """A ``torch.optim.Optimizer`` that checks and carries over its own state.

    Subclass it beside a torch optimiser (``class Adam(TrainingOptimizer, torch.optim.Adam)``): it adds
    no state of its own and leaves the update to the optimiser it is mixed into. Each parameter group
    carries ``base_lr``, the rate the learning-rate schedule scales (``engine.optim``).
    """

    def state_shape(self, key: str, param: torch.Tensor) -> tuple:
        """The shape that state entry ``key`` of ``param`` has: () for ``step``, the parameter's own
        shape for every other entry (Adam's moments). Override for another layout."""
        return () if key == "step" else tuple(param.shape)

    def check_state(self, state: dict, where: str) -> None:
        """Refuse (RunError naming ``where``) saved state that does not fit this optimiser: the group
        layout, the parameter numbering, each entry's shape (``state_shape``) and finite values.

        Nothing mis-shaped may reach ``load_state_dict``: a fused kernel trusts the shapes and would
        write out of bounds.

        Args:
            state: a checkpoint's ``optimizer`` entry (``state_dict()``'s layout: ``state`` and
                ``param_groups``; ``runs.checkpoint_checks.check_entries`` has checked that much).
            where: the file, for messages.
        """
        groups, mine = state["param_groups"], self.param_groups
        if len(groups) != len(mine) or any(len(g["params"]) != len(m["params"]) for g, m in zip(groups, mine)):
            raise RunError(f"{where}: entry 'optimizer' has {[len(g['params']) for g in groups]} parameters per "
                           f"group; the model's optimiser has {[len(m['params']) for m in mine]}")
        params = [p for m in mine for p in m["params"]]
        ids = [i for g in groups for i in g["params"]]
        if any(not _whole(i) for i in ids) or sorted(ids) != list(range(len(params))):
            raise RunError(f"{where}: entry 'optimizer' numbers its parameters {ids[:8]}..., "
                           f"not 0..{len(params) - 1}")
        index = {pid: params[k] for k, pid in enumerate(ids)}
        for pid, entries in state["state"].items():
            if pid not in index or not isinstance(entries, dict):
                raise RunError(f"{where}: entry 'optimizer' has state for parameter {pid!r}, which the model lacks")
            for key, value in entries.items():
                self._check_entry(where, pid, key, value, index[pid])

    def _check_entry(self, where: str, pid: int, key: str, value, param: torch.Tensor) -> None:
        if not isinstance(value, torch.Tensor):
            raise RunError(f"{where}: optimiser state {key!r} of parameter {pid} must be a tensor")
        want = self.state_shape(key, param)
        if tuple(value.shape) != want:
            raise RunError(f"{where}: optimiser state {key!r} of parameter {pid} has shape {tuple(value.shape)}; "
                           f"it must be {want} to fit the model")
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise RunError(f"{where}: optimiser state {key!r} of parameter {pid} holds NaN or infinite values")
        if key == "step" and value.numel() and float(value.min()) < 0:
            raise RunError(f"{where}: optimiser state 'step' of parameter {pid} is negative")
        if key == "step" and value.numel() and not math.isfinite(float(value.max())):
            raise RunError(f"{where}: optimiser state 'step' of parameter {pid} is not finite")

    def carry_state_from(self, old: torch.optim.Optimizer) -> None:
        """Keep ``old``'s state for every parameter of this optimiser that ``old`` also optimised with
        the same shape (the same tensor object); a grown parameter starts afresh."""
        for g in self.param_groups:
            for p in g["params"]:
                st = old.state.get(p)
                if st and all(not torch.is_tensor(v) or tuple(v.shape) == self.state_shape(k, p)
                              for k, v in st.items()):
                    self.state[p] = st
