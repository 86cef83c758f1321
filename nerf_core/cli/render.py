"""``python -m nerf_core render RUN --out DIR``: novel views of a trained run, written to disk.
"""
from __future__ import annotations

import json

from nerf_core.cli.options import add_model_args, folder, positive_float
from nerf_core.render.views import render_run


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    r = sub.add_parser("render", help="render novel views of a trained run", formatter_class=fmt,
                       description="Render RGBA PNGs (alpha = opacity), planar depth EXRs and renders.json.")
    add_model_args(r, split_help="split to render when --cameras is a dataset folder or split transforms.json",
                    downscale=(positive_float, "render"),
                    chunk_help="most rays per model call (lower it to save memory; CPU calls are smaller)")
    r.add_argument(
        "--cameras",
        metavar="TRANSFORMS.json",
        help="dataset folder, transforms file (either layout) or JSON list of cameras; default: the run's dataset",
    )
    r.add_argument("--out", required=True, type=folder, metavar="DIR", help="output folder")
    r.add_argument("--overwrite", action="store_true", help="replace existing outputs in DIR")
    r.set_defaults(handler=run)


def run(a) -> int:
    path = render_run(a.run, a.cameras, a.out, split=a.split, overwrite=a.overwrite, device=a.device,
                      downscale=a.downscale, chunk=a.chunk, checkpoint=a.checkpoint, show_progress=not a.no_bar,
                      pixel_filter=a.pixel_filter)
    print(json.dumps({"renders": str(path.resolve()), "out": str(path.parent.resolve())}))
    return 0
