"""Where a training step of a trained run goes: the median step time and a torch.profiler table.

    python benchmarks/profile_step.py RUN DATASET [--res N] [--rays 2048] [--steps 15] [--threads 1]
                                   [--device cpu|cuda] [--table 18]

Loads RUN's checkpoint (after growth, so the grids have the size a long run ends with; ``--res``
resamples them to N cells instead), draws ``--rays`` random training rays of DATASET, and times
``--steps`` optimiser steps as the trainer makes them (its fused Adam, the method's own loss terms),
after 3 warm-up steps: with one CPU thread by ``time.thread_time`` (CPU time of this thread, which a
machine shared with other jobs disturbs less than wall time), else by wall time (around
``torch.cuda.synchronize`` on CUDA). Then it profiles 5 more steps with ``torch.profiler`` and prints the
ops by self time. Set ``NERF_CORE_NATIVE=0`` to time the grid_sample fallback instead of the native
CPU kernel.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="profile_step.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a trained run folder")
    ap.add_argument("dataset", help="the dataset it was trained on (its train split gives the rays)")
    ap.add_argument("--res", type=int, help="resample the grids to this many cells first (vmgrid)")
    ap.add_argument("--rays", type=int, default=2048)
    ap.add_argument("--steps", type=int, default=15)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    ap.add_argument("--table", type=int, default=18, help="rows of the profiler table (0: none)")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.rays < 1:
        ap.error("--steps and --rays must be positive")

    import torch

    from bench.profiler import training_rays
    from nerf_core.engine.optim import make_optimizer
    from nerf_core.errors import RunError
    from nerf_core.runs.checkpoints import load_run

    torch.set_num_threads(args.threads)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    try:
        model, *_ = load_run(args.run, device)
    except RunError as exc:
        raise SystemExit(f"profile_step: {exc}")
    model.train()
    if args.res:
        if not hasattr(getattr(model, "field", None), "upsample"):
            raise SystemExit(f"profile_step: --res: method {model.method_name!r} has no grids to resample")
        model.field.upsample(args.res)
    o, d, near, far, rgba, _ = training_rays(args.dataset, args.rays)
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    rays_o, rays_d, t_near, t_far = as_t(o), as_t(d), as_t(near), as_t(far)
    target = as_t(rgba[:, :3] * rgba[:, 3:] + (1 - rgba[:, 3:]))
    background = torch.ones_like(target)
    opt = make_optimizer(model, 1e-3)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    # CPU time of this thread is steadier on a shared machine, but counts one thread only: wall time
    # whenever torch (or the native kernel) may run on more than one.
    clock = time.thread_time if device.type == "cpu" and args.threads == 1 else time.perf_counter

    def step():
        out = model.render_rays(rays_o, rays_d, t_near, t_far, background, training=True)
        loss = torch.mean((out["rgb"] - target) ** 2)
        if "aux_loss" in out:
            loss = loss + out["aux_loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    for _ in range(3):
        step()
    sync()
    times = []
    for _ in range(args.steps):
        t0 = clock()
        step()
        sync()
        times.append(clock() - t0)
    kernels = model.kernels(device) if hasattr(model, "kernels") else {}
    print(f"profile_step: {model.method_name}, grids {getattr(getattr(model, 'field', None), 'resolution', '-')}, "
          f"{args.rays} rays, {device}, {args.threads} thread(s), kernels {kernels}: median step "
          f"{1000 * statistics.median(times):.1f} ms (min {1000 * min(times):.1f}) over {args.steps} steps")
    if args.table:
        from torch.profiler import ProfilerActivity, profile

        acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
        with profile(activities=acts) as prof:
            for _ in range(5):
                step()
            sync()
        key = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
        print(prof.key_averages().table(sort_by=key, row_limit=args.table))
    return 0


if __name__ == "__main__":
    sys.exit(main())
