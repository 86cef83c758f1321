"""Render a compare .blend through its camera to one PNG (how docs/images/gallery.png is made).

    python scripts/render_gallery.py --blend compare_gallery.blend --out gallery.png
    blender -b compare_gallery.blend --python scripts/render_gallery.py -- --out gallery.png

Renders the scene's camera (``import_views.py --layout gallery`` makes it ``NeRF Gallery Camera``,
orthographic, framing every tile and header) at the scene's resolution. The tiles must show the
PNGs' own colours, so the view transform is Standard and Workbench draws textures unlit (Flat
lighting, Texture colour); ``--engine cycles`` renders the planes' emission instead. The .blend is
never saved and an existing --out is kept unless --overwrite.
"""
from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from nerf_core.utils.atomic import atomic_path  # noqa: E402


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="render_gallery.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--blend", help="the compare .blend (plain Python; under Blender the open file is used)")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--engine", choices=("workbench", "cycles"), default="workbench")
    ap.add_argument("--samples", type=_bootstrap.whole_number(1, 1 << 24, "Cycles' samples a pixel"), default=8,
                    help="Cycles samples (default 8)")
    ap.add_argument("--background", type=_bootstrap.share, nargs=3, default=(0.08, 0.08, 0.08), metavar=("R", "G", "B"),
                    help="world colour behind the tiles (default dark grey)")
    # Blender clamps 0 to 1 % silently and would report a 0x0 image; past 1000 % a gallery is a poster
    ap.add_argument("--percent", type=_bootstrap.whole_number(1, 1000, "a share of the scene's resolution"),
                    default=100,
                    help="resolution %% of the scene's resolution (default 100: a tile at the views' own size)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    args = ap.parse_args(argv)
    out = _bootstrap.check_output("render_gallery", "--out", args.out, args.overwrite, {"--blend": args.blend})
    import bpy

    _bootstrap.open_blend(args.blend)
    scene = bpy.context.scene
    if scene.camera is None:
        print(f"render_gallery: error: {bpy.data.filepath or 'the scene'} has no active camera "
              "(write it with scripts/import_views.py)", file=sys.stderr)
        return 2
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    if scene.world is None:
        scene.world = bpy.data.worlds.new("Gallery Background")
    scene.world.color = args.background
    scene.render.film_transparent = False
    if args.engine == "workbench":
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.display.shading.light = "FLAT"
        scene.display.shading.color_type = "TEXTURE"
        scene.display.render_aa = "8"
    else:
        scene.render.engine = "CYCLES"
        scene.cycles.samples = args.samples
        scene.cycles.device = "CPU"
        if scene.world.use_nodes and scene.world.node_tree:
            bg = scene.world.node_tree.nodes.get("Background")
            if bg is not None:
                bg.inputs["Color"].default_value = (*args.background, 1.0)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.resolution_percentage = args.percent
    os.makedirs(os.path.dirname(out), exist_ok=True)
    scene.render.use_file_extension = False  # the fresh name below is the file, as it is
    # Blender writes a fresh private name, renamed over --out once whole: never through a link.
    with atomic_path(out, flag="--out") as tmp:
        scene.render.filepath = str(tmp)
        bpy.ops.render.render(write_still=True)
    size = [v * args.percent // 100 for v in (scene.render.resolution_x, scene.render.resolution_y)]
    print(f"render_gallery: wrote {out} ({size[0]}x{size[1]}) "
          f"through {scene.camera.name!r}")
    return 0


if __name__ == "__main__":
    _bootstrap.exit_code(main(_bootstrap.script_args()))
