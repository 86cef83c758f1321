"""``python -m nerf_core export mesh|volume RUN --out FILE``: the trained scene as geometry; and
``export colmap DATASET --out DIR``: a capture as a COLMAP sparse model (``nerf_core.export.colmap``).

stdout: ``{"event": "progress", "stage", "fraction", "time"}`` lines (at most every 0.5 s) and
``{"event": "note", "message", "time"}`` lines while it works, then the summary JSON as the last line.
"""
from __future__ import annotations

import argparse
import json
import time

from nerf_core.cli.options import checked_number, positive_float, positive_int
from nerf_core.export import colmap, mesh
from nerf_core.export.run_export import export_mesh, export_volume

share = checked_number(float, "a number", lambda v: 0 <= v < 1, "must lie in [0, 1)")
grid_res = checked_number(int, "an integer", lambda v: v >= 2, "must be at least 2 samples per axis")


def _events():
    """(on_progress, on_note) printing JSON event lines, progress at most every 0.5 s."""
    last = [0.0]

    def progress(stage: str, fraction: float) -> None:
        now = time.time()
        if now - last[0] >= 0.5 or fraction >= 1.0:
            last[0] = now
            print(json.dumps({"event": "progress", "stage": stage, "fraction": round(float(fraction), 4),
                              "time": now}), flush=True)

    def note(message: str) -> None:
        print(json.dumps({"event": "note", "message": message, "time": time.time()}), flush=True)
    return progress, note


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    e = sub.add_parser("export", help="the trained scene as geometry: a coloured mesh (PLY) or a volume (npz); "
                       "a capture as a COLMAP model", formatter_class=fmt,
                       description="Write the run's geometry in the scene's own frame (mesh, volume), or a capture "
                       "as a COLMAP model (colmap). The last line of stdout is a JSON summary.")
    kinds = e.add_subparsers(dest="kind", metavar="KIND")
    kinds.required = True
    m = kinds.add_parser("mesh", help="marching cubes, culled and coloured: binary PLY", formatter_class=fmt)
    v = kinds.add_parser("volume", help="density and colour grids (.npz) for a Blender Volume", formatter_class=fmt)
    for p in (m, v):
        p.add_argument("run", metavar="RUN", help="run folder written by `train`")
        p.add_argument("--out", required=True, metavar="FILE",
                       help="file to write (.ply for a mesh, .npz for a volume)")
        p.add_argument("--resolution", type=grid_res, metavar="N",
                       help="samples per axis of the scene box (default: the model's own grid; 256 for nerf)")
        p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
        p.add_argument("--checkpoint", metavar="FILE", help="checkpoint to use instead of RUN/checkpoints/latest.pt")
        p.add_argument("--device", metavar="DEV", help="torch device; default: cuda if available else cpu")
    m.add_argument("--faces", type=positive_int, metavar="N", help="decimate to about N faces")
    m.add_argument("--level", type=positive_float, metavar="SIGMA",
                   help="surface density per scene unit (default: where the training rays first meet the surface, "
                        "transmittance 0.95 over the 4 grid steps before it)")
    m.add_argument("--min-component", type=share, default=mesh.DEFAULT_MIN_COMPONENT, metavar="SHARE",
                   help="drop connected pieces with less than this share of the total area (floaters; 0 keeps all)")
    m.add_argument("--keep-unseen", action="store_true", help="keep what no training camera sees")
    m.set_defaults(handler=run_mesh)
    v.set_defaults(handler=run_volume)
    c = kinds.add_parser("colmap", formatter_class=fmt,
                         help="a capture folder as a COLMAP model (sparse/0, images/, masks/) for splatting trainers",
                         description="Write DATASET's views as a COLMAP folder: sparse/0/{cameras,images,points3D}"
                         ".{bin,txt}, opaque RGB images/, masks/ where the film was transparent, and "
                         "nerf_bridge_colmap.json. The scene's own units and frame: no normalisation.")
    c.add_argument("dataset", metavar="DATASET", help="a capture (dataset folder)")
    c.add_argument("--out", required=True, metavar="DIR", help="the COLMAP folder to write (new, or empty)")
    c.add_argument("--splits", type=_splits, default=["train"], metavar="LIST",
                   help="comma-separated splits to export (default train; e.g. train,test)")
    c.add_argument("--overwrite", action="store_true", help="replace a non-empty --out folder")
    c.set_defaults(handler=run_colmap)


def _splits(text: str):
    try:
        return colmap.parse_splits(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run_mesh(a) -> int:
    progress, note = _events()
    summary = export_mesh(a.run, a.out, resolution=a.resolution, n_faces=a.faces, level=a.level,
                          min_component=a.min_component, cull_unseen=not a.keep_unseen, overwrite=a.overwrite,
                          checkpoint=a.checkpoint, device=a.device, on_progress=progress, on_note=note)
    print(json.dumps(summary))
    return 0


def run_volume(a) -> int:
    progress, note = _events()
    summary = export_volume(a.run, a.out, resolution=a.resolution, overwrite=a.overwrite, checkpoint=a.checkpoint,
                            device=a.device, on_progress=progress, on_note=note)
    print(json.dumps(summary))
    return 0


def run_colmap(a) -> int:
    _, note = _events()
    print(json.dumps(colmap.export_colmap(a.dataset, a.out, splits=a.splits, overwrite=a.overwrite, on_note=note)))
    return 0
