"""Import the cameras of a transforms file into a Blender scene, as cameras in their own collection.

    python scripts/import_cameras.py --blend SCENE --transforms FILE --out OUT.blend [--dataparser-transforms F]
    blender -b SCENE --python scripts/import_cameras.py -- --transforms FILE --out OUT.blend

FILE is any transforms file: the synthetic layout (a dataset folder or one of its
``transforms_{train,val,test}.json``: every split is imported), nerfstudio's or instant-ngp's
``transforms.json``, or nerfstudio's ``camera_path.json``. Each view becomes a camera in the
collection "Imported Cameras" with its exact intrinsics (focal length, sensor fit, lens shift from the
principal point; the scene's resolution and pixel aspect are the first view's) and records its split
and place in the file. Distortion Blender cannot model is reported naming the frames.
``--dataparser-transforms`` (nerfstudio's ``dataparser_transforms.json``, or its output folder) takes
poses written in nerfstudio's world (its viewer's camera paths) back into the scene's.

Without ``--blend`` (plain Python) the cameras go into an empty scene. The scene file itself is never
changed: the result is saved to OUT.blend, which must not exist unless ``--overwrite``. Then
``capture.py --blend OUT.blend --layout scene-cameras`` re-renders exactly these views, in the file's
splits. The last stdout line is a JSON summary.
"""
from __future__ import annotations

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from _bootstrap import exit_code, open_blend, scene_parser, script_args  # noqa: E402


def parse(argv):
    ap = scene_parser("import_cameras.py", __doc__, "scene to import into (default: an empty scene)")
    ap.add_argument("--transforms", required=True, metavar="FILE",
                    help="transforms file (synthetic, nerfstudio, instant-ngp), dataset folder, or camera_path.json")
    ap.add_argument("--out", required=True, metavar="OUT.blend", help="the .blend to write")
    ap.add_argument("--dataparser-transforms", metavar="FILE",
                    help="nerfstudio's dataparser_transforms.json: the poses are in nerfstudio's world")
    ap.add_argument("--overwrite", action="store_true", help="replace OUT.blend when it exists")
    return ap.parse_args(argv)


def fail(message: str) -> None:
    _bootstrap.fail("import_cameras", message)


def main(argv) -> int:
    args = parse(argv)
    out = _bootstrap.out_blend("import_cameras", args.out, args.overwrite, {
        "--blend": args.blend, "--transforms": args.transforms, "--dataparser-transforms": args.dataparser_transforms})
    import bpy

    if args.blend:
        open_blend(args.blend)
    elif not _bootstrap.inside_blender():
        bpy.ops.wm.read_factory_settings(use_empty=True)
    from addon.capture.layout import camera_import

    try:
        summary = camera_import.import_cameras(bpy.context.scene, args.transforms, args.dataparser_transforms)
    except camera_import.CameraImportError as exc:
        fail(f"--transforms: {exc}")
    for note in summary["notes"]:
        print(f"import_cameras: note: {note}", file=sys.stderr)
    for warning in summary["warnings"]:
        print(f"import_cameras: warning: {warning}", file=sys.stderr)
    _bootstrap.save_blend("import_cameras", out)
    summary["out"] = out
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    exit_code(main(script_args()))
