"""Data-parallel scaling on this machine: 1 process against N processes (torchrun), one thread each.

    python benchmarks/bench_ddp.py --out DIR [--dataset DS] [--procs 1,2] [--steps 200] [--method vmgrid]
                                [--batch-rays N] [--repeats 1]

For each process count it runs the command users run (``python -m nerf_core train`` for 1,
``python -m torch.distributed.run --standalone --nproc_per_node N -m nerf_core train`` for more)
with ``OMP_NUM_THREADS=1``, the same step budget and the same per-rank ``--batch-rays``, and reads
the progress events rank 0 writes:

* steps/s and rays/s over the steady part of the run (from the step event after the first 10 % of
  the steps to the last one, training time only: the ``elapsed`` field), so start-up, growth at the
  start and the final evaluation do not count; rays/s = steps/s x batch x processes;
* test PSNR at the end (``--eval-views 2``): N processes see N times the rays per step, so at a
  fixed step count they should score at least as well;
* the wall time of the whole command, start-up included.

Without ``--dataset`` it writes the analytic sphere dataset of the tests (64x64 px, 24 train views)
into DIR. Writes DIR/bench_ddp.md (a markdown table with the machine, its load average before and
after, and the exact commands) and DIR/bench_ddp.json. Timings on a machine shared with other jobs
are not speed claims: the table says so when the load average exceeds the core count.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
import _bootstrap  # noqa: E402,F401  (puts the checkout on sys.path)
from bench import report, runner  # noqa: E402  (benchmarks/bench)
from bench.plan import name_problem  # noqa: E402


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder (runs, dataset, bench_ddp.md, bench_ddp.json)")
    p.add_argument("--dataset", help="dataset to train on (default: a synthetic sphere written into --out)")
    p.add_argument("--procs", default="1,2", help="comma-separated process counts (default 1,2)")
    p.add_argument("--steps", type=int, default=200, help="training steps per run (default 200)")
    p.add_argument("--method", default="vmgrid")
    p.add_argument("--batch-rays", type=int, help="rays per step per process (default: the method's)")
    p.add_argument("--repeats", type=int, default=1, help="runs per process count; the table shows medians")
    p.add_argument("--python", default=runner.PYTHON, help="the Python with torch (default: this one)")
    return p.parse_args(argv)


def ensure_dataset(args) -> str:
    if args.dataset:
        return os.path.abspath(args.dataset)
    ds = os.path.join(os.path.abspath(args.out), "sphere_dataset")
    if not os.path.isfile(os.path.join(ds, "transforms_train.json")):
        from nerf_core.tests.conftest import make_dataset  # the tests' analytic sphere (needs pytest installed)

        make_dataset(ds, n_train=24, n_val=1, n_test=2, w=64, h=64, depth=False)
    return ds


def command(args, procs: int, dataset: str, run: str) -> list[str]:
    train = ["train", dataset, "--out", run, "--method", args.method, "--max-steps", str(args.steps),
             "--log-every", "10", "--eval-views", "2", "--preview-every", str(10 ** 9),
             "--checkpoint-every", str(10 ** 9), "--no-bar", "--overwrite"]
    if args.batch_rays:
        train += ["--batch-rays", str(args.batch_rays)]
    if procs == 1:
        return [args.python, "-m", "nerf_core", *train]
    return [args.python, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(procs),
            "-m", "nerf_core", *train]


def measure(events: list[dict], steps: int) -> dict:
    """steps/s over the steady part (training time), final test PSNR, from rank 0's events."""
    step_events = [e for e in events if e["event"] == "step"]
    skip = max(1, steps // 10)
    steady = [e for e in step_events if e["step"] >= skip]
    a, b = steady[0], steady[-1]
    rate = (b["step"] - a["step"]) / max(1e-9, b["elapsed"] - a["elapsed"])
    done = next(e for e in events if e["event"] == "done")
    return {"steps_per_s": rate, "psnr": (done.get("metrics") or {}).get("psnr"),
            "elapsed": done["elapsed"], "steps": done["step"]}


def main(argv=None) -> int:
    args = parse_args(argv if argv is not None else _bootstrap.script_args())
    unknown = name_problem("--method", [args.method], runner.method_names())
    if unknown:
        print(f"bench_ddp: {unknown}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    dataset = ensure_dataset(args)
    procs_list = [int(p) for p in args.procs.split(",") if p.strip()]
    env = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    load_before = os.getloadavg() if hasattr(os, "getloadavg") else None
    rows, raw, commands = [], [], {}
    for procs in procs_list:
        runs = []
        for k in range(args.repeats):
            run = os.path.join(os.path.abspath(args.out), f"run_p{procs}_{k}")
            cmd = command(args, procs, dataset, run)
            commands[procs] = " ".join(cmd)
            print(f"bench_ddp: {procs} process(es), run {k + 1}/{args.repeats}", file=sys.stderr, flush=True)
            res = runner.run_cli(cmd, env_extra=env, log_path=run + ".log")
            if res.returncode != 0:
                raise SystemExit(f"bench_ddp: {' '.join(cmd)} failed ({res.returncode}): "
                                 + "\n".join(res.stderr_tail[-10:]))
            cfg = json.load(open(os.path.join(run, "config.json"), encoding="utf-8"))
            m = measure(res.events, args.steps)
            m.update(batch=int(cfg["batch_rays"]), world_size=int(cfg.get("world_size", 1)), wall=res.wall)
            runs.append(m)
            raw.append({"procs": procs, **m})
        sps = statistics.median(r["steps_per_s"] for r in runs)
        batch = runs[0]["batch"]
        rows.append({"procs": procs, "batch": batch, "rays_per_step": batch * procs, "steps_per_s": sps,
                     "rays_per_s": sps * batch * procs,
                     "psnr": statistics.median(r["psnr"] for r in runs if r["psnr"] is not None)
                     if any(r["psnr"] is not None for r in runs) else None,
                     "wall": statistics.median(r["wall"] for r in runs)})
    base = rows[0]["rays_per_s"] if rows else None
    for r in rows:
        r["speedup"] = r["rays_per_s"] / base if base else None
    load_after = os.getloadavg() if hasattr(os, "getloadavg") else None
    import torch  # only for the record of the version

    cores = os.cpu_count() or 1
    contended = runner.contended(load_before[0] if load_before else None, load_after[0] if load_after else None,
                                 max(procs_list))
    table = report.markdown_table(
        rows, ["procs", "batch", "rays_per_step", "steps_per_s", "rays_per_s", "speedup", "psnr", "wall"],
        ["processes (1 thread each)", "rays/step/rank", "rays/step", "steps/s", "rays/s", "rays/s vs first",
         f"test PSNR at {args.steps} steps", "wall s (with start-up)"])
    lines = [f"# Data-parallel scaling: {args.method}, {args.steps} steps, dataset `{dataset}`", "",
             f"Machine: {platform.processor() or platform.machine()}, {cores} cores, Python "
             f"{platform.python_version()}, "
             f"torch {torch.__version__}, {time.strftime('%Y-%m-%d %H:%M', time.gmtime())} UTC. "
             f"Load average (1 min) before/after: {load_before[0] if load_before else '?':.2f} / "
             f"{load_after[0] if load_after else '?':.2f}.", ""]
    if contended:
        lines += [runner.CONTENDED_NOTE, ""]
    lines += [table, "", "Commands (`OMP_NUM_THREADS=1`):", ""] + [f"    {c}" for c in commands.values()] + [""]
    with open(os.path.join(args.out, "bench_ddp.md"), "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    report.write_json(os.path.join(args.out, "bench_ddp.json"),
                  {"rows": rows, "runs": raw, "commands": commands, "load_before": load_before,
                   "load_after": load_after, "contended": contended})
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    _bootstrap.exit_code(main())
