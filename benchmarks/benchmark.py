"""Speed against accuracy: train every method on the demo scenes and chart test PSNR against time and size.

    python benchmarks/benchmark.py [--quick] --out DIR [--methods a,b] [--scenes x,y] [--minutes M]
                                [--resolution R] [--views N] [--test-views N] [--checkpoints log|1,2,5]
                                [--no-sizes] [--no-profile] [--report-only]

What it does, through the same command lines users run:
 1. builds each demo scene (scripts/make_demo_scene.py) and captures it (scripts/capture.py) into
    DIR/datasets, reusing a capture whose settings match;
 2. trains each method on each scene (``python -m nerf_core train``) and measures held-out test PSNR
    and SSIM (``python -m nerf_core eval``) at checkpoints in *training* time: by default log-spaced,
    10 s doubling up to the budget, plus 1, 2, 5 and 10 minutes where they fit (5 minutes: 10, 20,
    40, 60, 80, 120, 160, 300 s). Each run is one training run with ``--eval-at`` the earlier
    checkpoints, so evaluation time is never counted as training time and the schedules are real;
 3. runs the fast method at fixed sizes and with ``--size auto`` as separate series, to show whether
    auto-sizing lands on the Pareto front of the sizes tried;
 4. profiles a few training steps in-process to split step time into sampling, field, rendering,
    backward and optimiser (unless ``--no-profile``);
 5. writes DIR/results.csv, DIR/results.json (every checkpoint), DIR/final.csv, DIR/summary.md and
    the charts DIR/psnr_vs_time.png (log time axis; nerf and nerf-nope drawn as a pair) and
    DIR/psnr_vs_size.png. ``--report-only`` redraws the charts and summary.md from DIR/results.json
    without training.

Defaults are the issue-3 setup: 200x200 images, 100 train and 20 test views, 5 minutes per run, on
the diffuse, highfreq, glossy, thin and multi scenes (objects on a transparent film) and the hdri
(an object in a visible studio-light HDRI world), interior (a room captured from inside) and ground
(a figure on a floor that runs to the horizon) scenes, which are captured opaque. ``--quick`` shrinks
everything to finish in under 10 minutes on 2 CPU cores. A progress bar with an ETA covers the whole plan.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Optional, Sequence

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
from bench import datasets, report, runner  # noqa: E402  (benchmarks/bench, found through the line above)
from bench.analysis import (checkpoint_size, eval_at_points, pair_gap_table, psnr_at_table,  # noqa: E402
                            rows_from_results, size_analysis, summarize_training)
from bench.plan import (FULL_SCENES, Plan, Series, default_fast_method, make_plan, parse_checkpoints,  # noqa: E402
                        unknown_names)
from bench.profiler import profile_method  # noqa: E402

from nerf_core.utils.progressbar import ProgressBar  # noqa: E402


# --------------------------------------------------------------------------------------------
# One training run, measured at checkpoints
# --------------------------------------------------------------------------------------------


def train_with_checkpoints(dataset: str, run_dir: str, series: Series, checkpoints: list[float], seed: int,
                           log_path: str, on_progress, n_test: int, independent: bool = False,
                           env_extra: Optional[dict] = None) -> dict:
    """Test PSNR/SSIM of ``series`` at each budget in ``checkpoints`` (seconds of training time).

    Default: ONE run with the last checkpoint as its budget and ``--eval-at`` the earlier ones: the
    trainer pauses its clock, evaluates ``n_test`` test views and emits an ``eval`` event carrying the
    training time, so every point comes from the real schedules (learning-rate decay, grid growth) of
    one run and evaluation time is never training time. The trainer's final evaluation gives the last
    point. ``independent=True`` trains a fresh run per budget instead ("what budget T gives", costs
    the sum of the budgets). ``on_progress(seconds)`` follows the step events. ``env_extra`` goes to
    every child (``runner.thread_env`` when runs share the machine).
    Returns ``points`` [{seconds, budget, step, psnr, ssim}], a training summary, ``error`` and paths.
    """
    events_all: list[dict] = []
    points: list[dict] = []
    error = None
    done_before = 0.0
    budgets = checkpoints if independent else checkpoints[-1:]
    for budget in budgets:
        this_run = os.path.join(run_dir, f"budget_{budget:g}s") if independent else run_dir
        cmd = runner.nerf_core_cmd("train", dataset, "--out", this_run, "--method", series.method,
                               "--max-seconds", f"{budget:g}", "--seed", str(seed), "--eval-views", str(n_test),
                               # Step events every 10 steps: slow methods (seconds per step on a CPU)
                               # would otherwise move the overall bar once a minute.
                               "--log-every", "10", "--no-bar", *series.extra)
        if not independent and len(checkpoints) > 1:
            cmd += ["--eval-at", ",".join(f"{c:g}" for c in checkpoints[:-1])]
        if os.path.isdir(this_run) and os.listdir(this_run):
            cmd.append("--overwrite")  # a run folder this benchmark wrote in an earlier attempt

        def on_event(ev, offset=done_before):
            if ev.get("event") == "step" and ev.get("elapsed") is not None:
                on_progress(offset + float(ev["elapsed"]))

        res = runner.run_cli(cmd, on_event=on_event, log_path=log_path, env_extra=env_extra)
        events_all.extend(res.events)
        if not res.ok:
            error = f"train to {budget:g}s: {res.error_message()}"
            break
        points += eval_at_points(res.events, [] if independent else checkpoints[:-1])
        metrics, why = runner.final_test_metrics(res, this_run, log_path, env_extra)
        if metrics is None:
            error = f"eval after {budget:g}s: {why}"
            break
        done = [e for e in res.events if e.get("event") == "done"]
        points.append({
            "seconds": float(done[-1].get("elapsed", budget)) if done else budget,
            "budget": budget,
            "step": int(done[-1].get("step", 0)) if done else None,
            "psnr": metrics.get("psnr"),
            "ssim": metrics.get("ssim"),
        })
        if independent:
            done_before += budget
    summary = summarize_training(events_all)
    last_run = os.path.join(run_dir, f"budget_{checkpoints[-1]:g}s") if independent else run_dir
    ckpt = os.path.join(last_run, "checkpoints", "latest.pt")
    return {"points": points, "train": summary, "error": error or summary.get("error"),
            "checkpoint": ckpt, "checkpoint_bytes": checkpoint_size(ckpt)}


def model_size(checkpoint: str) -> tuple[Optional[int], Optional[int]]:
    """(parameters, bytes of parameters and buffers) of the model in ``checkpoint`` at its final size.

    Grid methods grow during training, so the ``start`` event's count is the initial size only. When
    the checkpoint no longer builds with the installed method (its options changed since it was
    written), the count comes from the saved tensors, minus the buffers a default build declares.
    """
    if not os.path.isfile(checkpoint):
        return None, None
    from pathlib import Path

    import torch

    from nerf_core.methods.registry import build_model
    from nerf_core.runs.checkpoints import model_from_checkpoint, read_checkpoint

    try:
        ckpt = read_checkpoint(Path(checkpoint))
    except Exception as exc:  # noqa: BLE001 (a size we cannot read is reported as missing, not fatal)
        print(f"benchmark: {checkpoint}: cannot read the model size ({exc})", file=sys.stderr)
        return None, None
    try:
        model = model_from_checkpoint(ckpt, torch.device("cpu"), checkpoint)
        return model.num_parameters(), model.num_bytes()
    except Exception as exc:  # noqa: BLE001
        state = ckpt.get("model") or {}
        try:
            buffers = {name for name, _ in build_model(ckpt["method"], torch.as_tensor(ckpt["aabb"])).named_buffers()}
        except Exception:  # noqa: BLE001
            print(f"benchmark: {checkpoint}: cannot read the model size ({exc})", file=sys.stderr)
            return None, None
        n_params = sum(t.numel() for k, t in state.items() if k not in buffers)
        n_bytes = sum(t.numel() * t.element_size() for t in state.values())
        print(f"benchmark: {checkpoint}: counted parameters from the saved tensors ({exc})", file=sys.stderr)
        return n_params, n_bytes


def reusable_results(out: str, plan: Plan, series_names: set[str], run_settings: dict) -> dict:
    """Finished runs of ``series_names`` in OUT/results.json that this plan would repeat unchanged.

    For re-running only the series whose code changed (``--reuse nerf,nerf-nope`` after editing the
    fast method): a stored run counts only when the capture, the checkpoints, the seed, the number of
    scored views and the series' method and flags all match, and it had no error. Returns
    {(scene, series label): result}, each marked ``"reused": True``; the caller says so in the summary.
    """
    path = os.path.join(out, "results.json")
    if not series_names or not os.path.isfile(path):
        return {}
    with open(path, encoding="utf-8") as fh:
        old = json.load(fh)
    if old.get("capture") != plan.capture or [float(c) for c in old.get("checkpoints_seconds", [])] != plan.checkpoints:
        print(f"benchmark: {path}: other capture settings or checkpoints, nothing reused", file=sys.stderr)
        return {}
    for key, value in run_settings.items():
        if key not in old:  # written before the key was recorded
            print(f"benchmark: {path} does not record {key}; assuming {value!r}", file=sys.stderr)
        elif old.get(key) != value:
            print(f"benchmark: {path}: {key} was {old.get(key)!r}, now {value!r}; nothing reused", file=sys.stderr)
            return {}
    wanted = {(scene, s.label): s for scene, s in plan.runs() if s.label in series_names}
    found = {}
    for r in old.get("runs", []):
        s = wanted.get((r.get("scene"), r.get("series")))
        if s and not r.get("error") and r.get("method") == s.method and list(r.get("flags") or []) == s.extra:
            found[(r["scene"], r["series"])] = {**r, "reused": True}
    return found


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------


def write_outputs(out: str, results: list[dict], plan: Plan, fast: str, profile: Optional[dict],
                  wall: float, machine: dict, run_settings: Optional[dict] = None) -> dict:
    """Every run's numbers to OUT/results.{csv,json} and final.csv, then ``draw_report``."""
    rows, finals = rows_from_results(results)
    report.write_csv(os.path.join(out, "results.csv"), rows)
    report.write_csv(os.path.join(out, "final.csv"), finals)
    sizes = size_analysis(finals, fast)
    report.write_json(os.path.join(out, "results.json"), {
        "machine": machine, "wall_seconds": wall, "checkpoints_seconds": plan.checkpoints,
        "capture": plan.capture, "runs": results, "size_study": sizes, "profile": profile,
        **(run_settings or {}),
    })
    return draw_report(out, results, plan.checkpoints, plan.capture, sizes, profile, wall, machine)


def draw_report(out: str, results: list[dict], checkpoints: list[float], capture: dict, sizes: list[dict],
                profile: Optional[dict], wall: float, machine: dict) -> dict:
    """The charts (OUT/psnr_vs_time.png, OUT/psnr_vs_size.png) and OUT/summary.md from ``results``."""
    rows, finals = rows_from_results(results)
    curves = {}
    for r in results:
        curves[(r["scene"], r["series"])] = [(p["seconds"], p["psnr"]) for p in r["points"]]
    charts = []
    if any(curves.values()):
        charts.append(report.chart_psnr_vs_time(curves, os.path.join(out, "psnr_vs_time.png"),
                                            "Test PSNR against training time"))
    pts = [{"scene": f["scene"], "series": f["series"], "params": f["n_params"], "psnr": f["psnr"]}
           for f in finals if f["n_params"] and f["psnr"] is not None]
    if pts:
        charts.append(report.chart_psnr_vs_size(pts, os.path.join(out, "psnr_vs_size.png"),
                                            "Final test PSNR against model size"))
    md = summary_markdown(rows, finals, sizes, profile, checkpoints, capture, wall, machine,
                          reused=[f"{r['scene']}/{r['series']}" for r in results if r.get("reused")])
    with open(os.path.join(out, "summary.md"), "w", encoding="utf-8") as fh:
        fh.write(md)
    return {"rows": rows, "finals": finals, "sizes": sizes, "charts": charts, "markdown": md}


def summary_markdown(rows, finals, sizes, profile, checkpoints: Sequence[float], capture: dict, wall: float,
                     machine: dict, reused: Sequence[str] = ()) -> str:
    cols = ["scene", "series"] + [f"psnr@{c:g}s" for c in checkpoints] + ["ssim", "n_params", "samples_per_s"]
    table = psnr_at_table(rows, list(checkpoints))
    gaps = pair_gap_table(table, list(checkpoints), *report.PAIR)
    lines = [
        "# Benchmark results",
        "",
        f"Machine: {machine.get('cpu', '?')}, {machine.get('cpus', '?')} logical CPUs, torch "
        f"{machine.get('torch', '?')}, load average at start {machine.get('load_avg', '?')}; "
        f"total wall time {wall / 60:.1f} min. "
        + (f"{machine['jobs']} runs at a time, {machine.get('threads_per_run')} thread(s) each."
           if machine.get("jobs", 1) > 1 else "One run at a time, all cores."),
        f"Capture: {capture.get('resolution')}x{capture.get('resolution')} px, {capture.get('count')} train / "
        f"{capture.get('test_count')} test views. Checkpoints at {', '.join(f'{c:g}' for c in checkpoints)} "
        "seconds of training time (evaluation time excluded).",
        *([f"Reused from this folder's previous results.json (`--reuse`, settings matched): {', '.join(reused)}. "
           "Their wall time is not in the total."] if reused else []),
        "",
        "## Test PSNR (dB) at each checkpoint",
        "",
        report.markdown_table(table, cols),
        "",
    ]
    if gaps:
        gap_cols = [f"{c:g}s" for c in checkpoints]
        lines += [f"## {report.PAIR[0]} \u2212 {report.PAIR[1]} (dB) at each checkpoint", "",
                  "Positive where positional encoding is ahead of the same MLP on raw coordinates.", "",
                  report.markdown_table(gaps, ["scene"] + gap_cols, digits=2), ""]
    errors = [f for f in finals if f.get("error")]
    if errors:
        lines += ["## Failed runs", ""] + [f"- {f['scene']} / {f['series']}: {f['error']}" for f in errors] + [""]
    if sizes:
        lines += ["## Does `--size auto` land on the Pareto front?", "",
                  report.markdown_table(sizes, ["scene", "auto_params", "auto_psnr", "best_params",
                                                "best_psnr", "gap_db",
                                            "param_ratio", "on_front", "within_0.5dB_at_half", "front"]), ""]
    if profile and profile.get("shares"):
        lines += [f"## Where a training step's time goes ({profile.get('method')}, {profile.get('steps')} steps, "
                  f"{profile.get('rays')} rays per step)", "",
                  report.markdown_table([{"stage": k, "share_%": 100 * v} for k, v in profile["shares"].items()],
                                    ["stage", "share_%"], digits=1), ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="output folder (datasets are cached in OUT/datasets)")
    ap.add_argument("--quick", action="store_true", help="2 scenes, 48 px, 20 views, 40 s per run: under 10 min")
    ap.add_argument("--methods", help="comma-separated methods (default: nerf, nerf-nope and the fast method)")
    ap.add_argument("--scenes", help=f"comma-separated demo scenes (default: {','.join(FULL_SCENES)})")
    ap.add_argument("--minutes", type=float, help="training budget per run in minutes (default 5; quick 0.67); "
                                                  "--checkpoints given as minutes sets it to their last instead")
    ap.add_argument("--checkpoints", metavar="log|MINUTES",
                    help="training times at which to score each run, inside one run (--eval-at): 'log' (the default) "
                         "is 10 s doubling up to the budget plus 1, 2, 5 and 10 min where they fit (5 min: 10, 20, 40, "
                         "60, 80, 120, 160, 300 s); or comma-separated minutes like 1,2,5, the last being the budget. "
                         "Each point costs an evaluation of --eval-views views (not training time). --quick without "
                         "this flag: 50%% and 100%% of the budget")
    ap.add_argument("--resolution", type=int, help="capture resolution in pixels (default 200; quick 48)")
    ap.add_argument("--views", type=int, help="train views (default 100; quick 20)")
    ap.add_argument("--test-views", type=int, help="held-out test views (default 20; quick 3)")
    ap.add_argument("--eval-views", type=int,
                    help="evaluate this many evenly spaced test views at each checkpoint (default: all); the "
                         "classic MLP needs minutes per 200x200 view on a CPU")
    ap.add_argument("--engine", default="cycles", help="capture render engine (default cycles)")
    ap.add_argument("--samples", type=int, default=16, help="render samples per pixel for the capture")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-sizes", action="store_true", help="skip the fixed-size and --size auto series")
    ap.add_argument("--sizes", help="fixed sizes of the fast method to run beside --size auto "
                                    "(default small,medium; quick: small)")
    ap.add_argument("--size-scenes", help="scenes on which the size series run (default: all; quick: the first)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="training runs at a time, each given cores/jobs threads (default 1: one run uses the whole "
                         "machine). With 2 jobs on 2 cores every run gets one core: 'minutes of CPU' per run")
    ap.add_argument("--no-profile", action="store_true", help="skip the per-stage time profile")
    ap.add_argument("--reuse", help="comma-separated series to take from OUT/results.json instead of training again, "
                                    "where their settings match (after a code change that does not touch them)")
    ap.add_argument("--report-only", action="store_true",
                    help="train nothing: redraw the charts and summary.md from OUT/results.json")
    ap.add_argument("--independent", action="store_true",
                    help="a fresh run per checkpoint budget instead of one run with --eval-at (exact "
                         "per-budget schedules, "
                         "costs the sum of the budgets)")
    args = ap.parse_args(argv)
    quick = args.quick
    args.minutes = args.minutes if args.minutes is not None else (40 / 60 if quick else 5.0)
    args.resolution = args.resolution or (48 if quick else 200)
    args.views = args.views or (20 if quick else 100)
    args.test_views = args.test_views or (3 if quick else 20)
    if args.minutes <= 0:
        ap.error("--minutes must be positive")
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    try:
        parse_checkpoints(args.checkpoints, args.minutes * 60.0, quick)
    except ValueError as exc:
        ap.error(str(exc))
    return args


def report_only(out: str) -> int:
    """Redraw the charts and summary.md from the runs stored in OUT/results.json; nothing is trained."""
    path = os.path.join(out, "results.json")
    try:
        with open(path, encoding="utf-8") as fh:
            stored = json.load(fh)
        runs = stored["runs"]
        checkpoints = [float(c) for c in stored["checkpoints_seconds"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"benchmark: --report-only needs the results of an earlier benchmark in {path}: "
              f"{type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    try:
        written = draw_report(out, runs, checkpoints, stored.get("capture") or {}, stored.get("size_study") or [],
                              stored.get("profile"), stored.get("wall_seconds") or 0.0, stored.get("machine") or {})
    except (KeyError, TypeError) as exc:  # a hand-edited or foreign file: name it, no traceback
        print(f"benchmark: {path}: a run lacks a field the report needs ({type(exc).__name__}: {exc})", file=sys.stderr)
        return 1
    print(written["markdown"])
    print(f"benchmark: redrew {out}/summary.md" + "".join(f", {os.path.basename(c)}" for c in written["charts"])
          + f" from {path}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    out = os.path.abspath(args.out)
    if args.report_only:
        return report_only(out)
    machine = runner.machine_info()
    machine["jobs"] = args.jobs
    machine["threads_per_run"] = runner.thread_env(args.jobs).get("OMP_NUM_THREADS", os.cpu_count())
    train_help = runner.cli_help(*runner.nerf_core_cmd("train"))
    if "--max-seconds" not in train_help:
        print("benchmark: `python -m nerf_core train --help` failed or lacks --max-seconds; is "
              "nerf_core/engine/trainer.py built?\n"
              + train_help[-800:], file=sys.stderr)
        return 2
    plan = make_plan(args, train_help)
    unknown = unknown_names(plan, datasets.demo_scene_names(), runner.method_names())
    if unknown:
        print(f"benchmark: {unknown}", file=sys.stderr)
        return 2
    os.makedirs(out, exist_ok=True)
    logs = os.path.join(out, "logs")
    os.makedirs(logs, exist_ok=True)
    fast = default_fast_method()
    runs = plan.runs()
    budget = plan.checkpoints[-1]
    print(f"benchmark: {len(plan.scenes)} scenes x {len(plan.series)} series = {len(runs)} runs of {budget:g}s; "
          f"checkpoints {', '.join(f'{c:g}s' for c in plan.checkpoints)}; output {out}", file=sys.stderr)
    # The bar counts seconds of planned work: a capture ~ one run's budget / 2, a run its budget.
    capture_cost = budget / 2
    per_run = sum(plan.checkpoints) if args.independent else budget
    bar = ProgressBar(total=len(plan.scenes) * capture_cost + len(runs) * per_run, label="benchmark")
    t0 = time.monotonic()
    captured: dict = {}
    failures = 0
    for scene in plan.scenes:
        bar.set(bar.done, info=f"capture {scene}")
        try:
            ds, reused = datasets.ensure_dataset(scene, os.path.join(out, "datasets"), plan.capture,
                                                 log_path=os.path.join(logs, f"capture_{scene}.log"))
            captured[scene] = ds
        except runner.BenchError as exc:
            print(f"\nbenchmark: {exc} (log: {os.path.join(logs, f'capture_{scene}.log')})", file=sys.stderr)
            failures += 1
        bar.update(capture_cost)
    env_extra = runner.thread_env(args.jobs)
    progress = runner.SharedProgress(bar)
    failed: list[str] = []
    run_settings = {"seed": args.seed, "eval_views": args.eval_views, "jobs": args.jobs}
    reused = reusable_results(out, plan, set((args.reuse or "").split(",")) - {""}, run_settings)
    if reused:
        print(f"benchmark: reusing {len(reused)} runs from {out}/results.json: "
              + ", ".join(f"{sc}/{se}" for sc, se in reused), file=sys.stderr)

    def one_run(scene: str, series: Series):
        if (scene, series.label) in reused:
            progress.finish((scene, series.label), per_run)
            return reused[(scene, series.label)]
        if scene not in captured:
            progress.finish((scene, series.label), per_run)
            return None
        label = f"{scene}/{series.label}"
        r = train_with_checkpoints(
            captured[scene], os.path.join(out, "runs", scene, series.label.replace(" ", "_")), series,
            plan.checkpoints, args.seed, os.path.join(logs, f"train_{scene}_{series.label.replace(' ', '_')}.log"),
            lambda elapsed: progress.advance(label, min(elapsed, per_run), info=label),
            n_test=min(datasets.count_frames(captured[scene], "test"), args.eval_views or 10 ** 9),
            independent=args.independent, env_extra=env_extra)
        tr = r["train"]
        n_params, n_bytes = model_size(r["checkpoint"])
        if r["error"]:
            failed.append(label)
            print(f"\nbenchmark: {label}: {r['error']}", file=sys.stderr)
        progress.finish(label, per_run,
                        info=f"{label} " + (f"{report.fmt(r['points'][-1]['psnr'])} dB" if r["points"] else "failed"))
        return {"scene": scene, "series": series.label, "method": series.method, "flags": series.extra,
                "points": r["points"], "n_params": n_params or tr["n_params"], "model_bytes": n_bytes,
                "checkpoint_bytes": r["checkpoint_bytes"], "samples_per_s": tr["samples_per_s"],
                "steps": tr["steps"], "rollbacks": tr["rollbacks"], "nan": tr["nan"], "error": r["error"],
                "stage_times": tr.get("stage_times"), "threads": env_extra.get("OMP_NUM_THREADS")}

    results = [r for r in runner.run_parallel([lambda sc=sc, se=se: one_run(sc, se) for sc, se in runs],
                                              args.jobs) if r]
    failures += len(failed)
    bar.close(info="runs done")
    profile = None
    if plan.profile and captured and fast:
        try:
            profile = profile_method(next(iter(captured.values())), fast, steps=8 if args.quick else 20)
        except Exception as exc:  # noqa: BLE001 (a profile failure must not lose the benchmark's results)
            profile = {"error": f"{type(exc).__name__}: {exc}"}
            print(f"benchmark: profile of {fast} failed: {profile['error']}", file=sys.stderr)
    wall = time.monotonic() - t0
    written = write_outputs(out, results, plan, fast, profile, wall, machine, run_settings)
    print(written["markdown"])
    print(f"benchmark: wrote {out}/results.csv, final.csv, results.json, summary.md"
          + "".join(f", {os.path.basename(c)}" for c in written["charts"]) + f" in {wall / 60:.1f} min",
          file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
