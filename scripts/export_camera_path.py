"""Export a Blender camera's animation as nerfstudio's camera_path.json.

    python scripts/export_camera_path.py --blend SCENE --camera NAME --frames A:B --out camera_path.json
    blender -b SCENE --python scripts/export_camera_path.py -- --camera NAME --frames A:B --out camera_path.json

Every frame A..B (inclusive; default the scene's range and step) becomes one camera_path entry: the
camera's pose at that frame and its own vertical field of view (an animated focal length is kept)
and aspect, at the scene's render size (resolution x percentage). ``--camera`` defaults to the
scene's active camera. Then ``python -m nerf_core render RUN --cameras camera_path.json`` renders the
same images as ``scripts/render_nerf.py`` over those frames (outputs ``frame_00000.png``, ... in frame order).
``--dataparser-transforms`` (nerfstudio's ``dataparser_transforms.json``, or its output folder) writes
the poses in nerfstudio's world, for ``ns-render camera-path``. A lens shift or non-square pixels,
which the format cannot hold, are refused naming the frames. An existing --out is refused unless
``--overwrite``. The last stdout line is a JSON summary.
"""
from __future__ import annotations

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _bootstrap  # noqa: E402
from _bootstrap import exit_code, open_blend, scene_parser, script_args  # noqa: E402


def parse(argv):
    ap = scene_parser("export_camera_path.py", __doc__, "scene holding the camera")
    ap.add_argument("--camera", help="camera object name (default: the scene's active camera)")
    ap.add_argument("--frames", metavar="A:B", help="first and last frame, inclusive (default: the scene's range)")
    ap.add_argument("--out", required=True, help="camera_path.json to write")
    ap.add_argument("--dataparser-transforms", metavar="FILE",
                    help="nerfstudio's dataparser_transforms.json: write the poses in nerfstudio's world")
    ap.add_argument("--overwrite", action="store_true", help="replace --out when it exists")
    return ap.parse_args(argv)


def fail(message: str) -> None:
    _bootstrap.fail("export_camera_path", message)


def main(argv) -> int:
    args = parse(argv)
    _bootstrap.check_output("export_camera_path", "--out", args.out, args.overwrite,
                            {"--blend": args.blend, "--dataparser-transforms": args.dataparser_transforms})
    import bpy

    open_blend(args.blend)
    scene = bpy.context.scene
    if args.camera:
        cam = bpy.data.objects.get(args.camera)
        if cam is None or cam.type != "CAMERA":
            names = sorted(o.name for o in scene.objects if o.type == "CAMERA")
            fail(f"--camera {args.camera!r}: no camera of that name in the scene (cameras: "
                 f"{', '.join(names) or 'none'})")
    else:
        cam = scene.camera
        if cam is None:
            fail(f"scene {scene.name!r} has no active camera; pass --camera NAME")
    frames = _bootstrap.frame_range("export_camera_path", args.frames, scene)
    from addon.compare import camera_path_export
    from addon.dataset.errors import ExportError

    try:
        summary = camera_path_export.export_camera_path(scene, cam, frames, args.out, args.dataparser_transforms,
                                                        overwrite=args.overwrite)
    except ExportError as exc:
        fail(str(exc))
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    exit_code(main(script_args()))
