"""A cache of data derived from tensors (lookup tables, a dilated mask) that follows every change of them.

A tensor changes in one of three ways:
- it is replaced by another tensor (growth, a device move): caught by comparing the tensors themselves,
  by weak reference (a new tensor may reuse a freed ``id()``);
- it is changed in place by an op that moves its version counter (loading, ``copy_``, ``fill_``);
- an optimiser writes it. Fused optimisers (the trainer's Adam, ``nerf_core.engine.optim``) do **not** move
  version counters, so a cache over trained weights also counts the optimiser steps taken anywhere in
  the process (``follow_optimizers``). Missing this once made every evaluation during training render
  vmgrid's grids as they were after the last growth step.

The cache pickles as empty (weak references cannot be pickled), so a module holding one can still be
saved whole (``torch.save(model)``) or deep-copied; the copy rebuilds the value on demand.
"""
from __future__ import annotations

import weakref
from typing import Callable, Generic, Optional, Sequence, Tuple, TypeVar

import torch
from torch.optim.optimizer import register_optimizer_step_post_hook

T = TypeVar("T")

_optimizer_steps = 0


def _count_optimizer_step(optimizer, args, kwargs) -> None:
    global _optimizer_steps
    _optimizer_steps += 1


register_optimizer_step_post_hook(_count_optimizer_step)


class DerivedCache(Generic[T]):
    """One value built from ``tensors`` by ``build``, rebuilt when any of them changes (see above).

    ``follow_optimizers``: also rebuild after any optimiser step in the process (for values derived
    from trainable weights; off for buffers that optimisers never touch).
    """

    def __init__(self, follow_optimizers: bool):
        self.follow_optimizers = follow_optimizers
        self._entry: Optional[Tuple[tuple, tuple, T]] = None  # (weak refs, stamp, value)

    @property
    def empty(self) -> bool:
        return self._entry is None

    def get(self, tensors: Sequence[torch.Tensor], build: Callable[[], T]) -> T:
        stamp = (_optimizer_steps if self.follow_optimizers else 0,
                 tuple((t._version, t.device, t.dtype) for t in tensors))
        e = self._entry
        if (e is None or e[1] != stamp or len(e[0]) != len(tensors)
                or any(r() is not t for r, t in zip(e[0], tensors))):
            self._entry = None  # free the old value before building the new one
            self._entry = (tuple(weakref.ref(t) for t in tensors), stamp, build())
        return self._entry[2]

    def __getstate__(self):
        return {"follow_optimizers": self.follow_optimizers, "_entry": None}
