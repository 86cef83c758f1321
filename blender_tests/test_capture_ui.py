"""The add-on registers and unregisters cleanly; the Capture panel's settings and operators work headless."""
from __future__ import annotations

import json
import os

import bpy
import pytest

import addon
from addon import capture as capture_feature
from addon.capture.ui import panel as ui_panel
from addon.capture.layout import positions
from addon.capture.layout import collection, cameras
from addon.common import jobs


@pytest.fixture
def registered():
    # Only this feature: the panel's tests should not depend on the other panels registering.
    capture_feature.register()
    yield
    capture_feature.unregister()


def test_capture_ui_register_unregister_twice():
    for _ in range(2):
        capture_feature.register()
        assert hasattr(bpy.types.Scene, "nerf_capture") and hasattr(bpy.types, "NERF_PT_capture")
        capture_feature.unregister()
        assert not hasattr(bpy.types.Scene, "nerf_capture") and not hasattr(bpy.types, "NERF_PT_capture")


def test_settings_are_saved_with_the_blend(registered, tmp_path):
    s = bpy.context.scene.nerf_capture
    s.train_count, s.resolution_x, s.engine = 42, 320, "workbench"
    path = tmp_path / "settings.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(path))
    s = bpy.context.scene.nerf_capture
    assert (s.train_count, s.resolution_x, s.engine) == (42, 320, "workbench")


def test_layout_choice_sets_elevation_defaults(registered):
    s = bpy.context.scene.nerf_capture
    s.layout = "sphere"
    assert (s.elevation_min, s.elevation_max) == (-90.0, 90.0)
    s.layout = "hemisphere"
    assert (s.elevation_min, s.elevation_max) == (0.0, 90.0)
    s.layout = "inside"
    assert (s.elevation_min, s.elevation_max) == positions.INSIDE_ELEVATION


def test_generate_and_capture_operators(registered, tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    s = bpy.context.scene.nerf_capture
    s.train_count, s.val_count, s.test_count = 3, 1, 1
    s.resolution_x, s.resolution_y, s.engine = 24, 16, "workbench"
    s.output_dir = str(tmp_path / "ds")
    assert bpy.ops.nerf.generate_cameras() == {"FINISHED"}
    assert [len(v) for v in collection.capture_cameras(bpy.context.scene).values()] == [3, 1, 1]
    assert bpy.ops.nerf.capture() == {"FINISHED"}
    with open(tmp_path / "ds" / "nerf_capture" / "manifest.json") as fh:
        assert json.load(fh)["status"] == "complete"
    assert os.path.isfile(tmp_path / "ds" / "test" / "r_0.png")
    s.resolution_x = 30  # a different capture into the same folder must be confirmed
    with pytest.raises(RuntimeError, match="different capture"):
        bpy.ops.nerf.capture()
    assert bpy.ops.nerf.capture(overwrite=True) == {"FINISHED"}
    assert bpy.ops.nerf.clear_cameras() == {"FINISHED"}
    assert not any(collection.capture_cameras(bpy.context.scene).values())


def test_operator_errors_are_reported_not_raised_deep(registered, tmp_path):
    bpy.context.scene.nerf_capture.layout = "scene-cameras"
    bpy.ops.mesh.primitive_cube_add()
    with pytest.raises(RuntimeError, match="no camera of its own"):
        bpy.ops.nerf.generate_cameras()
    bpy.context.scene.nerf_capture.output_dir = str(tmp_path / "x")
    with pytest.raises(RuntimeError, match="no camera of its own"):
        bpy.ops.nerf.capture()  # generates the layout first, which fails the same way


def test_the_panel_cannot_capture_a_dataset_without_val_or_test_views(registered, tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    s = bpy.context.scene.nerf_capture
    s.val_count = 0  # the property clamps: the panel cannot ask for an empty split
    assert s.val_count == 1
    s.train_count = 1  # nor for a train split of one view, which train and check refuse
    assert s.train_count == 2
    # A collection made elsewhere (a script, an older file) without test cameras is refused, naming it.
    cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(train=3, val=1, test=0), 16, 16)
    s.output_dir, s.engine = str(tmp_path / "ds"), "workbench"
    with pytest.raises(RuntimeError, match="no test camera"):
        bpy.ops.nerf.capture()
    assert not (tmp_path / "ds").exists()


def _fake_modal_operator(job):
    """The job follower's modal method bound to a stand-in instance (no event loop runs headless),
    following ``job`` as the Capture operator hands it over."""
    from types import SimpleNamespace

    ui_panel.follow_capture(bpy.context.scene, job)
    op = SimpleNamespace(_timer=None, reports=[])
    op.report = lambda kind, msg: op.reports.append((kind, msg))
    op.modal = lambda ctx, event: jobs.NERF_OT_follow_jobs.modal(op, ctx, event)
    ctx = SimpleNamespace(scene=bpy.context.scene, screen=None,
                          window_manager=SimpleNamespace(event_timer_remove=lambda timer: None))
    return op, ctx


@pytest.mark.parametrize("how", ["esc", "button", "finish"])
def test_modal_capture_steps_per_tick_and_cancels(registered, tmp_path, how):
    from types import SimpleNamespace

    from addon.capture.run import job as run_job

    bpy.ops.mesh.primitive_cube_add()
    s = bpy.context.scene.nerf_capture
    s.train_count, s.val_count, s.test_count = 3, 1, 1
    s.resolution_x, s.resolution_y, s.engine, s.output_dir = 16, 16, "workbench", str(tmp_path / "ds")
    bpy.ops.nerf.generate_cameras()
    job = run_job.CaptureJob(bpy.context.scene, s.capture_settings(), progress=lambda d, t, i: None)
    job.prepare()
    op, ctx = _fake_modal_operator(job)
    s.is_running = True
    assert op.modal(ctx, SimpleNamespace(type="MOUSEMOVE")) == {"PASS_THROUGH"}
    assert op.modal(ctx, SimpleNamespace(type="TIMER")) == {"RUNNING_MODAL"}
    assert len(job.done_keys) == 1  # exactly one frame per tick
    with open(tmp_path / "ds" / "nerf_capture" / "manifest.json") as fh:
        assert json.load(fh)["status"] == "incomplete"
    if how == "finish":
        results = [op.modal(ctx, SimpleNamespace(type="TIMER")) for _ in range(4)]
        assert results[-1] == {"FINISHED"} and s.status.startswith("done: 5 frames")
        expected = "complete"
    else:
        if how == "button":
            bpy.ops.nerf.capture_cancel()
        assert op.modal(ctx, SimpleNamespace(type="ESC" if how == "esc" else "TIMER")) == {"CANCELLED"}
        assert "resume" in s.status and op.reports[-1][0] == {"WARNING"}
        expected = "incomplete"
    assert not s.is_running and not s.cancel_requested
    with open(tmp_path / "ds" / "nerf_capture" / "manifest.json") as fh:
        assert json.load(fh)["status"] == expected
    assert os.path.isfile(tmp_path / "ds" / "transforms_train.json")


def test_cancel_with_no_capture_running_says_so_and_sets_no_flag(registered, capfd):
    # It finished silently and left cancel_requested set, with no capture to read it; a set flag left
    # over (a stale .blend) is cleared too. With a capture running the flag is set:
    # test_modal_capture_steps_per_tick_and_cancels[button].
    s = bpy.context.scene.nerf_capture
    s.cancel_requested = True
    capfd.readouterr()
    assert bpy.ops.nerf.capture_cancel() == {"CANCELLED"}
    out, err = capfd.readouterr()
    assert "Warning: No capture is running: nothing to cancel." in out + err
    assert not s.cancel_requested and jobs.get(ui_panel.CAPTURE) is None


def test_addon_register_unregister_twice():
    """The whole add-on (every panel, not only Capture) registers and unregisters cleanly twice."""
    try:
        for _ in range(2):
            addon.register()
            assert hasattr(bpy.types.Scene, "nerf_capture")
            assert hasattr(bpy.types, "NERF_PT_capture") and bpy.types.NERF_PT_capture.bl_category == "NeRF"
            assert hasattr(bpy.ops.nerf, "capture") and hasattr(bpy.ops.nerf, "generate_cameras")
            addon.unregister()
            assert not hasattr(bpy.types.Scene, "nerf_capture")
            assert not hasattr(bpy.types, "NERF_PT_capture")
    finally:
        # A failure above must not leave classes registered for the tests that follow.
        for module in reversed(addon._MODULES):
            try:
                module.unregister()
            except Exception:
                pass


class _RecordingLayout:
    """Stands in for UILayout in Panel.draw: records props and operators, checks the props exist."""

    def __init__(self, log):
        self.log = log
        self.use_property_split = self.use_property_decorate = self.enabled = False

    def _child(self, *args, **kwargs):
        return _RecordingLayout(self.log)

    column = row = box = split = _child

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, f"panel draws unknown property {name!r}"
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        module, op = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), op), f"panel draws unknown operator {idname}"
        self.log.append(("operator", idname))
        return type("Props", (), {})()

    def operator_menu_enum(self, idname, prop, **kwargs):
        self.operator(idname)

    def label(self, text="", **kwargs):
        self.log.append(("label", text))

    def progress(self, factor=0.0, type="BAR", text=""):
        self.log.append(("progress", factor, text))


@pytest.mark.parametrize("layout_name", ["hemisphere", "rings", "spiral", "inside", "animation", "scene-cameras"])
def test_panel_draws_every_layout_and_the_running_state(registered, layout_name, monkeypatch):
    from types import SimpleNamespace

    from addon.common import jobs

    s = bpy.context.scene.nerf_capture
    s.layout = layout_name
    log = []
    panel = SimpleNamespace(layout=_RecordingLayout(log))
    ui_panel.NERF_PT_capture.draw(panel, bpy.context)
    props = {entry[1] for entry in log if entry[0] == "prop"}
    assert {"layout", "engine", "resolution_x", "resolution_y", "output_dir", "depth", "masks"} <= props
    assert ("operator", "nerf.capture") in log and ("operator", "nerf.generate_cameras") in log
    assert ("rings" in props) == (layout_name == "rings") and ("frame_step" in props) == (layout_name == "animation")
    assert ("radius" in props) == (layout_name in positions.GENERATED_LAYOUTS and layout_name != "inside")
    s.is_running, s.progress, s.status = True, 0.25, "3/12 train/r_2"
    log.clear()
    ui_panel.NERF_PT_capture.draw(panel, bpy.context)
    # A flag without a capture job (left by an add-on reload) is stale: the panel offers Capture, not
    # a Cancel that has nothing to cancel.
    assert ("operator", "nerf.capture") in log and ("operator", "nerf.capture_cancel") not in log
    monkeypatch.setattr(jobs, "is_running", lambda key: key == ui_panel.CAPTURE)
    log.clear()
    ui_panel.NERF_PT_capture.draw(panel, bpy.context)
    assert ("progress", 0.25, "3/12 train/r_2") in log and ("operator", "nerf.capture_cancel") in log


def test_cameras_laid_out_with_other_settings_are_called_out_of_date(registered, tmp_path):
    # The panel's Radius, Focal Length and Train count changed after the cameras were made: Capture
    # rendered the old cameras and said nothing, so the dataset was not what the panel showed.
    from types import SimpleNamespace

    bpy.ops.mesh.primitive_cube_add()
    scene = bpy.context.scene
    s = scene.nerf_capture
    s.layout, s.train_count, s.val_count, s.test_count = "hemisphere", 3, 1, 1
    s.resolution_x = s.resolution_y = 16
    s.radius, s.focal_length = 0.0, 50.0

    def stale():
        return collection.stale_layout_note(scene, s.layout_spec(), s.resolution_x, s.resolution_y)

    def panel_lines():
        log = []
        ui_panel.NERF_PT_capture.draw(SimpleNamespace(layout=_RecordingLayout(log)), bpy.context)
        return " ".join(entry[1] for entry in log if entry[0] == "label")

    assert stale() is None  # no cameras yet
    assert bpy.ops.nerf.generate_cameras() == {"FINISHED"}
    assert stale() is None and "out of date" not in panel_lines()
    s.radius, s.focal_length, s.train_count = 12.0, 120.0, 6
    s.turns = 7.0  # the hemisphere layout does not use it: not named
    note = stale()
    assert note and "radius 0 -> 12" in note and "focal length 50 -> 120" in note and "train count 3 -> 6" in note
    assert "turns" not in note and "Generate Cameras" in note
    assert "Cameras out of date" in panel_lines()
    assert bpy.ops.nerf.generate_cameras() == {"FINISHED"}
    assert stale() is None
    assert bpy.ops.nerf.clear_cameras() == {"FINISHED"}
    # cameras the user puts in the collection were laid out by no settings of ours
    user = bpy.data.objects.new("mine", bpy.data.cameras.new("mine"))
    collection.nerf_collection(scene).objects.link(user)
    s.radius = 3.0
    assert stale() is None


def test_relative_output_of_an_unsaved_file_is_refused(registered):
    bpy.ops.mesh.primitive_cube_add()
    bpy.context.scene.nerf_capture.output_dir = "//nerf_dataset/"
    with pytest.raises(RuntimeError, match="not saved yet"):
        bpy.ops.nerf.capture()


def test_relative_output_resolves_next_to_the_saved_blend(registered, tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    s = bpy.context.scene.nerf_capture
    s.train_count, s.val_count, s.test_count, s.engine = 2, 0, 0, "workbench"
    s.resolution_x = s.resolution_y = 8
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    s.output_dir = "//nerf_dataset/"
    assert bpy.ops.nerf.capture() == {"FINISHED"}
    assert (tmp_path / "nerf_dataset" / "train" / "r_1.png").is_file()
