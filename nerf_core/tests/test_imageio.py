"""Which pass of a multilayer EXR is the colour, the depth and the normals (``nerf_core.image.io``).

Blender writes a multilayer EXR as ``ViewLayer.<Pass>.<channel>``: Blender 4 in one part with the
channels sorted by name (``ViewLayer.AO.R`` before ``ViewLayer.Combined.R``), Blender 5 in one part
per pass. Both layouts are built here with OpenEXR, with an ambient-occlusion pass that sorts (or
comes) first, which was read as the image before.
"""
import numpy as np
import OpenEXR
import pytest

from nerf_core.errors import ImageReadError
from nerf_core.image.io import read_depth, read_exr_rgba, read_normals

H, W = 3, 4


def _full(v):
    return np.full((H, W), v, dtype=np.float32)


# Pass -> channels, as Blender names them; every value tells the passes apart.
PASSES = {
    "AO": {"R": _full(0.25), "G": _full(0.25), "B": _full(0.25)},
    "Combined": {"R": _full(0.9), "G": _full(0.5), "B": _full(0.1), "A": _full(0.75)},
    "Depth": {"Z": _full(3.5)},
    "Diffuse Color": {"R": _full(0.6), "G": _full(0.6), "B": _full(0.6)},
    "Normal": {"X": _full(0.0), "Y": _full(1.0), "Z": _full(0.0)},
}


def _write(path, passes, multipart, view_layers=("ViewLayer",)):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if multipart:  # Blender 5: one part per pass, the AO part first here
        parts = [OpenEXR.Part(dict(header), {f"{vl}.{p}.{c}": v for c, v in chans.items()}, f"{vl}.{p}")
                 for vl in view_layers for p, chans in passes.items()]
        with OpenEXR.File(parts) as f:
            f.write(str(path))
    else:  # Blender 4: one part, the channels sorted by name
        chans = {f"{vl}.{p}.{c}": v for vl in view_layers for p, cs in passes.items() for c, v in cs.items()}
        with OpenEXR.File(header, dict(sorted(chans.items()))) as f:
            f.write(str(path))
    return path


@pytest.mark.parametrize("multipart", [False, True], ids=["blender4_one_part", "blender5_part_per_pass"])
def test_the_combined_pass_is_the_colour_whatever_sorts_first(tmp_path, multipart):
    path = _write(tmp_path / "r_0.exr", PASSES, multipart)
    rgba = read_exr_rgba(path)
    assert rgba.shape == (H, W, 4)
    assert np.allclose(rgba[0, 0], [0.9, 0.5, 0.1, 0.75])  # not the AO's 0.25, and the Combined alpha
    assert np.allclose(read_depth(path), 3.5)  # the Depth pass, not Normal.Z (0)
    assert np.allclose(read_normals(path)[0, 0], [0.0, 1.0, 0.0])


def test_one_colour_layer_of_another_name_is_still_the_colour(tmp_path):
    path = _write(tmp_path / "r_0.exr", {"Noisy Image": PASSES["Combined"]}, multipart=False)
    assert np.allclose(read_exr_rgba(path)[0, 0], [0.9, 0.5, 0.1, 0.75])


def test_plain_channels_come_before_any_layer(tmp_path):
    path = tmp_path / "plain.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    chans = {"R": _full(0.2), "G": _full(0.3), "B": _full(0.4), "A": _full(1.0), "Z": _full(2.0),
             "ViewLayer.AO.R": _full(0.25), "ViewLayer.AO.G": _full(0.25), "ViewLayer.AO.B": _full(0.25)}
    with OpenEXR.File(header, dict(sorted(chans.items()))) as f:
        f.write(str(path))
    assert np.allclose(read_exr_rgba(path)[0, 0], [0.2, 0.3, 0.4, 1.0])
    assert np.allclose(read_depth(path), 2.0)


def test_two_view_layers_are_named_not_guessed(tmp_path):
    path = _write(tmp_path / "r_0.exr", PASSES, multipart=True, view_layers=("Front", "Back"))
    with pytest.raises(ImageReadError, match=r"colour in several layers \(Back.Combined, Front.Combined\)"):
        read_exr_rgba(path)


def test_several_passes_and_no_combined_are_named(tmp_path):
    path = _write(tmp_path / "r_0.exr", {k: PASSES[k] for k in ("AO", "Diffuse Color")}, multipart=False)
    with pytest.raises(ImageReadError, match=r"ViewLayer.AO, ViewLayer.Diffuse Color\) and none is the Combined"):
        read_exr_rgba(path)


# ---------------------------------------------------------------------------------------------- other files


@pytest.mark.parametrize("mode", ["RGB", "L"])
def test_a_trns_colour_in_an_rgb_or_grey_png_is_alpha(tmp_path, mode):
    from PIL import Image

    from nerf_core.image.io import read_png

    px = np.zeros((H, W, 3) if mode == "RGB" else (H, W), np.uint8)
    px[0, 0] = 200  # one opaque pixel; the black rest is the transparent colour
    path = tmp_path / "cut.png"
    Image.fromarray(px, mode).save(path, transparency=(0, 0, 0) if mode == "RGB" else 0)
    arr = read_png(path)
    assert arr.shape == (H, W, 4)
    assert arr[0, 0, 3] == 255 and (arr[..., 3] == 0).sum() == H * W - 1


def test_an_8_bit_depth_png_is_refused_as_a_picture_of_depth(tmp_path):
    from PIL import Image

    path = tmp_path / "d.png"
    Image.fromarray(np.full((H, W), 128, np.uint8)).save(path)
    with pytest.raises(ImageReadError, match="8-bit depth PNG .* visualisation"):
        read_depth(path)
    Image.fromarray(np.full((H, W), 2500, np.uint16)).save(path)  # 16-bit millimetres stay depth
    assert np.allclose(read_depth(path), 2.5)


def test_npy_depth_is_read_without_unpickling_and_bad_ones_are_named(tmp_path):
    np.save(tmp_path / "d.npy", np.full((H, W, 1), 2500.0))
    assert read_depth(tmp_path / "d.npy").shape == (H, W) and np.allclose(read_depth(tmp_path / "d.npy"), 2.5)
    assert np.allclose(read_depth(tmp_path / "d.npy", png_scale=1.0), 2500.0)
    # an array of objects would unpickle, which runs code: refused, never loaded
    np.save(tmp_path / "o.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ImageReadError, match="o.npy: .*holds Python objects"):
        read_depth(tmp_path / "o.npy")
    np.save(tmp_path / "rgb.npy", np.zeros((H, W, 3)))
    with pytest.raises(ImageReadError, match=r"rgb.npy: a depth .npy must be a \(height, width\) array"):
        read_depth(tmp_path / "rgb.npy")
    np.savez(tmp_path / "z.npz", depth=np.zeros((H, W)))
    (tmp_path / "z.npz").rename(tmp_path / "z.npy")
    with pytest.raises(ImageReadError, match="z.npy: not a .npy array \\(a .npz archive\\)"):
        read_depth(tmp_path / "z.npy")
    (tmp_path / "t.npy").write_bytes((tmp_path / "d.npy").read_bytes()[:90])  # cut inside its header
    with pytest.raises(ImageReadError, match="t.npy: cannot read depth .npy"):
        read_depth(tmp_path / "t.npy")
    with open(tmp_path / "huge.npy", "wb") as fh:  # a header claiming 60000 x 60000, and no values
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (60000, 60000)})
    with pytest.raises(ImageReadError, match="huge.npy: cannot read depth .npy"):
        read_depth(tmp_path / "huge.npy")


def test_an_exr_header_claiming_a_huge_image_is_refused_before_reading(tmp_path):
    import struct

    path = _write(tmp_path / "r_0.exr", {"Combined": PASSES["Combined"]}, multipart=False)
    data = bytearray(path.read_bytes())
    for name in (b"dataWindow\x00box2i\x00", b"displayWindow\x00box2i\x00"):
        at = data.index(name) + len(name) + 4  # after the attribute's size
        data[at:at + 16] = struct.pack("<iiii", 0, 0, 59999, 59999)  # 60000 x 60000: 54 GiB of float32
    path.write_bytes(bytes(data))
    with pytest.raises(ImageReadError, match="header claims 14400 million values"):
        read_exr_rgba(path)


def test_without_openexr_an_exr_is_named_in_one_line_not_a_traceback(tmp_path, monkeypatch):
    import sys

    from nerf_core.image.io import read_exr, write_exr

    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # as if the package were not installed
    path = tmp_path / "d.exr"
    with pytest.raises(ImageReadError, match=r"d\.exr: writing an EXR needs the OpenEXR package.*pip install"):
        write_exr(path, {"Z": _full(1.0)})
    path.write_bytes(b"not read")
    with pytest.raises(ImageReadError, match=r"d\.exr: reading an EXR needs the OpenEXR package"):
        read_exr(path)


def test_check_without_openexr_names_the_depth_file(sphere_dataset):
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys; sys.modules['OpenEXR'] = None; from nerf_core.cli.main import main; "
            "sys.exit(main(['check', sys.argv[1], '--for-training']))")
    repo = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, "-c", code, str(sphere_dataset)], capture_output=True, text=True,
                          timeout=120, cwd=repo)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "Traceback" not in out
    assert "needs the OpenEXR package" in out and ".exr" in out


def test_values_near_an_8_bit_edge_move_clear_of_it_to_the_level_write_png_gives():
    """The render engine's colours pass Blender's approximate colour round trip (off by up to 0.0024
    levels): moved at least EDGE_MARGIN levels from every half-level edge, they round as write_png does."""
    from nerf_core.contract.eight_bit import EDGE_MARGIN, clear_of_8bit_edges, to_8bit

    k = np.arange(256, dtype=np.float64)[:, None]
    offsets = np.array([-0.02, -EDGE_MARGIN, -1e-3, -1e-6, 0.0, 1e-6, 1e-3, EDGE_MARGIN, 0.02])
    v = np.clip((k + 0.5 + offsets) / 255.0, 0.0, 1.0).astype(np.float32)
    v = np.concatenate([v.ravel(), [np.nan, -1.0, 2.0, 0.0, 1.0]]).astype(np.float32)
    out = clear_of_8bit_edges(v)
    assert out.dtype == np.float32 and np.array_equal(to_8bit(out), to_8bit(v))
    x = out.astype(np.float64) * 255.0
    edge = np.abs(x - np.round(x - 0.5) - 0.5)  # distance to the nearest half-level edge, in levels
    inside = (x > 0.5) & (x < 254.5)
    assert edge[inside].min() >= EDGE_MARGIN - 2e-5  # float32 steps near 1 are 1.5e-5 levels
    far = np.abs(np.nan_to_num(v) * 255.0 - np.round(np.nan_to_num(v) * 255.0 - 0.5) - 0.5) > EDGE_MARGIN
    assert np.array_equal(out[far & (v >= 0) & (v <= 1)], v[far & (v >= 0) & (v <= 1)])  # others untouched
    assert np.abs(out - np.clip(np.nan_to_num(v), 0, 1)).max() <= EDGE_MARGIN / 255.0 * 1.001
