"""Build a procedural demo scene and save it as a .blend.

    python scripts/make_demo_scene.py NAME --out scene.blend
    blender -b --python scripts/make_demo_scene.py -- NAME --out scene.blend

NAME: cube, diffuse, highfreq, glossy, thin, multi (objects for a transparent film), hdri, interior, ground
(scenes with their own background: capture them with the flags ``--list`` shows). An existing --out
file is kept unless --overwrite.
"""
from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402


def main(argv: list[str]) -> int:
    from addon.capture.demo import scenes

    ap = argparse.ArgumentParser(prog="make_demo_scene.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("name", nargs="?", choices=sorted(scenes.SCENES), help="which scene")
    ap.add_argument("--out", help="the .blend to write")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    ap.add_argument("--list", action="store_true", help="describe the scenes and exit")
    args = ap.parse_args(argv)
    if args.list:
        for key, text in scenes.SCENES.items():
            flags = " ".join(scenes.capture_flags(key))
            print(f"{key:10s} {text}" + (f"\n{'':10s} capture with: {flags}" if flags else ""))
        return 0
    if not args.name or not args.out:
        ap.error("NAME and --out are required")
    out = _bootstrap.out_blend("make_demo_scene", args.out, args.overwrite)
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    try:
        scenes.build(args.name)
    except scenes.DemoSceneError as exc:
        print(f"make_demo_scene: error: {exc}", file=sys.stderr)
        return 2
    _bootstrap.save_blend("make_demo_scene", out)
    print(f"make_demo_scene: wrote {args.name!r} to {out}")
    return 0


if __name__ == "__main__":
    _bootstrap.exit_code(main(_bootstrap.script_args()))
