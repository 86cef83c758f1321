"""``python -m nerf_core export NAME RUN --out FILE``: the trained scene as geometry, one subcommand per
declared format (``nerf_core.contract.exports``, made by ``nerf_core.export.formats``); and ``export
colmap DATASET --out DIR``: a capture as a COLMAP sparse model (``nerf_core.export.colmap``).

stdout: ``{"event": "progress", "time", "stage", "fraction"}`` lines (at most every 0.5 s) and
``{"event": "note", "time", "message"}`` lines while it works, through the event log
(``runs.events.EventLog``, names in ``contract.EVENTS``), then the summary JSON as the last line.
"""
from __future__ import annotations

import argparse
import json
import time

from nerf_core.cli.options import checked_number, nonneg_int, positive_float, positive_int
from nerf_core.contract.exports import EXPORTS, ExportFormat
from nerf_core.export import colmap, formats
from nerf_core.export.run_export import export_run
from nerf_core.runs.events import EventLog

share = checked_number(float, "a number", lambda v: 0 <= v < 1, "must lie in [0, 1)")
grid_res = checked_number(int, "an integer", lambda v: v >= 2, "must be at least 2 samples per axis")
PARSERS = {"positive_int": positive_int, "nonneg_int": nonneg_int, "positive_float": positive_float, "share": share}
PROGRESS_EVERY = 0.5  # seconds between progress events (the last, fraction 1, always goes)


def _events():
    """(on_progress, on_note) emitting ``progress`` and ``note`` events, progress at most every 0.5 s."""
    log = EventLog(stdout=True)
    last = [0.0]

    def progress(stage: str, fraction: float) -> None:
        now = time.time()
        if now - last[0] >= PROGRESS_EVERY or fraction >= 1.0:
            last[0] = now
            log.emit("progress", stage=stage, fraction=round(float(fraction), 4))

    def note(message: str) -> None:
        log.emit("note", message=message)
    return progress, note


def _add_format(kinds, fmt: ExportFormat, help_fmt) -> None:
    p = kinds.add_parser(fmt.name, help=fmt.help, formatter_class=help_fmt,
                         description=f"{fmt.help}: {fmt.extracts}. The last line of stdout is a JSON summary.")
    p.add_argument("run", metavar="RUN", help="run folder written by `train`")
    p.add_argument("--out", required=True, metavar="FILE", help=f"file to write (a {fmt.suffix} file)")
    if fmt.grid:
        p.add_argument("--resolution", type=grid_res, metavar="N",
                       help="samples per axis of the scene box (default: the model's own grid, 256 for nerf; "
                            "a volume twice that, at most 320)")
    else:
        p.set_defaults(resolution=None)  # a world samples directions, not the box
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument("--checkpoint", metavar="FILE", help="checkpoint to use instead of RUN/checkpoints/latest.pt")
    p.add_argument("--device", metavar="DEV", help="torch device; default: cuda if available else cpu")
    for o in fmt.options:
        if o.kind == "switch":
            p.add_argument(o.flag, dest=o.dest, action="store_true", help=o.help)
        else:
            p.add_argument(o.flag, dest=o.dest, type=PARSERS[o.kind], default=o.default, metavar=o.metavar,
                           help=o.help)
    p.set_defaults(handler=run_format, format=fmt)


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    made = [f for name, f in EXPORTS.items() if name in formats.WRITERS]
    e = sub.add_parser("export", help="the trained scene as geometry (" + ", ".join(f.name for f in made) +
                       "); a capture as a COLMAP model", formatter_class=fmt,
                       description="Write the run's geometry in the scene's own frame (" +
                       ", ".join(f"{f.name}: {f.suffix}" for f in made) + "), or a capture as a COLMAP model "
                       "(colmap). The last line of stdout is a JSON summary.")
    kinds = e.add_subparsers(dest="kind", metavar="KIND")
    kinds.required = True
    for f in made:
        _add_format(kinds, f, fmt)
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


def run_format(a) -> int:
    progress, note = _events()
    options = {o.dest: getattr(a, o.dest) for o in a.format.options}
    summary = export_run(a.format.name, a.run, a.out, resolution=a.resolution, overwrite=a.overwrite,
                         checkpoint=a.checkpoint, device=a.device, on_progress=progress, on_note=note, **options)
    print(json.dumps(summary))
    return 0


def run_colmap(a) -> int:
    _, note = _events()
    print(json.dumps(colmap.export_colmap(a.dataset, a.out, splits=a.splits, overwrite=a.overwrite, on_note=note)))
    return 0
