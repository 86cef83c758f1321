"""addon/bridge/core_contract.py: the add-on reads nerf_core's contract without torch, from the same nerf_core
its trainer gets (the checkout, or the installed extension's vendor/ folder)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from addon.bridge import core_contract, core_path
from addon.compare import planes

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts"))
import build_addon  # noqa: E402

BLOCK_TORCH = (
    "import sys\n"
    "class BlockTorch:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name == 'torch' or name.startswith('torch.'):\n"
    "            raise ImportError('torch blocked: the add-on must not import it')\n"
    "sys.meta_path.insert(0, BlockTorch())\n"
)


def test_checkout_addon_loads_the_contract_with_torch_blocked(repo_root):
    code = BLOCK_TORCH + (
        "import json, bpy, addon\n"
        "addon.register()\n"  # every module of the add-on, registered, as Blender loads it
        "from addon.bridge.core_contract import contract\n"
        "from addon.bridge import progress, runs, child_process\n"
        "from addon.common import jobs\n"
        "from addon.compare import compare_views\n"
        "addon.unregister()\n"
        "print(json.dumps({'file': contract.__file__, 'torch': 'torch' in sys.modules,\n"
        "                  'nerf_core': 'nerf_core' in sys.modules, 'latest': contract.latest_checkpoint('R')}))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=repo_root, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["file"] == os.path.join(repo_root, "nerf_core", "contract", "__init__.py")
    assert got["torch"] is False
    assert got["nerf_core"] is False  # loaded by path: nerf_core.engine.trainer stays out of Blender's reach
    assert got["latest"] == os.path.join("R", "checkpoints", "latest.pt")


def test_the_add_on_and_its_trainer_read_the_same_contract(repo_root):
    assert core_contract.contract.__file__ == os.path.join(core_path.nerf_core_search_path(), "nerf_core",
                                                          "contract", "__init__.py")
    assert core_path.nerf_core_search_path() == repo_root


def test_installed_layout_prefers_the_vendored_copy(tmp_path):
    installed = tmp_path / "nerf_bridge"
    build_addon.stage(build_addon.ADDON_DIR, str(installed))
    vendored = installed / "vendor" / "nerf_core" / "contract" / "__init__.py"
    # Mark the vendored copy so that loading the checkout's instead cannot pass unnoticed.
    vendored.write_text(vendored.read_text() + "\nVENDORED_MARK = 'installed copy'\n")
    module = core_contract.load(str(installed))
    assert module.__file__ == str(vendored) and module.VENDORED_MARK == "installed copy"
    assert module.config_path("R") == os.path.join("R", "config.json")


def test_a_vendored_nerf_core_without_the_contract_is_named(tmp_path):
    installed = tmp_path / "nerf_bridge"
    build_addon.stage(build_addon.ADDON_DIR, str(installed))
    os.remove(installed / "vendor" / "nerf_core" / "contract" / "__init__.py")
    with pytest.raises(ImportError, match=r"vendor/nerf_core/contract/__init__\.py: missing.*build_addon\.py"):
        core_contract.load(str(installed))


def test_installed_extension_uses_its_vendored_contract_without_torch(tmp_path):
    """Build the zip, install it with Blender's own extension operator into a private user folder,
    then use the installed add-on's contract, progress parser and run listing with torch blocked."""
    source = tmp_path / "addon"
    shutil.copytree(build_addon.ADDON_DIR, source, ignore=shutil.ignore_patterns("__pycache__"))
    manifest = source / "blender_manifest.toml"  # Blender's 64-character tagline limit, as test_register
    manifest.write_text(re.sub(r'(?m)^tagline = .*$', 'tagline = "Capture a scene as a NeRF dataset, train, compare"',
                               manifest.read_text()))
    zip_path = build_addon.build(out_dir=str(tmp_path / "dist"), addon_dir=str(source))
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "latest.pt").write_bytes(b"x")
    (run / "config.json").write_text(json.dumps({"method": "vmgrid"}))
    code = BLOCK_TORCH + (
        "import importlib, json, bpy\n"
        f"zip_path, run = {str(zip_path)!r}, {str(run)!r}\n"
        "result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo='user_default',\n"
        "                                                   enable_on_install=True)\n"
        "pkg = 'bl_ext.user_default.nerf_bridge'\n"
        "assert pkg in bpy.context.preferences.addons, 'the extension was not enabled'\n"
        "cc = importlib.import_module(pkg + '.bridge.core_contract')\n"
        "progress = importlib.import_module(pkg + '.bridge.progress')\n"
        "runs = importlib.import_module(pkg + '.bridge.runs')\n"
        "p = progress.ProgressParser()\n"
        "p.feed(json.dumps({'event': 'start', 'max_steps': 100}) + '\\n')\n"
        "p.feed(json.dumps({'event': 'step', 'step': 20, 'elapsed': 1.0}) + '\\n')\n"
        "old = p.fraction()\n"
        "p.feed(json.dumps({'event': 'step', 'step': 30, 'elapsed': 2.0, 'frac': 0.75}) + '\\n')\n"
        "info = runs.read_run(run)\n"
        "print(json.dumps({'result': sorted(result), 'file': cc.contract.__file__, 'addon': cc.__file__,\n"
        "                  'torch': 'torch' in sys.modules, 'old': old, 'new': p.fraction(),\n"
        "                  'method': info.method, 'checkpoint': info.has_checkpoint,\n"
        "                  'train_panel': hasattr(bpy.types, 'NERF_PT_train')}))\n")
    home = tmp_path / "blender_home"  # Blender's user folders, so the user's own extensions stay untouched
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(home))
    out = subprocess.run([sys.executable, "-c", code], cwd=str(tmp_path), env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    installed = home / "extensions" / "user_default" / "nerf_bridge"
    assert got["result"] == ["FINISHED"] and got["train_panel"]
    assert got["addon"] == str(installed / "bridge" / "core_contract.py")
    assert got["file"] == str(installed / "vendor" / "nerf_core" / "contract" / "__init__.py")
    assert got["torch"] is False
    assert got["old"] == 0.2 and got["new"] == 0.75  # 20/100 from the budgets, then the trainer's frac
    assert got["method"] == "vmgrid" and got["checkpoint"] is True


def test_planes_and_nerf_core_read_one_rule():
    """The gallery's intrinsics are the loader's: a file with fl_x at the top and camera_angle_x on a
    frame (fl_x wins) and no fl_y (fy = fx)."""
    contract = core_contract.contract
    meta = {"fl_x": 30.0, "w": 40, "h": 20, "cx": 19.0}
    frame = {"camera_angle_x": 1.2, "cy": 11.0}
    intr = planes.intrinsics_from(meta, frame)
    assert (intr["fx"], intr["fy"], intr["cx"], intr["cy"], intr["w"],
            intr["h"]) == contract.resolve_intrinsics(meta, frame)
    assert intr == {"fx": 30.0, "fy": 30.0, "cx": 19.0, "cy": 11.0, "w": 40.0, "h": 20.0}
