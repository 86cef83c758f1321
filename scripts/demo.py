"""The main job, end to end, on an embedded default scene.

    python scripts/demo.py [--out DIR] [--scene NAME] [--train-seconds S] [--resolution R]

Steps, each one a real subprocess of the same tools users run (so the demo tests them too):
 1. build a procedural demo scene with bpy             scripts/make_demo_scene.py
 2. capture a NeRF dataset from it                     scripts/capture.py
 3. validate the dataset                               python -m nerf_core check
 4. train a NeRF on the CPU for a short budget         python -m nerf_core train
 5. render the held-out test views once, scoring each
    against its ground truth (PSNR, SSIM, error map)   python -m nerf_core render
 6. import those renders as image planes beside
    Blender's renders of the same cameras, twice       scripts/import_views.py --renders (gallery and
                                                       camera layouts: each file opens looking through its
                                                       own camera, the images packed inside it)
 7. write DIR/metrics.json and print where everything went.

Each test view is rendered once: both imports reuse step 5's folder (its renders.json), and the
scores come from the same renders.

The output folder is never reused: without --out, a new timestamped folder under demo_out/ is made.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPTS = os.path.join(REPO_ROOT, "scripts")
if REPO_ROOT not in sys.path:
    sys.path.insert(0, REPO_ROOT)

from nerf_core.utils.atomic import open_exclusive, write_json_atomic  # noqa: E402  (never through a link)
from nerf_core.utils.interrupts import honour_interrupts  # noqa: E402

honour_interrupts()  # Ctrl-C stops the demo even when its parent left SIGINT ignored (scripts/_bootstrap.py)


class StepFailed(RuntimeError):
    pass


def run_step(title: str, cmd: list[str], log_dir: str, capture_stdout: bool = False) -> str:
    """Run one step, streaming its stderr (progress bars) and keeping a log; raise StepFailed on error."""
    print(f"\n=== {title}\n    $ {' '.join(cmd)}", flush=True)
    log_path = os.path.join(log_dir, title.split(":")[0].strip().replace(" ", "_") + ".log")
    start = time.monotonic()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = REPO_ROOT + os.pathsep + env.get("PYTHONPATH", "")
    with open_exclusive(log_path, binary=False) as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                cwd=REPO_ROOT)
        lines = []
        assert proc.stdout is not None
        for line in proc.stdout:
            log.write(line)
            lines.append(line)
            # JSON progress events go to the log; people get the bars and messages.
            if not line.lstrip().startswith("{"):
                sys.stdout.write("    " + line)
                sys.stdout.flush()
        code = proc.wait()
    took = time.monotonic() - start
    if code != 0:
        tail = "".join(lines[-15:])
        raise StepFailed(f"step '{title}' failed with exit code {code} after {took:.0f}s.\n"
                         f"Last lines (full log: {log_path}):\n{tail}")
    print(f"    done in {took:.1f}s (log: {log_path})", flush=True)
    return "".join(lines)


def last_json(output: str) -> dict:
    for line in reversed(output.strip().splitlines()):
        line = line.strip()
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                continue
    raise StepFailed("expected a JSON object on the last line of the output")


def scores_of(renders: str) -> dict:
    """Mean test PSNR and SSIM over the views of ``renders``/renders.json, which ``nerf_core render``
    scores exactly as ``eval`` does (the same compositing, pixel filter and ground truth)."""
    try:
        with open(os.path.join(renders, "renders.json"), encoding="utf-8") as fh:
            frames = json.load(fh)["frames"]
    except (OSError, ValueError, KeyError) as exc:
        raise StepFailed(f"{renders}/renders.json: not readable ({exc})") from None
    scored = [f for f in frames if isinstance(f.get("psnr"), (int, float)) and isinstance(f.get("ssim"), (int, float))]
    if not scored:
        raise StepFailed(f"{renders}/renders.json: no view has ground truth to score against")
    return {"psnr": sum(f["psnr"] for f in scored) / len(scored), "ssim": sum(f["ssim"] for f in scored) / len(scored),
            "n_views": len(scored), "renders": renders}


def scene_capture_flags(scene: str) -> list[str]:
    """Extra scripts/capture.py flags demo scene ``scene`` needs (addon/capture/demo/capture_flags.py, loaded by path
    because importing the add-on package imports bpy): e.g. --opaque for hdri, --layout inside for interior."""
    import importlib.util

    path = os.path.join(REPO_ROOT, "addon", "capture", "demo", "capture_flags.py")
    if not os.path.isfile(path):
        return []
    spec = importlib.util.spec_from_file_location("_nerf_bridge_demo_capture", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.capture_flags(scene)


def missing_pieces() -> list[str]:
    needed = ["scripts/make_demo_scene.py", "scripts/capture.py", "scripts/import_views.py",
              "nerf_core/engine/trainer.py", "nerf_core/render/views.py", "nerf_core/check/dataset.py"]
    return [p for p in needed if not os.path.exists(os.path.join(REPO_ROOT, p))]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", help="output folder (must not exist or be empty); default demo_out/<timestamp>")
    ap.add_argument("--scene", default="diffuse",
                    help="demo scene name (scripts/make_demo_scene.py --list); hdri and interior get their capture "
                         "flags (--opaque, --layout inside) automatically")
    ap.add_argument("--train-seconds", type=float, default=180.0, help="training budget in seconds (default 180)")
    ap.add_argument("--resolution", type=int, default=100, help="capture resolution in pixels (square)")
    ap.add_argument("--count", type=int, default=60, help="train views")
    ap.add_argument("--test-count", type=int, default=6, help="held-out test views (also the gallery rows)")
    ap.add_argument("--method", default=None, help="NeRF method (default: the library's best fast method)")
    args = ap.parse_args(argv)

    missing = missing_pieces()
    if missing:
        print("demo: these pieces are not built yet, so the main job cannot run end to end:\n  "
              + "\n  ".join(missing), file=sys.stderr)
        return 2

    out = os.path.abspath(args.out or os.path.join(REPO_ROOT, "demo_out", time.strftime("%Y%m%d-%H%M%S")))
    if os.path.isdir(out) and os.listdir(out):
        print(f"demo: {out} already exists and is not empty; pick another --out (nothing was changed)", file=sys.stderr)
        return 2
    os.makedirs(out, exist_ok=True)
    logs = os.path.join(out, "logs")
    os.makedirs(logs, exist_ok=True)
    py = sys.executable
    scene = os.path.join(out, "scene.blend")
    dataset = os.path.join(out, "dataset")
    run = os.path.join(out, "run")
    compare = os.path.join(out, "compare_gallery.blend")
    overlay = os.path.join(out, "compare_camera.blend")
    t0 = time.monotonic()
    try:
        run_step("1 build scene", [py, os.path.join(SCRIPTS, "make_demo_scene.py"), args.scene, "--out", scene], logs)
        run_step("2 capture", [py, os.path.join(SCRIPTS, "capture.py"), "--blend", scene, "--out", dataset,
                               "--count", str(args.count), "--val-count", "2", "--test-count", str(args.test_count),
                               "--resolution", str(args.resolution), "--engine", "cycles", "--samples", "16",
                               "--depth", *scene_capture_flags(args.scene)], logs)
        run_step("3 check dataset", [py, "-m", "nerf_core", "check", dataset], logs)
        train_cmd = [py, "-m", "nerf_core", "train", dataset, "--out", run, "--max-seconds", str(args.train_seconds),
                     "--seed", "0"]
        if args.method:
            train_cmd += ["--method", args.method]
        run_step("4 train", train_cmd, logs)
        renders = os.path.join(run, "views", "test")
        run_step("5 render test views", [py, "-m", "nerf_core", "render", run, "--split", "test",
                                         "--out", renders], logs)
        metrics = scores_of(renders)
        gallery_out = run_step("6 import gallery", [py, os.path.join(SCRIPTS, "import_views.py"), "--blend", scene,
                                                    "--run", run,
                                                    "--renders", renders, "--out", compare,
                                                    "--layout", "gallery"], logs)
        run_step("7 import camera-aligned", [py, os.path.join(SCRIPTS, "import_views.py"), "--blend", scene,
                                             "--run", run,
                                             "--renders", renders, "--out", overlay, "--layout", "camera"], logs)
    except StepFailed as exc:
        print(f"\ndemo: FAILED: {exc}", file=sys.stderr)
        return 1

    summary = {
        "scene": args.scene,
        "blend": scene,
        "dataset": dataset,
        "run": run,
        "comparison_gallery_blend": compare,
        "comparison_camera_blend": overlay,
        "test_metrics": metrics,
        "train_seconds_budget": args.train_seconds,
        "wall_seconds": round(time.monotonic() - t0, 1),
    }
    try:
        summary["gallery"] = last_json(gallery_out)
    except StepFailed:
        pass
    write_json_atomic(os.path.join(out, "metrics.json"), summary)
    print("\n=== Done. Where everything went:")
    for key in ("blend", "dataset", "run", "comparison_gallery_blend", "comparison_camera_blend"):
        print(f"  {key:26s} {summary[key]}")
    print(f"  {'metrics':26s} {os.path.join(out, 'metrics.json')}")
    print("  (open a compare .blend and press Numpad 0 to look through its camera: the whole gallery, or\n"
          "   test view r_0 with the NeRF's image over it; the other views' cameras are in 'NeRF View Cameras')")
    print(f"  test PSNR {metrics.get('psnr', float('nan')):.2f} dB, SSIM {metrics.get('ssim', float('nan')):.3f} "
          f"over {metrics.get('n_views', '?')} views; total {summary['wall_seconds']:.0f}s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
