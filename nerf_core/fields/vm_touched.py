"""Which rows of a VM grid's stored parameters a training step's lookups read, and so wrote gradient to.

A grid step should cost what the rays touch, not the grid's size (issue 55). The field marks, at each
lookup with grad, the texels that bilinear interpolation reads: for a point's coordinate c in [-1, 1]
on an axis of N cells, ``ix = (c + 1) / 2 * (N - 1)`` (grid_sample's ``align_corners=True``, and the
native kernel's, in the same float32 operations) and the taps ``floor(ix)`` and ``floor(ix) + 1``
that fall inside the grid (zero padding: the others weigh nothing). A plane cell is one row of the
channels-last plane parameter (3, N, N, R) viewed as (3 N N, R); a line cell one row of (3 N, R).

Every texel that received gradient is marked (a tap of weight 0 is marked too: it received a zero),
so a row-sparse optimiser that updates only the marked rows applies every gradient the step made.
"""
from __future__ import annotations

from typing import Dict, Optional

import torch

from nerf_core.fields.vm_products import LINE_AXIS, PLANE_AXES

Tensor = torch.Tensor


def _taps(c: Tensor, n: int) -> tuple[Tensor, Tensor]:
    """(m,) coordinates in [-1, 1] -> the two taps (2, m) long on an axis of ``n`` cells and whether
    each lies inside the grid (2, m) bool."""
    ix = torch.floor((c + 1.0) / 2.0 * float(n - 1))
    ok = torch.isfinite(ix)
    lo = torch.where(ok, ix, torch.full_like(ix, -2.0)).clamp(-2, n + 1).long()
    taps = torch.stack([lo, lo + 1])
    return taps, (taps >= 0) & (taps < n) & ok


def plane_rows(u: Tensor, n: int) -> tuple[Tensor, Tensor]:
    """Flat rows (12 m,) of a (3 N N, R) plane parameter read at points ``u`` (m, 3), and which are real."""
    rows, valid = [], []
    for k, (a, b) in enumerate(PLANE_AXES):
        xs, okx = _taps(u[:, a], n)
        ys, oky = _taps(u[:, b], n)
        rows.append(((k * n + ys[:, None]) * n + xs[None, :]).reshape(-1))  # (2, 2, m): every pair
        valid.append((oky[:, None] & okx[None, :]).reshape(-1))
    return torch.cat(rows), torch.cat(valid)


def line_rows(u: Tensor, n: int) -> tuple[Tensor, Tensor]:
    """Flat rows (6 m,) of a (3 N, R) line parameter read at points ``u`` (m, 3), and which are real."""
    rows, valid = [], []
    for k, a in enumerate(LINE_AXIS):
        ys, ok = _taps(u[:, a], n)
        rows.append((k * n + ys).reshape(-1))
        valid.append(ok.reshape(-1))
    return torch.cat(rows), torch.cat(valid)


class TouchedRows:
    """The rows of each grid parameter that this step's lookups touched, as one bool mask per
    parameter (kept on the parameter's device; no host read until ``rows``).

    With ``sinks``, it also keeps one gradient buffer per parameter (stored layout) that the native
    kernel's backward adds into instead of a freshly zeroed grid, so that a step's gradient costs what
    the step touched: ``clear`` zeroes only the rows the last step wrote. Only valid while nothing else
    writes those gradients densely (vmgrid turns it off when the TV prior is on).

    Args:
        sinks: keep the gradient buffers.
    """

    def __init__(self, sinks: bool = False):
        self.masks: Dict[str, Tensor] = {}
        self.use_sinks = bool(sinks)
        self.sinks: Dict[str, Tensor] = {}
        self._rows: Dict[str, Tensor] = {}  # ``rows``'s answer, until ``clear``

    def _mark(self, key: str, n_rows: int, rows: Tensor, valid: Tensor) -> None:
        mask = self.masks.get(key)
        if mask is None or mask.numel() != n_rows + 1 or mask.device != rows.device:
            mask = self.masks[key] = torch.zeros(n_rows + 1, dtype=torch.bool, device=rows.device)
        # Taps outside the grid go to the spare last slot, which is never read: no compaction here.
        mask[torch.where(valid, rows, torch.full_like(rows, n_rows))] = True

    def mark(self, planes_key: str, lines_key: str, u: Tensor, n: int) -> None:
        """Mark what a lookup of planes ``planes_key`` and lines ``lines_key`` (both N = ``n`` cells a
        side) at points ``u`` (m, 3) in [-1, 1] reads."""
        u = u.detach()
        self._mark(planes_key, 3 * n * n, *plane_rows(u, n))
        self._mark(lines_key, 3 * n, *line_rows(u, n))

    def rows(self, key: str) -> Optional[Tensor]:
        """The touched rows (k,) long of ``key``, in increasing order, or None when nothing marked it."""
        if key not in self._rows:
            mask = self.masks.get(key)
            if mask is None:
                return None
            self._rows[key] = mask[:-1].nonzero().squeeze(-1)
        return self._rows[key]

    def sink(self, key: str, stored: Tensor) -> Optional[Tensor]:
        """The zero gradient buffer for parameter ``key`` (its stored tensor ``stored``), or None
        without sinks. A new one when the grid changed size (growth) or place."""
        if not self.use_sinks:
            return None
        buf = self.sinks.get(key)
        if buf is None or buf.shape != stored.shape or buf.device != stored.device or buf.dtype != stored.dtype:
            buf = self.sinks[key] = torch.zeros_like(stored, memory_format=torch.contiguous_format)
            self._rows.pop(key, None)
            if key in self.masks:
                self.masks[key].zero_()  # a new buffer is zero everywhere: nothing to clear in it
        return buf

    def masks_for_replicas(self) -> list[Tensor]:
        """The masks themselves (ranks of a torchrun job OR them, so that every rank updates the same rows)."""
        return list(self.masks.values())

    def clear(self) -> None:
        """Forget the marks, and zero the gradient buffers where the last marks said they were written."""
        for key, mask in self.masks.items():
            buf = self.sinks.get(key)
            if buf is not None:
                rows = self.rows(key)
                buf.view(-1, buf.shape[-1]).index_fill_(0, rows, 0.0)
            mask.zero_()
        self._rows.clear()
