"""Capture a Blender scene as a NeRF dataset, headless.

    blender -b scene.blend --python scripts/capture.py -- --out DATASET [options]
    python scripts/capture.py --blend scene.blend --out DATASET [options]

Default: a hemisphere of cameras around everything visible, at the distance where the scene fills
the frame; 100 train, 10 val and 20 test views, 200x200, Cycles. The cameras are created in the
"NeRF Cameras" collection of the scene in memory (the .blend on disk is not modified; pass
--save-blend to keep them). --keep-cameras captures the cameras that collection already holds.
For a room (a scene that surrounds the camera), --layout inside stands the cameras inside the scene's
box looking outward, and --opaque keeps the walls' and world's pixels (no transparent film).

Re-running the same command resumes: frames already rendered with the same settings are kept.
A folder holding something else is refused unless --overwrite. Prints one JSON summary line last.

Render farm: run the same command N times with --shard 1/N ... N/N (at once, on machines sharing
--out, or one after another); each renders its share of the frames (frame i goes to shard
i mod N + 1) and writes only its frames and its own state file. Then
``capture.py --out DATASET --merge`` checks every planned frame and writes the transforms files,
the point cloud and the manifest (README: "Capturing on a render farm").

--colmap also writes DATASET/colmap/ once the capture is complete (after the capture, or after --merge):
the views of --colmap-splits (default train) as a COLMAP sparse model for splatting trainers, by the
same code as ``python -m nerf_core export colmap DATASET --out DIR`` (``nerf_core.export.colmap``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402  (puts the repository on sys.path)
from nerf_core.contract.errors import DatasetError  # noqa: E402  (standard library: fine in Blender)


def parse_resolution(text: str) -> tuple[int, int | None]:
    try:
        if "x" in text.lower():
            w, h = text.lower().split("x")
            w, h = int(w), int(h)
        else:
            w, h = int(text), None
    except ValueError:
        raise argparse.ArgumentTypeError(f"--resolution {text!r}: expected R or WxH, e.g. 200 or 320x240")
    # 32x0 used to fall back to 32x32 (0 read as "not given"): every axis must be a real size.
    for v in (w, h):
        if v is not None and not 1 <= v <= MAX_RESOLUTION:
            raise argparse.ArgumentTypeError(
                f"--resolution {text!r}: {v} px is outside Blender's range 1..{MAX_RESOLUTION} (each axis)")
    return w, h


MAX_RESOLUTION = 65536  # Blender clamps render resolution here (the manifest would record the unclamped size)


def argument_errors(args) -> list[str]:
    """Every capture argument outside what Blender accepts, each naming its flag (empty when all are fine)."""
    errors = []
    res_x, res_y = args.resolution or (None, None)
    for flag, v in (("--resolution", res_x), ("--resolution", res_y), ("--resolution-y", args.resolution_y)):
        if v is not None and not 1 <= v <= MAX_RESOLUTION:
            errors.append(f"{flag}: {v} px is outside Blender's range 1..{MAX_RESOLUTION} (each axis)")
    for flag, v in (("--count", args.count), ("--val-count", args.val_count), ("--test-count", args.test_count)):
        if v < 0:
            errors.append(f"{flag}: must be >= 0, got {v}")
    if args.count < 2 and not args.keep_cameras:
        # `train` and `check` refuse a train split of one view: a capture must not write one
        errors.append(f"--count: a capture needs at least 2 train views, got {args.count}")
    for flag, v in (("--val-count", args.val_count), ("--test-count", args.test_count)):
        # An empty split file is refused by `train` and `check` (the original NeRF loader and 3DGS read
        # every split): a capture must not write a dataset our own tools reject.
        if v == 0 and not args.keep_cameras:
            errors.append(f"{flag}: a dataset needs at least 1 view in each split (train, val, test), got 0")
    for flag, v, lo in (("--samples", args.samples, 1), ("--frame-step", args.frame_step, 1),
                        ("--n-points", args.n_points, 1), ("--rings", args.rings, 1)):
        if v < lo:
            errors.append(f"{flag}: must be >= {lo}, got {v}")
    import math

    for flag, v, positive in (("--focal-length", args.focal_length, True), ("--radius", args.radius, False),
                              ("--turns", args.turns, True)):
        if not math.isfinite(v) or (v <= 0 if positive else v < 0):
            errors.append(f"{flag}: must be {'> 0' if positive else '>= 0'}, got {v}")
    if args.save_blend and os.path.lexists(args.save_blend):
        # A user's .blend (or any file) is never replaced: Blender's one .blend1 backup would not
        # survive a second run, and the --blend input itself could be the path.
        errors.append(f"--save-blend: {args.save_blend} already exists; choose a new file name "
                      "(nothing was captured)")
    elif args.save_blend:
        folder = os.path.dirname(os.path.abspath(args.save_blend))
        if not os.path.isdir(folder):
            # Blender would fail only after the whole capture, with a traceback.
            errors.append(f"--save-blend: folder {folder} does not exist (nothing was captured)")
        elif not os.access(folder, os.W_OK):
            errors.append(f"--save-blend: folder {folder} is not writable (nothing was captured)")
    for flag, v in (("--elevation-min", args.elevation_min), ("--elevation-max", args.elevation_max)):
        if v is not None and not (math.isfinite(v) and -90.0 <= v <= 90.0):
            errors.append(f"{flag}: {v} degrees is outside [-90, 90]")
    if args.colmap or args.colmap_splits:
        errors += colmap_errors(args)
    if args.shard is not None:
        from addon.capture.plan import frame_plan

        try:
            frame_plan.parse_shard(args.shard)
        except ValueError as exc:
            errors.append(str(exc))
        if args.merge:
            errors.append("--merge joins the shards once they are all done: run it without --shard")
        if args.overwrite:
            errors.append("--overwrite cannot go with --shard: shards share the folder and one would delete "
                          "another's frames; empty the folder once before starting the shards")
    if (args.elevation_min is not None and args.elevation_max is not None
            and args.elevation_min > args.elevation_max):
        errors.append(f"--elevation-min {args.elevation_min} is above --elevation-max {args.elevation_max}")
    return errors


def colmap_errors(args) -> list[str]:
    """Why --colmap cannot run here (before anything renders): bad splits, a shard, no Pillow in this Python."""
    errors = []
    if args.colmap_splits and not args.colmap:
        errors.append("--colmap-splits needs --colmap")
    if args.shard is not None and args.colmap:
        errors.append("--colmap needs the whole capture: give it to --merge, not to a shard")
    try:
        from nerf_core.export import colmap  # Pillow reads and writes its images: not in every Blender
    except ImportError as exc:
        return errors + [f"--colmap: this Python cannot import the COLMAP export ({exc}); capture without it, "
                         "then run `python -m nerf_core export colmap DATASET --out DATASET/colmap`"]
    try:
        colmap.parse_splits(args.colmap_splits or "train")
    except ValueError as exc:
        errors.append(str(exc).replace("--splits", "--colmap-splits"))
    return errors


def write_colmap(args, summary: dict) -> None:
    """DATASET/colmap from the finished capture, its notes on stderr and its summary in ``summary``."""
    from nerf_core.export import colmap

    def note(message: str) -> None:
        print(f"capture: note: colmap: {message}", file=sys.stderr)

    out = os.path.join(os.path.abspath(args.out), colmap.CAPTURE_SUBDIR)
    splits = colmap.parse_splits(args.colmap_splits or "train")
    try:
        summary["colmap"] = colmap.export_colmap(args.out, out, splits=splits, overwrite=True, on_note=note,
                                                 in_capture=True)
    except ValueError as exc:  # the output path; the capture itself is complete and kept
        raise DatasetError(f"--colmap: {exc}") from None


def build_parser() -> argparse.ArgumentParser:
    from addon.capture.layout import positions

    ap = _bootstrap.scene_parser("capture.py", __doc__.split("\n\n")[0], "scene to open")
    ap.add_argument("--out", required=True, help="dataset folder to write")
    ap.add_argument("--layout", default="hemisphere", choices=positions.LAYOUTS)
    ap.add_argument("--count", type=int, default=100, help="train views (generated layouts)")
    ap.add_argument("--val-count", type=int, default=10)
    ap.add_argument("--test-count", type=int, default=20)
    ap.add_argument("--resolution", type=parse_resolution, default=None,
                    help="R (square) or WxH (default 200; with --layout scene-cameras and cameras imported by "
                         "import_cameras.py, the size of their file's images)")
    ap.add_argument("--resolution-y", type=int, help="image height when --resolution gives only the width")
    ap.add_argument("--engine", default="cycles", choices=("cycles", "eevee", "workbench"))
    ap.add_argument("--samples", type=int, default=16, help="render samples per pixel (Cycles/EEVEE)")
    ap.add_argument("--denoise", action="store_true", help="Cycles denoising (off by default: it blurs detail)")
    ap.add_argument("--opaque", action="store_true", help="render the world background instead of a transparent film")
    ap.add_argument("--seed", type=int, default=0, help="random layout and split assignment")
    ap.add_argument("--radius", type=float, default=0.0,
                    help="camera distance from the target centre; 0 = auto (unused by --layout inside)")
    ap.add_argument("--elevation-min", type=float,
                    help="degrees (default 0 for hemisphere/spiral, 10 for rings, -25 for inside, -90 else)")
    ap.add_argument("--elevation-max", type=float, help="degrees (default 90; 60 for rings, 15 for inside)")
    ap.add_argument("--focal-length", type=float, default=50.0, help="mm on a 36 mm sensor")
    ap.add_argument("--rings", type=int, default=3)
    ap.add_argument("--turns", type=float, default=3.0, help="spiral turns")
    ap.add_argument("--frame-step", type=int, default=10, help="animation layout: every Nth frame")
    ap.add_argument("--target", choices=("scene", "selection"), default="scene",
                    help="what the cameras aim at and frame (and what masks cover)")
    ap.add_argument("--keep-cameras", action="store_true", help="capture the existing 'NeRF Cameras' collection")
    ap.add_argument("--depth", action="store_true", help="planar depth EXRs (depth/<split>/r_i.exr, channel Z)")
    ap.add_argument("--normals", action="store_true", help="world-space normal EXRs (Cycles/EEVEE)")
    ap.add_argument("--masks", action="store_true", help="object mask PNGs (masks/<split>/r_i.png)")
    ap.add_argument("--points", action="store_true", help="points3d.ply back-projected from the train views")
    ap.add_argument("--n-points", type=int, default=100_000)
    ap.add_argument("--normalize-camera-scale", action="store_true",
                    help="accept scaled cameras, dropping their scale (recorded in the manifest)")
    ap.add_argument("--overwrite", action="store_true", help="replace a different dataset in --out")
    ap.add_argument("--resume", action="store_true", help="require an existing capture in --out to continue")
    ap.add_argument("--shard", metavar="K/N",
                    help="render only shard K of N (K = 1..N) into the shared --out; then run --merge")
    ap.add_argument("--merge", action="store_true",
                    help="after every shard: verify all planned frames in --out and write the dataset's JSON, "
                         "point cloud and manifest (needs only --out)")
    ap.add_argument("--colmap", action="store_true",
                    help="also write DATASET/colmap/: a COLMAP model (sparse/0, images/, masks/) for splatting")
    ap.add_argument("--colmap-splits", metavar="LIST", help="splits --colmap exports (default train; e.g. train,test)")
    ap.add_argument("--save-blend", help="also save the scene with its NeRF cameras to this .blend")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def imported_resolution(scene, layout: str):
    """The scene's render size when ``layout`` re-renders cameras imported from a transforms file
    (import_cameras.py set it to their images' size), else None."""
    from addon.capture.layout import camera_import

    if layout != "scene-cameras" or not any(camera_import.is_imported(o) for o in scene.objects):
        return None
    r = scene.render
    return r.resolution_x * r.resolution_percentage // 100, r.resolution_y * r.resolution_percentage // 100


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    errors = argument_errors(args)
    if errors:  # before Blender opens anything or renders a frame
        for e in errors:
            print(f"capture: error: {e}", file=sys.stderr)
        return 2
    if args.save_blend:  # the output rule too: never an input, a dataset's file, or through a link
        args.save_blend = _bootstrap.check_output("capture", "--save-blend", args.save_blend, False,
                                                  {"--blend": args.blend}, need_folder=True)
    if args.merge:
        from addon.capture.run import merge

        summary = merge.merge(args.out)
        if args.colmap:
            write_colmap(args, summary)
        print(json.dumps(summary), flush=True)
        return 0
    _bootstrap.open_blend(args.blend)
    import bpy

    from addon.capture.run import job as run_job
    from addon.capture.plan import frame_plan, settings as plan_settings
    from addon.capture.layout import positions
    from addon.capture.layout import collection, cameras, notes
    from addon.dataset import capture_manifest
    from nerf_core.utils.progressbar import ProgressBar

    scene = bpy.context.scene
    res_x, res_y = args.resolution or (imported_resolution(scene, args.layout) or (200, None))
    res_y = res_y if res_y is not None else (args.resolution_y if args.resolution_y is not None else res_x)
    if args.resume and capture_manifest.read_manifest(os.path.abspath(args.out)) is None:
        raise frame_plan.CaptureError(f"--resume: {args.out} holds no capture to continue")
    spec = positions.LayoutSpec(
        layout=args.layout, train=args.count, val=args.val_count, test=args.test_count, radius=args.radius,
        elevation_min=args.elevation_min, elevation_max=args.elevation_max, seed=args.seed, rings=args.rings,
        turns=args.turns, frame_step=args.frame_step, focal_length=args.focal_length, target=args.target.upper())
    if args.keep_cameras:
        kept = collection.capture_cameras(scene)
        if not any(kept.values()):
            raise frame_plan.CaptureError(f"--keep-cameras: scene has no cameras in {positions.COLLECTION_NAME!r}")
        problem = collection.held_out_problem(kept) if kept["train"] else None
        if problem:
            raise frame_plan.CaptureError(f"--keep-cameras: {problem}")
        layout_record = {"layout": "existing 'NeRF Cameras' collection"}
    else:
        cameras.create_cameras(scene, spec, res_x, res_y)
        layout_record = spec.to_dict()
        for note in notes.layout_notes(scene, spec):
            print(f"capture: note: {note}", file=sys.stderr)
    settings = plan_settings.CaptureSettings(
        out_dir=args.out, engine=args.engine, samples=args.samples, res_x=res_x, res_y=res_y,
        film_transparent=not args.opaque, denoise=args.denoise, depth=args.depth, normals=args.normals,
        masks=args.masks, points=args.points, n_points=args.n_points, overwrite=args.overwrite,
        target=args.target.upper(), normalize_camera_scale=args.normalize_camera_scale, layout=layout_record,
        seed=args.seed, shard=frame_plan.parse_shard(args.shard) if args.shard else None)
    bar = ProgressBar(total=None, label="capture", enabled=not args.quiet)

    def progress(done, total, info):
        bar.total = total
        bar.set(done, info)

    job = run_job.CaptureJob(scene, settings, progress=progress)
    job.plan()  # its notes (the cameras' intrinsics) come before any render
    for note in job.notes:
        print(f"capture: note: {note}", file=sys.stderr)
    try:
        summary = job.run()
    except KeyboardInterrupt:
        bar.close("cancelled")
        print(f"capture: interrupted; {args.out} is consistent and resumes when you run the same command",
              file=sys.stderr)
        return 130
    bar.close("done")
    if args.colmap:
        write_colmap(args, summary)
    if args.save_blend:
        _bootstrap.save_blend("capture", os.path.abspath(args.save_blend))
    print(json.dumps(summary), flush=True)
    return 0


def run() -> int:
    from addon.capture.plan import frame_plan
    from addon.capture.layout import positions
    from addon.dataset.errors import ExportError
    from addon.scene import scene_bounds

    from addon.scene import passes

    # DatasetError: the COLMAP export of the finished capture (--colmap); the capture itself is kept
    known = (frame_plan.CaptureError, positions.LayoutError, ExportError, scene_bounds.BoundsError,
             passes.PassError, DatasetError)
    try:
        return main(_bootstrap.script_args())
    except known as exc:
        print(f"capture: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    _bootstrap.exit_code(run())
