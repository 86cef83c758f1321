"""Rendering speed against training speed, per method, in one run on one machine.

    python benchmarks/bench_render.py --dataset DS --out DIR [--methods vmgrid,nerf,nerf-nope]
                                   [--seconds 60] [--runs vmgrid=RUN,...] [--frame-size 800x800]
                                   [--threads N] [--python PY]

For each method it trains with the command users run (``python -m nerf_core train DS --out
DIR/runs/M --method M --max-seconds S``), or takes the run given by ``--runs M=RUN``, then:

* training rays/s: steps x rays per step / training seconds over the second half of the run's
  training time, from RUN/progress.jsonl (so it is the speed of the grown model);
* render rays/s: ``python -m nerf_core render RUN --cameras DS`` of the test views into
  DIR/renders/M, the model's own time from its renders.json (no start-up, model loading or image
  files; the first view left out as warm-up). ``eval`` renders with the same code;
* seconds per frame: one test camera rendered at ``--frame-size`` (800x800) into DIR/frame/M.

Writes DIR/render_speed.json and DIR/render_speed.md (the table, the machine, threads, torch
version, load average and the exact commands). Nothing is overwritten: existing output folders are
refused. Timings on a machine shared with other jobs are not speed claims; the page says so when
the load average shows other jobs (``bench.runner.contended``).
"""
from __future__ import annotations

import json
import os
import shlex
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
import _bootstrap  # noqa: E402  (puts the checkout on sys.path)
from bench import render_speed, report, runner  # noqa: E402  (benchmarks/bench)
from bench.plan import name_problem  # noqa: E402
from nerf_core.runs.folder import dataset_overlap  # noqa: E402

PROG = "bench_render.py"


def parse_args(argv):
    import argparse

    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", required=True,
                   help="NeRF dataset folder (transforms_train.json and transforms_test.json)")
    p.add_argument("--out", required=True, help="output folder (runs/, renders/, frame/, render_speed.json/.md)")
    p.add_argument("--methods", default="vmgrid,nerf,nerf-nope", help="comma-separated methods (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=60.0, help="training seconds per method (default: %(default)s)")
    p.add_argument("--runs", help="reuse trained runs instead of training: METHOD=RUN_FOLDER,... (read only)")
    p.add_argument("--frame-size", default="800x800", help="size of the timed single frame, WxH (default: %(default)s)")
    p.add_argument("--threads", type=int, help="OMP/MKL threads for training and rendering (default: torch's own)")
    _bootstrap.add_python_option(p, "training and rendering")
    return p.parse_args(argv)


def frame_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise render_speed.SpeedInputError(f"--frame-size {text!r}: expected WxH like 800x800") from None
    if w < 1 or h < 1:
        raise render_speed.SpeedInputError(f"--frame-size {text!r}: must be positive")
    return w, h


def read_events(run: str) -> list[dict]:
    path = os.path.join(run, "progress.jsonl")
    try:
        with open(path, encoding="utf-8") as fh:
            return runner.parse_events(fh)
    except OSError as exc:
        raise render_speed.SpeedInputError(f"{path}: cannot read the run's progress events ({exc})") from None


def image_size(path) -> tuple[int, int]:
    from PIL import Image

    with Image.open(path) as im:
        return im.size


def bench_method(args, method: str, run: str | None, out: str, env: dict, commands: list) -> dict:
    """Train (unless ``run`` is given), then time rendering; a failure is recorded, not raised."""
    py = args.python or runner.PYTHON
    row: dict = {"method": method}
    if run is None:
        run = os.path.join(out, "runs", method)
        cmd = [py, "-m", "nerf_core", "train", args.dataset, "--out", run, "--method", method,
               "--max-seconds", f"{args.seconds:g}", "--log-every", "10", "--eval-views", "1", "--no-bar"]
        commands.append(" ".join(shlex.quote(c) for c in cmd))
        print(f"{PROG}: training {method} for {args.seconds:g} s", file=sys.stderr, flush=True)
        res = runner.run_cli(cmd, env_extra=env, log_path=os.path.join(out, f"train_{method}.log"))
        if not res.ok:
            return dict(row, run=run, error=f"train failed: {res.error_message()}")
    row["run"] = os.path.abspath(run)
    try:
        with open(os.path.join(run, "config.json"), encoding="utf-8") as fh:
            config = json.load(fh)
        rate = render_speed.training_rate(read_events(run), int(config["rays_per_step"]))
    except (OSError, ValueError, KeyError, render_speed.SpeedInputError) as exc:
        return dict(row, error=f"{run}: cannot read the training rate ({exc})")
    row.update(train_rays_per_s=rate["rays_per_s"], train_window=rate, steps=rate["to_step"],
               rays_per_step=int(config["rays_per_step"]))

    def render(cameras: list[str], kind: str, what: str):
        """``render RUN --cameras ...`` into OUT/<kind>/<method>: its renders.json, or an error line."""
        folder = os.path.join(out, kind, method)
        cmd = [py, "-m", "nerf_core", "render", run, "--cameras", *cameras, "--out", folder, "--no-bar"]
        commands.append(" ".join(shlex.quote(c) for c in cmd))
        print(f"{PROG}: rendering {what} of {method}", file=sys.stderr, flush=True)
        res = runner.run_cli(cmd, env_extra=env, log_path=os.path.join(out, f"{kind}_{method}.log"))
        if not res.ok:
            return None, f"{what} failed: {res.error_message()}"
        with open(os.path.join(folder, "renders.json"), encoding="utf-8") as fh:
            return json.load(fh), None

    renders, error = render([args.dataset, "--split", "test"], "renders", "the test views")
    if error:
        return dict(row, error=error)
    rend = render_speed.render_rate(renders)
    row.update(render_rays_per_s=rend["rays_per_s"], render_window=rend)
    frame, error = render([os.path.join(out, "frame_camera.json")], "frame", f"one {args.frame_size} frame")
    if error:
        return dict(row, error=error)
    row["frame_seconds"] = float(frame["frames"][0]["render_seconds"])
    return row


def main(argv=None) -> int:
    args = parse_args(argv if argv is not None else _bootstrap.script_args())
    try:
        methods = render_speed.parse_methods(args.methods)
        unknown = name_problem("--methods", methods, runner.method_names())
        if unknown:
            raise render_speed.SpeedInputError(unknown)
        runs = render_speed.parse_runs(args.runs, methods)
        width, height = frame_size(args.frame_size)
        if args.seconds <= 0:
            raise render_speed.SpeedInputError(f"--seconds {args.seconds:g}: must be positive")
        if args.threads is not None and args.threads < 1:
            raise render_speed.SpeedInputError(f"--threads {args.threads}: must be at least 1")
        for m, run in runs.items():
            if not os.path.isfile(os.path.join(run, "config.json")):
                raise render_speed.SpeedInputError(f"--runs {m}={run}: no config.json there (not a run folder)")
            trained = render_speed.run_method(run)
            if trained != m:  # its numbers would be reported under the wrong name
                raise render_speed.SpeedInputError(f"--runs {m}={run}: that run was trained with method {trained!r}, "
                                                   f"not {m!r}")
        out = os.path.abspath(args.out)
        args.dataset = os.path.abspath(args.dataset)
        overlap = dataset_overlap(out, args.dataset)
        if overlap:  # its JSON at the dataset root would make every loader refuse the dataset
            raise render_speed.SpeedInputError(f"--out {out}: {overlap}; choose an output folder outside the dataset")
        targets = [os.path.join(out, d, m) for m in methods for d in ("renders", "frame")]
        targets += [os.path.join(out, "runs", m) for m in methods if m not in runs]
        targets += [os.path.join(out, f) for f in ("render_speed.json", "render_speed.md", "frame_camera.json")]
        taken = render_speed.existing_outputs(targets)
        if taken:
            raise render_speed.SpeedInputError(f"{taken[0]} already exists (and {len(taken) - 1} more); choose another "
                                               "--out (reuse trained runs with --runs METHOD=RUN)")
        camera = render_speed.camera_at_size(args.dataset, width, height, size_of=image_size)
    except render_speed.SpeedInputError as exc:
        _bootstrap.fail(PROG, str(exc))
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "frame_camera.json"), "w", encoding="utf-8") as fh:
        json.dump(camera, fh, indent=1)
    env = {}
    if args.threads:
        env = {k: str(args.threads) for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    threads = args.threads or os.environ.get("OMP_NUM_THREADS") or f"torch default ({os.cpu_count()} cores)"
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    commands: list[str] = []
    results = [bench_method(args, m, runs.get(m), out, env, commands) for m in methods]
    load_after = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    cores = os.cpu_count() or 1
    info = {"dataset": args.dataset, "machine": runner.machine_info(), "threads": threads,
            "frame_size": f"{width}x{height}", "load_before": load_before, "load_after": load_after,
            "contended": runner.contended(load_before, load_after, int(args.threads or cores)),
            "command": " ".join(shlex.quote(a) for a in [sys.executable, os.path.abspath(__file__), *sys.argv[1:]]),
            "commands": commands}
    rows = render_speed.speed_rows(results)
    report.write_json(os.path.join(out, "render_speed.json"), {**info, "rows": rows, "results": results})
    page = render_speed.markdown(rows, info)
    with open(os.path.join(out, "render_speed.md"), "w", encoding="utf-8") as fh:
        fh.write(page)
    print(page)
    return 1 if any(r.get("error") for r in results) else 0


if __name__ == "__main__":
    _bootstrap.exit_code(main())
