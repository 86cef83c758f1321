"""Shared start-up for the headless scripts.

Every script in ``scripts/`` runs two ways with the same flags:

    blender -b scene.blend --python scripts/X.py -- ARGS       (Blender's own Python)
    python scripts/X.py [--blend scene.blend] ARGS              (the ``bpy`` module from PyPI)

``script_args()`` returns ARGS in both cases; ``open_blend()`` loads ``--blend`` when the script runs
as plain Python (under Blender the file on the command line is already open).
"""
from __future__ import annotations

import os
import sys

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    # Makes ``import addon`` and ``import nerf_core`` work from a checkout without installing.
    sys.path.insert(0, REPO_ROOT)


def inside_blender() -> bool:
    """True when running inside a Blender executable rather than the PyPI ``bpy`` module."""
    try:
        import bpy
    except ImportError:
        return False
    return not getattr(bpy.app, "module", False)


def script_args() -> list[str]:
    """The script's own arguments: what follows ``--`` under Blender, else ``sys.argv[1:]``."""
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1 :]
    if inside_blender():
        return []
    return sys.argv[1:]


def open_blend(path: str | None) -> None:
    """Open ``path`` when given; errors name the file. Under Blender without --blend, keep the open file."""
    if not path:
        return
    import bpy

    if not os.path.isfile(path):
        raise SystemExit(f"error: --blend {path!r}: no such file")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path))
    except RuntimeError as exc:
        raise SystemExit(f"error: --blend {path!r}: Blender could not open it: {exc}")


def exit_code(code: int) -> None:
    """Exit with ``code`` in both modes (under Blender, sys.exit inside --python is honoured in -b)."""
    sys.stdout.flush()
    sys.stderr.flush()
    if inside_blender():
        os._exit(code)
    sys.exit(code)
