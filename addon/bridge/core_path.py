"""Where the add-on finds nerf_core: the copy vendored into the installed extension, else the
repository checkout the add-on runs from. The child trainer gets this folder on its PYTHONPATH
(``child_process.child_env``) and ``core_contract`` loads ``nerf_core/contract/`` from it, so both
sides of the JSON-line seam read the same rules. Standard library only.
"""
from __future__ import annotations

import os
from typing import Optional

ADDON_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the add-on root, above bridge/
VENDOR_DIRNAME = "vendor"  # scripts/build_addon.py stages nerf_core into ADDON/vendor/nerf_core


def nerf_core_search_path(addon_dir: str = ADDON_DIR) -> Optional[str]:
    """The folder to put on the child's PYTHONPATH so ``import nerf_core`` works, or None.

    Order: the copy that scripts/build_addon.py vendors into the installed add-on, then the repository
    root when the add-on runs from a checkout, else None (rely on the interpreter's site-packages).
    """
    vendored = os.path.join(addon_dir, VENDOR_DIRNAME)
    if os.path.isfile(os.path.join(vendored, "nerf_core", "__init__.py")):
        return vendored
    repo = os.path.dirname(addon_dir)
    if os.path.isfile(os.path.join(repo, "nerf_core", "__init__.py")):
        return repo
    return None
