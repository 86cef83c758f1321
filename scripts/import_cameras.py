"""Import the cameras of a transforms file into a Blender scene, as cameras in their own collection.

    python scripts/import_cameras.py --blend SCENE --transforms FILE --out OUT.blend [--dataparser-transforms F]
    python scripts/import_cameras.py --blend SCENE --colmap DIR/sparse/0 --out OUT.blend [--points]
    blender -b SCENE --python scripts/import_cameras.py -- --transforms FILE --out OUT.blend

FILE is any transforms file: the synthetic layout (a dataset folder or one of its
``transforms_{train,val,test}.json``: every split is imported), nerfstudio's or instant-ngp's
``transforms.json``, or nerfstudio's ``camera_path.json``. Each view becomes a camera in the
collection "Imported Cameras" with its exact intrinsics (focal length, sensor fit, lens shift from the
principal point; the scene's resolution and pixel aspect are the first view's) and records its split
and place in the file. Distortion Blender cannot model is reported naming the frames.
``--dataparser-transforms`` (nerfstudio's ``dataparser_transforms.json``, or its output folder) takes
poses written in nerfstudio's world (its viewer's camera paths) back into the scene's.

``--colmap`` reads a COLMAP sparse model instead (``sparse/0`` with ``cameras/images/points3D`` ``.bin`` or
``.txt``, or the COLMAP folder above it): one camera per registered image, COLMAP's world-to-camera
pose turned into Blender's camera-to-world, its intrinsics as focal length, sensor and lens shift (from
cx/cy). ``--points`` adds the sparse points as one mesh of loose vertices with their colours
(attribute ``Col``). The reconstruction's units and frame are kept: no scale or alignment is applied.

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

from nerf_core import contract  # noqa: E402  (standard library + numpy: fine in Blender)


def parse(argv):
    ap = scene_parser("import_cameras.py", __doc__, "scene to import into (default: an empty scene)")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--transforms", metavar="FILE",
                     help="transforms file (synthetic, nerfstudio, instant-ngp), dataset folder, or camera_path.json")
    src.add_argument("--colmap", metavar="DIR", help="a COLMAP sparse model folder (DIR/sparse/0) or its COLMAP folder")
    ap.add_argument("--out", required=True, metavar="OUT.blend", help="the .blend to write")
    ap.add_argument("--dataparser-transforms", metavar="FILE",
                    help="nerfstudio's dataparser_transforms.json: the poses are in nerfstudio's world")
    ap.add_argument("--points", action="store_true", help="with --colmap: the sparse points as a coloured point mesh")
    ap.add_argument("--overwrite", action="store_true", help="replace OUT.blend when it exists")
    args = ap.parse_args(argv)
    if args.points and not args.colmap:
        ap.error("--points needs --colmap (the sparse points of a COLMAP model)")
    if args.colmap and args.dataparser_transforms:
        ap.error("--dataparser-transforms is nerfstudio's; a COLMAP model is in its own frame")
    return args


def fail(message: str) -> None:
    _bootstrap.fail("import_cameras", message)


def main(argv) -> int:
    args = parse(argv)
    out = _bootstrap.out_blend("import_cameras", args.out, args.overwrite, {
        "--blend": args.blend, "--transforms": args.transforms, "--dataparser-transforms": args.dataparser_transforms,
        "--colmap": args.colmap})
    flag, source = ("--colmap", args.colmap) if args.colmap else ("--transforms", args.transforms)
    if args.colmap and contract.colmap_model.find_sparse(args.colmap) is None:
        fail(f"--colmap {args.colmap}: no COLMAP model there (cameras.bin or cameras.txt in it, sparse/0 or sparse)")
    import bpy

    if args.blend:
        open_blend(args.blend)
    elif not _bootstrap.inside_blender():
        bpy.ops.wm.read_factory_settings(use_empty=True)
    from addon.capture.layout import camera_import

    try:
        summary = camera_import.import_cameras(bpy.context.scene, source, args.dataparser_transforms)
        if args.points:
            sparse = contract.colmap_model.find_sparse(args.colmap)
            points = contract.colmap_model.read_model(sparse).points
            if not len(points):
                summary["notes"].append(f"{sparse}: the model has no points; no point object was made")
            else:
                ob = camera_import.import_points(bpy.context.scene, points.xyz, points.rgb, str(sparse))
                summary["points"] = {"object": ob.name, "count": len(points)}
    except (camera_import.CameraImportError, contract.DatasetError) as exc:
        fail(f"{flag}: {exc}")
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
