"""The whole add-on registers and unregisters cleanly, twice in a row, and builds into an installable
zip whose vendored nerf_core the trainer process can import."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import types
import zipfile

import bpy
import pytest

import addon
from addon.bridge import child_process

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts"))
import build_addon  # noqa: E402


def test_register_unregister_twice():
    for _ in range(2):
        addon.register()
        assert hasattr(bpy.types.Scene, "nerf_train")
        assert hasattr(bpy.types, "NERF_PT_train") and hasattr(bpy.types, "NERF_PT_compare")
        assert bpy.context.scene.nerf_train.view_source == "TEST"
        assert "train" in dir(bpy.ops.nerf) and "render_views" in dir(bpy.ops.nerf)
        addon.unregister()
        assert not hasattr(bpy.types.Scene, "nerf_train")
        assert not hasattr(bpy.types, "NERF_PT_train")


def test_manifest_passes_blenders_rules():
    assert build_addon.validate_manifest(build_addon.read_manifest(build_addon.ADDON_DIR)) == []


def test_manifest_checks_catch_what_blender_refuses():
    bad = {"schema_version": "1.0.0", "id": "nerf-bridge", "version": "1.0", "name": "x", "maintainer": "m",
           "type": "add-on", "tagline": "y" * 70 + ".", "blender_version_min": "4.2", "license": ["GPL"]}
    problems = " | ".join(build_addon.validate_manifest(bad))
    for needle in ("id 'nerf-bridge'", "version '1.0'", "at most 64", "punctuation", "blender_version_min",
                   "SPDX"):
        assert needle in problems


@pytest.mark.parametrize("use_bundled", [False, True], ids=["zipfile", "blender_ext"])
def test_built_zip_carries_nerf_core_for_the_trainer(tmp_path, use_bundled):
    if use_bundled and not build_addon.bundled_blender_ext():
        pytest.fail("the bpy module ships bl_pkg/cli/blender_ext.py; it was not found")
    # Built from a copy whose tagline fits Blender's 64 characters, so that this test checks the
    # packaging alone; test_manifest_passes_blenders_rules checks the real manifest.
    source = tmp_path / "addon"
    shutil.copytree(build_addon.ADDON_DIR, source, ignore=shutil.ignore_patterns("__pycache__"))
    manifest = source / "blender_manifest.toml"
    manifest.write_text(re.sub(r'(?m)^tagline = .*$', 'tagline = "Capture a scene as a NeRF dataset, train, compare"',
                               manifest.read_text()))
    path = build_addon.build(out_dir=str(tmp_path / "dist"), use_bundled=use_bundled, addon_dir=str(source))
    assert os.path.basename(path) == "nerf_bridge-0.1.0.zip"
    names = zipfile.ZipFile(path).namelist()
    assert {"blender_manifest.toml", "__init__.py", "train/train_ui.py", "vendor/nerf_core/__init__.py",
            "vendor/nerf_core/cli/main.py"} <= set(names)
    assert not [n for n in names if "/tests/" in n or "__pycache__" in n or n.endswith(".pyc")]
    installed = tmp_path / "installed" / "nerf_bridge"
    zipfile.ZipFile(path).extractall(installed)
    assert child_process.nerf_core_search_path(str(installed)) == str(installed / "vendor")
    env = child_process.child_env(str(installed), base={"PATH": os.environ.get("PATH", "")})
    out = subprocess.run([sys.executable, "-c", "import nerf_core; print(nerf_core.__file__)"], env=env,
                         capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().startswith(str(installed / "vendor"))


class RecordingLayout:
    """Stands in for UILayout (there is no window in background mode): records calls and checks that
    every property, operator and list the panels name really exists."""

    def __init__(self, calls):
        self.__dict__["calls"] = calls

    def __setattr__(self, name, value):  # use_property_split etc.
        self.calls.append(("set", name, value))

    def __getattr__(self, name):
        def method(*args, **kwargs):
            self.calls.append((name, args, kwargs))
            if name == "prop":
                assert args[1] in args[0].bl_rna.properties, f"no property {args[1]!r}"
            elif name == "operator":
                module, op = args[0].split(".")
                assert op in dir(getattr(bpy.ops, module)), f"no operator {args[0]}"
                return types.SimpleNamespace()
            elif name == "template_list":
                assert hasattr(bpy.types, args[0]), f"UIList {args[0]} is not registered"
                assert args[3] in args[2].bl_rna.properties and args[5] in args[4].bl_rna.properties
            return RecordingLayout(self.calls)
        return method


def _draw(panel):
    calls = []
    panel.draw(types.SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    return calls


def _labels(calls):
    return " | ".join(str(c[2].get("text", "")) for c in calls if c[0] in ("label", "progress"))


def test_panels_draw_in_every_state(tmp_path):
    from addon.compare import compare_ui
    from addon.train import train_ui

    addon.register()
    try:
        s = bpy.context.scene.nerf_train
        assert "Runs" in _labels(_draw(train_ui.NERF_PT_train))
        s.running, s.step, s.loss, s.psnr = True, 120, 0.01, 21.5
        s.elapsed, s.eta, s.fraction, s.rollbacks = 65, 30, .5, 1
        s.status = "Step 120 (50%)"
        from addon.common import jobs

        real = jobs.is_running
        jobs.is_running = lambda key: key == train_ui.TRAIN
        try:
            calls = _draw(train_ui.NERF_PT_train)
        finally:
            jobs.is_running = real
        labels, ops = _labels(calls), [c[1][0] for c in calls if c[0] == "operator"]
        for text in ("Step 120 (50%)", "PSNR 21.50 dB", "Elapsed 1:05", "ETA 0:30", "1 rollback(s)"):
            assert text in labels
        assert "Background:" not in labels  # no start event yet: nothing to say
        assert "nerf.train_cancel" in ops and "nerf.train" not in ops
        # The flag is saved with the file: with no training job in this session it is stale, and the
        # panel offers Train and Resume rather than only a Cancel that has nothing to cancel, and no
        # progress bar or ETA frozen at the moment of saving.
        calls = _draw(train_ui.NERF_PT_train)
        labels, ops = _labels(calls), [c[1][0] for c in calls if c[0] == "operator"]
        assert "nerf.train" in ops and "nerf.train_cancel" not in ops
        assert "ETA" not in labels and "Step 120 (50%)" not in labels
        assert "Training was running when this was saved (step 120)" in labels and "Resume" in labels
        # A Compare render (a fly-through of hundreds of frames) is stopped from the Compare panel.
        jobs.is_running = lambda key: key == train_ui.RENDER
        try:
            calls = _draw(compare_ui.NERF_PT_compare)
        finally:
            jobs.is_running = real
        cancel = [c for c in calls if c[0] == "operator" and c[1][0] == "nerf.train_cancel"]
        assert cancel and cancel[0][2]["text"] == "Cancel Render"
        s.running = False  # a run that ended in this session: its last numbers stay on show
        s.background = "environment: the images have no alpha channel (RGB)"
        labels = _labels(_draw(train_ui.NERF_PT_train))
        assert "Background: environment: the images have no alpha channel (RGB)" in labels
        s.running = False
        s.error = "Training stopped: boom\n--- last lines of the log ---\n" + "\n".join(f"l{i}" for i in range(30))
        labels = _labels(_draw(train_ui.NERF_PT_train))
        assert "Training stopped: boom" in labels and "l29" in labels and "l5 " not in labels + " "
        item = s.runs.add()
        item.name, item.method, item.metrics, item.settings = "run", "nerf", "PSNR 20.00 dB", "max 60 s"
        assert "nerf: max 60 s" in _labels(_draw(train_ui.NERF_PT_train))
        s.layout = "CAMERA"
        m = s.view_metrics.add()
        m.name, m.psnr, m.ssim, m.has_metrics = "r_0", 20.0, 0.9, True
        calls = _draw(compare_ui.NERF_PT_compare)
        assert any(c[0] == "prop" and c[1][1] == "plane_distance" for c in calls)
        assert any(c[0] == "template_list" and c[1][0] == "NERF_UL_view_metrics" for c in calls)
    finally:
        addon.unregister()
