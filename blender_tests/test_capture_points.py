"""points3d.ply as 3D Gaussian Splatting reads it (plyfile: x y z nx ny nz red green blue), and the
manifest's record of the add-on's version.

The scene is one sphere, so the true outward normal at a surface point p is (p - centre) / radius:
the normals written must be unit length and point out of it, whichever way they were made (Cycles'
Normal pass, or Workbench's depth map, which has no normal pass).
"""
from __future__ import annotations

import json
import tomllib

import bpy
import numpy as np
import pytest
from plyfile import PlyData

from addon.capture.layout import positions
from addon.capture.run import job
from addon.capture.plan import settings as plan_settings
from addon.capture.layout import cameras

CENTRE, RADIUS = np.array([0.3, -0.2, 0.4]), 1.0
GS_PROPERTIES = ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]  # 3DGS fetchPly / storePly


def sphere_capture(out, engine):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=RADIUS, location=tuple(CENTRE), segments=64, ring_count=32)
    bpy.ops.object.shade_smooth()
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    bpy.context.scene.collection.objects.link(sun)
    scene = bpy.context.scene
    spec = positions.LayoutSpec(layout="sphere", train=4, val=0, test=1, radius=5.0, seed=2)
    cameras.create_cameras(scene, spec, 40, 40)
    settings = plan_settings.CaptureSettings(out_dir=str(out), engine=engine, samples=1, res_x=40,
                                             res_y=40, points=True,
                                       n_points=4000, layout=spec.to_dict())
    return job.CaptureJob(scene, settings).run()


@pytest.mark.parametrize("engine", ["cycles", "workbench"])
def test_point_cloud_normals_are_unit_and_point_out_of_the_surface(tmp_path, engine):
    out = tmp_path / "ds"
    assert sphere_capture(out, engine)["status"] == "complete"
    ply = PlyData.read(str(out / "points3d.ply"))
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == GS_PROPERTIES
    assert [vertex[c].dtype.kind for c in GS_PROPERTIES] == ["f"] * 6 + ["u"] * 3
    # What 3DGS's fetchPly does with them:
    pts = np.vstack([vertex["x"], vertex["y"], vertex["z"]]).T.astype(float)
    nrm = np.vstack([vertex["nx"], vertex["ny"], vertex["nz"]]).T.astype(float)
    assert len(pts) > 500
    np.testing.assert_allclose(np.linalg.norm(pts - CENTRE, axis=1), RADIUS, atol=0.03)  # on the sphere
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    outward = (pts - CENTRE) / np.linalg.norm(pts - CENTRE, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", nrm, outward)
    assert (cos > 0).all()  # every normal points out of the surface
    # and along the true normal: the Normal pass nearly exactly; depth differences within a few degrees
    assert np.median(cos) > (0.999 if engine == "cycles" else 0.99)
    assert (cos > np.cos(np.radians(25))).all()


def test_manifest_records_the_addon_version(tmp_path, repo_root):
    out = tmp_path / "ds"
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    scene = bpy.context.scene
    cameras.create_cameras(scene, positions.LayoutSpec(train=2, val=0, test=1), 16, 16)
    job.CaptureJob(scene, plan_settings.CaptureSettings(out_dir=str(out), engine="workbench", res_x=16, res_y=16)).run()
    with open(f"{repo_root}/addon/blender_manifest.toml", "rb") as fh:
        version = tomllib.load(fh)["version"]
    manifest = json.loads((out / "nerf_capture" / "manifest.json").read_text())
    assert manifest["addon_version"] == version and version.count(".") == 2


def test_the_occupancy_grid_carved_from_a_captures_depth_keeps_its_surface_and_little_else(tmp_path):
    """Issue 56, on a real capture (Workbench, 32 views of 64 px with depth and points): no point of the
    capture's points3d.ply lies in a cell that its depth marks empty at step 0, and the grid keeps less
    than twice the sphere's true volume (the shell of two cells around its surface is the rest)."""
    import torch

    from nerf_core import load_dataset
    from nerf_core.data.carving import free_cells

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=RADIUS, location=tuple(CENTRE), segments=64, ring_count=32)
    scene = bpy.context.scene
    spec = positions.LayoutSpec(layout="sphere", train=32, val=0, test=1, radius=5.0, seed=2)
    cameras.create_cameras(scene, spec, 64, 64)
    settings = plan_settings.CaptureSettings(out_dir=str(tmp_path / "ds"), engine="workbench", samples=1, res_x=64,
                                             res_y=64, points=True, depth=True, n_points=4000,
                                             layout=spec.to_dict())
    assert job.CaptureJob(scene, settings).run()["status"] == "complete"
    ds = load_dataset(tmp_path / "ds")
    train = ds.split("train")
    r = 48
    free = free_cells(ds.aabb, r, train, train.depth)
    pts = torch.as_tensor(np.vstack([PlyData.read(str(tmp_path / "ds" / "points3d.ply"))["vertex"][c]
                                     for c in "xyz"]).T, dtype=torch.float32)
    lo, hi = ds.aabb[0], ds.aabb[1]
    cell = ((pts - lo) / (hi - lo) * r).floor().long().clamp(0, r - 1)
    assert len(pts) > 500 and not free[cell[:, 0], cell[:, 1], cell[:, 2]].any()
    box_volume = float(torch.prod(hi - lo))
    sphere = 4 / 3 * np.pi * RADIUS ** 3 / box_volume
    kept = 1 - float(free.float().mean())
    assert sphere < kept < 2.0 * sphere, (kept, sphere)
