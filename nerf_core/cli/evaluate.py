"""``python -m nerf_core eval RUN``: PSNR, SSIM and depth error on held-out views.
"""
from __future__ import annotations

import json

from nerf_core.cli.options import add_model_args, positive_int
from nerf_core.evaluation.evaluate import evaluate_run


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    e = sub.add_parser("eval", help="evaluate a run on held-out views (PSNR, SSIM, depth error)", formatter_class=fmt,
                       description="Prints one line per view, then one JSON object as the last line of stdout.")
    add_model_args(
        e,
        split_help="split to evaluate (test or val)",
        downscale=(positive_int, "evaluate", "default: the --downscale the run trained at"),
        chunk_help="most rays per model call (CPU calls are smaller)",
    )
    e.add_argument("--views", type=positive_int, metavar="N", help="evaluate N evenly spaced views only")
    e.set_defaults(handler=run)


def run(a) -> int:
    summary = evaluate_run(a.run, split=a.split, device=a.device, max_views=a.views, downscale=a.downscale,
                           chunk=a.chunk, checkpoint=a.checkpoint, show_progress=not a.no_bar,
                           print_fn=lambda line: print(line, flush=True), pixel_filter=a.pixel_filter)
    print(json.dumps(summary, default=lambda o: None))
    return 0
