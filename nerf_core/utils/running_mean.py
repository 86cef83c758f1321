"""``RunningMean``: an exponential running mean fed on the device and read by the host only when asked.

A training step should read nothing back to the host that it does not need to decide its shapes: on
a GPU every read waits for the device. So a statistic of the training batches (vmgrid's running
opacity) is folded in on the device every step (``add``) and brought to the host on a method's
periodic steps only (``read``); between reads the host sees the value of the last read (``value``).
"""
from __future__ import annotations

from typing import Optional

import torch


class RunningMean:
    """Running mean ``m <- keep * m + new * mean(x)``, float64 on the device.

    Args:
        value: the starting value (host).
        keep: the share of the old mean kept at each ``add``.
        new: the weight of each new mean (``1 - keep``, given as its own literal: 1 - 0.9 is not 0.1
            in floating point, and the seeded runs were fixed with 0.1).
    """

    def __init__(self, value: float = 0.0, keep: float = 0.9, new: float = 0.1):
        self.value = float(value)  # the host's copy: the last ``read`` or ``set``
        self.keep, self.new = float(keep), float(new)
        self._device: Optional[torch.Tensor] = None
        self._read = float(value)  # the host value the device copy last started from

    def add(self, x: torch.Tensor) -> None:
        """Fold the mean of ``x`` (any shape, detached here) in, on ``x``'s device; no host read."""
        if x.numel() == 0:
            return
        prev = self._device
        if prev is None or self._read != self.value:  # the host's value was set since (replicas, a test)
            prev = torch.tensor(self.value, dtype=torch.float64, device=x.device)
        self._device = self.keep * prev + self.new * x.detach().mean().double()
        self._read = self.value

    def read(self) -> float:
        """Bring the device's mean to the host (one sync) and return it."""
        if self._device is not None:
            self.value = self._read = float(self._device)
        return self.value

    def set(self, value: float) -> None:
        """Replace the mean (the next ``add`` starts from it)."""
        self.value = float(value)
