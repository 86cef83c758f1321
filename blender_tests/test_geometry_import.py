"""Geometry back into Blender: the volume round trip (npz -> .vdb -> Volume object -> grids back,
equal) and the mesh import, each in its own collection and in the scene's frame."""
import os

import bpy
import numpy as np
import pytest

from addon.compare import geometry_import, volume_files


def _volume_npz(path, shape=(6, 7, 8)):
    rng = np.random.default_rng(0)
    density = rng.random(shape).astype(np.float32) * 50
    density[density < 20] = 0.0  # empty space, as a real volume has
    color = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    box = np.array([[-1.0, -0.5, 0.25], [1.0, 1.5, 2.0]])
    spacing = (box[1] - box[0]) / (np.array(shape) - 1)
    np.savez(path, density=density, color=color, box=box, spacing=spacing, level=np.float64(3.0),
             format=np.str_("nerf_bridge.volume"), version=np.int64(1))
    return density, color, box, spacing


def test_volume_round_trip_gives_the_grids_back_equal_in_the_scene_frame(tmp_path):
    npz = str(tmp_path / "volume.npz")
    density, color, box, spacing = _volume_npz(npz)
    obj = geometry_import.import_volume(bpy.context.scene, npz)
    assert obj.type == "VOLUME" and obj.users_collection[0].name == geometry_import.VOLUME_COLLECTION
    assert np.allclose(np.array(obj.matrix_world), np.eye(4))  # the scene frame: no transform of its own
    vol = obj.data
    assert os.path.isfile(bpy.path.abspath(vol.filepath))
    grids = {g.name: g for g in vol.grids}
    assert set(grids) == {"density", "color"}
    assert grids["density"].data_type == "FLOAT" and grids["color"].data_type == "VECTOR_FLOAT"
    m = np.array(grids["density"].matrix_object)  # index -> object space, as Blender read it
    assert np.allclose(m[:3, :3], np.diag(spacing), atol=1e-6) and np.allclose(m[:3, 3], box[0], atol=1e-6)
    back = volume_files.read_vdb(bpy.path.abspath(vol.filepath), density.shape, geometry_import.openvdb_dirs())
    assert np.array_equal(back["density"], density)
    assert np.allclose(back["color"], volume_files.srgb_to_linear(color / 255.0), atol=1e-6)
    restored = np.rint(volume_files.linear_to_srgb(back["color"]) * 255).astype(np.uint8)
    assert np.array_equal(restored, color)
    assert np.allclose(back["density_origin"], box[0]) and np.allclose(back["density_step"], spacing)
    # the material renders it as the NeRF does: absorption and emission, both from the density grid
    nodes = obj.data.materials[0].node_tree.nodes
    assert {n.type for n in nodes} >= {"VOLUME_ABSORPTION", "EMISSION", "ADD_SHADER", "ATTRIBUTE"}


def test_a_file_that_is_not_a_volume_export_is_refused(tmp_path):
    bad = tmp_path / "x.npz"
    np.savez(bad, a=np.zeros(3))
    with pytest.raises(volume_files.VolumeFileError, match="not a volume file"):
        geometry_import.import_volume(bpy.context.scene, str(bad))
    assert not (tmp_path / "x.vdb").exists()


def test_mesh_import_keeps_positions_and_colours_in_its_collection(tmp_path):
    from nerf_core.export.ply import write_mesh_ply

    v = np.array([[0.5, 1.0, 2.0], [1.5, 1.0, 2.0], [0.5, 2.0, 2.5]])
    c = np.array([[255, 0, 0], [0, 128, 0], [0, 0, 255]], dtype=np.uint8)
    write_mesh_ply(tmp_path / "m.ply", v, np.array([[0, 1, 2]]), c)
    obj = geometry_import.import_mesh(bpy.context.scene, str(tmp_path / "m.ply"))
    assert obj.users_collection[0].name == geometry_import.MESH_COLLECTION
    world = np.array([np.array(obj.matrix_world) @ [*p.co, 1.0] for p in obj.data.vertices])[:, :3]
    assert np.allclose(world, v, atol=1e-6)
    col = np.array([d.color for d in obj.data.color_attributes["Col"].data])[:, :3]
    assert np.allclose(col, volume_files.srgb_to_linear(c / 255.0), atol=2e-3)  # read as sRGB, stored linear
    assert obj.active_material is not None
