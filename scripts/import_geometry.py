"""Export a trained run's geometry and import it into a .blend beside the objects it was trained on.

    python scripts/import_geometry.py --blend scene.blend --run RUN --kind mesh|volume|world --out OUT.blend
    blender -b scene.blend --python scripts/import_geometry.py -- --run RUN --kind mesh --out OUT.blend

Runs ``python -m nerf_core export KIND RUN`` in a child process (a progress bar on stderr; Ctrl+C stops
it), writing a new ``RUN/geometry/<kind>_NNN`` file (``--geometry FILE`` to choose), then imports it:
a coloured mesh into the ``NeRF Mesh`` collection, a Volume object (its ``.vdb`` written beside the
``.npz`` with Blender's own OpenVDB) into ``NeRF Volume``, in the scene's frame, or the world the run learned
behind the scene (an opaque capture's) as the scene's World (its light in an ``.exr`` beside the ``.png``;
the scene's old world is kept in the file). Saves ``--out``
(never the scene file; an existing --out only with --overwrite) and prints a JSON summary as the last
stdout line.
"""
from __future__ import annotations

import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _bootstrap import (add_python_option, check_output, exit_code, fail, open_blend, out_blend,  # noqa: E402
                        save_blend, scene_parser, script_args, torch_python)
from nerf_core.contract.exports import EXPORTS  # noqa: E402  (standard library only: fine in Blender)

PROG = "import_geometry.py"
# the exports of the table (nerf_core/contract/exports.py) that this script can bring into Blender
# (names: geometry_import itself needs bpy, imported only after the export)
IMPORTERS = {"mesh": "import_mesh", "volume": "import_volume", "world": "import_world"}
assert set(IMPORTERS) <= set(EXPORTS), "an importer for an export the table does not declare"


def parse(argv):
    ap = scene_parser(PROG, __doc__, "scene to import into")
    ap.add_argument("--run", required=True, help="training run folder (has checkpoints/latest.pt)")
    ap.add_argument("--kind", required=True, choices=sorted(IMPORTERS),
                    help="a coloured mesh, a volume, or the learned world (a run on opaque images)")
    ap.add_argument("--out", required=True, help=".blend to write")
    ap.add_argument("--geometry", metavar="FILE",
                    help="where the export goes (default: a new RUN/geometry/<kind>_NNN.ply, .npz or .png)")
    ap.add_argument("--resolution", type=int, metavar="N",
                    help="samples per axis (default: the model's grid; a volume twice that, at most 320)")
    ap.add_argument("--faces", type=int, metavar="N", help="mesh: decimate to about N faces")
    ap.add_argument("--far-levels", type=int, metavar="N",
                    help="volume of an unbounded run: nested grids beyond the box (default 4, out to 16 times it; "
                         "0: the box only, a far quicker render)")
    add_python_option(ap, "the export")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an existing --out file (and a volume's .vdb beside --geometry)")
    return ap.parse_args(argv)


def export(cmd: list, what: str) -> dict:
    """Run the export with a progress bar fed by its ``progress`` events; its summary (last stdout line)."""
    from addon.bridge import child_process
    from addon.compare import geometry_job
    from nerf_core.utils.progressbar import ProgressBar

    proc = child_process.BackgroundProcess(cmd).start()
    bar = ProgressBar(total=100, label=f"export {what}")
    try:
        while not proc.finished():
            proc.poll()
            ev = proc.progress.last_event
            if geometry_job.stage_text(ev):
                bar.set(int(100 * float(ev.get("fraction") or 0)))
            time.sleep(0.2)
    except KeyboardInterrupt:
        proc.cancel()
        fail(PROG, "interrupted; nothing was imported")
    proc.poll()
    bar.close()
    failure = proc.failure_message()
    if failure:
        fail(PROG, f"export of {what} failed: {failure}")
    for line in reversed(proc.tail):
        try:
            summary = json.loads(line)
        except ValueError:
            continue
        if isinstance(summary, dict) and "out" in summary:
            return summary
    return {}


def main(argv) -> int:
    args = parse(argv)
    from addon.bridge import child_process
    from addon.compare import compare_views, geometry_job
    from nerf_core import contract

    run = os.path.abspath(args.run)
    # The output rule: never the scene (by identity, so also through a linked folder), never a link.
    out = out_blend(PROG, args.out, args.overwrite, {"--blend": args.blend, "--geometry": args.geometry})
    for flag, value, least in (("--resolution", args.resolution, 2), ("--faces", args.faces, 1),
                               ("--far-levels", args.far_levels, 0)):
        if value is not None and value < least:
            fail(PROG, f"{flag} {value}: must be at least {least}")
    if args.resolution and args.kind == "world":
        fail(PROG, "--resolution: the world samples no grid over the scene box; its image is as wide as the "
             "learned world's finest texture")
    if not os.path.isfile(contract.latest_checkpoint(run)) and not child_process.step_checkpoints(run):
        fail(PROG, f"--run {run}: no trained checkpoint (train it first with python -m nerf_core train)")
    try:
        checkpoint = compare_views.require_checkpoint(run)
        geometry = os.path.abspath(args.geometry) if args.geometry else geometry_job.fresh_file(run, args.kind)
    except child_process.SetupError as exc:
        fail(PROG, str(exc))
    inputs = {"--blend": args.blend, "--out": out}
    if os.path.lexists(geometry):
        fail(PROG, f"--geometry {geometry}: exists; an export never replaces a file. Choose another name")
    # What the import writes beside the export (a volume's .vdb, a world's .exr) is an output too: the same rule.
    check_output(PROG, "--geometry", geometry, True, inputs, suffix=geometry_job.SUFFIX[args.kind])
    for ext in geometry_job.BESIDE[args.kind]:
        check_output(PROG, "--geometry", os.path.splitext(geometry)[0] + ext, args.overwrite, inputs)
    python = torch_python(PROG, args.python)
    cmd = child_process.export_command(python, args.kind, run, geometry, checkpoint=checkpoint)
    if args.resolution:
        cmd += ["--resolution", str(args.resolution)]
    if args.faces and args.kind == "mesh":
        cmd += ["--faces", str(args.faces)]
    if args.far_levels is not None and args.kind == "volume":
        cmd += ["--far-levels", str(args.far_levels)]
    summary = export(cmd, args.kind)

    import bpy

    from addon.compare import geometry_import

    open_blend(args.blend)
    scene = bpy.context.scene
    try:
        obj = getattr(geometry_import, IMPORTERS[args.kind])(scene, geometry)
    except (ValueError, RuntimeError, OSError) as exc:
        fail(PROG, f"{geometry}: cannot import the {args.kind}: {exc}")
    notes = [n for n in str(obj.get(geometry_import.NOTES_PROPERTY, "")).split("\n") if n]
    for note in notes:
        print(f"{PROG}: note: {note}", file=sys.stderr)
    save_blend(PROG, out)
    collection = obj.users_collection[0].name if isinstance(obj, bpy.types.Object) else None  # a World has none
    print(json.dumps({"out": out, "kind": args.kind, "object": obj.name, "collection": collection,
                      "geometry": geometry, "export": summary, "notes": notes}))
    return 0


if __name__ == "__main__":
    exit_code(main(script_args()))
