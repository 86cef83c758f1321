"""Render a scene's active camera over its frame range through a trained NeRF (the "NeRF" render engine).

    python scripts/render_nerf.py --blend scene.blend --run RUN --out DIR [--frames A:B] [--depth] [--python PY]
    blender -b scene.blend --python scripts/render_nerf.py -- --run RUN --out DIR [--frames A:B] [--depth]

For each frame F (``--frames A:B`` inclusive, default the scene's range and step) the scene is rendered
with ``scene.render.engine = "NERF_BRIDGE"`` (addon/render_engine/engine.py: the active camera's lens, sensor
fit, shift and pixel aspect at the scene's resolution x percentage) and written as ``DIR/FFFF.png``
(RGBA, 8 bit) and, with ``--depth``, ``DIR/FFFF_depth.exr``: Blender's multilayer EXR of the same
render (float32; layer ``ViewLayer``, passes ``Combined`` and ``Depth``, channel ``ViewLayer.Depth.Z`` =
planar z-depth in scene units; where nothing was hit inf, which Blender stores as 3.4e38). The render
process loads the model once for all frames. Colour management is set to Standard for these renders
(the NeRF's colours are already display-referred); the scene file is never saved. Existing outputs
are refused unless ``--overwrite``. The last stdout line is a JSON summary.
"""
from __future__ import annotations

import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from _bootstrap import add_python_option, exit_code, open_blend, scene_parser, script_args  # noqa: E402
from nerf_core.utils.atomic import atomic_path  # noqa: E402


def parse(argv):
    ap = scene_parser("render_nerf.py", __doc__, "scene to render")
    ap.add_argument("--run", required=True, help="training run folder (has checkpoints/latest.pt)")
    ap.add_argument("--checkpoint", default="", help="checkpoint instead of RUN/checkpoints/latest.pt")
    ap.add_argument("--out", required=True, help="output folder for FFFF.png (and FFFF_depth.exr)")
    ap.add_argument("--frames", metavar="A:B", help="first and last frame, inclusive (default: the scene's range)")
    ap.add_argument("--depth", action="store_true",
                    help="also write FFFF_depth.exr (multilayer EXR with the Depth pass)")
    add_python_option(ap, "the render process")
    ap.add_argument("--overwrite", action="store_true", help="replace existing outputs in --out")
    return ap.parse_args(argv)


def fail(message: str) -> None:
    _bootstrap.fail("render_nerf", message)


def frame_range(text, scene) -> list:
    """Frames to render (``_bootstrap.frame_range``)."""
    return _bootstrap.frame_range("render_nerf", text, scene)


def set_format(settings, fmt: str) -> None:
    """PNG RGBA 8 bit, or multilayer float EXR (Blender 5 has ``media_type``; 4.x a file format of its own)."""
    if fmt == "PNG":
        if hasattr(settings, "media_type"):
            settings.media_type = "IMAGE"
        settings.file_format = "PNG"
        settings.color_mode, settings.color_depth = "RGBA", "8"
    else:
        if hasattr(settings, "media_type"):
            settings.media_type = "MULTI_LAYER_IMAGE"
        else:
            settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"


def main(argv) -> int:
    args = parse(argv)
    from addon.bridge import render_client, child_process

    run = os.path.abspath(args.run)
    problem = render_client.run_problem(run, os.path.abspath(args.checkpoint) if args.checkpoint else "")
    if problem:
        fail(f"--run: {problem}")
    python = _bootstrap.torch_python("render_nerf", args.python)
    os.environ["NERF_PYTHON"] = python  # the engine's interpreter when no add-on preference names one

    import bpy

    open_blend(args.blend)
    scene = bpy.context.scene
    frames = frame_range(args.frames, scene)
    out = os.path.abspath(args.out)
    names = [f"{f:04d}{suffix}" for f in frames for suffix in ((".png", "_depth.exr") if args.depth else (".png",))]
    # The output rule: no link written through, no dataset's image replaced, existing files only with --overwrite.
    _bootstrap.check_outputs_in("render_nerf", "--out", out, names, args.overwrite,
                                {"--blend": args.blend, "--checkpoint": args.checkpoint})
    if scene.camera is None:
        fail(f"scene {scene.name!r} has no active camera")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        fail(child_process.describe_os_error(exc, out, "creating"))

    import addon
    from addon.render_engine import engine as render_engine

    if not hasattr(bpy.types.Scene, "nerf_render"):  # an installed copy of the extension may have registered it
        addon.register()
    scene.render.engine = render_engine.ENGINE_ID
    scene.nerf_render.run_dir = run
    scene.nerf_render.checkpoint = os.path.abspath(args.checkpoint) if args.checkpoint else ""
    bpy.context.view_layer.use_pass_z = bool(args.depth)
    warning = render_engine.colour_warning(scene)
    if warning:
        print(f"render_nerf: note: {warning}; rendering with Standard (the scene file is not changed)", file=sys.stderr)
    vs = scene.view_settings
    vs.view_transform, vs.look, vs.exposure, vs.gamma = "Standard", "None", 0.0, 1.0
    # Blender dithers float renders into 8-bit files (noise of about one level); the NeRF's colours are
    # already the image, so they are written as `nerf_core render` writes them, byte for byte.
    scene.render.dither_intensity = 0.0

    t0 = time.monotonic()
    written = []
    for k, frame in enumerate(frames):
        scene.frame_set(frame)
        try:
            bpy.ops.render.render(write_still=False)
        except RuntimeError as exc:
            fail(str(exc).strip().removeprefix("Error: ").strip())
        image = bpy.data.images["Render Result"]
        entry = {"frame": frame, "png": os.path.join(out, f"{frame:04d}.png")}
        set_format(scene.render.image_settings, "PNG")
        try:
            with atomic_path(entry["png"], flag="--out") as tmp:
                image.save_render(filepath=str(tmp), scene=scene)
        except (RuntimeError, OSError) as exc:
            fail(f"frame {frame}: could not write {entry['png']}: {str(exc).strip().splitlines()[0]}")
        if args.depth:
            entry["depth"] = os.path.join(out, f"{frame:04d}_depth.exr")
            set_format(scene.render.image_settings, "EXR")
            # Blender 5.0 refuses to write a multilayer EXR whose headers carry a pixel aspect other
            # than 1 ("Conflicting attributes ... pixelAspectRatio"); the pixels are the same either way.
            aspect = (scene.render.pixel_aspect_x, scene.render.pixel_aspect_y)
            scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
            try:
                with atomic_path(entry["depth"], flag="--out") as tmp:
                    image.save_render(filepath=str(tmp), scene=scene)
            except (RuntimeError, OSError) as exc:
                fail(f"frame {frame}: could not write {entry['depth']}: {str(exc).strip().splitlines()[0]}")
            finally:
                scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect
        written.append(entry)
        print(f"render_nerf: frame {frame} ({k + 1}/{len(frames)}) -> {entry['png']}", file=sys.stderr, flush=True)
    render_client.shutdown_all()
    summary = {"out": out, "run": run, "frames": written, "depth": bool(args.depth),
               "width": scene.render.resolution_x * scene.render.resolution_percentage // 100,
               "height": scene.render.resolution_y * scene.render.resolution_percentage // 100,
               "seconds": round(time.monotonic() - t0, 2)}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    exit_code(main(script_args()), skip_finalization=True)
