"""Bad input gets a clear error and never loses data; resume and cancel leave consistent folders."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import bpy
import pytest
from mathutils import Matrix

from addon import file_writes
from addon.capture.files import frame_files
from addon.capture.layout import positions
from addon.capture.run import job as run_job
from addon.capture.plan import frame_plan, settings as plan_settings
from addon.capture.layout import collection, cameras as layout_cameras
from addon.dataset import capture_manifest

PY = sys.executable
SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts", "capture.py")


def scene_with_cameras(train=4, val=1, test=1):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    layout_cameras.create_cameras(bpy.context.scene, positions.LayoutSpec(train=train, val=val, test=test), 24, 16)
    return bpy.context.scene


def settings(out, **kw):
    base = dict(out_dir=str(out), engine="workbench", samples=1, res_x=24, res_y=16)
    base.update(kw)
    return plan_settings.CaptureSettings(**base)


def mtimes(folder):
    return {os.path.join(d, f): os.stat(os.path.join(d, f)).st_mtime_ns
            for d, _, files in os.walk(folder) for f in files if "nerf_capture" not in d}


def manifest(out):
    with open(os.path.join(out, "nerf_capture", "manifest.json")) as fh:
        return json.load(fh)


def test_no_visible_objects(tmp_path):
    bpy.ops.object.light_add(type="SUN")
    with pytest.raises(frame_plan.CaptureError, match="no visible objects"):
        run_job.CaptureJob(bpy.context.scene, settings(tmp_path / "ds"))
    hidden = bpy.data.objects.new("Hidden", bpy.data.meshes.new("Hidden"))
    bpy.context.scene.collection.objects.link(hidden)
    hidden.hide_render = True
    with pytest.raises(frame_plan.CaptureError, match="no visible objects"):
        run_job.CaptureJob(bpy.context.scene, settings(tmp_path / "ds"))
    assert not (tmp_path / "ds").exists()


def test_no_capture_cameras(tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    with pytest.raises(frame_plan.CaptureError, match="no train cameras.*generate a camera layout"):
        run_job.CaptureJob(bpy.context.scene, settings(tmp_path / "ds")).run()


@pytest.mark.parametrize("kind", ["scale", "shear"])
def test_scaled_or_sheared_camera_is_refused(tmp_path, kind):
    scene = scene_with_cameras()
    cam = collection.capture_cameras(scene)["train"][1]
    if kind == "scale":
        cam.scale = (2.0, 2.0, 2.0)
        pattern = "NeRF_train_001.*has scale"
    else:
        parent = bpy.data.objects.new("Squash", None)
        scene.collection.objects.link(parent)
        parent.scale = (1.0, 3.0, 1.0)
        world = cam.matrix_world.copy()
        cam.parent = parent
        cam.matrix_world = world @ Matrix.Rotation(math.radians(30), 4, "Z")
        bpy.context.view_layer.update()
        pattern = "NeRF_train_001"
    bpy.context.view_layer.update()
    with pytest.raises(frame_plan.CaptureError, match=pattern):
        run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()
    assert not (tmp_path / "ds").exists()


def test_scaled_camera_normalised_on_request_and_recorded(tmp_path):
    scene = scene_with_cameras(train=2, val=0, test=0)
    cam = collection.capture_cameras(scene)["train"][0]
    cam.scale = (0.5, 0.5, 0.5)
    bpy.context.view_layer.update()
    run_job.CaptureJob(scene, settings(tmp_path / "ds", normalize_camera_scale=True)).run()
    m = manifest(tmp_path / "ds")
    assert m["frames"]["train/r_0"]["camera_scale_removed"] == [0.5, 0.5, 0.5]
    with open(tmp_path / "ds" / "transforms_train.json") as fh:
        c2w = json.load(fh)["frames"][0]["transform_matrix"]
    assert sum(c2w[i][0] ** 2 for i in range(3)) == pytest.approx(1.0)


def _ring_of_scene_cameras(scene, n=5, parent=None):
    """n perspective cameras of the user's own on a ring around the origin, looking at it."""
    cams = []
    for i in range(n):
        a = 2 * math.pi * i / n
        cam = bpy.data.objects.new(f"Cam{i}", bpy.data.cameras.new(f"Cam{i}"))
        scene.collection.objects.link(cam)
        cam.location = (4 * math.cos(a), 4 * math.sin(a), 1.5)
        cam.rotation_euler = (-cam.location).to_track_quat("-Z", "Y").to_euler()
        cams.append(cam)
    bpy.context.view_layer.update()
    if parent is not None:  # a rig scaled by s: the cameras stand where they did, scaled by s
        for cam in cams:
            cam.parent = parent
            cam.location = cam.location / parent.scale[0]
    bpy.context.view_layer.update()
    return cams


def test_scene_cameras_that_are_mirrored_or_scaled_by_a_parent(tmp_path):
    # A mirrored camera rendered a whole dataset that check and train then refused (determinant -1):
    # refused before rendering now. A scale from a parent named the camera, whose own scale is 1.
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    spec = positions.LayoutSpec(layout="scene-cameras", val=1, test=1)
    cams = _ring_of_scene_cameras(scene)
    cams[2].scale = (-1.0, 1.0, 1.0)
    bpy.context.view_layer.update()
    with pytest.raises(positions.LayoutError, match="camera 'Cam2' is mirrored by its own scale"):
        layout_cameras.create_cameras(scene, spec, 24, 16)
    for cam in cams:
        bpy.data.objects.remove(cam)
    rig = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(rig)
    rig.scale = (2.0, 2.0, 2.0)
    _ring_of_scene_cameras(scene, parent=rig)
    layout_cameras.create_cameras(scene, spec, 24, 16)  # a scale alone waits for the capture
    with pytest.raises(frame_plan.CaptureError, match=r"\(the copy of 'Cam\d'\) has scale \(2.0, 2.0, 2.0\) from the "
                                                   r"scale of its parent 'Rig'; clear that scale, or let the capture"):
        run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()
    assert not (tmp_path / "ds").exists()
    run_job.CaptureJob(scene, settings(tmp_path / "ds", normalize_camera_scale=True)).run()
    assert manifest(tmp_path / "ds")["frames"]["train/r_0"]["camera_scale_removed"] == [2.0, 2.0, 2.0]
    rig.scale = (-2.0, 2.0, 2.0)  # mirrored by the parent: no normalising fixes that
    bpy.context.view_layer.update()
    with pytest.raises(positions.LayoutError, match="mirrored by the scale of its parent 'Rig'"):
        layout_cameras.create_cameras(scene, spec, 24, 16)


def test_a_scale_a_constraint_brings_is_named_as_the_constraints(tmp_path):
    # Ctrl+A on the camera changes nothing when a Child Of constraint's target carries the scale.
    scene = scene_with_cameras(train=2, val=0, test=1)
    rig = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(rig)
    rig.scale = (1.5, 1.5, 1.5)
    camera = next(o for o in collection.nerf_collection(scene).objects if o.type == "CAMERA")
    constraint = camera.constraints.new("CHILD_OF")
    constraint.target = rig
    constraint.set_inverse_pending = False
    bpy.context.view_layer.update()
    with pytest.raises(frame_plan.CaptureError, match=r"from its constraint 'Child Of'; turn off its scale"):
        run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()


def test_an_orthographic_scene_camera_is_named_in_the_error(tmp_path):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    for cam in _ring_of_scene_cameras(scene):
        cam.data.type = "ORTHO"
    layout_cameras.create_cameras(scene, positions.LayoutSpec(layout="scene-cameras", val=1, test=1), 24, 16)
    with pytest.raises(frame_plan.CaptureError, match=r"camera 'NeRF_train_000' \(the copy of 'Cam\d'\) is ortho"):
        run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()


def test_stereoscopy_is_turned_off_for_the_capture(tmp_path):
    # With Stereoscopy on, each view rendered a left and a right image and saving the PNG raised a
    # traceback, leaving r_0.partial_L.png and r_0.partial_R.png behind.
    scene = scene_with_cameras(train=2)
    scene.render.use_multiview = True
    scene.render.views_format = "STEREO_3D"
    run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()
    names = sorted(f for _d, _s, files in os.walk(tmp_path / "ds" / "train") for f in files)
    assert names == ["r_0.png", "r_1.png"]
    assert scene.render.use_multiview  # the user's setting comes back


def test_a_camera_bound_to_a_marker_does_not_take_over_the_views(tmp_path):
    # A camera bound to a timeline marker replaced the capture's camera at every render: every image
    # showed the marker camera's view while the transforms recorded each view's own pose.
    import numpy as np
    from PIL import Image

    scene = scene_with_cameras(train=3)
    shot = bpy.data.objects.new("Shot", bpy.data.cameras.new("Shot"))
    scene.collection.objects.link(shot)
    shot.location, shot.rotation_euler = (0.0, -6.0, 0.0), (math.radians(90), 0.0, 0.0)
    marker = scene.timeline_markers.new("m", frame=scene.frame_current)
    marker.camera = shot
    scene.camera = shot
    scene.render.image_settings.file_format = "JPEG"  # and the output format comes back, passes or not
    run_job.CaptureJob(scene, settings(tmp_path / "ds", depth=True)).run()
    images = [np.asarray(Image.open(tmp_path / "ds" / "train" / f"r_{k}.png")) for k in range(3)]
    assert not np.array_equal(images[0], images[1]) and not np.array_equal(images[1], images[2])
    assert marker.camera == shot and scene.camera == shot
    assert scene.render.image_settings.file_format == "JPEG"


def test_views_render_at_the_frame_the_capture_started_at(tmp_path):
    # The panel captures between timer events: scrubbing the timeline meanwhile rendered the rest of
    # the views at another moment of an animated scene.
    scene = scene_with_cameras(train=2)
    scene.frame_set(5)
    job = run_job.CaptureJob(scene, settings(tmp_path / "ds"))
    job.prepare()
    scene.frame_set(30)
    job.step()
    assert scene.frame_current == 5
    job.finish()


def test_resuming_after_the_scene_changed_is_a_conflict(tmp_path):
    # Frame hashes cover cameras and render settings only: after an edit, a resume kept pictures of the
    # old scene beside an aabb and near/far computed for the new one.
    scene = scene_with_cameras(train=2)
    run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()
    manifest_before = manifest(tmp_path / "ds")
    assert manifest_before["scene_signature"]
    _, conflict = run_job.CaptureJob(scene, settings(tmp_path / "ds")).inspect_folder()
    assert conflict is None  # nothing changed: resumes (keeps every frame)
    bpy.data.objects["Cube"].scale = (0.3, 0.3, 0.3)
    bpy.context.view_layer.update()
    with pytest.raises(frame_plan.CaptureError, match="holds frames of this scene as it was before it changed"):
        run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()
    summary = run_job.CaptureJob(scene, settings(tmp_path / "ds", overwrite=True)).run()
    assert summary["rendered"] == summary["frames"]


def test_resuming_after_the_look_changed_is_a_conflict_but_moving_a_node_is_not(tmp_path):
    # A material's colour, the world's strength or a lamp's power change every picture without moving
    # a vertex: scene_signature did not see them, and a resume mixed old and new pictures.
    scene = scene_with_cameras(train=2)
    material = bpy.data.materials.new("Look")  # Blender 5 gives it a node tree (use_nodes is always on)
    bpy.data.objects["Cube"].data.materials.append(material)
    bpy.ops.object.light_add(type="POINT", location=(2.0, 2.0, 2.0))
    lamp = bpy.context.object
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    background = next(n for n in scene.world.node_tree.nodes if n.type == "BACKGROUND")
    run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()
    assert manifest(tmp_path / "ds")["appearance_signature"]
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.location.x += 200  # tidying the node editor changes no pixel
    _, conflict = run_job.CaptureJob(scene, settings(tmp_path / "ds")).inspect_folder()
    assert conflict is None
    edits = [lambda: setattr(bsdf.inputs["Base Color"], "default_value", (1.0, 0.0, 0.0, 1.0)),
             lambda: setattr(background.inputs["Strength"], "default_value", 3.0),
             lambda: setattr(lamp.data, "energy", 5000.0),
             lambda: setattr(scene.world, "color", (0.9, 0.1, 0.1))]  # the background Workbench shows
    for edit in edits:
        run_job.CaptureJob(scene, settings(tmp_path / "ds", overwrite=True)).run()
        edit()
        with pytest.raises(frame_plan.CaptureError, match="as it looked before it changed"):
            run_job.CaptureJob(scene, settings(tmp_path / "ds")).run()


def test_cameras_and_subjects_disabled_in_viewports_keep_their_places_after_reopening(tmp_path):
    # Blender 5 does not save matrix_world: what the viewport does not evaluate (monitor icon, an
    # excluded collection) read back as the identity once the file was opened again. The render still
    # placed it right, so every such camera's pose was wrong and the subject was boxed at the origin.
    scene = scene_with_cameras(train=3, val=0, test=1)
    cube = bpy.data.objects["Cube"]
    cube.location = (1.5, 0.5, 0.25)
    cameras = [o for o in collection.nerf_collection(scene).objects if o.type == "CAMERA"]
    poses = {o.name: [v for row in o.matrix_world.normalized() for v in row] for o in cameras}
    for obj in cameras + [cube]:
        obj.hide_viewport = True
    blend = str(tmp_path / "disabled.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.open_mainfile(filepath=blend)
    scene = bpy.context.scene
    assert bpy.data.objects["Cube"].matrix_world.translation.length < 1e-6  # what the capture used to read
    homes = {o.name: sorted(c.name for c in o.users_collection) for o in bpy.data.objects}
    job = run_job.CaptureJob(scene, settings(tmp_path / "ds"))
    for fr in job.plan():
        assert sum(fr["transform_matrix"], []) == pytest.approx(poses[fr["camera"]], abs=1e-5), fr["camera"]
    lo, hi = job.bounds
    assert lo[0] == pytest.approx(1.0, abs=1e-3) and hi[0] == pytest.approx(2.0, abs=1e-3)  # the cube, moved
    assert all(bpy.data.objects[name].hide_viewport for name in list(poses) + ["Cube"])  # left as they were
    assert homes == {o.name: sorted(c.name for c in o.users_collection) for o in bpy.data.objects}


def test_the_layer_the_box_comes_from_is_the_layer_rendered_whatever_its_use_flag(tmp_path):
    # In background mode every layer "Used for Rendering" renders and the first is saved: with the
    # active layer's flag off, the pictures came from another layer than the box (or, with no other
    # layer, saving the render failed with a traceback).
    scene = scene_with_cameras(train=2, val=0, test=1)
    subject = bpy.data.collections.new("Subject")
    scene.collection.children.link(subject)
    cube = bpy.data.objects["Cube"]
    scene.collection.objects.unlink(cube)
    subject.objects.link(cube)
    active = bpy.context.view_layer
    active.use = False
    summary = run_job.CaptureJob(scene, settings(tmp_path / "one")).run()  # its only layer: rendered anyway
    assert summary["rendered"] == summary["frames"]
    other = scene.view_layers.new("Other")
    other.layer_collection.children["Subject"].exclude = True  # this layer renders nothing
    run_job.CaptureJob(scene, settings(tmp_path / "two")).run()
    alpha = frame_files.read_png_rgba(str(tmp_path / "two" / "train" / "r_0.png"))[..., 3]
    assert alpha.max() > 0  # the cube of the active layer, not the empty other layer
    assert active.use is False and other.use is True  # the file's flags are restored


def test_cameras_whose_clipping_cuts_the_scene_box_are_named(tmp_path):
    # Generated layouts fit their clipping to the box; a user's own clip_end short of the scene left
    # parts of it out of some views only, with no word.
    scene = scene_with_cameras(train=3, val=0, test=1)
    job = run_job.CaptureJob(scene, settings(tmp_path / "ds"))
    job.plan()
    assert not any("clip the scene box" in n for n in job.notes)
    cameras = [o for o in collection.nerf_collection(scene).objects if o.type == "CAMERA"]
    cameras[0].data.clip_end = 0.5
    job = run_job.CaptureJob(scene, settings(tmp_path / "ds"))
    job.plan()
    clipped = f"1 camera(s) clip the scene box, e.g. {cameras[0].name!r}: clip"
    assert any(n.startswith(clipped) for n in job.notes), job.notes


def test_an_overwrite_says_what_it_would_delete(tmp_path):
    scene = scene_with_cameras(train=2)
    out = tmp_path / "ds"
    (out / "test").mkdir(parents=True)
    (out / "test" / "test_shading.py").write_text("user code")
    (out / "notes.txt").write_text("user notes")
    _, conflict = run_job.CaptureJob(scene, settings(out)).inspect_folder()
    assert "holds no capture of ours (notes.txt, test)" in conflict
    assert conflict.endswith("overwrite deletes test (the dataset's names) and keeps the rest")


def test_output_folder_not_writable(tmp_path):
    scene = scene_with_cameras()
    blocker = tmp_path / "a_file"
    blocker.write_text("user data")
    with pytest.raises(frame_plan.CaptureError, match="not a folder"):
        run_job.CaptureJob(scene, settings(blocker)).run()
    with pytest.raises(frame_plan.CaptureError, match="not writable"):
        run_job.CaptureJob(scene, settings(blocker / "ds")).run()
    assert blocker.read_text() == "user data"


def test_foreign_folder_refused_then_overwrite_keeps_unrelated_files(tmp_path):
    scene = scene_with_cameras()
    out = tmp_path / "ds"
    (out / "train").mkdir(parents=True)
    (out / "train" / "holiday.png").write_bytes(b"precious")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(frame_plan.CaptureError, match="not empty and holds no capture.*notes.txt.*--overwrite"):
        run_job.CaptureJob(scene, settings(out)).run()
    assert (out / "train" / "holiday.png").read_bytes() == b"precious"
    assert not (out / "transforms_train.json").exists()
    run_job.CaptureJob(scene, settings(out, overwrite=True)).run()
    assert (out / "notes.txt").read_text() == "mine"  # only the dataset's own paths are replaced
    assert not (out / "train" / "holiday.png").exists() and (out / "train" / "r_0.png").exists()


def test_different_capture_refused_unless_overwrite(tmp_path):
    scene = scene_with_cameras()
    out = tmp_path / "ds"
    run_job.CaptureJob(scene, settings(out)).run()
    before = mtimes(out)
    with pytest.raises(frame_plan.CaptureError, match="different capture.*render settings changed.*--overwrite"):
        run_job.CaptureJob(scene, settings(out, res_x=32)).run()
    collection.capture_cameras(scene)["train"][0].location.x += 0.5
    bpy.context.view_layer.update()
    with pytest.raises(frame_plan.CaptureError, match="cameras changed.*train/r_0"):
        run_job.CaptureJob(scene, settings(out)).run()
    assert mtimes(out) == before
    run_job.CaptureJob(scene, settings(out, res_x=32, overwrite=True)).run()
    assert manifest(out)["render"]["resolution"] == [32, 16]


def test_resume_keeps_finished_frames(tmp_path):
    scene = scene_with_cameras()
    out = tmp_path / "ds"
    first = run_job.CaptureJob(scene, settings(out)).run()
    assert first["rendered"] == 6
    before = mtimes(out)
    again = run_job.CaptureJob(scene, settings(out)).run()
    assert (again["rendered"], again["kept"]) == (0, 6)
    pngs = {k: v for k, v in mtimes(out).items() if k.endswith(".png")}
    assert pngs == {k: v for k, v in before.items() if k.endswith(".png")}
    os.remove(out / "val" / "r_0.png")
    third = run_job.CaptureJob(scene, settings(out)).run()
    assert (third["rendered"], third["kept"]) == (1, 5) and (out / "val" / "r_0.png").exists()


def test_a_view_blender_cannot_render_is_named_with_the_resolution(tmp_path, monkeypatch):
    # Workbench fails past 16384 px ("Failed to allocate GPU buffers"), inside the 1..65536 the field
    # allows: a traceback reached the user, or "capture stopped: Error: ..." that named no resolution.
    scene = scene_with_cameras()
    out = tmp_path / "ds"
    job = run_job.CaptureJob(scene, settings(out))
    job.prepare()
    assert job.step()  # one frame is rendered before the failure

    def cannot(*args, **kwargs):
        raise RuntimeError("Error: Failed to allocate GPU buffers\n")

    monkeypatch.setattr(frame_files, "render_still", cannot)
    with pytest.raises(frame_plan.CaptureError, match=r"train/r_1: Blender could not render this view at 24x16 px with "
                                                   r"BLENDER_WORKBENCH \(Failed to allocate GPU buffers\); a lower "
                                                   r"resolution may fit.*resumes"):
        job.step()
    job.cancel()
    assert manifest(out)["status"] == "incomplete" and (out / "train" / "r_0.png").exists()


def test_cancel_leaves_consistent_resumable_folder(tmp_path):
    scene = scene_with_cameras()
    user_camera = bpy.data.objects.new("Mine", bpy.data.cameras.new("Mine"))
    scene.collection.objects.link(user_camera)
    scene.camera = user_camera
    scene.render.resolution_x, scene.render.engine = 1234, "CYCLES"
    out = tmp_path / "ds"
    job = run_job.CaptureJob(scene, settings(out, depth=True))
    job.prepare()
    for _ in range(3):
        assert job.step()
    summary = job.cancel()
    assert summary["status"] == "incomplete" and summary["pending"] == 3
    assert scene.camera == user_camera and scene.render.resolution_x == 1234 and scene.render.engine == "CYCLES"
    m = manifest(out)
    assert m["status"] == "incomplete" and sum(f["done"] for f in m["frames"].values()) == 3
    with open(out / "transforms_train.json") as fh:
        done = json.load(fh)["frames"]
    assert len(done) == 3
    for fr in done:
        assert (out / (fr["file_path"] + ".png")).is_file() and (out / fr["depth_file_path"]).is_file()
    assert not [p for p in mtimes(out) if ".partial" in p]
    resumed = run_job.CaptureJob(scene, settings(out, depth=True)).run()
    assert (resumed["kept"], resumed["rendered"], resumed["status"]) == (3, 3, "complete")
    with open(out / "nerfstudio" / "transforms.json") as fh:
        assert len(json.load(fh)["frames"]) == 6


def test_normals_with_workbench_and_bad_engine(tmp_path):
    scene = scene_with_cameras()
    with pytest.raises(frame_plan.CaptureError, match="normals need the Cycles or EEVEE"):
        run_job.CaptureJob(scene, settings(tmp_path, normals=True))
    with pytest.raises(frame_plan.CaptureError, match="unknown render engine 'povray'"):
        run_job.CaptureJob(scene, settings(tmp_path, engine="povray"))


def test_script_default_layout_leaves_user_camera_and_file_alone(tmp_path):
    bpy.ops.mesh.primitive_monkey_add(location=(0.2, 0.1, 0.0))
    cam = bpy.data.objects.new("LooksAway", bpy.data.cameras.new("LooksAway"))
    bpy.context.scene.collection.objects.link(cam)
    cam.matrix_world = Matrix(positions.look_at((0, -5, 0), (0, -20, 0)))  # the scene is behind it
    bpy.context.scene.camera = cam
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    blend_bytes = blend.read_bytes()
    out = tmp_path / "ds"
    cmd = [PY, SCRIPT, "--blend", str(blend), "--out", str(out), "--count", "3", "--val-count", "1",
           "--test-count", "1", "--resolution", "24x16", "--engine", "workbench", "--quiet"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["status"] == "complete" and summary["frames"] == 5
    assert blend.read_bytes() == blend_bytes
    from PIL import Image
    import numpy as np
    alpha = np.asarray(Image.open(out / "train" / "r_0.png"))[..., 3]
    assert (alpha > 0).mean() > 0.05  # the generated cameras see the monkey
    # the same command on a folder holding something else: refused, exit 2, one clear line
    (out / "transforms_train.json").write_text("{}")  # pretend the user edited it, then ask for other settings
    proc = subprocess.run(cmd + ["--resolution", "32"], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 2 and "different capture" in proc.stderr and "Traceback" not in proc.stderr
    assert (out / "transforms_train.json").read_text() == "{}"
    empty = tmp_path / "empty.blend"
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(empty))
    proc = subprocess.run([PY, SCRIPT, "--blend", str(empty), "--out", str(tmp_path / "ds2"), "--quiet"],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 2 and "no visible objects" in proc.stderr and "Traceback" not in proc.stderr
    assert capture_manifest.read_manifest(str(tmp_path / "ds2")) is None


def test_script_keep_cameras_captures_the_edited_collection(tmp_path):
    scene = scene_with_cameras(train=3, val=1, test=1)
    cam = collection.capture_cameras(scene)["train"][0]
    cam.matrix_world = Matrix(positions.look_at((0.5, -4.0, 1.0), (0, 0, 0)))  # a user edit
    blend = tmp_path / "cams.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "ds"
    base = [PY, SCRIPT, "--blend", str(blend), "--out", str(out), "--resolution", "16", "--engine", "workbench",
            "--quiet"]
    proc = subprocess.run(base + ["--keep-cameras"], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr
    with open(out / "transforms_train.json") as fh:
        doc = json.load(fh)
    assert len(doc["frames"]) == 3
    assert [row[3] for row in doc["frames"][0]["transform_matrix"][:3]] == pytest.approx([0.5, -4.0, 1.0])
    proc = subprocess.run(base + ["--resume", "--keep-cameras"], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0 and json.loads(proc.stdout.splitlines()[-1])["kept"] == 5
    proc = subprocess.run(base[:5] + [str(tmp_path / "new"), "--resume", "--quiet"], capture_output=True, text=True,
                          timeout=180)
    assert proc.returncode == 2 and "no capture to continue" in proc.stderr


def test_script_keep_cameras_refuses_a_collection_without_val_or_test_cameras(tmp_path):
    scene_with_cameras(train=3, val=0, test=1)
    blend = tmp_path / "cams.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "ds"
    proc = subprocess.run([PY, SCRIPT, "--blend", str(blend), "--out", str(out), "--resolution", "16", "--engine",
                           "workbench", "--quiet", "--keep-cameras"], capture_output=True, text=True, timeout=180)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "no 'val' camera" in proc.stderr or "no val camera" in proc.stderr
    assert not out.exists()  # nothing written that `train` would refuse


def test_pass_files_round_trip_and_unreadable_ones_are_named(tmp_path):
    import numpy as np
    import OpenEXR
    from PIL import Image

    from addon.scene import passes

    z = np.arange(12, dtype=np.float32).reshape(3, 4) / 7
    z[0, 0] = np.inf
    path = str(tmp_path / "d.exr")
    passes.write_exr(path, {"Z": z, "A": -z})
    ch = OpenEXR.File(path, separate_channels=True).parts[0].channels
    assert np.array_equal(ch["Z"].pixels, z) and np.array_equal(ch["A"].pixels, -z)
    assert np.array_equal(passes.read_exr_channels(path)["Z"], z)
    zipped = str(tmp_path / "zip.exr")
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"Z": z}).write(zipped)
    with pytest.raises(passes.PassError, match="zip.exr: compressed EXR"):
        passes.read_exr_channels(zipped)
    (tmp_path / "junk.exr").write_bytes(b"not an image")
    with pytest.raises(passes.PassError, match="junk.exr: not an OpenEXR"):
        passes.read_exr_channels(str(tmp_path / "junk.exr"))
    mask = (np.arange(20).reshape(4, 5) % 3 == 0).astype(np.uint8) * 255
    file_writes.write_png_gray(str(tmp_path / "m.png"), mask)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "m.png")), mask)
