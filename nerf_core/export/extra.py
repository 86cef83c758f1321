"""The optional ``mesh`` extra (scikit-image for marching cubes, fast-simplification for decimation,
scipy, which scikit-image brings, for nearest neighbours): loaded when first needed, so that training
and rendering never need it, and one clear error that names the extra when it is missing."""
from __future__ import annotations

import importlib

INSTALL = "pip install nerf-bridge[mesh]"


class MissingExtra(ValueError):
    """An optional module of the ``mesh`` extra is not installed (the message says how to install it)."""


def load(module: str, purpose: str):
    """The module ``module`` of the mesh extra, or MissingExtra saying that ``purpose`` needs it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.split(".")[0]
        raise MissingExtra(f"{purpose} needs the optional module {top!r} ({exc.__class__.__name__}: {exc}); "
                           f"install the mesh extra: {INSTALL}") from exc
