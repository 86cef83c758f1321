"""The dataset folder as each outside loader reads it (CONVENTIONS.md, "Files and splits").

The loaders' path rules are re-implemented here from their sources: instant-ngp (every ``*.json``
with a ``frames`` array in the folder it is given, or the one file; ``file_path`` relative to the
JSON's folder, an extension added when missing), nerfstudio-data (``DATA/transforms.json``, paths
relative to DATA) and the original NeRF loader (``transforms_{split}.json`` at the root, ``.png``
added).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import bpy

from addon.capture.layout import positions
from addon.capture.run import job
from addon.capture.plan import settings
from addon.capture.layout import cameras

EXTS = ("png", "jpg", "jpeg", "exr")


def _capture(out):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    cameras.create_cameras(scene, positions.LayoutSpec(train=4, val=1, test=2, seed=1), 16, 16)
    return job.CaptureJob(scene, settings.CaptureSettings(out_dir=str(out), engine="workbench", res_x=16,
                                                             res_y=16, depth=True, points=True)).run()


def instant_ngp_images(path) -> list[str]:
    """Images instant-ngp trains on when given ``path`` (a folder or a .json), as real paths."""
    jsons = ([os.path.join(path, f) for f in sorted(os.listdir(path)) if f.lower().endswith(".json")]
             if os.path.isdir(path) else [path])
    images = []
    for j in jsons:
        with open(j) as fh:
            doc = json.load(fh)
        if not isinstance(doc.get("frames"), list):
            continue  # instant-ngp: "does not contain any frames. Skipping."
        for fr in doc["frames"]:
            p = os.path.join(os.path.dirname(j), fr["file_path"])
            if not os.path.splitext(p)[1] and not os.path.exists(p):
                p = next(f"{p}.{e}" for e in EXTS if os.path.exists(f"{p}.{e}"))
            images.append(os.path.realpath(p))
    return images


def test_each_loader_reads_the_frames_it_should_once(tmp_path):
    out = tmp_path / "ds"
    assert _capture(out)["status"] == "complete"
    real = lambda *p: os.path.realpath(os.path.join(out, *p))  # noqa: E731
    train = [real("train", f"r_{i}.png") for i in range(4)]
    held = [real("val", "r_0.png"), real("test", "r_0.png"), real("test", "r_1.png")]
    # instant-ngp given the root: every frame at most once (before: twice, with transforms.json there)
    root_load = instant_ngp_images(str(out))
    assert sorted(root_load) == sorted(train + held)
    # instant-ngp given the train file (the README's way): exactly the train views, no held-out one
    assert sorted(instant_ngp_images(str(out / "transforms_train.json"))) == sorted(train)
    # nerfstudio-data given DATASET/nerfstudio: paths against that folder, split lists of those paths
    ns_dir = out / "nerfstudio"
    ns = json.loads((ns_dir / "transforms.json").read_text())
    files = {fr["file_path"]: os.path.realpath(ns_dir / fr["file_path"]) for fr in ns["frames"]}
    assert sorted(files.values()) == sorted(train + held)
    assert sorted(files[n] for n in ns["train_filenames"]) == sorted(train)
    assert sorted(files[n] for n in ns["val_filenames"] + ns["test_filenames"]) == sorted(held)
    for fr in ns["frames"]:
        assert os.path.isfile(ns_dir / fr["depth_file_path"])
    assert os.path.realpath(ns_dir / ns["ply_file_path"]) == real("points3d.ply")
    # the original NeRF loader (and nerfstudio's blender-data, 3DGS): root split files, '.png' added
    for split, want in (("train", train), ("val", held[:1]), ("test", held[1:])):
        doc = json.loads((out / f"transforms_{split}.json").read_text())
        assert [os.path.realpath(os.path.join(out, fr["file_path"] + ".png")) for fr in doc["frames"]] == want


def test_resuming_an_older_capture_moves_nerfstudio_file_out_of_the_root(tmp_path):
    out = tmp_path / "ds"
    _capture(out)
    # a capture from before nerfstudio/: its transforms.json at the root, paths relative to the root
    ns = json.loads((out / "nerfstudio" / "transforms.json").read_text())
    for fr in ns["frames"]:
        fr["file_path"] = fr["file_path"][3:]
    (out / "transforms.json").write_text(json.dumps(ns))
    proc = subprocess.run([sys.executable, "-m", "nerf_core", "check", str(out)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1 and "loads every frame twice" in proc.stdout + proc.stderr
    bpy.ops.wm.read_factory_settings(use_empty=True)
    again = _capture(out)
    assert (again["kept"], again["rendered"]) == (7, 0)
    assert not (out / "transforms.json").exists() and (out / "nerfstudio" / "transforms.json").is_file()
    proc = subprocess.run([sys.executable, "-m", "nerf_core", "check", str(out)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
