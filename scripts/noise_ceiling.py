"""How high can a model score on a Cycles capture? Render its test views again with another seed.

    python scripts/noise_ceiling.py --blend scene.blend --dataset DATASET [--views 5] [--seed 1] [--out ceiling.json]
    blender -b scene.blend --python scripts/noise_ceiling.py -- --dataset DATASET

A path-traced capture is noisy, so test PSNR has a ceiling that no model passes by much. This script
re-renders ``--views`` evenly spread test views of ``DATASET`` (the views ``eval --views K`` scores)
from the scene they were captured from, with the capture's recorded render settings (engine, samples,
resolution, film, denoising, colour management) but Cycles seed ``--seed``, then scores each new render
against the dataset's image exactly as ``eval`` scores a model: both composited on white, PSNR over
every pixel.

Two renders that differ only in their noise score ``P`` against each other. A model that learnt the
noise-free scene differs from each by one render's noise, half the squared error of two renders, so
it scores about ``P + 3 dB`` (10 log10 2): the ``model_ceiling`` in the output. Scores above it mean
the model fits the capture's own noise; scores near it leave nothing to gain.

The .blend is never saved; the scene's camera is replaced only in memory.
"""
from __future__ import annotations

import json
import math
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from nerf_core.utils.atomic import write_text_atomic  # noqa: E402

PROG = "noise_ceiling.py"


def composite_white(rgba):
    """(h, w, 4) float RGBA in [0, 1] -> (h, w, 3) on white, as ``eval`` composites ground truth."""
    return rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])


def psnr(a, b) -> float:
    import numpy as np

    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def read_rgba(path: str):
    import numpy as np
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0


def apply_capture_settings(scene, render_meta: dict, seed: int) -> None:
    """The manifest's recorded render settings on ``scene``, with Cycles seed ``seed``."""
    r = scene.render
    r.engine = "CYCLES"  # main() refuses other engines: only Cycles captures have sampling noise
    r.resolution_x, r.resolution_y = (int(v) for v in render_meta["resolution"])
    r.resolution_percentage = 100
    r.pixel_aspect_x, r.pixel_aspect_y = (float(v) for v in render_meta.get("pixel_aspect", (1.0, 1.0)))
    r.film_transparent = bool(render_meta["film_transparent"])
    scene.cycles.samples = int(render_meta["samples"])
    scene.cycles.use_denoising = bool(render_meta.get("denoise", False))
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.seed = int(seed)
    scene.cycles.use_animated_seed = False
    scene.cycles.device = "CPU"
    cm = render_meta.get("color_management", {})
    vs, ds = scene.view_settings, scene.display_settings
    for obj, attr in ((ds, "display_device"), (vs, "view_transform"), (vs, "look"), (vs, "exposure"), (vs, "gamma")):
        if attr in cm:
            setattr(obj, attr, cm[attr])
    img = r.image_settings
    img.file_format, img.color_mode, img.color_depth = "PNG", "RGBA", "8"


def render_view(scene, cam_obj, frame, path: str) -> None:
    """Render ``frame`` (a validated ``contract.FrameInfo``) through ``cam_obj`` to the PNG ``path``."""
    from mathutils import Matrix

    from nerf_core import contract

    fx, _, _, _, w, _ = contract.resolve_intrinsics(None, frame.intrinsics, where=frame.where)
    cam_obj.matrix_world = Matrix(frame.c2w.tolist())
    cam_obj.data.sensor_fit = "HORIZONTAL"
    cam_obj.data.angle_x = contract.fov_from_focal(fx, w)
    scene.camera = cam_obj
    scene.render.filepath = path
    import bpy

    bpy.ops.render.render(write_still=True)


def main(argv: list[str]) -> int:
    ap = _bootstrap.scene_parser(PROG, __doc__.split("\n\n")[0], "the scene the dataset was captured from")
    ap.add_argument("--dataset", required=True,
                    help="dataset folder (transforms_test.json, nerf_capture/manifest.json)")
    ap.add_argument("--views", type=int, default=5,
                    help="test views to render, evenly spread (default 5, as eval --views 5)")
    ap.add_argument("--seed", type=int, default=1,
                    help="Cycles seed of the new renders (the capture used the scene's, 0 by default)")
    ap.add_argument("--out",
                    help="JSON file to write (default: print only); an existing file is kept unless --overwrite")
    ap.add_argument("--keep-renders", metavar="DIR",
                    help="keep the new renders there (vVIEW.png, RGBA as captured), e.g. to see where the noise lies; "
                         "the folder must not exist yet")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    if args.views < 1:
        _bootstrap.fail(PROG, f"--views must be at least 1, got {args.views}")
    if args.out:  # the output rule: never an input, a dataset's file or through a link
        args.out = _bootstrap.check_output(PROG, "--out", args.out, args.overwrite,
                                           {"--blend": args.blend, "--dataset": args.dataset}, need_folder=True)
    if args.keep_renders and os.path.exists(args.keep_renders):
        _bootstrap.fail(PROG, f"{args.keep_renders} exists; --keep-renders writes a new folder")
    manifest_path = os.path.join(args.dataset, "nerf_capture", "manifest.json")
    test_path = os.path.join(args.dataset, "transforms_test.json")
    for p in (manifest_path, test_path):
        if not os.path.isfile(p):
            _bootstrap.fail(PROG, f"{p}: not found (is --dataset a capture written by scripts/capture.py?)")
    from nerf_core import contract

    try:
        manifest = contract.read_json(manifest_path)
        render_meta = manifest["render"]
        frames = contract.read_frames(contract.read_json(test_path), test_path, add_png=True)
    except KeyError as exc:
        _bootstrap.fail(PROG, f"{manifest_path}: field {exc} is missing")
    except contract.DatasetError as exc:
        _bootstrap.fail(PROG, str(exc))
    if render_meta.get("engine") != "CYCLES":
        _bootstrap.fail(PROG,
                        f"{manifest_path}: engine {render_meta.get('engine')!r}; only Cycles "
                        f"captures have sampling noise")
    import bpy

    if not args.blend and not bpy.data.filepath:
        # Plain Python with no scene named: Blender's empty default scene would be rendered and compared
        # with the capture (about 10 dB, and no warning). Use the .blend the manifest records instead.
        captured = manifest.get("blend_file")
        if not (isinstance(captured, str) and os.path.isfile(captured)):
            _bootstrap.fail(PROG, f"no --blend given and {manifest_path} names no .blend that exists here "
                                  f"({captured!r}); pass --blend with the scene the dataset was captured from")
        print(f"{PROG}: no --blend: using the captured scene {captured} (from {manifest_path})", file=sys.stderr)
        args.blend = captured
    _bootstrap.open_blend(args.blend)
    scene = bpy.context.scene
    apply_capture_settings(scene, render_meta, args.seed)
    cam_data = bpy.data.cameras.new("NoiseCeilingCamera")
    cam_obj = bpy.data.objects.new("NoiseCeilingCamera", cam_data)
    scene.collection.objects.link(cam_obj)
    views = contract.evenly_spaced(len(frames), max(1, min(args.views, len(frames))))
    per_view = []
    with tempfile.TemporaryDirectory() as scratch:
        tmp = scratch
        if args.keep_renders:
            os.makedirs(args.keep_renders)
            tmp = args.keep_renders
        for v in views:
            frame = frames[v]
            out = os.path.join(tmp, f"v{v}.png")
            render_view(scene, cam_obj, frame, out)
            score = psnr(composite_white(read_rgba(out)), composite_white(read_rgba(str(frame.image))))
            per_view.append({"view": v, "file": frame.file_path, "psnr_two_renders": round(score, 3)})
            print(f"{PROG}: view {v}: two renders {score:.2f} dB", flush=True)
    # The mean of the per-view PSNRs, as eval reports a model's: the two compare directly.
    mean_psnr = sum(e["psnr_two_renders"] for e in per_view) / len(per_view)
    result = {"dataset": os.path.abspath(args.dataset),
              "blend": os.path.abspath(args.blend) if args.blend else bpy.data.filepath,
              "seed": args.seed, "samples": render_meta.get("samples"), "views": views, "per_view": per_view,
              "psnr_two_renders": round(mean_psnr, 3), "model_ceiling": round(mean_psnr + 10 * math.log10(2), 3)}
    print(f"{PROG}: two renders {result['psnr_two_renders']:.2f} dB; a noise-free model scores about "
          f"{result['model_ceiling']:.2f} dB", flush=True)
    if args.out:
        write_text_atomic(args.out, json.dumps(result, indent=1), flag="--out")
    return 0


if __name__ == "__main__":
    _bootstrap.exit_code(main(_bootstrap.script_args()))
