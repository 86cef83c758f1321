"""Side by side on one device: our default method against TensoRF's official code, test PSNR over seconds.

    python benchmarks/bench_gpu_tensorf.py --dataset DS --tensorf TENSORF_DIR --out OUT [--device cuda]
        [--ours-seconds 90] [--eval-at 10,20,30,45,60,90] [--eval-views 20]
        [--tensorf-iters 5000] [--tensorf-eval-every 1000] [--skip-ours | --skip-tensorf] [--quick]
    python benchmarks/bench_gpu_tensorf.py --out OUT --report-only      # summary.md + chart from results.json

Ours: ``python -m nerf_core train DS --out OUT/ours --max-seconds S --eval-at ... --eval-views N``
(the default method, the command users run). TensoRF: its unmodified code from ``--tensorf`` (a
checkout of apchenstu/TensoRF), through ``bench.tensorf_launch``: VM-192 (``configs/lego.txt``) for
``--tensorf-iters`` iterations with its upsampling and alpha-mask schedule scaled by iterations/10000
(5000 -> halved), every test view evaluated each ``--tensorf-eval-every`` iterations and at the end.
Both report training seconds without data loading and evaluation. ``--quick`` is a CPU plumbing test
(seconds, tiny grids; numbers mean nothing).

Writes ``OUT/results.json`` (after each side, so a run cut short keeps what finished),
``OUT/summary.md`` (device, torch, headline, table, commands) and ``OUT/psnr_vs_seconds.png`` where
matplotlib is installed. The device run, step by step: docs/benchmarks/gpu_tensorf.md.

Preparing a GPU session (no internet there; the working tree and up to 8 ignored paths travel):

    fetch github:apchenstu/TensoRF                       # the search tool, into /work/.mirror
    git -C /work/.mirror/apchenstu+TensoRF/repo archive --prefix=third_party/tensorf/ HEAD | tar -x -C .
    python scripts/make_demo_scene.py multi --out bench_gpu/multi.blend --overwrite   # bpy: here only
    python scripts/capture.py --blend bench_gpu/multi.blend --out bench_gpu/multi200 \
        --resolution 200 --count 100 --val-count 1 --test-count 20 --engine cycles --samples 16
    run(carry=["third_party/tensorf", "bench_gpu/multi200"], timeout_s=570, command=
        "export PYTHONUNBUFFERED=1; python3 benchmarks/bench_gpu_tensorf.py --dataset bench_gpu/multi200
         --tensorf third_party/tensorf --out /tmp/gpubench --timeout 270; cp /tmp/gpubench/results.json
         /tmp/gpubench/summary.md /tmp/gpubench/*.log /tmp/gpubench/psnr_vs_seconds.png $OUT/")
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
import _bootstrap  # noqa: E402
from bench import gpu_compare
from bench.runner import PYTHON, REPO_ROOT, nerf_core_cmd, run_cli

QUICK = {"ours_seconds": 6.0, "eval_at": "2,4", "eval_views": 2, "tensorf_iters": 40, "tensorf_eval_every": 20}


def parse_args(argv):
    ap = argparse.ArgumentParser(prog="bench_gpu_tensorf.py", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", help="synthetic-layout capture (transforms_{train,test}.json, RGBA PNGs)")
    ap.add_argument("--tensorf", help="checkout of apchenstu/TensoRF (train.py, configs/lego.txt)")
    ap.add_argument("--out", required=True, help="result folder (refused if it holds results.json, unless --overwrite)")
    ap.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    ap.add_argument("--ours-seconds", type=float, help="our training budget (default 90; quick 6)")
    ap.add_argument("--eval-at", help="our evaluation times in training seconds (default 10,20,30,45,60,90 up to "
                                      "--ours-seconds; quick 2,4)")
    ap.add_argument("--eval-views", type=int, help="test views ours evaluates each time (default 20; quick 2); "
                                                   "TensoRF evaluates all of them")
    ap.add_argument("--tensorf-iters", type=int, help="TensoRF iterations (default 5000; quick 40)")
    ap.add_argument("--tensorf-eval-every", type=int, help="TensoRF test evaluation every N iterations (default "
                                                           "1000; 0 = only the final)")
    ap.add_argument("--timeout", type=float, default=480, help="seconds each side may take in all (default 480)")
    ap.add_argument("--skip-ours", action="store_true",
                    help="run TensoRF only (keeps ours from an earlier results.json)")
    ap.add_argument("--skip-tensorf", action="store_true", help="run ours only (keeps TensoRF's from results.json)")
    ap.add_argument("--quick", action="store_true", help="CPU plumbing test: tiny budgets and grids")
    ap.add_argument("--overwrite", action="store_true", help="replace an earlier result in --out")
    ap.add_argument("--report-only", action="store_true", help="write summary.md and the chart from OUT/results.json")
    a = ap.parse_args(argv)
    defaults = QUICK if a.quick else {"ours_seconds": 90.0, "eval_at": None, "eval_views": 20,
                                      "tensorf_iters": 5000, "tensorf_eval_every": 1000}
    for key, value in defaults.items():
        if getattr(a, key) is None:
            setattr(a, key, value)
    if a.eval_at is None:
        a.eval_at = ",".join(str(s) for s in (10, 20, 30, 45, 60, 90) if s < a.ours_seconds)
    return a


def check_args(a) -> str:
    """The first problem with the flags, or ''."""
    if a.report_only:
        return "" if os.path.isfile(os.path.join(a.out, "results.json")) else f"--report-only: no {a.out}/results.json"
    if not a.dataset:
        return "--dataset is required"
    if not os.path.isfile(os.path.join(a.dataset, "transforms_train.json")):
        return f"--dataset {a.dataset}: no transforms_train.json there (a synthetic-layout capture)"
    if not a.skip_tensorf and (not a.tensorf or not os.path.isfile(os.path.join(a.tensorf, "train.py"))):
        return f"--tensorf {a.tensorf}: no train.py there (a checkout of apchenstu/TensoRF; or --skip-tensorf)"
    if a.skip_ours and a.skip_tensorf:
        return "--skip-ours and --skip-tensorf leave nothing to run (--report-only redraws the report)"
    if a.ours_seconds <= 0 or a.tensorf_iters < 10:
        return "--ours-seconds must be > 0 and --tensorf-iters >= 10"
    try:
        times = [float(s) for s in a.eval_at.split(",") if s.strip()]
    except ValueError:
        return f"--eval-at {a.eval_at!r}: expected seconds separated by commas"
    if any(t <= 0 or t >= a.ours_seconds for t in times):
        return f"--eval-at {a.eval_at}: every time must lie in (0, --ours-seconds {a.ours_seconds:g})"
    old = os.path.join(a.out, "results.json")
    if os.path.isfile(old) and not a.overwrite:
        with open(old, encoding="utf-8") as fh:
            earlier = json.load(fh)
        held = [s for s in ("ours", "tensorf") if earlier.get(s) and not getattr(a, f"skip_{s}")]
        if held:  # one side may be added to a results.json that lacks it (--skip-ours / --skip-tensorf)
            return f"--out {a.out} already holds results of {' and '.join(held)}; pass --overwrite to replace them"
    return ""


def machine(device: str, dataset: str) -> dict:
    """Device name, versions, date, and the dataset's size and view counts."""
    info = {"python": platform.python_version(), "date": datetime.date.today().isoformat()}
    try:
        import torch

        info["torch"] = torch.__version__
        info["cuda"] = torch.version.cuda
        if device == "cuda" and torch.cuda.is_available():
            info["device_name"] = torch.cuda.get_device_name(0)
    except ImportError:
        pass
    info.setdefault("device_name", f"CPU ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)")
    for split in ("train", "test"):
        with open(os.path.join(dataset, f"transforms_{split}.json"), encoding="utf-8") as fh:
            meta = json.load(fh)
        info[f"n_{split}"] = len(meta.get("frames", []))
        if "w" in meta:
            info["image_size"] = f"{meta['w']}x{meta.get('h', meta['w'])}"
    return info


def commit() -> str:
    out = subprocess.run(["git", "-C", REPO_ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return out.stdout.strip() or "?"


def save(out: str, results: dict) -> None:
    tmp = os.path.join(out, "results.json.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(results, fh, indent=1)
    os.replace(tmp, os.path.join(out, "results.json"))


def run_ours(a, results: dict) -> None:
    run = os.path.join(a.out, "ours")
    cmd = nerf_core_cmd("train", a.dataset, "--out", run, "--max-seconds", f"{a.ours_seconds:g}", "--eval-at",
                        a.eval_at, "--eval-views", str(a.eval_views), "--device", a.device, "--no-bar", "--overwrite")
    results["commands"].append(" ".join(cmd).replace(PYTHON, "python"))
    print(f"ours: training {a.ours_seconds:g} s on {a.device} ...", flush=True)
    res = run_cli(cmd, log_path=os.path.join(a.out, "ours.log"), timeout=a.timeout,
                  on_event=lambda e: e.get("event") == "eval" and print(
                      f"ours: test PSNR {e.get('psnr', float('nan')):.2f} dB at "
                      f"{e.get('elapsed', a.ours_seconds):.1f} s",
                      flush=True))
    config = None
    if os.path.isfile(os.path.join(run, "config.json")):
        with open(os.path.join(run, "config.json"), encoding="utf-8") as fh:
            config = json.load(fh)
    results["ours"] = gpu_compare.summarise_ours(res.events, config)
    if not res.ok:
        results["ours_error"] = res.error_message()


def run_tensorf(a, results: dict) -> None:
    result = os.path.join(a.out, "tensorf_result.json")
    cmd = [PYTHON, "-m", "bench.tensorf_launch", "--tensorf", a.tensorf, "--dataset", a.dataset,
           "--logdir", os.path.join(a.out, "tensorf"), "--result", result, "--iters", str(a.tensorf_iters),
           "--eval-every", str(a.tensorf_eval_every), "--device", a.device] + (["--quick"] if a.quick else [])
    results["commands"].append("PYTHONPATH=benchmarks:scripts " + " ".join(cmd).replace(PYTHON, "python"))
    print(f"tensorf: {a.tensorf_iters} iterations on {a.device} ...", flush=True)
    env = {"PYTHONPATH": os.pathsep.join([HERE, os.path.join(REPO_ROOT, "scripts")])}
    if a.device == "cpu":
        env["CUDA_VISIBLE_DEVICES"] = ""  # TensoRF picks cuda whenever it sees one
    if os.path.exists(result):
        os.remove(result)
    res = run_cli(cmd, log_path=os.path.join(a.out, "tensorf.log"), timeout=a.timeout, env_extra=env,
                  on_event=None)
    for line in res.stdout_tail[-3:]:
        print(line, flush=True)
    if res.ok and os.path.isfile(result):
        with open(result, encoding="utf-8") as fh:
            results["tensorf"] = json.load(fh)
    else:
        results["tensorf_error"] = res.error_message()


def main(argv=None) -> int:
    a = parse_args(sys.argv[1:] if argv is None else argv)
    problem = check_args(a)
    if problem:
        _bootstrap.fail("bench_gpu_tensorf.py", problem)
    if not a.report_only:
        os.makedirs(a.out, exist_ok=True)
        old = {}
        if (a.skip_ours or a.skip_tensorf) and os.path.isfile(os.path.join(a.out, "results.json")):
            with open(os.path.join(a.out, "results.json"), encoding="utf-8") as fh:
                old = json.load(fh)
        results = {**old, "dataset": a.dataset, "quick": a.quick, "commit": commit(),
                   "machine": machine(a.device, a.dataset), "commands": [c for c in old.get("commands", [])]}
        for side, runner_fn, skip in (("ours", run_ours, a.skip_ours), ("tensorf", run_tensorf, a.skip_tensorf)):
            if skip:
                continue
            results.pop(f"{side}_error", None)
            results["commands"] = [c for c in results["commands"] if ("tensorf_launch" in c) == (side == "ours")]
            runner_fn(a, results)
            save(a.out, results)
    path, note = gpu_compare.write_report(a.out)
    print(open(path, encoding="utf-8").read(), flush=True)
    if note:
        print(note, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
