"""Where the host syncs of a training step come from, by source line (issue 51's evidence).

    OMP_NUM_THREADS=1 python benchmarks/bench/sync_sources.py DATASET [--steps 160] [--batch-rays 64]

Trains DATASET (the default method, seed 0, no evaluation) under a ``TorchDispatchMode`` that sees
every ATen call, and prints, per training step, how often each sync primitive (``nonzero``,
``_local_scalar_dense`` = ``.item()``/``float(t)``/``bool(t)``, ``is_nonzero``, ``masked_select``, the
fused Adam, whose CPU kernel reads scalars) and each tensor-indexing call ran, with the two innermost
``nerf_core`` frames that called it. (``torch.profiler``'s ``with_stack`` fails on this torch with a
UnicodeDecodeError while it parses the trace, so the stacks come from Python.)
"""
from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))  # the checkout

SYNC = {"aten.nonzero.default", "aten._local_scalar_dense.default", "aten.is_nonzero.default",
        "aten.masked_select.default", "aten.item.default", "aten._fused_adam_.default", "aten.index.Tensor"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="sync_sources.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--steps", type=int, default=160)
    ap.add_argument("--batch-rays", type=int, default=64)
    ap.add_argument("--rows", type=int, default=30)
    a = ap.parse_args(argv)
    if a.steps < 1 or a.batch_rays < 1:
        ap.error("--steps and --batch-rays must be >= 1")

    import torch
    from torch.utils._python_dispatch import TorchDispatchMode

    import nerf_core
    from nerf_core.engine.config import TrainConfig

    torch.set_num_threads(1)
    seen = collections.Counter()

    class Where(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if str(func) in SYNC:
                frames = [f"{f.filename.split('nerf_core/')[-1]}:{f.lineno}" for f in traceback.extract_stack()
                          if "/nerf_core/" in f.filename][-2:]
                seen[(str(func), " < ".join(reversed(frames)))] += 1
            return func(*args, **(kwargs or {}))

    with tempfile.TemporaryDirectory() as tmp:
        cfg = TrainConfig(dataset=a.dataset, out=os.path.join(tmp, "run"), max_steps=a.steps,
                          batch_rays=a.batch_rays, eval_views=0, show_bar=False, stdout_events=False)
        with Where():
            nerf_core.train(cfg)
    print(f"per step, {a.steps} steps of {a.batch_rays} rays from the first on (aten.index.Tensor: a sync only "
          "with a boolean mask)")
    for (name, where), k in seen.most_common(a.rows):
        print(f"{k / a.steps:6.2f}  {name:34s} {where}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
