"""CPU training speed side by side: this checkout's default method against another commit's, per scene.

    python benchmarks/bench_cpu_speed.py --baseline REV_OR_DIR --out DIR [--scenes diffuse,glossy,...]
                                      [--seconds 300] [--resolution 200] [--datasets DIR] [--after 0.4]
                                      [--baseline-args "FLAGS"] [--new-args "FLAGS"] [--report-only]

For each demo scene (captured once at ``--resolution`` px, 100 train / 20 test views, Cycles 16
samples, as ``benchmarks/benchmark.py`` does, and cached in ``--datasets``), it starts

    OMP_NUM_THREADS=1 python -m nerf_core train DATASET --out RUN --max-seconds S --seed 0 --eval-views 5

from the baseline tree and from this one *at the same time*, one thread each, so both see the same
share of the machine (a shared machine slows both alike). ``--baseline`` is a folder holding another
checkout, or a git revision, checked out into a temporary worktree that is removed afterwards.

From each run's progress.jsonl it reads the steps made, the steps per second after growth (step
events from ``--after`` of the budget to the end: vmgrid's last growth stage is at 0.36) and the test
PSNR of the final evaluation. Writes DIR/results.json and DIR/summary.md (a table with the ratios, the
command, both commits and the machine) and DIR/cpu_speed.png (both, per scene). ``--baseline-args`` and
``--new-args`` add train flags to one side: ``--baseline . --new-args="--train-rays filter"`` (with the
``=``) measures a flag against the default on this very tree, side by side. ``--report-only``
rewrites the summary from results.json. Run again into the same folder (same commits and budget), it
keeps the scenes already measured and adds the others.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
from bench import datasets  # noqa: E402
from bench.plan import FULL_SCENES  # noqa: E402
from bench.runner import REPO_ROOT, git_commit, machine_info  # noqa: E402


def parse_args(argv):
    ap = argparse.ArgumentParser(prog="bench_cpu_speed.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", required=True, help="a folder with another checkout, or a git revision")
    ap.add_argument("--out", required=True, help="folder for the runs, results.json and summary.md")
    ap.add_argument("--scenes", default=",".join(FULL_SCENES), help=f"demo scenes (default: {','.join(FULL_SCENES)})")
    ap.add_argument("--seconds", type=float, default=300.0, help="training budget of every run (default 300)")
    ap.add_argument("--resolution", type=int, default=200, help="capture resolution in pixels (default 200)")
    ap.add_argument("--views", type=int, default=100, help="train views (default 100)")
    ap.add_argument("--test-views", type=int, default=20, help="test views captured (default 20)")
    ap.add_argument("--eval-views", type=int, default=5, help="test views scored at the end (default 5)")
    ap.add_argument("--datasets", help="capture cache folder (default OUT/datasets)")
    ap.add_argument("--after", type=float, default=0.4,
                    help="share of the budget after which the step rate counts as 'after growth' (default 0.4)")
    ap.add_argument("--capture-depth", action="store_true",
                    help="capture with depth maps (capture.py --depth), for runs with train --depth")
    ap.add_argument("--baseline-args", default="", help="extra train flags for the baseline's runs (one string)")
    ap.add_argument("--new-args", default="", help="extra train flags for this tree's runs (one string)")
    ap.add_argument("--report-only", action="store_true", help="train nothing: rewrite summary.md from results.json")
    args = ap.parse_args(argv)
    if not 0 <= args.after < 1:
        ap.error(f"--after: a share of the budget in [0, 1), got {args.after}")
    if args.seconds <= 0:
        ap.error(f"--seconds must be positive, got {args.seconds}")
    return args


def _git(*args: str, cwd: str = REPO_ROOT) -> str:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()


def run_stats(run: str, after: float) -> dict:
    """Steps, steps/s after ``after`` of the budget, and the final test PSNR from RUN/progress.jsonl."""
    events = []
    with open(os.path.join(run, "progress.jsonl"), encoding="utf-8") as fh:
        for line in fh:
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    steps = [e for e in events if e.get("event") == "step"]
    late = [e for e in steps if float(e.get("frac") or 0.0) >= after]
    rate = None
    if len(late) >= 2 and late[-1]["elapsed"] > late[0]["elapsed"]:
        rate = (late[-1]["step"] - late[0]["step"]) / (late[-1]["elapsed"] - late[0]["elapsed"])
    evals = [e for e in events if e.get("event") == "eval" and e.get("psnr") is not None]
    start = next((e for e in events if e.get("event") == "start"), {})
    return {"steps": steps[-1]["step"] if steps else 0, "steps_per_s_after_growth": rate,
            "psnr": float(evals[-1]["psnr"]) if evals else None,
            "resolution": (start.get("model") or {}).get("options", {}).get("res_final"),
            "notes": start.get("notes", [])}


def train_pair(trees: dict, dataset: str, out: str, args) -> dict:
    """Both trees' runs on ``dataset`` at the same time; returns {name: run_stats}."""
    procs = {}
    for name, tree in trees.items():
        run = os.path.join(out, name)
        log = open(os.path.join(out, name + ".log"), "w", encoding="utf-8")
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        env.pop("PYTHONPATH", None)  # each tree imports its own nerf_core (python -m from its root)
        cmd = [sys.executable, "-m", "nerf_core", "train", os.path.abspath(dataset), "--out", os.path.abspath(run),
               "--max-seconds", f"{args.seconds:g}", "--seed", "0", "--eval-views", str(args.eval_views), "--no-bar",
               *shlex.split(args.baseline_args if name == "baseline" else args.new_args)]
        procs[name] = (subprocess.Popen(cmd, cwd=tree, env=env, stdout=log, stderr=subprocess.STDOUT), log, run)
    result = {}
    for name, (proc, log, run) in procs.items():
        code = proc.wait()
        log.close()
        if code != 0:
            raise SystemExit(f"bench_cpu_speed: the {name} run failed (exit {code}); see {log.name}")
        result[name] = run_stats(run, args.after)
    return result


def summary(results: dict) -> str:
    rows = results["scenes"]
    lines = [
        "# CPU training speed side by side: this commit against a baseline",
        "",
        f"Command: `{results['command']}`",
        f"Baseline `{results['baseline_commit']}`, this tree `{results['commit']}`. Machine: "
        f"{results['machine'].get('cpu', '?')}, {results['machine'].get('cpus', '?')} cores, torch "
        f"{results['machine'].get('torch', '?')}, load average at the end {results['machine'].get('load_avg', '?')}. "
        f"Each pair trained at the same time, one thread each ({results['seconds']:g} s budget, seed 0); "
        f"test PSNR on {results['eval_views']} evenly spaced test views at the end. Steps per second "
        f"after growth: step events from {results['after']:.0%} of the budget to the end.",
        f"Train flags: baseline `{results.get('baseline_args') or '(defaults)'}`, new "
        f"`{results.get('new_args') or '(defaults)'}`.",
        "",
        "| scene | steps (base / new) | steps/s after growth (base / new) | ratio | PSNR base | PSNR new | gain dB |",
        "|---|---|---|---|---|---|---|",
    ]
    ratios, gains = [], []
    for scene, r in rows.items():
        b, n = r["baseline"], r["new"]
        ratio = (n["steps_per_s_after_growth"] / b["steps_per_s_after_growth"]
                 if b["steps_per_s_after_growth"] and n["steps_per_s_after_growth"] else None)
        gain = n["psnr"] - b["psnr"] if n["psnr"] is not None and b["psnr"] is not None else None
        ratios += [ratio] if ratio else []
        gains += [gain] if gain is not None else []
        fmt = lambda v, f: "n/a" if v is None else format(v, f)  # noqa: E731
        lines.append(f"| {scene} | {b['steps']} / {n['steps']} | {fmt(b['steps_per_s_after_growth'], '.2f')} / "
                     f"{fmt(n['steps_per_s_after_growth'], '.2f')} | {fmt(ratio, '.2f')}x | {fmt(b['psnr'], '.2f')} | "
                     f"{fmt(n['psnr'], '.2f')} | {fmt(gain, '+.2f')} |")
    if ratios:
        geo = 1.0
        for x in ratios:
            geo *= x
        geo **= 1.0 / len(ratios)
        lines += ["", f"Steps per second after growth: {min(ratios):.2f}x to {max(ratios):.2f}x, geometric mean "
                      f"{geo:.2f}x. PSNR change at the end of the budget: {min(gains):+.2f} to {max(gains):+.2f} dB."]
    return "\n".join(lines) + "\n"


def chart(results: dict, path: str) -> bool:
    """DIR/cpu_speed.png: steps per second after growth and final PSNR per scene, baseline beside new.
    False (and no file) without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    scenes = list(results["scenes"])
    rows = [results["scenes"][s] for s in scenes]
    x = list(range(len(scenes)))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, label in ((axes[0], "steps_per_s_after_growth", "training steps per second after growth"),
                           (axes[1], "psnr", f"test PSNR (dB) after {results['seconds']:g} s")):
        base = [r["baseline"][key] or 0.0 for r in rows]
        new = [r["new"][key] or 0.0 for r in rows]
        # a flag A/B on one tree is labelled by its flags, not by two equal commits
        ax.bar([i - 0.2 for i in x], base, 0.4, color="#999999",
               label=f"baseline {results['baseline_commit']} {results.get('baseline_args', '')}".strip())
        ax.bar([i + 0.2 for i in x], new, 0.4, color="#1f77b4",
               label=f"this commit {results['commit']} {results.get('new_args', '')}".strip())
        if key == "psnr":
            lo = min(v for v in base + new if v) - 2
            ax.set_ylim(lo, max(base + new) + 1)
        else:
            for i, (b, n) in enumerate(zip(base, new)):
                if b and n:
                    ax.annotate(f"{n / b:.2f}x", (i + 0.2, n), ha="center", va="bottom", fontsize=8)
        ax.set_xticks(x)
        ax.set_xticklabels(scenes, rotation=30)
        ax.set_title(label, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower left")
    fig.suptitle("vmgrid on one CPU thread each, the two runs side by side", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "results.json")
    if args.report_only:
        with open(path, encoding="utf-8") as fh:
            results = json.load(fh)
        with open(os.path.join(args.out, "summary.md"), "w", encoding="utf-8") as fh:
            fh.write(summary(results))
        chart(results, os.path.join(args.out, "cpu_speed.png"))
        return 0
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = sorted(set(scenes) - set(datasets.demo_scene_names()))
    if unknown:
        raise SystemExit(f"bench_cpu_speed: --scenes: unknown demo scene(s) {unknown}; "
                         f"known: {datasets.demo_scene_names()}")
    temp = None
    baseline = args.baseline
    if not os.path.isdir(baseline):
        temp = tempfile.mkdtemp(prefix="nerf_baseline_")
        try:
            _git("worktree", "add", "--detach", temp, baseline)
        except subprocess.CalledProcessError as exc:
            raise SystemExit(f"bench_cpu_speed: --baseline {baseline!r} is neither a folder nor a git revision "
                             f"({exc.stderr.strip()})")
        baseline = temp
    cache = args.datasets or os.path.join(args.out, "datasets")
    results = {"command": "python benchmarks/bench_cpu_speed.py " + shlex.join(sys.argv[1:] if argv is None else argv),
               "baseline_commit": git_commit(baseline), "commit": git_commit(REPO_ROOT),
               "machine": machine_info(),
               "seconds": args.seconds, "eval_views": args.eval_views, "after": args.after,
               "baseline_args": args.baseline_args, "new_args": args.new_args, "scenes": {}}
    if os.path.isfile(path):  # an earlier invocation into the same folder: keep its scenes, add the rest
        with open(path, encoding="utf-8") as fh:
            earlier = json.load(fh)
        if earlier.get("baseline_commit") == results["baseline_commit"] and earlier.get("commit") == results["commit"] \
                and earlier.get("seconds") == args.seconds and earlier.get("new_args", "") == args.new_args \
                and earlier.get("baseline_args", "") == args.baseline_args:
            results["scenes"] = earlier.get("scenes", {})
            results["command"] = earlier.get("command", results["command"]) + "; then " + results["command"]
    try:
        for i, scene in enumerate(scenes, 1):
            if scene in results["scenes"]:
                print(f"bench_cpu_speed: [{i}/{len(scenes)}] {scene}: already in {path}", flush=True)
                continue
            settings = {"resolution": args.resolution, "count": args.views, "val_count": 1,
                        "test_count": args.test_views, "engine": "cycles", "samples": 16,
                        **({"depth": True} if args.capture_depth else {})}
            ds, _ = datasets.ensure_dataset(scene, cache, settings, log_path=os.path.join(args.out, "capture.log"))
            out = os.path.join(args.out, "runs", scene)
            os.makedirs(out, exist_ok=True)
            t0 = time.time()
            print(f"bench_cpu_speed: [{i}/{len(scenes)}] {scene}: two runs of {args.seconds:g} s side by side "
                  f"(about {args.seconds * 1.3 / 60:.0f} min)", flush=True)
            results["scenes"][scene] = train_pair({"baseline": baseline, "new": REPO_ROOT}, ds, out, args)
            results["scenes"][scene]["wall_s"] = time.time() - t0
            with open(path, "w", encoding="utf-8") as fh:
                json.dump(results, fh, indent=1)
    finally:
        if temp:
            subprocess.run(["git", "worktree", "remove", "--force", temp], cwd=REPO_ROOT, capture_output=True)
    results["machine"] = machine_info()  # the load average at the end
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(results, fh, indent=1)
    with open(os.path.join(args.out, "summary.md"), "w", encoding="utf-8") as fh:
        fh.write(summary(results))
    chart(results, os.path.join(args.out, "cpu_speed.png"))
    print(summary(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
