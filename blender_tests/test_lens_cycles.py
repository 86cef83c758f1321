"""nerf_core's OPENCV_FISHEYE model against Cycles' own equidistant fisheye: an independent check of
the lens maths (nerf_core/cameras/distortion.py), since Cycles traces its fisheye rays with code of its own."""
import math

import bpy
import numpy as np
import torch

from nerf_core.cameras.rays import Cameras, project_points, rays_for_pixels
from nerf_core.contract.lens import Lens
from nerf_core.image.io import read_exr_rgba

W, H, FOV = 160, 120, 3.0  # a 172-degree fisheye
# 12, 30, 80 and 63 degrees off the camera's axis (a pinhole of this width could not see the last two).
POINTS = [(0.0, 0.0, -5.0), (3.0, 1.0, -4.0), (-4.0, -2.5, -1.5), (2.0, 3.5, -1.0)]


def _scene(tmp_path):
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 16
    scene.cycles.device = "CPU"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = W, H, 100
    scene.render.filter_size = 0.01  # a point sample per pixel: the blob's centroid is the projection
    scene.render.image_settings.file_format = "OPEN_EXR"
    cam = bpy.data.objects.new("Fisheye", bpy.data.cameras.new("Fisheye"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.data.type = "PANO"
    cam.data.panorama_type = "FISHEYE_EQUIDISTANT"
    cam.data.fisheye_fov = FOV
    cam.location = (0.3, -0.2, 0.1)
    cam.rotation_euler = (0.2, -0.1, 0.3)
    world = bpy.data.worlds.new("Black")
    scene.world = world
    # A new world's Background node glows grey (5.x worlds always have nodes); only the spheres may light pixels.
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    spheres = []
    for k, p in enumerate(POINTS):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.02 * np.linalg.norm(p), location=p)
        ob = bpy.context.object
        mat = bpy.data.materials.new(f"glow{k}")
        nt = mat.node_tree
        nt.nodes.clear()
        emit, out = nt.nodes.new("ShaderNodeEmission"), nt.nodes.new("ShaderNodeOutputMaterial")
        emit.inputs["Strength"].default_value = 5.0
        nt.links.new(emit.outputs[0], out.inputs[0])
        ob.data.materials.append(mat)
        spheres.append(ob)
    return scene, cam, spheres


def test_cycles_equidistant_fisheye_is_opencv_fisheye_with_zero_coefficients(tmp_path):
    scene, cam, spheres = _scene(tmp_path)
    bpy.context.view_layer.update()
    c2w = np.array(cam.matrix_world.normalized())
    # Cycles maps each image axis on its own onto [-1, 1] of the fisheye's circle (the panorama's
    # viewplane is the unit square), so the focal lengths are w / fov and h / fov.
    cams = Cameras.create(c2w[None], W / FOV, H / FOV, W / 2, H / 2, W, H, lenses=[Lens("OPENCV_FISHEYE", (0.0,) * 6)])
    uv, _ = project_points(cams, 0, torch.tensor(POINTS, dtype=torch.float32))
    yy, xx = np.mgrid[0:H, 0:W]
    for k, ob in enumerate(spheres):
        for other in spheres:
            other.hide_render = other is not ob
        scene.render.filepath = str(tmp_path / f"blob{k}.exr")
        bpy.ops.render.render(write_still=True)
        lum = read_exr_rgba(scene.render.filepath)[..., :3].sum(-1)
        assert lum.sum() > 0, f"sphere {k} not in the picture"
        centroid = ((lum * (xx + 0.5)).sum() / lum.sum(), (lum * (yy + 0.5)).sum() / lum.sum())
        # A pinhole reading of the same camera is many pixels off away from the centre; 0.3 px is
        # what the blob's own sampling leaves.
        assert np.hypot(*(np.array(centroid) - uv[k].numpy())) < 0.3, (k, centroid, uv[k].tolist())
        # And the other way: the ray nerf_core casts through the blob's pixel passes the sphere's centre.
        i, j = int(uv[k, 0]), int(uv[k, 1])
        o, d, _ = rays_for_pixels(cams, torch.tensor([0]), torch.tensor([i]), torch.tensor([j]))
        to_point = torch.tensor(POINTS[k]) - o[0]
        angle = math.acos(float((d[0] @ to_point) / to_point.norm()))
        assert angle < 1.5 * FOV / W, (k, angle)  # within about a pixel's angle
