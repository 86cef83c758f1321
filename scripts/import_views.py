"""Render a trained run's novel views and import them into a .blend as image planes.

    python scripts/import_views.py --blend scene.blend --run RUN --out compare.blend [--layout gallery|camera]
    blender -b scene.blend --python scripts/import_views.py -- --run RUN --out compare.blend

Renders the run's test views (``--split``) or the cameras of ``--cameras T.json`` with
``python -m nerf_core render`` in a child process (a progress bar with an ETA on stderr), imports them
(camera-aligned planes or a NeRF | Blender | error gallery with PSNR/SSIM), saves ``--out`` and prints
a JSON summary (mean and per-view PSNR/SSIM) as the last stdout line. Never overwrites the scene
file, and overwrites an existing ``--out`` only with ``--overwrite``. ``--renders DIR`` imports views
that ``nerf_core render`` already wrote for this run (DIR/renders.json) instead of rendering them again,
so a gallery and a camera-aligned file can share one set of renders.

What ``--out`` holds, ready to look at:
* ``--layout camera``: one camera per rendered view (``NeRF Cam <view>``, the view's pose and exact
  intrinsics from renders.json, so no camera needs to be saved with the capture), the first one the
  scene's camera, the scene's resolution the views'; each plane is parented to its camera:
  Numpad 0 (or any camera made active) shows the NeRF's image exactly over the frame.
* ``--layout gallery``: the gallery beside the scene's objects and ``NeRF Gallery Camera``, an
  orthographic camera framing it (headers included), as the scene's camera at the gallery's aspect.
* ``--images pack`` (default; why: addon/compare/image_storage.py) stores the images inside the .blend,
  ``relative`` as ``//`` paths relative to ``--out``, ``absolute`` as absolute paths.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from _bootstrap import REPO_ROOT, exit_code, open_blend, script_args  # noqa: E402


def parse(argv):
    ap = argparse.ArgumentParser(prog="import_views.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--blend", help="scene to import into (plain Python; under Blender the open file is used)")
    ap.add_argument("--run", required=True, help="training run folder (has checkpoints/latest.pt)")
    ap.add_argument("--out", required=True, help=".blend to write")
    ap.add_argument("--layout", choices=("camera", "gallery"), default="gallery")
    ap.add_argument("--cameras", help="transforms JSON of the cameras to render (default: the run's dataset split)")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"),
                    help="dataset split to render when --cameras is not given (default test)")
    ap.add_argument("--distance", type=_distance, default=0.0,
                    help="camera layout: plane distance from the camera (default: the scene centre's depth)")
    ap.add_argument("--images", choices=("pack", "relative", "absolute"), default="pack",
                    help="how --out keeps the images: inside the .blend (pack, the default: it still shows them "
                         "when the run folder moves), as paths relative to --out, or as absolute paths")
    ap.add_argument("--render-dir", help="where the renders go (default: a new RUN/views/<split>_NNN folder)")
    ap.add_argument("--renders", metavar="DIR",
                    help="import the renders already in DIR (its renders.json, written by `nerf_core render` of "
                         "this run) instead of rendering again; the cameras are the ones DIR was rendered from")
    ap.add_argument("--python", default=os.environ.get("NERF_PYTHON", ""),
                    help="interpreter with torch for nerf_core (default: $NERF_PYTHON, else this Python)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    ap.add_argument("--force", action="store_true",
                    help="import although the run's dataset was captured from another .blend (its manifest's sha256)")
    return ap.parse_args(argv)


def _finite(x):
    """JSON has no inf/NaN: identical images (PSNR inf) are reported as null."""
    return x if isinstance(x, (int, float)) and math.isfinite(x) else None


def _distance(text: str) -> float:
    """--distance: a finite number of scene units >= 0 (0: automatic)."""
    import argparse

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of scene units, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite distance >= 0 in front of the camera (0: automatic), "
                                         f"got {text}")
    return value


def fail(message: str) -> None:
    print(f"import_views: error: {message}", file=sys.stderr)
    exit_code(2)


def render(python: str, run: str, cameras: str, out_dir: str, n_views: int) -> None:
    """Run ``nerf_core render`` with a progress bar counting the PNGs as they appear."""
    from addon.compare import compare_views as compare
    from addon.bridge import child_process
    from nerf_core.utils.progressbar import ProgressBar

    proc = child_process.BackgroundProcess(child_process.render_command(python, run, cameras, out_dir)).start()
    bar = ProgressBar(total=n_views, label="render views")
    while not proc.finished():
        proc.poll()
        bar.set(min(compare.rendered_count(out_dir), n_views))
        time.sleep(0.2)
    proc.poll()
    bar.close()
    failure = proc.failure_message()
    if failure:
        fail(f"rendering {run} failed: {failure}")


def _file_sha256(path: str) -> str | None:
    import hashlib

    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return h.hexdigest()


def existing_renders(renders_dir: str, run: str) -> tuple[str, str]:
    """``(render_dir, cameras)`` of a folder that ``nerf_core render`` wrote for ``run``: import_views then
    imports those images rather than rendering the same views again. Exits naming the folder when it
    holds no renders.json or renders.json says another run made it."""
    render_dir = os.path.abspath(renders_dir)
    listing = os.path.join(render_dir, "renders.json")
    try:
        with open(listing, encoding="utf-8") as fh:
            meta = json.load(fh)
    except FileNotFoundError:
        fail(f"--renders {render_dir}: no renders.json (render the views first with "
             f"python -m nerf_core render {run} --out {render_dir})")
    except (OSError, ValueError) as exc:
        fail(f"--renders {listing}: not readable as JSON ({exc})")
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        fail(f"--renders {listing}: not a renders.json of nerf_core render (no 'frames' list)")
    made_by = meta.get("run")
    if not isinstance(made_by, str) or os.path.realpath(made_by) != os.path.realpath(run):
        fail(f"--renders {listing}: rendered from run {made_by!r}, not --run {run}; render this run's views "
             "or drop --renders")
    cameras = meta.get("cameras")
    return render_dir, cameras if isinstance(cameras, str) and os.path.isfile(cameras) else None


def check_scene_matches_run(run: str, scene_file: str, force: bool) -> None:
    """Warn, and refuse unless ``force``, when the run's dataset was captured from another .blend.

    The capture manifest (DATASET/nerf_capture/manifest.json) records the .blend's path and sha256;
    planes imported into another scene would sit beside renders of something else.
    """
    from addon.dataset import capture_manifest
    from addon.dataset.errors import ExportError
    from addon.bridge import runs

    dataset = runs.run_dataset(run)
    if not dataset or not scene_file or not os.path.isfile(scene_file):
        return
    try:
        manifest = capture_manifest.read_manifest(dataset)
    except ExportError as exc:
        print(f"import_views: warning: {exc}; cannot check that {scene_file} is the captured scene", file=sys.stderr)
        return
    want = (manifest or {}).get("blend_sha256")
    if not isinstance(want, str) or not want:
        return
    have = _file_sha256(scene_file)
    if have == want:
        return
    captured = manifest.get("blend_file") or "an unnamed .blend"
    message = (f"the run {run} was trained on a capture of {captured} (sha256 {want[:12]}), but the scene is "
               f"{scene_file} (sha256 {(have or '?')[:12]}): the imported views would not line up with it")
    print(f"import_views: warning: {message}", file=sys.stderr)
    if not force:
        fail(f"{message}; pass --force to import anyway")


def main(argv) -> int:
    args = parse(argv)
    # Flags are checked before the scene is opened or anything is rendered.
    from addon.bridge import runs, child_process
    from nerf_core import contract

    out = os.path.abspath(args.out)
    run = os.path.abspath(args.run)
    if args.blend:
        scene_file = os.path.abspath(args.blend)
    else:
        import bpy

        scene_file = bpy.data.filepath
    out = _bootstrap.check_output("import_views", "--out", args.out, args.overwrite,
                                  {"--blend": args.blend, "the scene": scene_file})
    if not os.path.isfile(contract.latest_checkpoint(run)) and not runs.step_checkpoints(run):
        fail(f"--run {run}: no {os.path.relpath(contract.latest_checkpoint(run), run)} "
             "(train it first with python -m nerf_core train)")
    check_scene_matches_run(run, scene_file, args.force)
    if args.renders and (args.cameras or args.render_dir):
        fail("--renders imports renders made before: it does not go with --cameras or --render-dir")
    reused = existing_renders(args.renders, run) if args.renders else None
    if reused:
        cameras = reused[1] or os.path.join(reused[0], "renders.json")
        n_views = 0
    elif args.cameras:
        cameras = os.path.abspath(args.cameras)
        if not os.path.isfile(cameras):
            fail(f"--cameras {cameras}: no such file")
    else:
        dataset = runs.run_dataset(run)
        if not dataset:
            fail(f"--run {run}: config.json names no dataset; pass --cameras T.json")
        cameras = os.path.join(dataset, f"transforms_{args.split}.json")
        if not os.path.isfile(cameras):
            fail(f"dataset {dataset} has no transforms_{args.split}.json; pass --cameras or another --split")
    if not reused:
        try:
            with open(cameras, encoding="utf-8") as fh:
                n_views = len(json.load(fh)["frames"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            fail(f"{cameras}: not a transforms file with 'frames' ({exc})")
        try:
            python = child_process.resolve_interpreter(args.python, addon_dir=os.path.join(REPO_ROOT, "addon"))
        except child_process.SetupError as exc:
            fail(f"{exc} (or pass --python / set NERF_PYTHON)")

    import bpy

    from addon.compare import compare_views as compare, image_storage, planes

    open_blend(args.blend)
    label = os.path.splitext(os.path.basename(cameras))[0].replace("transforms_", "")
    if reused:
        render_dir = reused[0]
    elif args.render_dir:
        render_dir = os.path.abspath(args.render_dir)
        if os.path.isdir(render_dir) and os.listdir(render_dir):
            fail(f"--render-dir {render_dir} is not empty; choose an empty or new folder")
        try:
            os.makedirs(render_dir, exist_ok=True)
        except OSError as exc:
            fail(child_process.describe_os_error(exc, render_dir, "creating"))
    else:
        try:  # a new RUN/views/<label>_NNN, as the Compare panel makes: earlier renders stay intact
            render_dir = compare.fresh_dir(os.path.join(run, compare.VIEWS_DIR), label)
        except child_process.SetupError as exc:
            fail(str(exc))
    if not reused:
        render(python, run, cameras, render_dir, n_views)

    try:
        views = planes.views_from_render(render_dir, cameras)
        scene = bpy.context.scene
        if args.layout == "gallery":
            planes.import_gallery(views, scene=scene, set_scene_camera=True)
            made = [o for o in bpy.data.collections[planes.GALLERY_COLLECTION].all_objects if o.get(planes.TAG)]
        else:
            distance = args.distance or compare.auto_distances(views, run)
            made = planes.import_camera_aligned(views, distance, scene=scene, set_scene_camera=True)
        # Relative paths are written relative to the open file, and saving rebases them onto --out
        # (relative_remap); an unsaved scene has no folder of its own, so they start at --out's.
        note = image_storage.store(image_storage.plane_images(made), args.images,
                                   "" if bpy.data.filepath else os.path.dirname(out))
        for warning in (note, planes.lens_note(views)):
            if warning:
                print(f"import_views: warning: {warning}", file=sys.stderr)
    except ValueError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(child_process.describe_os_error(exc, render_dir))
    try:
        os.makedirs(os.path.dirname(out), exist_ok=True)
    except OSError as exc:
        fail(child_process.describe_os_error(exc, out))
    _bootstrap.save_blend("import_views", out)

    scored = [v for v in views if v.metrics]
    summary = {
        "out": out, "layout": args.layout, "images": args.images, "render_dir": render_dir, "cameras": cameras,
        "n_views": len(views),
        "psnr": _finite(sum(v.metrics["psnr"] for v in scored) / len(scored)) if scored else None,
        "ssim": _finite(sum(v.metrics["ssim"] for v in scored) / len(scored)) if scored else None,
        "views": [{"name": v.name, **{k: _finite(x) for k, x in v.metrics.items()}} for v in views],
    }
    for v in views:
        m = v.metrics
        print(f"  {v.name:20s} " + (f"PSNR {m['psnr']:6.2f} dB  SSIM {m['ssim']:.3f}" if m else "(no ground truth)"))
    print(f"import_views: wrote {out}", file=sys.stderr)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    exit_code(main(script_args()))
