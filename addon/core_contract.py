"""``nerf_core.contract`` inside Blender: the shared rules (intrinsics, output names, ...) without torch.

The contract package needs only the standard library and numpy, which Blender's Python has. It is
found where the trainer process finds nerf_core (``trainer_process.nerf_core_search_path``: the
add-on's ``vendor/`` copy, else the repository the add-on runs from) and imported from that folder
without putting it on ``sys.path``: only ``nerf_core/__init__.py`` (a version string) and the
contract run, never torch.

    from .core_contract import contract
    fx, fy, cx, cy, w, h = contract.resolve_intrinsics(meta, frame)
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from types import ModuleType

from .trainer_process import nerf_core_search_path


def load_contract(addon_dir: str = "") -> ModuleType:
    """The ``nerf_core.contract`` module (ImportError saying where it was looked for when missing)."""
    loaded = sys.modules.get("nerf_core.contract")
    if loaded is not None:
        return loaded
    if "nerf_core" not in sys.modules:
        base = nerf_core_search_path(addon_dir) if addon_dir else nerf_core_search_path()
        if base is None:  # the trainer then relies on an installed nerf_core: so does the add-on
            try:
                return importlib.import_module("nerf_core.contract")
            except ImportError:
                raise ImportError("nerf_core not found: neither the add-on's vendor/ folder nor the repository "
                                  "around it holds nerf_core/__init__.py, and none is installed; rebuild the "
                                  "add-on with scripts/build_addon.py") from None
        package_dir = os.path.join(base, "nerf_core")
        spec = importlib.util.spec_from_file_location("nerf_core", os.path.join(package_dir, "__init__.py"),
                                                      submodule_search_locations=[package_dir])
        module = importlib.util.module_from_spec(spec)
        sys.modules["nerf_core"] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules["nerf_core"]
            raise
    return importlib.import_module("nerf_core.contract")


contract = load_contract()
