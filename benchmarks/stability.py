"""Where does each method break down? Seeds, few views, noisy poses and learning rates.

    python benchmarks/stability.py [--quick] --out DIR [--methods a,b] [--scene NAME] [--seeds N]
                                [--views 4,8,16,32,64] [--pose-noise 0.5:0.005,2:0.02]
                                [--lr-scales 0.1,0.3,1,3,10] [--seconds S] [--resolution R]
                                [--threshold DB] [--drop DB] [--report-only]

Every run goes through the user-facing tools: the scene is captured once (scripts/make_demo_scene.py,
scripts/capture.py, cached in DIR/datasets), derived datasets (fewer train views, perturbed train
poses) are copies whose images are links, and each setting is trained (``python -m nerf_core
train``), evaluated on the held-out test views (``eval``) and rendered (``render``) to look for
floaters: opacity where the ground-truth alpha is empty.

Studies (each method, each setting, ``--seeds`` seeds; mean and spread reported):
- ``base``: the full capture, default settings (this is the seed study);
- ``views``: train on 4, 8, 16, 32, 64 evenly spread views;
- ``pose_noise``: train poses rotated by D degrees and moved by F times the camera distance;
- ``lr``: learning rate scaled over a decade each way (needs the trainer's ``--lr-scale`` or ``--lr``).

A setting is *broken* when a run errors, produces NaN, diverges (3 or more rollbacks, or any rollback
with low PSNR), scores below ``--threshold`` dB or more than ``--drop`` dB below the method's own base
PSNR, or shows floaters on more than 5% of the background pixels. Writes DIR/stability.csv (every
run), DIR/settings.csv (mean/spread per setting), DIR/stability.md (the breakdown table) and
DIR/stability.png. ``--report-only`` re-judges a finished study's runs (say with another
``--threshold``) and redraws its chart without training anything.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
from bench import analysis, datasets, report, runner  # noqa: E402  (benchmarks/bench, found through the line above)
from bench.plan import BASE_METHODS, default_fast_method, name_problem  # noqa: E402

from nerf_core.utils.progressbar import ProgressBar  # noqa: E402

FLOATER_LIMIT = 0.05  # share of ground-truth background pixels rendered opaque
ROLLBACK_LIMIT = 3


def breakdown_reason(row: dict, threshold: float, base_psnr: float | None = None, drop: float = 3.0) -> str:
    """Why a run (or a setting's mean row) counts as broken; "" when it does not."""
    psnr = row.get("psnr")
    if row.get("error"):
        return f"error: {row['error']}"
    if row.get("nan"):
        return "NaN" + (" (no usable model)" if psnr is None else " (recovered by rollback)")
    rollbacks = row.get("rollbacks") or 0
    low = psnr is None or psnr < threshold or (base_psnr is not None and psnr < base_psnr - drop)
    if rollbacks >= ROLLBACK_LIMIT or (rollbacks and low):
        return f"diverged ({rollbacks} rollbacks)"
    if psnr is None:
        return "no PSNR"
    if psnr < threshold:
        return f"PSNR < {threshold:g}"
    if base_psnr is not None and psnr < base_psnr - drop:
        return f"PSNR {psnr - base_psnr:+.1f} dB vs base"
    if (row.get("floater_pixels") or 0.0) > FLOATER_LIMIT:
        return f"floaters ({100 * row['floater_pixels']:.0f}% of background)"
    return ""


def breakdown_table(rows: list[dict]) -> list[dict]:
    """One row per (method, study): the settings that broke, in the order they were run."""
    out: dict = {}
    for r in rows:
        key = (r["method"], r["study"])
        entry = out.setdefault(key, {"method": r["method"], "study": r["study"], "failing": [], "n": 0})
        entry["n"] += 1
        if r.get("broken"):
            entry["failing"].append(f"{r['setting']}: {r['broken']}")
    table = []
    for key in sorted(out):
        e = out[key]
        table.append({"method": e["method"], "study": e["study"],
                      "breaks_at": "; ".join(e["failing"]) if e["failing"] else "no breakdown",
                      "settings_tried": e["n"]})
    return table


def parse_pose_noise(text: str) -> list[tuple[float, float]]:
    """``"0.5:0.005,2:0.02"`` -> [(0.5, 0.005), (2.0, 0.02)] (degrees, fraction of camera distance)."""
    out = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if not re.fullmatch(r"[0-9.]+:[0-9.]+", item):
            raise SystemExit(f"stability: --pose-noise item {item!r} must be DEGREES:FRACTION, e.g. 2:0.02")
        deg, frac = item.split(":")
        out.append((float(deg), float(frac)))
    return out


def lr_flag(train_help: str) -> str | None:
    for flag in ("--lr-scale", "--lr"):
        if re.search(re.escape(flag) + r"\b(?!-)", train_help):
            return flag
    return None


def run_setting(dataset: str, run_dir: str, method: str, seed: int, seconds: float, extra: list[str],
                log_path: str, on_progress, render: bool = True, env_extra: dict | None = None) -> dict:
    """Train, evaluate and render one configuration; never raises for a failed run (that is data).

    The trainer's own final evaluation on every test view gives PSNR/SSIM (one process fewer than a
    separate ``eval``); ``render`` of the test cameras gives the alpha compared for floaters.
    ``env_extra`` goes to every child (``runner.thread_env`` when runs share the machine).
    """
    n_test = datasets.count_frames(dataset, "test")
    cmd = runner.nerf_core_cmd("train", dataset, "--out", run_dir, "--method", method, "--max-seconds", f"{seconds:g}",
                               "--seed", str(seed), "--overwrite", "--eval-views", str(n_test), "--log-every", "10",
                               "--no-bar", *extra)

    def on_event(ev):
        if ev.get("event") == "step" and ev.get("elapsed") is not None:
            on_progress(float(ev["elapsed"]))

    res = runner.run_cli(cmd, on_event=on_event, log_path=log_path, env_extra=env_extra)
    summary = analysis.summarize_training(res.events)
    row = {"psnr": None, "ssim": None, "rollbacks": summary["rollbacks"], "nan": summary["nan"],
           "steps": summary["steps"], "train_psnr": summary["train_psnr"], "n_params": summary["n_params"],
           "lr": _base_lr(run_dir), "floater_alpha": None, "floater_pixels": None, "error": None}
    if not res.ok:
        row["error"] = res.error_message()
        return row
    metrics, why = runner.final_test_metrics(res, run_dir, log_path, env_extra)
    if metrics is None:
        row["error"] = f"eval: {why}"
        return row
    row["psnr"], row["ssim"] = metrics.get("psnr"), metrics.get("ssim")
    if row["psnr"] is None:
        row["nan"] = True  # NaN metrics come out as null
    if render:
        out = os.path.join(run_dir, "test_renders")
        rr = runner.run_cli(runner.nerf_core_cmd("render", run_dir, "--cameras", os.path.join(dataset,
                                                                                              "transforms_test.json"),
                                                 "--out", out, "--split", "test", "--overwrite", "--no-bar"),
                            log_path=log_path, env_extra=env_extra)
        if rr.ok:
            row.update({k: v for k, v in analysis.floater_stats(out, dataset).items() if k != "n_views"})
        else:
            row["render_error"] = rr.error_message()
    return row


def _base_lr(run_dir: str):
    """The base learning rate the trainer used (RUN/config.json ``lr``; step events carry the scheduled one)."""
    try:
        with open(os.path.join(run_dir, "config.json"), encoding="utf-8") as fh:
            return float(json.load(fh).get("lr"))
    except (OSError, ValueError, TypeError):
        return None


def summarise(runs: list[dict], threshold: float, drop: float) -> tuple[list[dict], list[dict]]:
    """Per-setting mean and spread, then the verdicts (relative to each method's own base).

    ``runs``: one dict per training run (method, study, setting, seed, psnr, ...), in plan order;
    sets each run's ``broken``. Returns (settings, breakdown table), both in first-seen order.
    """
    groups: dict = {}  # (method, study, setting) -> runs, in first-seen order
    for r in runs:
        groups.setdefault((r["method"], r["study"], r["setting"]), []).append(r)
    methods = list(dict.fromkeys(k[0] for k in groups))
    settings = []
    for (method, study, setting), rs in sorted(groups.items(), key=lambda kv: methods.index(kv[0][0])):
        m, sd, n = analysis.mean_std([r["psnr"] for r in rs])
        fm, _, _ = analysis.mean_std([r["floater_pixels"] for r in rs])
        settings.append({"method": method, "study": study, "setting": setting, "psnr_mean": m, "psnr_std": sd,
                         "n_ok": n, "n_runs": len(rs), "ssim_mean": analysis.mean_std([r["ssim"] for r in rs])[0],
                         "floater_pixels": fm, "rollbacks": sum(r["rollbacks"] or 0 for r in rs),
                         "nan": any(r["nan"] for r in rs),
                         "error": next((r["error"] for r in rs if r["error"]), None)})
    base_psnr = {s["method"]: s["psnr_mean"] for s in settings if s["study"] == "base"}
    for r in runs:
        r["broken"] = breakdown_reason(r, threshold, base_psnr.get(r["method"]) if r["study"] != "base" else None, drop)
    for s in settings:
        # A setting is broken when any of its seeds broke: users get one seed, not the mean.
        reasons = [r["broken"] for r in groups[(s["method"], s["study"], s["setting"])] if r["broken"]]
        seeds = f" ({len(reasons)}/{s['n_runs']} seeds)" if s["n_runs"] > 1 else ""
        s["broken"] = reasons[0] + seeds if reasons else ""
    return settings, breakdown_table(settings)


def breakdown_rules(settings: list[dict], drop: float) -> dict:
    """{method: base mean PSNR - ``drop``}: the level below which ``breakdown_reason`` calls a run of
    that method broken relative to its own base (methods without a base PSNR are left out)."""
    return {s["method"]: s["psnr_mean"] - drop for s in settings
            if s["study"] == "base" and s.get("psnr_mean") is not None}


def chart_groups(settings: list[dict], n_train: int | None) -> dict:
    """{study: {method: [(label, mean, std), ...]}} for ``report.chart_bars``; a broken setting's
    point has a 4th element, True, and is drawn hatched.

    Each method's base run is drawn inside every study, at the place it belongs in that sweep
    (``64`` views, ``x1`` learning rate, ``0deg/0`` pose noise), so a panel reads as a sweep; the
    base panel itself is then left out.
    """
    base_label = {"views": str(n_train) if n_train else "all", "lr": "x1", "pose_noise": "0deg/0"}
    groups: dict = {}
    for s in settings:
        point = (str(s["setting"]), s["psnr_mean"], s["psnr_std"]) + ((True,) if s.get("broken") else ())
        groups.setdefault(s["study"], {}).setdefault(s["method"], []).append(point)
    base = groups.get("base", {})
    for study, per_method in groups.items():
        if study not in base_label:
            continue
        for method, pts in per_method.items():
            if method not in base:
                continue
            pts.append((base_label[study], *base[method][0][1:]))
            pts.sort(key=lambda p: _sweep_key(p[0]))
    if len(groups) > 1:
        groups.pop("base", None)  # shown inside every other panel already
    return groups


def _sweep_key(label: str) -> float:
    """Where a setting label sits on its sweep's axis: '16' -> 16, 'x0.3' -> 0.3, '2deg/0.02' -> 2."""
    m = re.match(r"x?([0-9.]+)", label)
    return float(m.group(1)) if m else float("inf")


def write_report(out: str, runs: list[dict], *, machine: dict, capture: dict, scene: str, seconds: float,
                 threshold: float, drop: float, jobs: int, env_extra: dict | None, notes: list[str],
                 wall: float) -> str:
    """Judge ``runs`` and write OUT/stability.{csv,json,md,png} and OUT/settings.csv; returns the markdown."""
    settings, table = summarise(runs, threshold, drop)
    report.write_csv(os.path.join(out, "stability.csv"), runs)
    report.write_csv(os.path.join(out, "settings.csv"), settings)
    report.write_json(os.path.join(out, "stability.json"), {"machine": machine, "wall_seconds": wall,
                                                            "capture": capture,
                                                        "scene": scene, "seconds_per_run": seconds, "jobs": jobs,
                                                        "threads_per_run": (env_extra or {}).get("OMP_NUM_THREADS"),
                                                        "threshold_db": threshold, "drop_db": drop, "runs": runs,
                                                        "settings": settings, "breakdown": table, "notes": notes})
    n_train = capture.get("count")
    chart = report.chart_bars(chart_groups(settings, n_train), os.path.join(out, "stability.png"),
                          f"Test PSNR per setting ({scene}, {seconds:g} s runs; bars: mean, whiskers: std)",
                          "test PSNR (dB)", threshold=threshold, rules=breakdown_rules(settings, drop),
                          rule_label=f"breakdown rule: method's base \u2212 {drop:g} dB (its colour)")
    threads = (env_extra or {}).get("OMP_NUM_THREADS")
    md = "\n".join([
        "# Stability: where each method breaks down", "",
        f"Scene `{scene}`, {capture.get('resolution')} px, {n_train} train / {capture.get('test_count')} test views, "
        f"{seconds:g} s of training per run; machine: {machine.get('cpu', '?')}, {machine.get('cpus')} CPUs, "
        f"load {machine.get('load_avg')}; wall time {wall / 60:.1f} min; "
        + (f"{jobs} runs at a time, {threads} thread(s) each." if threads else "one run at a time, all cores."),
        f"Broken = error, NaN, >= {ROLLBACK_LIMIT} rollbacks, PSNR < {threshold:g} dB or > {drop:g} dB "
        f"below the method's base, or floaters on > {100 * FLOATER_LIMIT:.0f}% of background pixels.", "",
        *[f"Note: {n}" for n in notes], "",
        "## Breakdown", "", report.markdown_table(table, ["method", "study", "breaks_at", "settings_tried"]), "",
        "## Every setting (mean and std over seeds)", "",
        report.markdown_table(settings, ["method", "study", "setting", "psnr_mean", "psnr_std", "n_ok", "n_runs",
                                     "floater_pixels", "rollbacks", "broken"]), "",
        f"![stability]({os.path.basename(chart)})", "",
    ])
    with open(os.path.join(out, "stability.md"), "w", encoding="utf-8") as fh:
        fh.write(md)
    print(f"stability: wrote {out}/stability.csv, settings.csv, stability.json, stability.md, stability.png",
          file=sys.stderr)
    return md


def report_only(args) -> int:
    """Re-judge the runs stored in OUT/stability.json with this call's --threshold/--drop; no training."""
    out = os.path.abspath(args.out)
    path = os.path.join(out, "stability.json")
    try:
        with open(path, encoding="utf-8") as fh:
            stored = json.load(fh)
        runs = stored["runs"]
    except (OSError, ValueError, KeyError) as exc:
        print(f"stability: --report-only needs the runs of an earlier study in {path}: {exc}", file=sys.stderr)
        return 1
    threshold = args.threshold_given if args.threshold_given is not None else stored.get("threshold_db", args.threshold)
    drop = args.drop_given if args.drop_given is not None else stored.get("drop_db", args.drop)
    threads = stored.get("threads_per_run")
    print(write_report(out, runs, machine=stored.get("machine", {}), capture=stored.get("capture", {}),
                       scene=stored.get("scene", args.scene), seconds=stored.get("seconds_per_run", args.seconds),
                       threshold=threshold, drop=drop, jobs=stored.get("jobs", args.jobs),
                       env_extra={"OMP_NUM_THREADS": threads} if threads else None,
                       notes=stored.get("notes", []), wall=stored.get("wall_seconds", 0.0)))
    return 0


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true", help="fewer settings, 1 seed off-base, 15 s runs at 48 px")
    ap.add_argument("--methods", help="comma-separated methods (default: nerf, nerf-nope and the fast method)")
    ap.add_argument("--scene", default="diffuse", help="demo scene (default diffuse)")
    ap.add_argument("--seeds", type=int, help="seeds per setting (default 3; quick: 3 on base, 1 elsewhere)")
    ap.add_argument("--other-seeds", type=int, help="seeds for the settings other than base (default: --seeds)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="runs at a time, each given cores/jobs threads (default 1)")
    ap.add_argument("--views", help="train view counts (default 4,8,16,32,64; quick 4,8,24)")
    ap.add_argument("--pose-noise", help="DEG:FRAC items (default 0.5:0.005,1:0.01,2:0.02,5:0.05; quick 2:0.02)")
    ap.add_argument("--lr-scales", help="learning-rate multipliers (default 0.1,0.3,3,10; quick 0.1,10)")
    ap.add_argument("--seconds", type=float, help="training seconds per run (default 60; quick 15)")
    ap.add_argument("--resolution", type=int, help="capture resolution (default 64; quick 48)")
    ap.add_argument("--test-views", type=int, help="held-out views (default 8; quick 4)")
    ap.add_argument("--threshold", type=float, help="absolute PSNR floor in dB (default 18; quick 14)")
    ap.add_argument("--drop", type=float, help="dB below the method's own base PSNR that counts as broken (default 3)")
    ap.add_argument("--report-only", action="store_true",
                    help="train nothing: re-judge the runs in OUT/stability.json with --threshold/--drop and redraw")
    ap.add_argument("--engine", default="cycles")
    ap.add_argument("--samples", type=int, default=16)
    args = ap.parse_args(argv)
    q = args.quick
    args.views = [int(v) for v in (args.views or ("4,8,24" if q else "4,8,16,32,64")).split(",")]
    args.pose_noise = parse_pose_noise(args.pose_noise or ("2:0.02" if q else "0.5:0.005,1:0.01,2:0.02,5:0.05"))
    args.lr_scales = [float(x) for x in (args.lr_scales or ("0.1,10" if q else "0.1,0.3,3,10")).split(",")]
    args.seconds = args.seconds or (15.0 if q else 60.0)
    args.resolution = args.resolution or (48 if q else 64)
    args.test_views = args.test_views or (4 if q else 8)
    args.threshold_given, args.drop_given = args.threshold, args.drop
    args.threshold = args.threshold if args.threshold is not None else (14.0 if q else 18.0)
    args.drop = args.drop if args.drop is not None else 3.0
    args.base_seeds = args.seeds or 3
    args.other_seeds = args.other_seeds or args.seeds or (1 if q else 3)
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    return args


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.report_only:
        return report_only(args)
    machine = runner.machine_info()  # the load average before this study adds its own
    machine["jobs"] = args.jobs

    out = os.path.abspath(args.out)
    train_help = runner.cli_help(*runner.nerf_core_cmd("train"))
    if "--max-seconds" not in train_help:
        print("stability: `python -m nerf_core train --help` failed; is "
              "nerf_core/engine/trainer.py built?\n" + train_help[-800:],
              file=sys.stderr)
        return 2
    fast = default_fast_method()
    methods = ([m.strip() for m in args.methods.split(",") if m.strip()] if args.methods
               else BASE_METHODS + ([fast] if fast and fast not in BASE_METHODS else []))
    unknown = (name_problem("--scene", [args.scene], datasets.demo_scene_names())
               or name_problem("--methods", methods, runner.method_names()))
    if unknown:
        print(f"stability: {unknown}", file=sys.stderr)
        return 2
    logs = os.path.join(out, "logs")
    os.makedirs(logs, exist_ok=True)
    lr = lr_flag(train_help)
    notes = []
    if not lr:
        notes.append("The trainer has no --lr-scale/--lr flag, so the learning-rate study was skipped.")
    n_train = max(args.views)
    capture = {"resolution": args.resolution, "count": n_train, "val_count": 1, "test_count": args.test_views,
               "engine": args.engine, "samples": args.samples}

    # The plan: (study, setting label, dataset maker, extra flags, seeds)
    plan = [("base", "default", None, [], list(range(args.base_seeds)))]
    for v in args.views:
        if v != n_train:
            plan.append(("views", v, ("views", v), [], list(range(args.other_seeds))))
    for deg, frac in args.pose_noise:
        plan.append(("pose_noise", f"{deg:g}deg/{frac:g}", ("pose", deg, frac), [], list(range(args.other_seeds))))
    if lr:
        for s in args.lr_scales:
            if s != 1.0:
                plan.append(("lr", f"x{s:g}", None, [lr, f"{s:g}"] if lr == "--lr-scale" else None,
                             list(range(args.other_seeds))))
    n_runs = len(methods) * sum(len(p[4]) for p in plan)
    per_run = args.seconds + 10.0  # eval + render overhead, for the ETA only
    bar = ProgressBar(total=n_runs * per_run + 60.0, label="stability")
    t0 = time.monotonic()
    bar.set(0, info=f"capture {args.scene}")
    try:
        base_ds, _ = datasets.ensure_dataset(args.scene, os.path.join(out, "datasets"), capture,
                                       log_path=os.path.join(logs, "capture.log"))
    except runner.BenchError as exc:
        bar.close()
        print(f"stability: {exc}", file=sys.stderr)
        return 1
    bar.set(60.0)
    derived: dict = {}

    def dataset_for(spec):
        if spec is None:
            return base_ds
        if spec not in derived:
            name = "_".join(str(x) for x in spec)
            dst = os.path.join(out, "derived", name)
            if spec[0] == "views":
                derived[spec] = datasets.subset_views(base_ds, dst, spec[1])
            else:
                derived[spec] = datasets.perturb_poses(base_ds, dst, spec[1], spec[2], seed=0)
        return derived[spec]

    env_extra = runner.thread_env(args.jobs)
    progress = runner.SharedProgress(bar)

    def one_run(method, study, setting, ds, extra, seed):
        label = f"{method} {study}={setting} seed={seed}"
        run_dir = os.path.join(out, "runs", method, f"{study}_{setting}".replace("/", "_"), f"seed{seed}")
        row = run_setting(ds, run_dir, method, seed, args.seconds, list(extra),
                          os.path.join(logs, f"{method}_{study}_{setting}_{seed}.log".replace("/", "_")),
                          lambda elapsed: progress.advance(label, min(elapsed, args.seconds), info=label),
                          env_extra=env_extra)
        row.update({"method": method, "study": study, "setting": setting, "seed": seed})
        progress.finish(label, per_run, info=f"{label}: {report.fmt(row['psnr'])} dB")
        return row

    # Derived datasets are made up front so parallel runs never race to create one.
    for _study, _setting, spec, _extra, _seeds in plan:
        dataset_for(spec)
    # Phase 1: every run whose flags are known. Phase 2: learning rates given as a plain --lr,
    # which are multiples of the lr each method's base run reported.
    runs = runner.run_parallel([
        lambda m=method, p=p, seed=seed: one_run(m, p[0], p[1], dataset_for(p[2]), p[3], seed)
        for method in methods for p in plan if p[3] is not None for seed in p[4]], args.jobs)
    later = []
    for method in methods:
        for study, setting, spec, extra, seeds in plan:
            if extra is not None:
                continue
            base_lr = next((r["lr"] for r in runs if r["method"] == method and r["study"] == "base" and r["lr"]), None)
            if base_lr is None:
                notes.append(f"{method}: lr study skipped (its base run reported no lr)")
                continue
            flags = ["--lr", f"{base_lr * float(str(setting)[1:]):g}"]
            later += [lambda m=method, st=study, se=setting, sp=spec, f=flags, seed=seed:
                      one_run(m, st, se, dataset_for(sp), f, seed) for seed in seeds]
    runs += runner.run_parallel(later, args.jobs)
    bar.close()

    markdown = write_report(out, runs, machine=machine, capture=capture, scene=args.scene, seconds=args.seconds,
                            threshold=args.threshold, drop=args.drop, jobs=args.jobs, env_extra=env_extra,
                            notes=notes, wall=time.monotonic() - t0)
    print(markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
