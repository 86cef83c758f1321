"""The whole loop on a tiny scene, through the real nerf_core CLI: capture (addon.capture) -> train in
a background job (check, train, resume) -> render the test cameras -> camera-aligned planes that
sit exactly where the cameras look -> a gallery .blend from scripts/import_views.py."""
from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
import time

import bpy
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from addon.capture.layout import positions
from addon.capture.run import job as run_job
from addon.capture.plan import settings as plan_settings
from addon.capture.layout import collection, cameras
from addon.common import jobs
from addon.compare import planes
from addon.bridge import runs, child_process
from addon import compare, train
from addon.compare import compare_ui
from addon.train import train_ui, train_job

RES = 32


def drive(job, timeout=240.0):
    """What the modal timer does, in a loop: update the job until it leaves 'running'."""
    deadline = time.monotonic() + timeout
    while job.update() == "running":
        if isinstance(job, train_job.TrainJob):
            train_ui.sync_train_settings(job)
        assert time.monotonic() < deadline, f"{job.kind} did not finish in {timeout} s:\n{job.process.log_tail()}"
        time.sleep(0.1)
    if isinstance(job, train_job.TrainJob):
        train_ui.sync_train_settings(job)
    assert job.state == "done", job.message
    return job


@pytest.fixture
def registered():
    train.register()
    compare.register()
    yield
    compare.unregister()
    train.unregister()


def tiny_capture(root: str):
    scene = bpy.context.scene
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    mat = bpy.data.materials.new("red")
    mat.diffuse_color = (0.8, 0.2, 0.1, 1.0)
    bpy.context.object.data.materials.append(mat)
    cameras.create_cameras(scene, positions.LayoutSpec(layout="hemisphere", train=8, val=1, test=2, seed=0), RES, RES)
    settings = plan_settings.CaptureSettings(out_dir=os.path.join(root, "dataset"), engine="workbench",
                                             res_x=RES, res_y=RES)
    summary = run_job.CaptureJob(scene, settings).run()
    assert summary["status"] == "complete"
    return settings.out_dir


def test_capture_train_resume_render_and_import(tmp_path, registered, repo_root):
    root = str(tmp_path)
    dataset = tiny_capture(root)
    scene = bpy.context.scene
    s = scene.nerf_train
    s.dataset_dir, s.run_dir = dataset, os.path.join(root, "run")
    s.max_seconds, s.max_steps = 0.0, 6

    job = drive(train_ui.start_training(bpy.context))
    assert s.step == 6 and not s.running and s.error == ""
    assert s.psnr > 0 and os.path.isfile(s.preview_path) and s.preview_path.startswith(s.run_dir)
    assert job.process.progress.done and job.process.progress.method

    s.max_steps = 9  # Resume continues from checkpoints/latest.pt up to the new budget
    job = drive(train_ui.start_training(bpy.context, resume=True))
    assert s.step == 9 and job.process.progress.step == 9
    events = [json.loads(x) for x in open(os.path.join(s.run_dir, "progress.jsonl")) if x.startswith("{")]
    steps = [e["step"] for e in events if e["event"] == "step"]
    assert steps == sorted(steps) and steps[-1] == 9  # a restart from scratch would count from 1 again
    listed = runs.list_runs(root)
    assert [r.name for r in listed] == ["run"] and listed[0].method == job.process.progress.method
    assert "PSNR" in listed[0].metrics_summary() and listed[0].has_checkpoint
    # The run list and the live panel say which background model the run uses (a transparent capture: random).
    assert "background random" in listed[0].settings_summary()
    assert s.background.startswith("random: ")
    train_ui.refresh_runs(s)
    assert [r.name for r in s.runs] == ["run"] and "PSNR" in s.runs[0].metrics

    # Novel views of the test cameras, camera-aligned.
    s.view_source, s.layout = "TEST", "CAMERA"
    job = drive(compare_ui.start_render(bpy.context))
    views = job.views
    assert [v.name for v in views] == ["r_0", "r_1"]
    test_cams = collection.capture_cameras(scene)["test"]
    scene.render.resolution_x = scene.render.resolution_y = RES  # the capture's resolution
    scene.render.resolution_percentage = 100
    config = json.load(open(os.path.join(s.run_dir, "config.json")))
    coll = bpy.data.collections[planes.VIEWS_COLLECTION]
    assert len(coll.objects) == 2 and len(s.view_metrics) == 2
    for view, cam in zip(views, test_cams):
        ob = bpy.data.objects[f"NeRF {view.name}"]
        assert planes.plane_image_path(ob) == os.path.join(job.out, f"{view.name}.png")
        depth = -(cam.matrix_world.inverted() @ ob.matrix_world.translation).z  # auto: at the scene centre
        assert config["near"] < depth < config["far"]
        uv = ob.data.uv_layers.active.data
        for loop in ob.data.loops:
            ndc = world_to_camera_view(scene, cam, ob.matrix_world @ ob.data.vertices[loop.vertex_index].co)
            want = uv[loop.index].uv
            assert (ndc.x, ndc.y) == pytest.approx((want.x, want.y), abs=0.5 / RES / 10), (view.name, cam.name)
            assert ndc.z > 0  # in front of the camera

    # A fly-through: the first test camera animated over two frames, one view per frame, through the
    # real renderer; each plane lines up with the camera as it is at that frame.
    cam = test_cams[0]
    start = cam.matrix_world.copy()
    cam.keyframe_insert("location", frame=1)
    cam.location.z += 0.3
    cam.keyframe_insert("location", frame=2)
    scene.frame_start, scene.frame_end = 1, 2
    bpy.context.view_layer.objects.active = cam
    s.view_source = "ANIMATION"
    job = drive(compare_ui.start_render(bpy.context))
    assert [v.name for v in job.views] == ["frame_0001", "frame_0002"]
    for frame, view in ((1, job.views[0]), (2, job.views[1])):
        scene.frame_set(frame)
        ob = bpy.data.objects[f"NeRF {view.name}"]
        uv = ob.data.uv_layers.active.data
        for loop in ob.data.loops:
            ndc = world_to_camera_view(scene, cam, ob.matrix_world @ ob.data.vertices[loop.vertex_index].co)
            assert (ndc.x, ndc.y) == pytest.approx(tuple(uv[loop.index].uv), abs=0.5 / RES / 10)
    assert sum(job.views[0].c2w, []) == pytest.approx([x for row in start for x in row], abs=1e-5)
    assert len(bpy.data.collections[planes.VIEWS_COLLECTION].objects) == 2  # replaced the test views
    cam.animation_data_clear()
    cam.matrix_world = start

    # The gallery, headless, into a new .blend; the scene file is never touched.
    scene_blend = os.path.join(root, "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=scene_blend, copy=True)
    digest = hashlib.sha256(open(scene_blend, "rb").read()).hexdigest()
    out = os.path.join(root, "compare.blend")
    cmd = [sys.executable, os.path.join(repo_root, "scripts", "import_views.py"), "--blend", scene_blend,
           "--run", s.run_dir, "--out", out, "--layout", "gallery"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["n_views"] == 2 and math.isfinite(summary["psnr"]) and 0 < summary["ssim"] <= 1
    assert "render views" in proc.stderr  # the progress bar
    assert os.path.isfile(out) and hashlib.sha256(open(scene_blend, "rb").read()).hexdigest() == digest
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "already exists" in again.stderr and "--overwrite" in again.stderr

    bpy.ops.wm.open_mainfile(filepath=out)
    gallery = bpy.data.collections[planes.GALLERY_COLLECTION]
    names = {o.name for o in gallery.objects}
    assert {"Gallery NeRF r_0", "Gallery Blender r_0", "Gallery Error r_0", "Label r_1"} <= names
    assert f"PSNR {summary['views'][0]['psnr']:.2f} dB" in bpy.data.objects["Label r_0"].data.body
    # The file opens looking at the whole gallery, its images inside it (--images pack, the default).
    assert summary["images"] == "pack" and bpy.context.scene.camera.name == planes.GALLERY_CAMERA
    tiles = [o for o in gallery.objects if o.type == "MESH"]
    assert len(tiles) == 6 and all(i.packed_file is not None for i in bpy.data.images if i.name.startswith("r_"))
    for ob in tiles:
        for corner in ob.bound_box:
            ndc = world_to_camera_view(bpy.context.scene, bpy.context.scene.camera, ob.matrix_world @ Vector(corner))
            assert 0 < ndc.x < 1 and 0 < ndc.y < 1, ob.name

    # The camera layout carries a camera per test view, from renders.json alone: the scene's own
    # cameras are not in the file (capture.py does not save them), yet looking through the active
    # camera shows its plane over the frame. Images as paths relative to the .blend. The gallery's
    # renders are imported again (--renders), not rendered a second time.
    out = os.path.join(root, "compare_camera.blend")
    cmd = [sys.executable, os.path.join(repo_root, "scripts", "import_views.py"), "--blend", scene_blend,
           "--run", os.path.join(root, "run"), "--out", out, "--layout", "camera", "--images", "relative"]
    refused = subprocess.run(cmd + ["--renders", os.path.join(root, "run")], capture_output=True,
                             text=True, timeout=120)
    assert refused.returncode == 2 and "no renders.json" in refused.stderr and not os.path.exists(out)
    proc = subprocess.run(cmd + ["--renders", summary["render_dir"]], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "render views" not in proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1])["psnr"] == summary["psnr"]
    bpy.ops.wm.open_mainfile(filepath=out)
    scene = bpy.context.scene
    assert scene.camera.name == "NeRF Cam r_0" and (scene.render.resolution_x, scene.render.resolution_y) == (RES, RES)
    for name in ("r_0", "r_1"):
        ob, cam = bpy.data.objects[f"NeRF {name}"], bpy.data.objects[f"NeRF Cam {name}"]
        assert ob.parent == cam and ob["nerf_camera"] == cam.name
        img = ob.data.materials[0].node_tree.nodes["Image Texture"].image
        assert img.filepath.startswith("//run/views/test_") and os.path.isfile(bpy.path.abspath(img.filepath))
        uv = ob.data.uv_layers.active.data
        for loop in ob.data.loops:
            ndc = world_to_camera_view(scene, cam, ob.matrix_world @ ob.data.vertices[loop.vertex_index].co)
            assert (ndc.x, ndc.y) == pytest.approx(tuple(uv[loop.index].uv), abs=1e-4)


def test_cancel_stops_the_real_trainer_and_keeps_a_resumable_checkpoint(tmp_path, registered):
    root = str(tmp_path)
    s = bpy.context.scene.nerf_train
    s.dataset_dir, s.run_dir = tiny_capture(root), os.path.join(root, "run")
    # The job the Train button starts, minus the dataset check (the loop test above covers it).
    cmd = child_process.train_command(sys.executable, s.dataset_dir, s.run_dir, max_seconds=600)
    job = train_job.TrainJob(bpy.context.scene.name, sys.executable, s.dataset_dir, s.run_dir, cmd, check=False)
    jobs.add(train_ui.TRAIN, job)
    deadline = time.monotonic() + 180
    while job.stage != "train" or job.process.progress.step is None:  # the first step event
        assert job.update() == "running", job.message
        assert time.monotonic() < deadline, job.process.log_tail()
        time.sleep(0.1)
    pid = job.process.pid
    assert child_process.pid_alive(pid)
    assert bpy.ops.nerf.train_cancel() == {"FINISHED"}  # returns at once; the timer finishes the cancel
    deadline = time.monotonic() + 60
    while job.update() == "running":
        assert time.monotonic() < deadline
        time.sleep(0.1)
    train_ui.sync_train_settings(job)
    assert job.state == "cancelled" and not s.running and s.status.startswith("Training cancelled at step")
    assert not child_process.pid_alive(pid) and child_process.group_pids(pid) == []
    assert "checkpoint saved" in job.message
    assert runs.run_folder_state(s.run_dir) == "resumable"
