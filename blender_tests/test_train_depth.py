"""The Train panel turns depth supervision on when the capture has it, and says so (issue 56)."""
from __future__ import annotations

import json

import bpy

from addon.common import jobs
from addon.train import train_ui
from nerf_core.tests.conftest import make_dataset


def test_depth_is_on_only_where_every_train_view_has_a_map(tmp_path):
    with_depth = make_dataset(tmp_path / "with", n_train=4, w=24, h=20)
    on, note = train_ui.depth_choice(str(with_depth), True, resume=False)
    assert on and "every one of the 4 train views has a depth map" in note
    off, note = train_ui.depth_choice(str(with_depth), False, resume=False)
    assert not off and "Use Depth is unchecked" in note
    resumed, note = train_ui.depth_choice(str(with_depth), True, resume=True)
    assert not resumed and "keeps its own settings" in note  # --depth on a resume would be a changed flag
    reaching = make_dataset(tmp_path / "reaching", n_train=4, w=24, h=20)  # a floor past the box: unbounded
    for name in ("train", "test"):
        path = reaching / f"transforms_{name}.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), "beyond_box": ["Ground"]}))
    off, note = train_ui.depth_choice(str(reaching), True, resume=False)
    assert not off and "reach past its box" in note
    without = make_dataset(tmp_path / "without", n_train=4, w=24, h=20, depth=False)
    off, note = train_ui.depth_choice(str(without), True, resume=False)
    assert not off and "no depth maps" in note
    meta_path = with_depth / "transforms_train.json"
    meta = json.loads(meta_path.read_text())
    del meta["frames"][0]["depth_file_path"]
    meta_path.write_text(json.dumps(meta))
    off, note = train_ui.depth_choice(str(with_depth), True, resume=False)
    assert not off and "only 3 of the 4 train views" in note
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "transforms_train.json").write_text('{"frames": [')
    off, note = train_ui.depth_choice(str(broken), True, resume=False)
    assert not off and "could not be read" in note


def test_train_passes_depth_and_the_panel_shows_why(train_settings, tmp_path):
    s = train_settings
    s.dataset_dir = str(make_dataset(tmp_path / "dataset", n_train=4, w=24, h=20))
    job = train_ui.start_training(bpy.context)
    try:
        assert "--depth" in job.command
        assert s.depth_note.startswith("Depth: on")
    finally:
        jobs.cancel_jobs(wait=True)
    s.use_depth = False
    job = train_ui.start_training(bpy.context)
    try:
        assert "--depth" not in job.command and "unchecked" in s.depth_note
    finally:
        jobs.cancel_jobs(wait=True)
