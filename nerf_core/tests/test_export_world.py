"""Issue 57 part 4: the learned world as a Blender world (``export world``, ``nerf_core.export.world``).

The layout is Blender's equirectangular mapping, a mirror in longitude of the environment's own
texture; the values are the environment's, rounded as every render of a run is. The Blender side (the
world renders as the NeRF's background) is ``blender_tests/test_geometry_import.py``.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from nerf_core.cli.main import main
from nerf_core.contract import world_file
from nerf_core.contract.eight_bit import to_8bit
from nerf_core.export import run_export, world
from nerf_core.fields.environment import EnvironmentMap
from nerf_core.tests.conftest import use_model
from nerf_core.tests.test_export_mesh import SphereModel


def _env(width=16, seed=0):
    torch.manual_seed(seed)
    env = EnvironmentMap(width=width, levels=1)
    with torch.no_grad():
        env.textures[0].normal_(0.0, 2.0)
    return env


def _last(capsys):
    out = capsys.readouterr()
    return [json.loads(line) for line in out.out.strip().splitlines()], out.err.strip()


def test_blender_directions_follow_cycles_equirectangular_layout_by_hand():
    d = world.blender_directions(4)  # 4 x 2: u = 1/8, 3/8, 5/8, 7/8; polar angle pi/4, 3 pi/4
    assert d.shape == (2, 4, 3)
    s = math.sqrt(0.5)
    # longitude pi (1 - 2u): 3/4 pi, 1/4 pi, -1/4 pi, -3/4 pi; row 0 looks up
    assert torch.allclose(d[0, 1], torch.tensor([0.5, 0.5, s]), atol=1e-6)
    assert torch.allclose(d[0, 2], torch.tensor([0.5, -0.5, s]), atol=1e-6)
    assert torch.allclose(d[1, 0], torch.tensor([-0.5, 0.5, -s]), atol=1e-6)
    assert torch.allclose(d.norm(dim=-1), torch.ones(2, 4))


def test_the_world_image_is_the_environment_texture_mirrored_in_longitude():
    env = _env(16)
    img = world.world_image(env)
    tex = torch.sigmoid(env.textures[0].detach()).permute(1, 2, 0).numpy()  # (8, 16, 3), our own layout
    assert img.shape == (8, 16, 3) and img.dtype == np.uint8
    # at the texture's own width each pixel centre is a texel centre, mirrored: exact up to float error
    assert np.abs(img.astype(int) - to_8bit(tex[:, ::-1]).astype(int)).max() <= 1
    assert (img == to_8bit(tex[:, ::-1])).mean() > 0.99
    assert not np.array_equal(img, to_8bit(tex))  # the mirror matters
    assert world.world_image(env, 64).shape == (32, 64, 3)


def test_export_world_writes_a_png_that_says_what_it_is(monkeypatch, tmp_path, capsys):
    model = SphereModel()
    model.attach_environment(_env(32))
    use_model(monkeypatch, model)
    out = tmp_path / "w.png"
    assert main(["export", "world", "run", "--out", str(out)]) == 0
    events, _ = _last(capsys)
    summary = events[-1]
    assert summary["kind"] == "world" and summary["width"] == 32 and summary["height"] == 16
    assert summary["resolution"] is None
    assert any("no colour management" in n for n in summary["notes"])
    assert not any("not geometry" in n for n in summary["notes"])  # the world is what this export is
    image, info = world.read_world(out)
    assert np.array_equal(image, world.world_image(model.environment))
    assert info == {"version": 1, "color_management": {}}
    assert main(["export", "world", "run", "--out", str(tmp_path / "w2.png"), "--width", "8"]) == 0
    assert _last(capsys)[0][-1]["width"] == 8


def test_export_world_refuses_a_run_without_a_world_a_grid_size_and_another_suffix(monkeypatch, tmp_path, capsys):
    use_model(monkeypatch, SphereModel())
    out = tmp_path / "w.png"
    assert main(["export", "world", "run", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "learned no world" in err[0] and "Traceback" not in err[0]
    assert not out.exists()
    model = SphereModel()
    model.attach_environment(_env(16))
    use_model(monkeypatch, model)
    with pytest.raises(ValueError, match="--resolution: export world samples no grid.*--width"):
        run_export.export_run("world", "run", out, resolution=64)
    with pytest.raises(SystemExit):  # argparse: the world has no --resolution
        main(["export", "world", "run", "--out", str(out), "--resolution", "64"])
    capsys.readouterr()
    assert main(["export", "world", "run", "--out", str(tmp_path / "w.exr")]) == 2
    assert ".png" in capsys.readouterr().err
    assert main(["export", "world", "run", "--out", str(out), "--width", "1"]) == 2
    assert "--width 1" in capsys.readouterr().err
    assert not out.exists()


def test_the_world_file_reader_needs_no_pillow_and_refuses_other_pngs(tmp_path):
    from PIL import Image, PngImagePlugin

    path = tmp_path / "w.png"
    world.write_world(path, np.zeros((2, 4, 3), np.uint8), {"view_transform": "AgX"})
    assert world_file.read_world_info(str(path)) == {"version": 1, "color_management": {"view_transform": "AgX"}}
    plain = tmp_path / "plain.png"
    Image.new("RGB", (4, 2)).save(plain)
    with pytest.raises(ValueError, match="plain.png: not a world file written by `export world`"):
        world_file.read_world_info(str(plain))
    newer = tmp_path / "newer.png"
    info = PngImagePlugin.PngInfo()
    info.add_text(world_file.FORMAT_KEY, world_file.FORMAT)
    info.add_itxt("unrelated", "x", zip=True)
    info.add_text(world_file.VERSION_KEY, "9", zip=True)  # a zTXt chunk
    Image.new("RGB", (4, 2)).save(newer, pnginfo=info)
    with pytest.raises(ValueError, match="version 9, newer"):
        world_file.read_world_info(str(newer))
    cut = tmp_path / "cut.png"
    cut.write_bytes(path.read_bytes()[:40])
    with pytest.raises(ValueError, match="cut.png: .*truncated"):
        world_file.read_world_info(str(cut))
    text = tmp_path / "t.png"
    text.write_text("no png")
    with pytest.raises(ValueError, match="t.png: not a PNG file"):
        world_file.read_world_info(str(text))


# ----------------------------------------------------------------------------------------------
# An unbounded run's world beyond the box: the volume's far grids


class FloorModel(SphereModel):
    """A contracted run's field: the unit sphere in the box [-1, 1]^3 and a floor z < -0.9 to infinity."""

    contracted = True

    def density_at(self, pts):
        floor = 1e3 * (pts[:, 2] < -0.9).float()
        return torch.maximum(super().density_at(pts), floor)


def test_far_grids_nest_each_twice_the_last_and_count_no_place_twice():
    from nerf_core.export import volume

    model = FloorModel()
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    far = volume.far_grids(model, box, 2, 9)
    assert int(far["far_levels"]) == 2
    assert np.allclose(far["far1_box"], 2 * box) and np.allclose(far["far2_box"], 4 * box)
    assert np.allclose(far["far1_spacing"], 4 / 8) and np.allclose(far["far2_spacing"], 8 / 8)
    d1, d2 = far["far1_density"], far["far2_density"]
    # level 1's nodes at -2, -1.5, ..., 2: the seven in (-1, 1) on every axis lie in the box, and hold nothing
    assert d1[3:6, 3:6, 3:6].max() == 0 and d1.shape == (9, 9, 9)
    assert d1[0, 0, 0] == 1e3 and d1[4, 4, 1] == 1e3  # the floor outside the box (z = -1.5), and under it
    assert d2[3:6, 3:6, 3:6].max() == 0 and d2[0, 4, 0] == 1e3  # level 2 is empty inside level 1's box
    assert (far["far1_color"][d1 > 0] > 0).any(axis=-1).all()  # the floor is coloured where it is dense


def test_export_volume_of_an_unbounded_run_reaches_past_its_box(monkeypatch, tmp_path, capsys):
    from nerf_core.export import volume

    use_model(monkeypatch, FloorModel())
    out = tmp_path / "v.npz"
    assert main(["export", "volume", "run", "--out", str(out), "--resolution", "12"]) == 0
    summary = _last(capsys)[0][-1]
    assert summary["far_levels"] == volume.FAR_LEVELS
    assert any(f"reaches {2 ** volume.FAR_LEVELS} times the box" in n for n in summary["notes"])
    arrays = volume.read_volume(out)
    assert arrays["far4_density"].shape == (12, 12, 12) and np.allclose(arrays["far4_box"][1], 16.0)
    assert main(["export", "volume", "run", "--out", str(tmp_path / "v0.npz"), "--resolution", "12",
                 "--far-levels", "0"]) == 0
    summary = _last(capsys)[0][-1]
    assert summary["far_levels"] == 0 and any("covers the box only" in n for n in summary["notes"])
    assert "far1_density" not in volume.read_volume(tmp_path / "v0.npz")
    use_model(monkeypatch, SphereModel())  # a bounded run: no far grids unless asked
    assert main(["export", "volume", "run", "--out", str(tmp_path / "b.npz"), "--resolution", "12"]) == 0
    summary = _last(capsys)[0][-1]
    assert summary["far_levels"] == 0 and not any("beyond" in n for n in summary["notes"])
    arrays = dict(np.load(out))
    arrays.pop("far3_color")
    np.savez(tmp_path / "cut.npz", **arrays)
    with pytest.raises(ValueError, match="cut.npz: far level 3 of 4 is missing"):
        volume.read_volume(tmp_path / "cut.npz")
