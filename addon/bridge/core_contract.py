"""``nerf_core.contract`` for the add-on, loaded without torch: ``from .core_contract import contract``.

The rules the add-on shares with nerf_core (run folder paths, the training budget fraction, progress
event lines, the intrinsics rule, output names) have one home, the ``nerf_core/contract/`` package.
Inside Blender nerf_core is not importable: the installed extension carries it in ``vendor/``
(scripts/build_addon.py) for the child trainer only, and putting that folder on Blender's
``sys.path`` would invite an ``import nerf_core.engine.trainer`` (torch) into Blender. So the contract package
alone is loaded by path, from the same folder the child trainer is given
(``core_path.nerf_core_search_path``), under a private package name: its modules import only each
other (relatively), the standard library and numpy, never torch (nerf_core/tests/test_contract.py).

    from .core_contract import contract
    fx, fy, cx, cy, w, h = contract.resolve_intrinsics(meta, frame, None)
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from types import ModuleType

from .core_path import ADDON_DIR, nerf_core_search_path

_MODULE_NAME = f"{__package__ or 'nerf_bridge'}.nerf_core_contract"


def load(addon_dir: str = ADDON_DIR) -> ModuleType:
    """The contract package of the nerf_core that the add-on in ``addon_dir`` hands to its trainer.

    Raises ImportError, naming the folder searched, when there is none (a broken install).
    """
    root = nerf_core_search_path(addon_dir)
    if root is None:
        # No vendored copy and no checkout: the child relies on the interpreter's nerf_core, so do we.
        try:
            return importlib.import_module("nerf_core.contract")
        except ImportError:
            raise ImportError(f"nerf_core not found: neither {os.path.join(addon_dir, 'vendor')} nor a checkout "
                              "around the add-on has it; rebuild the extension with scripts/build_addon.py") from None
    package_dir = os.path.join(root, "nerf_core", "contract")
    path = os.path.join(package_dir, "__init__.py")
    name = _MODULE_NAME if addon_dir == ADDON_DIR else f"{_MODULE_NAME}_{abs(hash(root))}"
    loaded = sys.modules.get(name)
    if loaded is not None and getattr(loaded, "__file__", None) == path:
        return loaded
    if not os.path.isfile(path):
        raise ImportError(f"{path}: missing; the add-on's nerf_core is older than the add-on "
                          "(rebuild the extension with scripts/build_addon.py)")
    spec = importlib.util.spec_from_file_location(name, path, submodule_search_locations=[package_dir])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # its submodules (``from .intrinsics import ...``) and dataclasses look it up
    try:
        spec.loader.exec_module(module)
    except BaseException:
        for key in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
            del sys.modules[key]
        raise
    return module


contract = load()
