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

    python benchmarks/profile_step.py --train DATASET [--batch-rays 64] [--steps 300] [--threads 1]
                                   [--device cpu|cuda] [--method vmgrid]

trains a fresh run of DATASET through ``nerf_core.train`` (seed 0, no evaluation) for ``--steps``
steps of ``--batch-rays`` rays, from the first step on (growth and occupancy updates included), and
prints per step: the wall time (a run without the profiler), the top-level ATen operators (each one a
kernel launch or more on a GPU) and the host syncs, counted by ``torch.profiler`` in a second, equal
run (``step_counts``); mean and median over the steps (the median is the steady state).
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
    ap.add_argument("run", nargs="?", help="a trained run folder (not with --train)")
    ap.add_argument("dataset", nargs="?", help="the dataset it was trained on (its train split gives the rays)")
    ap.add_argument("--train", metavar="DATASET", help="count operators and host syncs of fresh training steps")
    ap.add_argument("--batch-rays", type=int, default=64, help="rays per training step (--train; default 64)")
    ap.add_argument("--method", help="method to train (--train; default: the trainer's default)")
    ap.add_argument("--res", type=int, help="resample the grids to this many cells first (vmgrid)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="rebuild the run's model with this option changed (e.g. grid_optimizer=sparse; repeatable)")
    ap.add_argument("--rays", type=int, default=2048)
    ap.add_argument("--steps", type=int, help="steps to time (default 15; --train: 300)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    ap.add_argument("--table", type=int, default=18, help="rows of the profiler table (0: none)")
    args = ap.parse_args(argv)
    if args.train:
        if args.run or args.dataset:
            ap.error("--train DATASET takes no RUN or DATASET arguments")
        args.steps = 300 if args.steps is None else args.steps
        if args.steps < 1 or args.batch_rays < 1:
            ap.error("--steps and --batch-rays must be positive")
        return train_counts(args)
    if not (args.run and args.dataset):
        ap.error("give RUN and DATASET, or --train DATASET")
    args.steps = 15 if args.steps is None else args.steps
    if args.steps < 1 or args.rays < 1:
        ap.error("--steps and --rays must be positive")

    import torch

    from bench.profiler import training_batch
    from nerf_core.contract.errors import DatasetError
    from nerf_core.engine.optim import make_optimizer
    from nerf_core.errors import RunError, TrainError
    from nerf_core.methods.vmgrid import VMGrid
    from nerf_core.cli.options import parse_options
    from nerf_core.runs.checkpoints import load_run
    from nerf_core.runs.weights import model_from_checkpoint

    torch.set_num_threads(args.threads)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    try:
        model, _, ckpt = load_run(args.run, device)
        if args.set:  # the same weights in a model built with the changed options
            ckpt = {**ckpt, "options": {**ckpt["options"], **parse_options(args.set)}}
            model = model_from_checkpoint(ckpt, device, args.run)
    except (RunError, TrainError, ValueError) as exc:
        raise SystemExit(f"profile_step: {exc}")
    model.train()
    if args.res:
        if not isinstance(model, VMGrid):
            raise SystemExit(f"profile_step: --res: method {model.method_name!r} has no grids to resample")
        model.field.upsample(args.res)
    budgeted = isinstance(model, VMGrid) and bool(model.opts.sample_budget)
    try:  # through the library's own loader: any layout it reads
        batch, near, far = training_batch(args.dataset, model, model.rays_per_step(args.rays), device)
    except DatasetError as exc:
        raise SystemExit(f"profile_step: {exc}")
    opt = make_optimizer(model, 1e-3)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    # CPU time of this thread is steadier on a shared machine, but counts one thread only: wall time
    # whenever torch (or the native kernel) may run on more than one.
    clock = time.thread_time if device.type == "cpu" and args.threads == 1 else time.perf_counter

    def step():  # the trainer's step, less its checks: the method's render, loss and optimiser step
        out = model.render_batch(batch.rays_o, batch.rays_d, batch.background, near, far, training=True)
        loss, _ = model.loss(out, batch.target, batch.weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        model.optimizer_step(opt, out)

    for _ in range(3):
        step()
    if budgeted:  # --set sample_budget=N: size the buffers from the warm-up, then draw the rays that fill them
        model.budget.adapt()
        batch, near, far = training_batch(args.dataset, model, model.rays_per_step(args.rays), device)
        for _ in range(2):
            step()
    sync()
    times = []
    for _ in range(args.steps):
        t0 = clock()
        step()
        sync()
        times.append(clock() - t0)
    kernels = model.kernels(device)
    rays = f"{batch.rays_o.shape[0]} rays (sample budget {model.budget.sizes()})" if budgeted else f"{args.rays} rays"
    print(f"profile_step: {model.method_name}, grids {model.run_state().get('resolution', '-')}, "
          f"{rays}, {device}, {args.threads} thread(s), kernels {kernels}: median step "
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


def _train(args, out: str, profile: bool):
    """Train a fresh run into ``out``. Returns ((wall, CPU time of this thread) in seconds per ``step``
    call, None) or, with ``profile``, (None, ``StepCounts``)."""
    import torch

    from bench.step_counts import STEP_MARK, count_steps
    from nerf_core.engine import trainer as trainer_mod
    from nerf_core.engine.config import TrainConfig

    cuda = args.device == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    spent, cpu = [], []

    class TimedTrainer(trainer_mod.Trainer):
        """The trainer, each of its steps timed and marked for the profiler."""

        def step(self, *a, **k):
            t0, c0 = time.perf_counter(), time.thread_time()
            with torch.profiler.record_function(STEP_MARK):
                ok = super().step(*a, **k)
            if self.cfg.finished(self.state.step, self.state.elapsed):
                sync()  # the last step's queued kernels belong to the steps' time
            spent.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
            return ok

    from nerf_core.cli.options import parse_options

    cfg = TrainConfig(dataset=args.train, out=out, method=args.method, max_steps=args.steps, seed=0,
                      options=parse_options(args.set),
                      device=args.device, batch_rays=args.batch_rays, eval_views=0, preview_every=10 ** 9,
                      checkpoint_every=10 ** 9, stdout_events=False, show_bar=False)
    if not profile:
        TimedTrainer(cfg).fit()
        n = max(1, len(spent))
        return (sum(spent) / n, sum(cpu) / n), None
    from torch.profiler import ProfilerActivity, profile as torch_profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with torch_profile(activities=acts) as prof:
        TimedTrainer(cfg).fit()
    return None, count_steps(prof.events())


def train_counts(args) -> int:
    """``--train``: wall ms, top-level ATen operators and host syncs per training step."""
    import tempfile

    import torch

    from nerf_core.errors import DatasetError, RunError, TrainError

    torch.set_num_threads(args.threads)
    args.device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    try:
        with tempfile.TemporaryDirectory(prefix="profile_step_") as tmp:
            wall, _ = _train(args, os.path.join(tmp, "timed"), profile=False)
            _, counts = _train(args, os.path.join(tmp, "profiled"), profile=True)
    except (DatasetError, RunError, TrainError, ValueError) as exc:
        raise SystemExit(f"profile_step: --train {args.train}: {exc}")
    s = counts.summary()
    print(f"profile_step --train: {args.method or 'default method'}, {args.batch_rays} rays, {args.device}, "
          f"{args.threads} thread(s), {s['steps']} steps from the first on")
    # The thread's CPU time is steadier than wall time on a loaded machine (one thread only).
    print(f"  wall per step:          {1000 * wall[0]:.2f} ms (mean, without the profiler; "
          f"CPU time of the training thread {1000 * wall[1]:.2f} ms)")
    print(f"  ATen operators / step:  {s['ops_mean']:.1f} mean, {s['ops_median']:g} median")
    print(f"  host syncs / step:      {s['syncs_mean']:.2f} mean, {s['syncs_median']:g} median")
    for kind, per_step in s["sync_kinds"].items():
        print(f"    {per_step:6.2f}  {kind}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
