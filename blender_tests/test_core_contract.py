"""addon/core_contract.py: the add-on finds nerf_core.contract where the trainer finds nerf_core and
imports it without torch (Blender's Python has none)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

from addon import planes
from addon.core_contract import contract


def test_installed_addon_uses_its_vendored_contract_without_torch(tmp_path, repo_root):
    ext = tmp_path / "extensions"
    addon = ext / "nerf_bridge"
    ignore = shutil.ignore_patterns("__pycache__", "tests")
    shutil.copytree(os.path.join(repo_root, "addon"), addon, ignore=ignore)
    shutil.copytree(os.path.join(repo_root, "nerf_core"), addon / "vendor" / "nerf_core", ignore=ignore)
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ImportError('torch blocked')\n"
            "sys.meta_path.insert(0, Block())\n"
            f"sys.path.insert(0, {str(ext)!r})\n"
            "import nerf_bridge\n"  # the whole add-on, as Blender loads it
            "from nerf_bridge.core_contract import contract\n"
            "assert 'torch' not in sys.modules\n"
            "print(contract.__file__)\n"
            "print(contract.resolve_intrinsics({'camera_angle_x': 1.0, 'w': 64, 'h': 48}, {}))\n")
    # Run from the extension folder so that the repository's own nerf_core is not importable.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", code], cwd=str(ext), capture_output=True, text=True, env=env,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    path, intr = out.stdout.strip().splitlines()[-2:]
    assert path == str(addon / "vendor" / "nerf_core" / "contract" / "__init__.py")
    fx = 0.5 * 64 / 0.5463024898437905  # tan(0.5)
    assert [round(float(v), 6) for v in intr.strip("()").split(",")] == [round(fx, 6), round(fx, 6), 32.0, 24.0, 64.0, 48.0]


def test_planes_and_nerf_core_read_one_rule(tmp_path):
    """The gallery's intrinsics are the loader's: a file with fl_x at the top and camera_angle_x on a
    frame (fl_x wins) and no fl_y (fy = fx)."""
    meta = {"fl_x": 30.0, "w": 40, "h": 20, "cx": 19.0}
    frame = {"camera_angle_x": 1.2, "cy": 11.0}
    intr = planes.intrinsics_from(meta, frame)
    assert (intr["fx"], intr["fy"], intr["cx"], intr["cy"], intr["w"], intr["h"]) == contract.resolve_intrinsics(meta, frame)
    assert intr == {"fx": 30.0, "fy": 30.0, "cx": 19.0, "cy": 11.0, "w": 40.0, "h": 20.0}
