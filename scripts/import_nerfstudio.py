"""Bring nerfstudio's results into a Blender scene, in the scene's own coordinates.

    python scripts/import_nerfstudio.py --blend SCENE --nerfstudio OUTPUT_DIR --geometry cloud.ply \\
        [--camera-path camera_path.json] --out OUT.blend
    blender -b SCENE --python scripts/import_nerfstudio.py -- --nerfstudio OUTPUT_DIR ... --out OUT.blend

OUTPUT_DIR is a nerfstudio output folder (its ``dataparser_transforms.json``; the file itself works too)
of a model trained on a capture of this scene. nerfstudio re-orients, re-centres and re-scales the poses
it reads; that file records how. Every ``--geometry`` (PLY point cloud or OBJ/PLY mesh from
``ns-export``) is imported as written and given the inverse transform as its object matrix, and a
``--camera-path`` (nerfstudio's viewer writes it in its own world) becomes cameras in "Imported
Cameras" at the scene's poses, exactly as ``import_cameras.py --dataparser-transforms`` does. Our
captures write the scene's own world into the dataset, so the chain lands in the scene exactly.

The scene file is never changed: the result is saved to OUT.blend (refused when it exists, unless
``--overwrite``). The last stdout line is a JSON summary.
"""
from __future__ import annotations

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from _bootstrap import exit_code, open_blend, scene_parser, script_args  # noqa: E402


def parse(argv):
    ap = scene_parser("import_nerfstudio.py", __doc__, "scene the capture was made from")
    ap.add_argument("--nerfstudio", required=True, metavar="DIR",
                    help="nerfstudio output folder holding dataparser_transforms.json (or that file)")
    ap.add_argument("--geometry", action="append", default=[], metavar="FILE",
                    help="a PLY or OBJ exported by nerfstudio (repeatable)")
    ap.add_argument("--camera-path", metavar="FILE", help="a camera_path.json in nerfstudio's world")
    ap.add_argument("--out", required=True, metavar="OUT.blend", help="the .blend to write")
    ap.add_argument("--overwrite", action="store_true", help="replace OUT.blend when it exists")
    return ap.parse_args(argv)


def fail(message: str) -> None:
    _bootstrap.fail("import_nerfstudio", message)


def main(argv) -> int:
    args = parse(argv)
    out = _bootstrap.out_blend("import_nerfstudio", args.out, args.overwrite, {
        "--blend": args.blend, "--camera-path": args.camera_path,
        **{f"--geometry {g}": g for g in args.geometry}})
    if not args.geometry and not args.camera_path:
        fail("nothing to import: pass --geometry FILE and/or --camera-path FILE")
    import bpy

    if args.blend:
        open_blend(args.blend)
    elif not _bootstrap.inside_blender():
        bpy.ops.wm.read_factory_settings(use_empty=True)
    from addon.capture.layout import camera_import
    from addon.compare import nerfstudio_results
    from addon.dataset.errors import ExportError

    scene = bpy.context.scene
    summary = {"out": out, "objects": [], "cameras": 0}
    for path in args.geometry:
        try:
            made = nerfstudio_results.import_geometry(scene, path, args.nerfstudio)
        except ExportError as exc:
            fail(f"--geometry: {exc}")
        summary["objects"] += [o.name for o in made]
    if args.camera_path:
        try:
            cams = camera_import.import_cameras(scene, args.camera_path, args.nerfstudio)
        except camera_import.CameraImportError as exc:
            fail(f"--camera-path: {exc}")
        summary["cameras"] = cams["cameras"]
    _bootstrap.save_blend("import_nerfstudio", out)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    exit_code(main(script_args()))
