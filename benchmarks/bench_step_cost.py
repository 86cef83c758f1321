"""What a vmgrid training step costs against the grid's size, dense Adam against the sparse step.

    python benchmarks/bench_step_cost.py RUN DATASET [--rays 2048] [--res 160,320] [--rounds 3]
                                         [--steps 10] [--out DIR]

On one checkpoint of RUN (resampled to each ``--res``), it times the training step with
``benchmarks/profile_step.py`` (one thread, CPU time of the thread) for each grid size in four
configurations: dense Adam (``grid_optimizer=adam``, today's default) and the sparse step
(``grid_optimizer=sparse``: the lazy Adam over the touched cells, gradients zeroed where written), each
at the marching step the grid gives (``step_ratio`` 0.5 voxels: a finer grid marches finer, so its
rays carry more samples) and at the step of the coarsest grid (``step_ratio`` scaled, so every size
evaluates the same samples and only the grid's own cost differs). The configurations take turns,
``--rounds`` times, and the median is reported with each size's ratio to the first size: machines
are shared, ratios side by side in one run are what carry over. Writes DIR/step_cost.md and .json.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
PROFILE = os.path.join(HERE, "profile_step.py")
STEP = re.compile(r"median step ([0-9.]+) ms")


def time_step(run: str, dataset: str, res: int, rays: int, steps: int, options: dict) -> float:
    """Median ms of one profile_step call (one thread)."""
    cmd = [sys.executable, PROFILE, run, dataset, "--res", str(res), "--rays", str(rays), "--steps", str(steps),
           "--table", "0", "--threads", "1"] + [a for k, v in options.items() for a in ("--set", f"{k}={v}")]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
    found = STEP.search(proc.stdout)
    if proc.returncode != 0 or not found:
        raise SystemExit(f"bench_step_cost: {' '.join(cmd)} failed: {proc.stderr.strip()[-400:]}")
    return float(found.group(1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench_step_cost.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("dataset")
    ap.add_argument("--rays", type=int, default=2048)
    ap.add_argument("--res", default="160,320", help="grid sizes, the first is the reference")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--out", default=None, help="folder for step_cost.md and step_cost.json")
    args = ap.parse_args(argv)
    sizes = [int(r) for r in args.res.split(",")]
    configs = {}
    for opt in ("adam", "sparse"):
        for same_samples in (False, True):
            name = f"{opt}, " + ("same samples" if same_samples else "grid's own step")
            configs[name] = [{"grid_optimizer": opt, **({"step_ratio": 0.5 * r / sizes[0]} if same_samples else {})}
                             for r in sizes]
    times = {name: [[] for _ in sizes] for name in configs}
    for _ in range(args.rounds):
        for name, per_size in configs.items():
            for k, (res, options) in enumerate(zip(sizes, per_size)):
                times[name][k].append(time_step(args.run, args.dataset, res, args.rays, args.steps, options))
    rows = ["| configuration | " + " | ".join(f"{r} cells (ms)" for r in sizes) + " | "
            + " | ".join(f"{r}/{sizes[0]}" for r in sizes[1:]) + " |",
            "|---|" + "---|" * (2 * len(sizes) - 1)]
    result = {}
    for name in configs:
        med = [statistics.median(t) for t in times[name]]
        result[name] = {"median_ms": med, "all_ms": times[name]}
        rows.append(f"| {name} | " + " | ".join(f"{m:.1f}" for m in med) + " | "
                    + " | ".join(f"{m / med[0]:.2f}x" for m in med[1:]) + " |")
    table = "\n".join(rows)
    print(table)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        cmd = "python benchmarks/bench_step_cost.py " + " ".join(sys.argv[1:] if argv is None else argv)
        with open(os.path.join(args.out, "step_cost.json"), "w", encoding="utf-8") as fh:
            json.dump({"command": cmd, "rays": args.rays, "sizes": sizes, "results": result}, fh, indent=2)
        with open(os.path.join(args.out, "step_cost.md"), "w", encoding="utf-8") as fh:
            fh.write(f"`{cmd}`, {args.rays} rays a step, median of {args.rounds} rounds:\n\n{table}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
