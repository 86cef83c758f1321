"""Fixtures for tests that drive real Blender through the ``bpy`` module (5.0.1 from PyPI)."""
from __future__ import annotations

import os
import sys

import pytest

bpy = pytest.importorskip("bpy") if os.environ.get("NERF_ALLOW_NO_BPY") else __import__("bpy")

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    sys.path.insert(0, REPO_ROOT)


@pytest.fixture(autouse=True)
def empty_blend():
    """Every test starts from an empty factory file, so no test sees another's objects."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield
    bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.fixture
def repo_root() -> str:
    return REPO_ROOT
