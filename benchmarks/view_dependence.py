"""View dependence as a chart: each method with and without the view direction, on a glossy and a diffuse scene.

    python benchmarks/view_dependence.py --out DIR [--scenes glossy,diffuse] [--methods vmgrid,nerf]
                                      [--seconds 120] [--checkpoints 15,30,60] [--resolution 128]
                                      [--views 100] [--test-views 10] [--eval-views 5] [--datasets DIR2]
                                      [--report-only]

NeRF's claim: the direction input is what lets a radiance field reproduce view-dependent effects
(highlights, reflections). For each scene and each method M this trains M and ``M-noview`` (the same
method with a colour blind to the direction, ``view_dependent`` off) *at the same time*, one thread
each, so both see the same share of a (possibly shared) machine; test PSNR is measured at
``--checkpoints`` seconds of training time inside each run (``--eval-at``, as ``benchmark.py`` does).
Then it renders one test view of the first scene with every run and crops its brightest highlight.

Writes DIR/view_dependence.json (every point), DIR/view_dependence.png (PSNR against time, one panel
per scene and method), DIR/highlight_crops.png and DIR/summary.md (tables, the command, the commit).
``--report-only`` redraws them from DIR/view_dependence.json and the run folders.
Demo scenes are built and captured once (scripts/make_demo_scene.py, scripts/capture.py) into
--datasets (default DIR/datasets) and reused while the capture settings match.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
from benchmark import train_with_checkpoints  # noqa: E402  (one run measured at checkpoints)
from bench import datasets, runner  # noqa: E402
from bench.plan import Series  # noqa: E402
from view_dependence_report import write_report  # noqa: E402

NOVIEW = "-noview"  # the registered variant of a method with view_dependent off


def parse_args(argv):
    ap = argparse.ArgumentParser(prog="view_dependence.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the runs, the charts, JSON and summary.md")
    ap.add_argument("--scenes", default="glossy,diffuse", help="demo scenes (default: glossy,diffuse; the first gets "
                                                              "the highlight crops)")
    ap.add_argument("--methods", default="vmgrid,nerf", help="methods, each run beside its -noview variant")
    ap.add_argument("--seconds", type=float, default=120.0, help="training budget per run (default 120)")
    ap.add_argument("--checkpoints", default="15,30,60",
                    help="training seconds at which to also score each run, below --seconds (default 15,30,60)")
    ap.add_argument("--resolution", type=int, default=128, help="capture resolution in pixels (default 128)")
    ap.add_argument("--views", type=int, default=100, help="train views (default 100)")
    ap.add_argument("--test-views", type=int, default=10, help="held-out test views captured (default 10)")
    ap.add_argument("--eval-views", type=int, default=5,
                    help="evenly spaced test views scored at each point (default 5)")
    ap.add_argument("--datasets", help="capture cache folder (default OUT/datasets)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--report-only", action="store_true", help="train nothing: redraw from OUT/view_dependence.json")
    args = ap.parse_args(argv)
    try:
        marks = sorted(float(c) for c in args.checkpoints.split(",") if c.strip())
    except ValueError:
        ap.error(f"--checkpoints: comma-separated seconds, got {args.checkpoints!r}")
    if args.seconds <= 0 or any(not 0 < c < args.seconds for c in marks):
        ap.error(f"--checkpoints must lie strictly between 0 and --seconds {args.seconds:g}")
    args.marks = marks + [args.seconds]
    args.scene_list = [s.strip() for s in args.scenes.split(",") if s.strip()]
    args.method_list = [m.strip() for m in args.methods.split(",") if m.strip()]
    known = datasets.demo_scene_names()
    bad = [s for s in args.scene_list if known and s not in known]
    if bad or not args.scene_list:
        ap.error(f"--scenes: unknown {bad or 'none given'}; choose from {', '.join(known)}")
    if not args.method_list or any(m.endswith(NOVIEW) for m in args.method_list):
        ap.error("--methods: name the plain methods (vmgrid, nerf); each is run beside its -noview variant")
    return args


def capture_settings(args) -> dict:
    """capture.py flags (the capture cache key): only those that differ from capture.py's defaults."""
    settings = {"resolution": args.resolution, "test_count": args.test_views}
    if args.views != 100:
        settings["count"] = args.views
    return settings


def run_pair(args, dataset: str, scene: str, method: str, logs: str) -> list[dict]:
    """Train ``method`` and its -noview variant at once (one thread each); their result rows."""
    env = runner.thread_env(2)
    n_test = min(datasets.count_frames(dataset, "test"), args.eval_views)

    def one(name):
        def task():
            t0 = time.monotonic()
            r = train_with_checkpoints(dataset, os.path.join(args.out, "runs", scene, name), Series(name, name),
                                       args.marks, args.seed, os.path.join(logs, f"train_{scene}_{name}.log"),
                                       lambda _s: None, n_test=n_test, env_extra=env)
            print(f"view_dependence: {scene}/{name}: "
                  + (r["error"] or " ".join(f"{p['budget']:g}s {p['psnr']:.2f}" for p in r["points"]))
                  + f" ({time.monotonic() - t0:.0f} s wall)", file=sys.stderr, flush=True)
            return {"scene": scene, "method": name, "base_method": method, "view_dependent": name == method,
                    "points": r["points"], "steps": r["train"].get("steps"), "error": r["error"],
                    "run": os.path.relpath(os.path.join(args.out, "runs", scene, name), args.out)}
        return task

    return runner.run_parallel([one(method), one(method + NOVIEW)], 2)


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    os.makedirs(args.out, exist_ok=True)
    results_path = os.path.join(args.out, "view_dependence.json")
    if args.report_only:
        with open(results_path, encoding="utf-8") as fh:
            results = json.load(fh)
    else:
        logs = os.path.join(args.out, "logs")
        os.makedirs(logs, exist_ok=True)
        cache = args.datasets or os.path.join(args.out, "datasets")
        rows, captured = [], {}
        t0, commit = time.monotonic(), runner.git_commit()  # the code the runs start from, not HEAD at the end
        for scene in args.scene_list:
            print(f"view_dependence: capturing {scene} (cached in {cache})", file=sys.stderr, flush=True)
            captured[scene], _ = datasets.ensure_dataset(scene, cache, capture_settings(args),
                                                         log_path=os.path.join(logs, f"capture_{scene}.log"))
        for scene in args.scene_list:
            for method in args.method_list:
                rows += run_pair(args, captured[scene], scene, method, logs)
        given = sys.argv[1:] if argv is None else argv
        command = "python benchmarks/view_dependence.py " + " ".join(shlex.quote(a) for a in given)
        results = {"command": command, "commit": commit, "machine": runner.machine_info(),
                   "wall_minutes": round((time.monotonic() - t0) / 60, 1), "datasets": captured,
                   "capture": capture_settings(args), "seconds": args.seconds, "marks": args.marks,
                   "eval_views": args.eval_views, "threads_per_run": 1, "runs": rows}
        with open(results_path, "w", encoding="utf-8") as fh:
            json.dump(results, fh, indent=1)
    written = write_report(args.out, results)
    print("view_dependence: wrote " + ", ".join(written), file=sys.stderr)
    return 1 if any(r.get("error") for r in results["runs"]) else 0


if __name__ == "__main__":
    sys.exit(main())
