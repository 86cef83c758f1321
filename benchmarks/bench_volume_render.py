"""The exported volume rendered by Cycles, against the NeRF's own render and Blender's ground truth.

    python benchmarks/bench_volume_render.py --blend SCENE.blend --run RUN --out DIR [--views 3] [--samples 64]
        [--threads N] [--view-transform NAME]

Exports the run's volume (``python -m nerf_core export volume``), renders the first ``--views`` test
views of the run's dataset with ``python -m nerf_core render``, then, in Blender, hides the scene's own
objects from the render, imports the volume (``addon/compare/geometry_import.py``: the add-on's own
import, which undoes the capture's recorded view transform) and renders the same cameras with Cycles
(transparent film, the scene's own colour management unless ``--view-transform``, as a user would).
A run that learned the world behind its box (an opaque capture's, ``background_used: environment``) also
gets that world (``export world``, imported as the scene's World) and an opaque film, as the NeRF's own
render shows it (``--world off``: the volume alone, on white).
Each image is composited onto white, as ``eval`` does, and
compared: Cycles' volume against the NeRF's render, and against the ground truth; the NeRF's render
against the ground truth for reference. Prints one JSON line per view and a summary as the last line.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # _bootstrap in scripts/
from _bootstrap import REPO_ROOT  # noqa: E402


def _rgb_on_white(path: str) -> np.ndarray:
    from PIL import Image

    im = np.asarray(Image.open(path).convert("RGBA"), dtype=np.float64) / 255.0
    return im[..., :3] * im[..., 3:] + (1.0 - im[..., 3:])


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a - b) ** 2))
    return 10 * math.log10(1.0 / mse) if mse > 0 else float("inf")


def _nerf_core(*args) -> None:
    env = dict(os.environ, PYTHONPATH=REPO_ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    subprocess.run([sys.executable, "-m", "nerf_core", *args], check=True, env=env, stdout=subprocess.DEVNULL)


def main(argv) -> int:
    ap = argparse.ArgumentParser(prog="bench_volume_render.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--blend", required=True)
    ap.add_argument("--run", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--resolution", type=int, help="volume samples per axis (default: the export's)")
    ap.add_argument("--threads", type=int, default=0, help="Cycles' CPU threads (0: all)")
    ap.add_argument("--view-transform", help="render under this view transform (default: the scene's own)")
    ap.add_argument("--biased", choices=("on", "off"), help="Cycles' biased volume ray marching (default: the scene's)")
    ap.add_argument("--denoise", choices=("on", "off"), help="Cycles' denoiser (default: the scene's)")
    ap.add_argument("--pixel-filter", choices=("auto", "none"), default="auto",
                    help="auto: both renders filter pixels as the capture did; none: one ray per pixel centre in both")
    ap.add_argument("--precision", choices=("FULL", "HALF", "VARIABLE"), help="the Volume's grid precision")
    ap.add_argument("--step-rate", type=float, help="Cycles' volume step rate (scene); needs --biased on")
    ap.add_argument("--world", choices=("auto", "off"), default="auto",
                    help="auto: import the learned world when the run has one; off: the volume alone")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.run, "config.json"), encoding="utf-8") as fh:
        config = json.load(fh)
    dataset = config["dataset"]
    with_world = a.world == "auto" and config.get("background_used") == "environment"
    png = os.path.join(a.out, "world.png")
    if with_world and not os.path.isfile(png):
        _nerf_core("export", "world", a.run, "--out", png)
    with open(os.path.join(dataset, "transforms_test.json"), encoding="utf-8") as fh:
        meta = json.load(fh)
    frames = meta["frames"][: a.views]
    npz = os.path.join(a.out, "volume.npz")
    if not os.path.isfile(npz):
        res = ["--resolution", str(a.resolution)] if a.resolution else []
        _nerf_core("export", "volume", a.run, "--out", npz, *res)
    cams = os.path.join(a.out, "cameras.json")
    with open(cams, "w", encoding="utf-8") as fh:
        json.dump({k: v for k, v in meta.items() if k != "frames"} | {"frames": frames}, fh)
    nerf_dir = os.path.join(a.out, "nerf")
    if not os.path.isfile(os.path.join(nerf_dir, "renders.json")):
        _nerf_core("render", a.run, "--cameras", cams, "--out", nerf_dir, "--no-bar", "--pixel-filter", a.pixel_filter)

    import bpy
    from mathutils import Matrix

    from addon.compare import geometry_import

    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(a.blend))
    scene = bpy.context.scene
    for obj in scene.objects:
        if obj.type != "CAMERA":
            obj.hide_render = True  # the NeRF's volume alone, on a transparent film
    if a.view_transform:  # before the import, which compares the scene's colour management with the capture's
        scene.view_settings.view_transform = a.view_transform
    obj = geometry_import.import_volume(scene, npz, os.path.join(a.out, "volume.vdb"))
    notes = str(obj.get(geometry_import.NOTES_PROPERTY, "")).split("\n")
    if with_world:
        notes += str(geometry_import.import_world(scene, png).get(geometry_import.NOTES_PROPERTY, "")).split("\n")
    for note in notes:
        if note:
            print(f"note: {note}", file=sys.stderr)
    if a.precision:
        obj.data.render.precision = a.precision
    scene.render.engine = "CYCLES"
    if a.biased:
        scene.cycles.volume_biased = a.biased == "on"
    if a.pixel_filter == "none":
        scene.render.filter_size = 0.01  # Blender's least: a point sample at each pixel's centre
    if a.denoise:
        scene.cycles.use_denoising = a.denoise == "on"
    if a.step_rate:
        scene.cycles.volume_step_rate = a.step_rate
    scene.cycles.samples = a.samples
    scene.cycles.device = "CPU"
    scene.render.threads_mode = "FIXED" if a.threads else "AUTO"
    scene.render.threads = max(1, a.threads)
    scene.render.film_transparent = not with_world  # the learned world behind, as the NeRF renders it
    w = int(frames[0].get("w", meta.get("w")))
    h = int(frames[0].get("h", meta.get("h")))
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
    cam = bpy.data.objects.new("bench camera", bpy.data.cameras.new("bench camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.data.sensor_fit = "HORIZONTAL"
    cam.data.angle = float(meta["camera_angle_x"])
    cam.data.clip_start, cam.data.clip_end = 0.01, 1000.0
    rows = []
    for fr in frames:
        stem = os.path.basename(fr["file_path"])
        cam.matrix_world = Matrix(fr["transform_matrix"])
        scene.render.filepath = os.path.join(a.out, "cycles", stem + ".png")
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        seconds = time.perf_counter() - t
        cyc = _rgb_on_white(scene.render.filepath)
        nerf = _rgb_on_white(os.path.join(nerf_dir, stem + ".png"))
        gt = _rgb_on_white(os.path.join(dataset, fr["file_path"].lstrip("./") + ".png"))
        row = {"view": stem, "cycles_vs_nerf": _psnr(cyc, nerf), "cycles_vs_truth": _psnr(cyc, gt),
               "nerf_vs_truth": _psnr(nerf, gt), "cycles_seconds": round(seconds, 1)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    summary = {k: float(np.mean([r[k] for r in rows])) for k in ("cycles_vs_nerf", "cycles_vs_truth", "nerf_vs_truth")}
    print(json.dumps({"views": len(rows), "samples": a.samples, "view_transform": scene.view_settings.view_transform,
                      "biased": scene.cycles.volume_biased, "denoise": scene.cycles.use_denoising,
                      "precision": obj.data.render.precision, "world": with_world,
                      **summary}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
