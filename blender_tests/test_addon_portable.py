"""The add-on loads in any Blender from 4.2 on, whatever its Python: Blender 5.1+ runs Python 3.13, and an
add-on that ships compiled files built for 3.11 (or imports a compiled package Blender lacks) would fail
to load there. So the add-on, and the nerf_core it vendors, are plain Python that imports only the
standard library, Blender's own modules, numpy and openvdb (which Blender bundles). Read from the source: nothing
is imported, bpy not needed.
"""
from __future__ import annotations

import ast
import os
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ADDON = os.path.join(REPO, "addon")
COMPILED = (".so", ".pyd", ".dll", ".dylib", ".whl", ".pyc", ".egg")
# What Blender itself provides: its Python API modules and the numpy it bundles.
BLENDER_PROVIDES = {"bpy", "bpy_extras", "mathutils", "gpu", "gpu_extras", "bmesh", "bl_math", "blf", "aud",
                    "addon_utils", "bl_ui", "numpy",
                    "openvdb"}  # Blender ships OpenVDB's Python module (the volume import writes .vdb with it)


def _files(root):
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        for f in files:
            yield os.path.join(folder, f)


def test_the_addon_ships_no_compiled_files():
    bad = [os.path.relpath(p, REPO) for p in _files(ADDON) if p.endswith(COMPILED)]
    assert not bad, f"compiled or binary packages in the add-on (they would tie it to one Python): {bad}"


def _external_imports(path):
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module.split(".")[0]


@pytest.mark.skipif(sys.version_info < (3, 10), reason="sys.stdlib_module_names is Python 3.10+")
def test_the_addon_imports_only_the_standard_library_blender_and_numpy():
    allowed = set(sys.stdlib_module_names) | BLENDER_PROVIDES | {"addon", "nerf_core"}
    bad = []
    for path in _files(ADDON):
        if path.endswith(".py"):
            bad += [f"{os.path.relpath(path, REPO)}:{line}: {mod}" for line, mod in _external_imports(path)
                    if mod not in allowed]
    assert not bad, "the add-on imports packages Blender does not ship:\n" + "\n".join(bad)


def test_the_vendored_contract_is_plain_python_too():
    # The add-on loads nerf_core/contract inside Blender (bridge/core_contract): standard library + numpy.
    contract = os.path.join(REPO, "nerf_core", "contract")
    allowed = set(sys.stdlib_module_names) | {"numpy", "nerf_core"}
    bad = [f"{os.path.relpath(p, REPO)}:{line}: {mod}" for p in _files(contract) if p.endswith(".py")
           for line, mod in _external_imports(p) if mod not in allowed]
    assert not bad and not [p for p in _files(contract) if p.endswith(COMPILED)], bad
