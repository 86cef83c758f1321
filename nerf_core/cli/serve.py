"""``python -m nerf_core serve RUN``: load a run once, then render one camera per JSON line on stdin
(the render server of the Blender render engine: ``nerf_core.render.server``).
"""
from __future__ import annotations

import json
import sys
import time
from typing import Optional

from nerf_core.cli.options import positive_int
from nerf_core.errors import RunError
from nerf_core.render.memory import DEFAULT_CHUNK
from nerf_core.render.server import RenderServer


def serve_main(
    run: str, checkpoint: Optional[str] = None, device: Optional[str] = None, chunk: int = DEFAULT_CHUNK
) -> int:
    """The ``serve`` subcommand. A run that cannot be loaded: one fatal ``error`` event, exit code 2."""
    try:
        server = RenderServer(run, checkpoint, device, chunk)
    except (RunError, ValueError, OSError) as exc:
        print(json.dumps({"event": "error", "time": time.time(), "message": str(exc), "fatal": True}), flush=True)
        print(f"nerf_core serve: error: {exc}", file=sys.stderr)
        return 2
    return server.serve()


def add_parser(sub, formatter_class) -> None:
    """The ``serve`` subcommand's flags (called by ``nerf_core.cli.main.build_parser``)."""
    s = sub.add_parser("serve", help="load a run once and render cameras given as JSON lines on stdin",
                       formatter_class=formatter_class,
                       description="Render server for the Blender render engine: one JSON request per line on "
                                   "stdin, one JSON event per line on stdout (docs/CONTRACTS.md, 'Render server').")
    s.add_argument("run", metavar="RUN", help="run folder written by `train`")
    s.add_argument("--checkpoint", metavar="FILE", help="checkpoint to use instead of RUN/checkpoints/latest.pt")
    s.add_argument("--device", metavar="DEV", help="torch device; default: cuda if available else cpu")
    s.add_argument(
        "--chunk", type=positive_int, default=DEFAULT_CHUNK, help="rays per model call (lower it to save memory)"
    )
    s.set_defaults(handler=lambda a: serve_main(a.run, a.checkpoint, a.device, a.chunk))
