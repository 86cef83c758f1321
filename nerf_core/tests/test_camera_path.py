"""nerfstudio's camera_path.json: the same cameras as a transforms-style file give the same pixels;
other camera types and broken fields are refused with the file, camera and field named."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from nerf_core.cameras.camera_path import CameraPathError, cameras_from_camera_path
from nerf_core.cli.main import main
from nerf_core.image.io import read_png
from nerf_core.render.cameras import cameras_from_file
from nerf_core.tests.conftest import look_at

W, H = 20, 14
FOVS = (40.0, 55.0)  # vertical, degrees


def _poses():
    return [look_at((3.0 * math.cos(a), 3.0 * math.sin(a), 1.0)) for a in (0.3, 1.4)]


def _camera_path(**top) -> dict:
    return {"camera_type": "perspective", "render_height": H, "render_width": W, "fps": 24, "seconds": 1,
            "keyframes": [], "camera_path": [{"camera_to_world": m.reshape(-1).tolist(), "fov": fov, "aspect": W / H}
                                             for m, fov in zip(_poses(), FOVS)], **top}


def _transforms() -> list:
    """The same cameras as a JSON list of transforms-style cameras, intrinsics computed by hand."""
    out = []
    for m, fov in zip(_poses(), FOVS):
        f = (H / 2) / math.tan(math.radians(fov) / 2)  # vertical fov -> focal length in pixels
        out.append({"transform_matrix": m.tolist(), "fl_x": f, "fl_y": f, "cx": W / 2, "cy": H / 2, "w": W, "h": H})
    return out


def test_camera_path_reads_as_the_equivalent_cameras(tmp_path):
    p = tmp_path / "camera_path.json"
    p.write_text(json.dumps(_camera_path()))
    cams, stems = cameras_from_file(p)
    assert stems == ["frame_00000", "frame_00001"]
    f0 = (H / 2) / math.tan(math.radians(40.0) / 2)
    assert cams.fx[0].item() == pytest.approx(f0) and cams.fy[0].item() == pytest.approx(f0)
    assert (cams.cx[1].item(), cams.cy[1].item(), int(cams.width[1]), int(cams.height[1])) == (W / 2, H / 2, W, H)
    # Row-major: the translation is elements 3, 7, 11 of the flat list.
    assert cams.c2w[1, :3, 3].numpy() == pytest.approx(_poses()[1][:3, 3], abs=1e-6)


def test_render_of_a_camera_path_matches_the_transforms_file(tmp_path, trained_run):
    path = tmp_path / "camera_path.json"
    path.write_text(json.dumps(_camera_path()))
    listing = tmp_path / "cams.json"
    listing.write_text(json.dumps(_transforms()))
    run = str(trained_run["run"])
    assert main(["render", run, "--cameras", str(path), "--out", str(tmp_path / "a"), "--no-bar"]) == 0
    assert main(["render", run, "--cameras", str(listing), "--out", str(tmp_path / "b"), "--no-bar"]) == 0
    for k in range(2):
        a = read_png(tmp_path / "a" / f"frame_{k:05d}.png")
        b = read_png(tmp_path / "b" / f"view_{k:03d}.png")
        assert a.shape == (H, W, 4)
        assert np.array_equal(a, b)
        assert a[..., 3].max() > 0.5  # the sphere is in view: not two empty images


@pytest.mark.parametrize("kind", ["fisheye", "equirectangular", "omnidirectional", "vr180"])
def test_non_perspective_camera_types_are_refused(tmp_path, kind):
    with pytest.raises(
        CameraPathError, match=rf"camera_path.json: field 'camera_type' is '{kind}'; only 'perspective'"
    ):
        cameras_from_camera_path(_camera_path(camera_type=kind), tmp_path / "camera_path.json")


def test_missing_camera_type_means_perspective(tmp_path):
    data = _camera_path()
    del data["camera_type"]
    cams, _ = cameras_from_camera_path(data, tmp_path / "p.json")
    assert len(cams) == 2


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda d: d["camera_path"][1].update(fov=0),
            r"camera_path\[1\]: field 'fov' must be the vertical field of view",
        ),
        (
            lambda d: d["camera_path"][0].update(camera_to_world=[1, 0, 0]),
            r"camera_path\[0\]: field 'camera_to_world' must hold 16",
        ),
        (
            lambda d: d["camera_path"][0].update(camera_to_world=[2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 1]),
            r"camera_path\[0\]: field 'camera_to_world': rotation part is scaled",
        ),
        (lambda d: d.update(render_width=0), r"field 'render_width' must be a positive whole number"),
        (lambda d: d.update(render_height=12.5), r"field 'render_height' must be a positive whole number"),
        (lambda d: d.update(camera_path=[]), r"field 'camera_path' must be a non-empty list"),
    ],
)
def test_bad_fields_are_named(tmp_path, change, message):
    data = _camera_path()
    change(data)
    with pytest.raises(CameraPathError, match=message):
        cameras_from_camera_path(data, tmp_path / "p.json")


def test_cli_reports_a_bad_camera_path_in_one_line(tmp_path, trained_run, capsys):
    p = tmp_path / "camera_path.json"
    p.write_text(json.dumps(_camera_path(camera_type="fisheye")))
    assert main(["render", str(trained_run["run"]), "--cameras", str(p), "--out", str(tmp_path / "o"), "--no-bar"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nerf_core render: error: ") and "fisheye" in err[0]


def test_a_written_camera_path_reads_back_the_same_cameras_and_refuses_what_it_cannot_hold(tmp_path):
    from nerf_core.contract.camera_path import camera_path_document, path_range, path_views

    c2w = np.eye(4)
    c2w[:3, 3] = (1.0, 2.0, 3.0)
    views = [{"c2w": c2w, "fx": f, "fy": f, "cx": 20.0, "cy": 15.0, "w": 40, "h": 30, "label": f"frame {k}"}
             for k, f in enumerate((30.0, 45.5))]
    doc = camera_path_document(views, 24.0, clip=(0.1, 50.0))
    back = path_views(doc, tmp_path / "p.json")
    assert [v["fy"] for v in back] == pytest.approx([30.0, 45.5], rel=1e-12)
    assert np.array_equal(back[1]["c2w"], c2w) and path_range(doc, "p") == (0.1, 50.0)
    assert doc["seconds"] == pytest.approx(2 / 24.0)
    shifted = [dict(views[0], cx=21.0, label="frame 7"), dict(views[1], fy=44.0, label="frame 8")]
    with pytest.raises(CameraPathError, match=r"frame 7 have a lens shift.*frame 8 have non-square pixels"):
        camera_path_document(shifted, 24.0)
    with pytest.raises(CameraPathError, match="'far'"):
        path_range({"near": 2.0, "far": 1.0}, "p.json")


def test_a_written_fov_gives_back_the_renderers_float32_focal_length_exactly():
    """fov in degrees -> tan -> fy loses the last float64 bits; near a float32 rounding midpoint that
    flipped fy's float32 (the renderer's) in 656 of 20000 such focal lengths, and with it ray directions."""
    from nerf_core.contract.camera_path import camera_path_intrinsics, exact_fov_degrees, fov_degrees

    rng = np.random.default_rng(1)
    plain_off = 0
    for _ in range(2000):
        h = int(rng.integers(2, 4000))
        a = np.float32(rng.uniform(0.5, 50) * h)
        mid = (float(a) + float(np.nextafter(a, np.float32(np.inf)))) / 2  # a float32 rounding midpoint
        fy = mid + float(rng.integers(-3, 4)) * math.ulp(mid)
        plain_off += np.float32(camera_path_intrinsics(fov_degrees(fy, h), h, h)[1]) != np.float32(fy)
        assert np.float32(camera_path_intrinsics(exact_fov_degrees(fy, h), h, h)[1]) == np.float32(fy)
    assert plain_off > 0  # the case exists: without the correction these focal lengths came back changed


def test_nerfstudios_dataparser_transform_is_undone_exactly():
    from nerf_core.contract import nerfstudio_frame as nf

    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    transform = np.concatenate([rot, rng.normal(size=(3, 1))], 1)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = np.linalg.qr(rng.normal(size=(3, 3)))[0] * 1.0, (1.0, -2.0, 0.5)
    there = nf.to_nerfstudio_pose(pose, transform, 0.37)
    assert np.allclose(nf.to_dataset_pose(there, transform, 0.37), pose, atol=1e-12)
    pts = rng.normal(size=(5, 3))
    moved = (nf.dataset_to_nerfstudio_matrix(transform, 0.37) @ np.c_[pts, np.ones(5)].T).T[:, :3]
    assert np.allclose(nf.to_dataset_points(moved, transform, 0.37), pts, atol=1e-12)
    assert np.allclose(there[:3, 3], moved[0] * 0 + 0.37 * (rot @ pose[:3, 3] + transform[:, 3]))
