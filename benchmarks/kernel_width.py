"""Kernel width, shown on one real photograph: no encoding vs NeRF PE vs Gaussian Fourier features.

    python benchmarks/kernel_width.py --out DIR [--jobs 2] [--steps 1000] [--sigmas 0.1,0.3,1,3,10,30,100,300]
                                   [--pe-freqs 4,5,6,7] [--hdri PATH | --hdri-name forest.exr]
                                   [--crop TOP,LEFT,SIDE] [--downscale K] [--overwrite]
    blender -b --python benchmarks/kernel_width.py -- --out DIR --python /path/to/.venv/bin/python

Fits a crop of one of Blender's studio-light HDRIs (a photograph) with a small MLP on pixel
coordinates, training on the even-row, even-column pixels and scoring PSNR on the other three
quarters (benchmarks/fourier2d/fit2d.py). Writes DIR/kernel_width.png (held-out and train PSNR against sigma),
DIR/kernel_width_crops.png (ground truth and reconstructions), DIR/kernel_width.json and
DIR/README.md (the table and the command).

Under Blender (no torch in Blender's Python) it finds the HDRI through ``bpy`` and runs itself again
with ``--python`` (default $NERF_PYTHON), the interpreter that has torch.
"""
from __future__ import annotations

import argparse
import os
import platform
import shlex
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # bench/ here, _bootstrap in scripts/
import _bootstrap  # noqa: E402  (puts the repository on sys.path)

OUTPUTS = ("kernel_width.json", "kernel_width.png", "kernel_width_crops.png", "README.md")


def parse_args(argv):
    ap = argparse.ArgumentParser(prog="kernel_width.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the chart, pictures, JSON and README.md")
    ap.add_argument("--hdri", default="", help="an EXR to crop (default: Blender's studio light --hdri-name)")
    ap.add_argument("--hdri-name", default=None, help="studio-light file name (default forest.exr)")
    ap.add_argument("--datafiles", default="",
                    help=argparse.SUPPRESS)  # Blender's DATAFILES, passed on by the Blender run
    ap.add_argument("--crop", default=None, help="TOP,LEFT,SIDE in the HDRI's pixels (default 250,700,128)")
    ap.add_argument("--downscale", type=int, default=1, help="box-downscale the crop by this factor (default 1)")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--depth", type=int, default=4, help="linear layers, output layer included")
    ap.add_argument("--features", type=int, default=128, help="Gaussian Fourier features")
    ap.add_argument("--sigmas", default="0.1,0.3,1,3,10,30,100,300", help="RFF scales, cycles per image width")
    ap.add_argument("--pe-freqs", default="",
                    help="PE frequency counts to try (default: the four counts up to the training Nyquist)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="models fitted at once")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads per fit (default 1: a small MLP gains little from more on a shared CPU)")
    ap.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run in --out")
    ap.add_argument("--python", default=os.environ.get("NERF_PYTHON", ""),
                    help="under Blender: the interpreter with torch that does the fitting (default $NERF_PYTHON)")
    return ap.parse_args(argv)


def fail(msg: str) -> None:
    print(f"error: {msg}", file=sys.stderr)
    _bootstrap.exit_code(2)


def number_list(text: str, flag: str, kind=float, minimum=None) -> list:
    """Comma-separated numbers of ``kind``, each > 0, or >= ``minimum`` when given (a crop's offsets
    may be 0)."""
    try:
        values = [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        fail(f"{flag} {text!r}: expected comma-separated numbers")
    low = (lambda v: v < minimum) if minimum is not None else (lambda v: v <= 0)
    if not values or any(low(v) for v in values):
        fail(f"{flag} {text!r}: expected " + (f"numbers >= {minimum}" if minimum is not None else "positive numbers"))
    return values


def rerun_outside_blender(args, argv) -> int:
    """Blender's Python has no torch: find the HDRI folder here, fit in ``--python``."""
    import bpy

    if not args.python:
        fail("Blender's Python has no torch: pass --python /path/to/python-with-torch (or set NERF_PYTHON)")
    cmd = [args.python, os.path.abspath(__file__), *argv, "--datafiles", bpy.utils.system_resource("DATAFILES")]
    return subprocess.call(cmd)


def load_target(args):
    from fourier2d.photo2d import DEFAULT_CROP, DEFAULT_HDRI, PhotoError, find_hdri, load_photo

    crop = tuple(number_list(args.crop, "--crop", int, minimum=0)) if args.crop else DEFAULT_CROP
    if len(crop) != 3:
        fail(f"--crop {args.crop!r}: expected TOP,LEFT,SIDE")
    if crop[2] < 1:
        fail(f"--crop {args.crop!r}: SIDE must be at least 1 pixel")
    datafiles = args.datafiles
    if not args.hdri and not datafiles:
        try:  # the bpy module (PyPI) knows its own DATAFILES; nerf_core only searches the disk
            import bpy

            datafiles = bpy.utils.system_resource("DATAFILES")
        except ImportError:
            pass
    try:
        path = args.hdri or find_hdri(args.hdri_name or DEFAULT_HDRI, datafiles or None)
        return load_photo(path, crop=crop, downscale=args.downscale)
    except PhotoError as exc:
        fail(str(exc))


def main(argv=None) -> int:
    argv = _bootstrap.script_args() if argv is None else argv
    args = parse_args(argv)
    try:
        import torch  # noqa: F401
    except ImportError:
        if _bootstrap.inside_blender():
            return rerun_outside_blender(args, argv)
        fail("this Python cannot import torch; run it with the project's .venv/bin/python")

    from fourier2d import fit2d
    import kernel_width_report as report

    if args.steps < 1:  # nothing fitted would chart untrained models
        fail(f"--steps {args.steps}: must be at least 1")

    existing = [f for f in OUTPUTS if os.path.exists(os.path.join(args.out, f))]
    if existing and not args.overwrite:
        fail(f"{args.out} already holds {', '.join(existing)}; choose another --out or pass --overwrite")
    photo = load_target(args)
    h, w = photo.image.shape[:2]
    sigmas = number_list(args.sigmas, "--sigmas")
    top_pe = fit2d.nyquist_pe_freqs(h, w)
    pe_freqs = number_list(args.pe_freqs, "--pe-freqs", int) if args.pe_freqs else \
        list(range(max(1, top_pe - 3), top_pe + 1))
    cfg = fit2d.FitConfig(steps=args.steps, lr=args.lr, width=args.width, depth=args.depth,
                          n_features=args.features, seed=args.seed, threads=args.threads)
    specs = fit2d.default_sweep(sigmas, pe_freqs)
    print(f"fitting {len(specs)} models on {photo.source} crop {photo.crop} -> {w}x{h} px, "
          f"{args.steps} steps each, {args.jobs} at a time", flush=True)
    start = time.time()
    results = fit2d.sweep(photo.image, specs, cfg, log=lambda s: print(s, flush=True), jobs=args.jobs)
    wall = time.time() - start

    os.makedirs(args.out, exist_ok=True)
    shown = list(argv)
    if "--datafiles" in shown:  # added by the Blender run, not typed by the user
        i = shown.index("--datafiles")
        del shown[i:i + 2]
    command = "python benchmarks/kernel_width.py " + shlex.join(shown)
    meta = {"command": command, "image": {"source": photo.source, "crop": photo.crop, "downscale": photo.downscale,
                                          "tonemap": photo.tonemap, "size": [w, h]},
            "config": {"steps": cfg.steps, "lr": cfg.lr, "width": cfg.width, "depth": cfg.depth,
                       "features": cfg.n_features, "seed": cfg.seed, "jobs": args.jobs, "threads": args.threads,
                       "train_pixels": "even row and even column (1/4)", "nyquist": fit2d.nyquist(h, w)},
            "machine": {"cpu": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                        "load_avg_end": round(os.getloadavg()[0], 2), "torch": torch.__version__},
            "wall_seconds": round(wall, 1), "date": time.strftime("%Y-%m-%d", time.gmtime())}
    report.write_all(args.out, photo, results, meta)
    for name in OUTPUTS:
        print(os.path.join(args.out, name))
    return 0


if __name__ == "__main__":
    _bootstrap.exit_code(main())
