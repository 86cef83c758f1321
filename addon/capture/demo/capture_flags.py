"""How each demo scene wants to be captured: extra ``scripts/capture.py`` flags per scene.

Object scenes on a transparent film need nothing; scenes whose background is part of the scene do:
``hdri`` shows its world (an opaque film) and ``interior`` is a closed room captured from inside.

This module is plain Python (no bpy, no relative imports) so the scripts that run outside Blender
(``scripts/demo.py``, ``benchmarks/bench/datasets.py``) can load it by file path without importing the
add-on package, whose ``__init__`` imports bpy. ``demo.scenes`` re-exports these names.

Keys are ``scripts/capture.py`` flag names without the dashes, ``_`` for ``-``; ``True`` is a bare flag.
"""
from __future__ import annotations

# The demo scenes ``demo.scenes.build`` makes, with a line each (here, not there, so that the
# benchmark can check ``--scenes`` without bpy).
SCENES = {
    "cube": "a flat-coloured cube (tiny; for model-sizing tests)",
    "diffuse": "a diffuse, procedurally textured sphere on a pedestal",
    "highfreq": "a cube with a fine checker and stripes (high-frequency texture)",
    "glossy": "a metallic sphere and a glossy torus",
    "thin": "thin rods and a wire lattice (thin structures)",
    "multi": "several objects of different shapes and colours",
    "hdri": "a textured sphere on a pedestal and a checker cube in a visible HDRI world (forest photo; opaque film)",
    "interior": "a closed 6 x 5 x 3 m room with textured walls and furniture, lit from inside",
    "ground": "a figure and a box on a 100 m checkered floor that runs to the horizon (opaque film)",
}

CAPTURE_DEFAULTS: dict[str, dict] = {
    "hdri": {"opaque": True},
    # A 24 mm lens (74 degrees across) sees a room; 50 mm from the middle of a room sees a patch of wall.
    "interior": {"opaque": True, "layout": "inside", "focal_length": 24.0},
    "ground": {"opaque": True},
}


def capture_defaults(name: str) -> dict:
    """The capture settings demo scene ``name`` needs (a copy; empty for object scenes and unknown names)."""
    return dict(CAPTURE_DEFAULTS.get(name, {}))


def capture_flags(name: str) -> list[str]:
    """``capture_defaults(name)`` as ``scripts/capture.py`` arguments, e.g. ``['--opaque', '--layout', 'inside']``."""
    out: list[str] = []
    for key, value in capture_defaults(name).items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        out += [flag] if value is True else [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    return out
