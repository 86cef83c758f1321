"""What one training step asks of the host, counted from a ``torch.profiler`` trace: top-level ATen
operators and host syncs per step (``benchmarks/profile_step.py --train``).

A step is a ``record_function(STEP_MARK)`` range. Inside it:

* an *operator* is an ``aten::`` event with no ``aten::`` event above it within the step (ops that one
  operator calls internally are part of it; autograd's backward functions and the optimiser's own
  marks are not ATen ops, so the ops they run count). On a GPU each one is one kernel launch or more.
* a *host sync* is an operator that makes the host wait for the device: it is, or calls, one of
  ``SYNC_OPS`` (``.item()``, ``float(t)``, ``bool(t)`` all end in ``aten::_local_scalar_dense``;
  boolean-mask indexing calls ``aten::nonzero``), or (CUDA traces) launches a device-to-host copy
  (``.cpu()``, ``.tolist()``, ``.numpy()``). On the CPU such copies are no-ops that the profiler does
  not see; everything else is counted the same way on both devices.
"""
from __future__ import annotations

import statistics
from collections import Counter
from dataclasses import dataclass, field

STEP_MARK = "nerf_core.train_step"
SYNC_OPS = frozenset({"aten::_local_scalar_dense", "aten::nonzero", "aten::nonzero_numpy",
                      "aten::masked_select", "aten::is_nonzero", "aten::item", "aten::equal"})


@dataclass
class StepCounts:
    """Per-step operator and sync counts (one entry per profiled step) and what the syncs were."""

    ops: list[int] = field(default_factory=list)
    syncs: list[int] = field(default_factory=list)
    sync_kinds: Counter = field(default_factory=Counter)  # "op (what it calls)" -> count over all steps

    def summary(self) -> dict:
        n = max(1, len(self.ops))
        return {"steps": len(self.ops),
                "ops_mean": sum(self.ops) / n, "ops_median": statistics.median(self.ops) if self.ops else 0,
                "syncs_mean": sum(self.syncs) / n, "syncs_median": statistics.median(self.syncs) if self.syncs else 0,
                "sync_kinds": {k: v / n for k, v in self.sync_kinds.most_common()}}


def _device_to_host(evt) -> bool:
    return any("DtoH" in getattr(k, "name", "") or "Device -> Host" in getattr(k, "name", "")
               for k in getattr(evt, "kernels", []) or [])


def _sync_cause(evt) -> str | None:
    """The sync primitive ``evt`` is or calls (depth first), or None."""
    if evt.name in SYNC_OPS or _device_to_host(evt):
        return evt.name if evt.name in SYNC_OPS else "device-to-host copy"
    for child in evt.cpu_children:
        cause = _sync_cause(child)
        if cause is not None:
            return cause
    return None


def _top_ops(evt):
    """The top-level ``aten::`` events below ``evt`` (not below another ``aten::`` event)."""
    for child in evt.cpu_children:
        if child.name.startswith("aten::"):
            yield child
        else:
            yield from _top_ops(child)


def count_steps(events) -> StepCounts:
    """``StepCounts`` of every ``STEP_MARK`` range in ``events`` (``prof.events()``), in order."""
    out = StepCounts()
    steps = sorted((e for e in events if e.name == STEP_MARK), key=lambda e: e.time_range.start)
    for step in steps:
        ops = list(_top_ops(step))
        n_sync = 0
        for op in ops:
            cause = _sync_cause(op)
            if cause is not None:
                n_sync += 1
                out.sync_kinds[op.name if cause == op.name else f"{op.name} ({cause})"] += 1
        out.ops.append(len(ops))
        out.syncs.append(n_sync)
    return out
