"""COLMAP both ways: ``export colmap`` of a capture, ``load_dataset`` of a COLMAP folder, and the files
agreeing with the official reader (pycolmap) when it is installed."""
from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nerf_core.contract import colmap_model as cm
from nerf_core.contract.colmap_dataset import camera_intrinsics, colmap_camera
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.lens import Lens
from nerf_core.contract.transforms import frame_infos
from nerf_core.export.colmap import export_colmap, project
from nerf_core.export.ply import write_mesh_ply

REPO = Path(__file__).resolve().parents[2]


def sphere_points(root: Path, n: int = 400, radius: float = 0.6) -> np.ndarray:
    """A capture's ``points3d.ply``: points on the test sphere's surface, with colours."""
    rng = np.random.default_rng(1)
    p = rng.normal(size=(n, 3))
    p = radius * p / np.linalg.norm(p, axis=1, keepdims=True)
    write_mesh_ply(root / "points3d.ply", p, np.zeros((0, 3), np.int64), (rng.random((n, 3)) * 255).astype(np.uint8))
    return p


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture
def exported(tmp_path, dataset_factory):
    """(dataset, colmap folder, summary) of a small capture with lens shift, depth and points."""
    base = tmp_path / "colmap"
    ds = dataset_factory(base / "ds", layouts=("synthetic",))
    sphere_points(ds)
    summary = export_colmap(ds, base / "out", splits=["train", "test"])
    return ds, base / "out", summary


def test_export_writes_the_layout_and_the_manifest(exported):
    ds, out, summary = exported
    for name in ("cameras", "images", "points3D"):
        for ext in (".bin", ".txt"):
            assert (out / "sparse" / "0" / f"{name}{ext}").is_file()
    assert summary["images"] == {"train": 8, "test": 2} and summary["cameras"] == 1
    assert 0 < summary["points"] <= 400 and summary["points"] + summary["dropped_points"] == 400
    man = json.loads((out / "nerf_bridge_colmap.json").read_text())
    assert man["normalization"] is None and man["splits"] == ["train", "test"] and man["source"] == str(ds)
    from PIL import Image

    im = np.asarray(Image.open(out / "images" / "train_r_0.png"))
    mask = np.asarray(Image.open(out / "masks" / "train_r_0.png"))
    assert im.shape[2] == 3 and mask.ndim == 2  # opaque RGB, grey mask
    assert (im[mask == 0] == 255).all()  # transparent film composited onto white
    assert not any(p.name.startswith(".") for p in out.parent.iterdir())  # no temporary folder left


def test_binary_and_text_agree_and_tracks_match_points2d(exported):
    _, out, _ = exported
    (tmp := out.parent / "txt_only").mkdir()
    for f in (out / "sparse" / "0").glob("*.txt"):
        (tmp / f.name).write_bytes(f.read_bytes())
    a, b = cm.read_model(out / "sparse" / "0"), cm.read_model(tmp)
    assert a.cameras.keys() == b.cameras.keys() and a.images.keys() == b.images.keys()
    for k in a.images:
        assert np.array_equal(a.images[k].qvec, b.images[k].qvec) and a.images[k].name == b.images[k].name
        assert np.array_equal(a.images[k].point3D_ids, b.images[k].point3D_ids)
    assert np.array_equal(a.points.xyz, b.points.xyz)
    train_ids = {i for i, im in a.images.items() if im.name.startswith("train_")}
    for pid, track in zip(a.points.ids, a.points.tracks):
        assert len(track)  # readers need non-empty tracks
        for iid, idx in track:
            assert int(iid) in train_ids and a.images[int(iid)].point3D_ids[idx] == pid


def test_points_reproject_onto_their_track_images(exported):
    """Each observation's stored pixel is the point's projection through that image's camera (< 1 px)."""
    _, out, _ = exported
    m = cm.read_model(out / "sparse" / "0")
    for pid, xyz, track in zip(m.points.ids, m.points.xyz, m.points.tracks):
        for iid, idx in track:
            im = m.images[int(iid)]
            cam = m.cameras[im.camera_id]
            x = cm.qvec_to_rotmat(im.qvec) @ xyz + im.tvec
            fx, fy, cx, cy = cam.params
            uv = np.array([cx + fx * x[0] / x[2], cy + fy * x[1] / x[2]])
            assert x[2] > 0 and np.abs(uv - im.xys[idx]).max() < 1e-6


def test_round_trip_poses_and_intrinsics(exported):
    """export -> read back as a dataset: the same poses (1e-6) and intrinsics (lens shift included)."""
    ds, out, _ = exported
    _, _, src, _ = frame_infos(ds)
    layout, _, back, scene = frame_infos(out)
    assert layout == "colmap"
    for split in ("train", "test"):
        assert [f.image.name for f in back[split]] == [f"{split}_{f.stem}.png" for f in src[split]]  # in order
        for a, b in zip(src[split], back[split]):
            assert np.abs(a.c2w - b.c2w).max() < 1e-6
            for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
                assert b.intrinsics[k] == pytest.approx(a.intrinsics[k], abs=1e-9)
    assert back["train"][0].intrinsics["cx"] != back["train"][0].intrinsics["w"] / 2  # the shift survived


def test_load_dataset_reads_a_colmap_folder(exported):
    import nerf_core

    src, out, _ = exported
    ds = nerf_core.load_dataset(out)
    assert ds.layout == "colmap" and len(ds.split("train")) == 8 and len(ds.split("test")) == 2
    # the capture's box, recorded as it was declared (not as our loader grew it: a round trip grows it once)
    assert np.allclose(ds.aabb.numpy(), nerf_core.load_dataset(src).aabb.numpy())
    assert np.allclose(ds.aabb.numpy(), [[-1.025] * 3, [1.025] * 3])
    # our export's masks are the film's alpha: the loader restores the RGBA film, which trains as the capture
    assert ds.film_transparent is True and ds.split("train").images.shape[-1] == 4
    orig = nerf_core.load_dataset(src).split("train")
    new = ds.split("train")
    assert torch.equal(orig.images[..., 3], new.images[..., 3])
    for bg in ([1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.2, 0.9, 0.4]):  # any background composites alike
        a, b = orig.image(0, torch.tensor(bg))[0], new.image(0, torch.tensor(bg))[0]
        assert float((a - b).abs().max()) <= 1.01 / 255


def test_foreign_model_splits_and_box_from_points(tmp_path, exported):
    """Without our manifest: every 8th image by name is held out (llffhold) and the box comes from the points."""
    _, out, _ = exported
    foreign = tmp_path / "foreign"
    (foreign / "sparse").mkdir(parents=True)
    for f in (out / "sparse" / "0").glob("*.bin"):
        (foreign / "sparse" / f.name).write_bytes(f.read_bytes())
    (foreign / "images").mkdir()
    for f in (out / "images").iterdir():
        (foreign / "images" / f.name).write_bytes(f.read_bytes())
    _, _, infos, scene = frame_infos(foreign)
    names = sorted(f.name for f in (out / "images").iterdir())
    assert [f.file_path for f in infos["test"]] == names[::8]
    assert [f.file_path for f in infos["val"]] == names[::8]
    lo, hi = np.asarray(scene["aabb"])
    assert (lo < -0.5).all() and (hi > 0.5).all() and (hi < 0.8).all()
    assert 0 < scene["near"] < 2.4 and scene["far"] > 3.6
    assert any("every 8th" in n for n in scene["notes"])


def test_pycolmap_reads_our_binary_model(exported):
    pycolmap = pytest.importorskip("pycolmap")
    _, out, _ = exported
    ours = cm.read_model(out / "sparse" / "0")
    rec = pycolmap.Reconstruction(str(out / "sparse" / "0"))
    assert set(rec.cameras) == set(ours.cameras) and set(rec.images) == set(ours.images)
    for cid, c in ours.cameras.items():
        assert rec.cameras[cid].model.name == c.model and rec.cameras[cid].width == c.width
        assert np.allclose(rec.cameras[cid].params, c.params, rtol=0, atol=1e-12)
    for iid, im in ours.images.items():
        theirs = rec.images[iid]
        pose = theirs.cam_from_world() if callable(theirs.cam_from_world) else theirs.cam_from_world
        qxyzw = np.asarray(pose.rotation.quat)  # pycolmap's order: x, y, z, w
        q = np.array([qxyzw[3], *qxyzw[:3]])
        assert np.allclose(q * np.sign(q[0]), im.qvec, atol=1e-12)
        assert np.allclose(pose.translation, im.tvec, atol=1e-12)
        assert theirs.name == im.name and theirs.camera_id == im.camera_id
        assert [p.point3D_id for p in theirs.points2D] == list(im.point3D_ids)
    assert set(rec.points3D) == set(int(i) for i in ours.points.ids)
    for pid, xyz, rgb, track in zip(ours.points.ids, ours.points.xyz, ours.points.rgb, ours.points.tracks):
        p = rec.points3D[int(pid)]
        assert np.allclose(p.xyz, xyz) and list(p.color) == list(rgb)
        assert sorted((e.image_id, e.point2D_idx) for e in p.track.elements) == sorted(map(tuple, track.tolist()))
    # and the other way: a model pycolmap writes reads back through our reader
    (out.parent / "pycolmap_txt").mkdir()
    rec.write_text(str(out.parent / "pycolmap_txt"))
    back = cm.read_model(out.parent / "pycolmap_txt")
    assert all(np.allclose(back.images[i].tvec, ours.images[i].tvec) for i in ours.images)


def test_camera_models_both_ways():
    lens = Lens("OPENCV", (0.1, -0.02, 0.0, 0.0, 0.001, -0.002))
    model, params = colmap_camera(30.0, 31.0, 12.5, 9.5, 24, 20, lens)
    assert model == "OPENCV" and params == (30.0, 31.0, 12.5, 9.5, 0.1, -0.02, 0.001, -0.002)
    intr, back = camera_intrinsics(cm.Camera(1, model, 24, 20, np.array(params)), "cameras.bin")
    assert back == lens and intr["fl_y"] == 31.0
    intr, back = camera_intrinsics(cm.Camera(2, "SIMPLE_RADIAL", 24, 20, np.array([30.0, 12, 10, 0.05])), "c")
    assert intr["fl_x"] == intr["fl_y"] == 30.0 and back.coeffs[0] == 0.05
    with pytest.raises(DatasetError, match="camera 3 has model FOV, which is not read"):
        camera_intrinsics(cm.Camera(3, "FOV", 24, 20, np.ones(5)), "cameras.bin")
    u, v, z = project(np.array([[0.0, 0.0, -2.0]]), np.eye(4), (30.0, 30.0, 12.0, 10.0, 24, 20), None)
    assert (u[0], v[0], z[0]) == (12.0, 10.0, 2.0)  # straight ahead along OpenGL's -z


def test_pose_conversion_is_exact_for_any_rotation():
    rng = np.random.default_rng(3)
    for _ in range(200):
        q = rng.normal(size=4)
        R = cm.qvec_to_rotmat(q)
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = R, rng.normal(size=3)
        qv, tv = cm.pose_to_colmap(c2w)
        assert np.abs(cm.pose_from_colmap(qv, tv) - c2w).max() < 1e-12


# -- bad input: one line naming the file and the camera or image -----------------------------------------
def _write(folder: Path, model, exts=(".bin",)) -> None:
    for name, data in cm.model_files_bytes(model, exts).items():
        (folder / name).write_bytes(data)


def _copy(out: Path, dst: Path) -> Path:
    (dst / "sparse" / "0").mkdir(parents=True)
    for f in (out / "sparse" / "0").glob("*.bin"):
        (dst / "sparse" / "0" / f.name).write_bytes(f.read_bytes())
    (dst / "images").mkdir()
    for f in (out / "images").iterdir():
        (dst / "images" / f.name).write_bytes(f.read_bytes())
    return dst


def test_truncated_bin_is_named(tmp_path, exported):
    d = _copy(exported[1], tmp_path / "t")
    f = d / "sparse" / "0" / "images.bin"
    f.write_bytes(f.read_bytes()[:-7])
    with pytest.raises(DatasetError, match=r"images\.bin: the file is truncated"):
        frame_infos(d)


def test_unknown_camera_model_id_is_named(tmp_path, exported):
    d = _copy(exported[1], tmp_path / "u")
    f = d / "sparse" / "0" / "cameras.bin"
    raw = bytearray(f.read_bytes())
    raw[12:16] = struct.pack("<i", 42)  # the first camera's model id
    f.write_bytes(bytes(raw))
    with pytest.raises(DatasetError, match=r"cameras\.bin: camera 1: unknown camera model id 42"):
        frame_infos(d)


def test_missing_image_and_missing_camera_and_nan_pose(tmp_path, exported):
    d = _copy(exported[1], tmp_path / "m")
    (d / "images" / "train_r_3.png").unlink()
    with pytest.raises(DatasetError, match=r"images\.bin: image \d+ \(train_r_3\.png\): its file .* not found"):
        frame_infos(d)
    m = cm.read_model(exported[1] / "sparse" / "0")
    d2 = _copy(exported[1], tmp_path / "c")
    m.images[1].camera_id = 9
    _write(d2 / "sparse" / "0", m)
    with pytest.raises(DatasetError, match=r"image 1 \(train_r_0\.png\) refers to camera 9, which cameras\.bin lacks"):
        frame_infos(d2)
    m.images[1].camera_id = 1
    m.images[1].tvec = np.array([np.nan, 0, 0])
    _write(d2 / "sparse" / "0", m)
    with pytest.raises(DatasetError, match=r"image 1 \(train_r_0\.png\): its pose .* is not finite"):
        frame_infos(d2)


def test_export_refuses_existing_output_and_the_dataset(tmp_path, exported):
    ds, out, _ = exported
    with pytest.raises(ValueError, match="exists and is not empty; pass --overwrite"):
        export_colmap(ds, out)
    with pytest.raises(ValueError, match="the export never writes there"):
        export_colmap(ds, ds / "colmap")
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    with pytest.raises(ValueError, match="symbolic link"):
        export_colmap(ds, tmp_path / "link")


def test_export_without_points_says_so(tmp_path, dataset_factory):
    ds = dataset_factory(tmp_path / "ds", n_train=3, n_val=1, n_test=1, layouts=("synthetic",), depth=False)
    notes = []
    s = export_colmap(ds, tmp_path / "out", on_note=notes.append)
    assert s["points"] == 0 and any("points3D is empty" in n and "3D Gaussian Splatting" in n for n in notes)
    assert cm.read_model(tmp_path / "out" / "sparse" / "0").points.ids.size == 0


def test_cli_export_colmap_and_its_errors(tmp_path, exported):
    ds = exported[0]
    env = {"PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    run = [sys.executable, "-m", "nerf_core", "export", "colmap", str(ds), "--out", str(tmp_path / "c"),
           "--splits", "train"]
    p = subprocess.run(run, capture_output=True, text=True, env=env, cwd=REPO)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout.strip().splitlines()[-1])["images"] == {"train": 8}
    p = subprocess.run(run, capture_output=True, text=True, env=env, cwd=REPO)
    assert p.returncode != 0 and "Traceback" not in p.stderr and "--overwrite" in p.stderr
    p = subprocess.run(run[:-1] + ["train,bogus"], capture_output=True, text=True, env=env, cwd=REPO)
    assert p.returncode == 2 and "choose among train, val, test" in p.stderr


def test_the_export_imports_without_torch():
    """Blender's Python has no torch: a capture's --colmap runs this same module there."""
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ImportError('torch blocked')\n"
            "sys.meta_path.insert(0, Block())\n"
            "import nerf_core.export.colmap\n"
            "assert 'torch' not in sys.modules\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_two_images_with_one_name_and_a_split_without_views(tmp_path, exported, dataset_factory):
    m = cm.read_model(exported[1] / "sparse" / "0")
    d = _copy(exported[1], tmp_path / "n")
    m.images[2].name = m.images[1].name
    _write(d / "sparse" / "0", m)
    with pytest.raises(DatasetError, match=r"images\.bin: images 1 and 2 have the same name 'train_r_0\.png'"):
        frame_infos(d)
    ds = dataset_factory(tmp_path / "noval", n_train=2, n_val=0, n_test=1, layouts=("synthetic",), depth=False)
    with pytest.raises(DatasetError, match=r"no frames in split\(s\) val to export"):
        export_colmap(ds, tmp_path / "o", splits=["val"])
    assert not (tmp_path / "o").exists()


def test_distorted_capture_projects_as_colmap_does(tmp_path, dataset_factory):
    """An OPENCV lens is written as COLMAP's OPENCV camera, and each stored 2D point is where COLMAP's
    own camera model puts the point (pycolmap's img_from_cam); the .txt twins read in pycolmap too."""
    pycolmap = pytest.importorskip("pycolmap")
    lens = {"camera_model": "OPENCV", "k1": -0.05, "k2": 0.01, "p1": 0.001, "p2": -0.002}
    ds = dataset_factory(tmp_path / "ds", n_train=4, n_val=1, n_test=1, layouts=("synthetic",), lens=lens)
    sphere_points(ds, n=150)
    export_colmap(ds, tmp_path / "out")
    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "sparse" / "0"))
    cam = rec.cameras[1]
    assert cam.model.name == "OPENCV" and np.allclose(cam.params[4:], [-0.05, 0.01, 0.001, -0.002])
    worst, n = 0.0, 0
    for pt in rec.points3D.values():
        for e in pt.track.elements:
            im = rec.images[e.image_id]
            pose = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
            uv = np.asarray(cam.img_from_cam(np.asarray(pose * pt.xyz)[None])).ravel()[:2]
            worst, n = max(worst, float(np.abs(uv - im.points2D[e.point2D_idx].xy).max())), n + 1
    assert n > 0 and worst < 1e-6
    txt = tmp_path / "txt"
    txt.mkdir()
    for f in (tmp_path / "out" / "sparse" / "0").glob("*.txt"):
        (txt / f.name).write_bytes(f.read_bytes())
    again = pycolmap.Reconstruction(str(txt))
    assert set(again.images) == set(rec.images) and len(again.points3D) == len(rec.points3D)


def test_check_reads_a_colmap_folder_by_the_loaders_rules(tmp_path, exported):
    """`check` of a COLMAP folder: no transforms-file conventions, but every problem train refuses."""
    from nerf_core.check.dataset import check_dataset

    assert check_dataset(exported[1]).ok
    d = _copy(exported[1], tmp_path / "k")
    (d / "images" / "train_r_2.png").unlink()
    report = check_dataset(d)
    assert not report.ok and "train_r_2.png" in report.format()


def test_overwrite_replaces_an_export_but_not_a_folder_of_other_files(tmp_path, exported):
    ds, out, _ = exported
    assert export_colmap(ds, out, splits=["train"], overwrite=True)["images"] == {"train": 8}
    assert not list((out / "images").glob("test_*"))  # the old export went, whole
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("x")
    with pytest.raises(ValueError, match=r"holds files an export does not write \(thesis\.tex\)"):
        export_colmap(ds, tmp_path / "mine", overwrite=True)
    assert (tmp_path / "mine" / "thesis.tex").read_text() == "x"


def test_load_dataset_of_a_foreign_model_holds_out_every_8th(tmp_path, exported):
    import nerf_core

    d = _copy(exported[1], tmp_path / "f")  # no manifest: a reconstruction of another tool
    ds = nerf_core.load_dataset(d)
    assert len(ds.split("test")) == 2 and len(ds.split("val")) == 2 and len(ds.split("train")) == 8
    assert ds.aabb_source.startswith("dataset (points3D.bin)")  # the box of the sparse points (then grown)


def test_a_mask_that_is_not_the_images_alpha_is_named(exported):
    import nerf_core
    from PIL import Image

    _, out, _ = exported
    Image.fromarray(np.zeros((5, 5), np.uint8)).save(out / "masks" / "train_r_1.png")
    with pytest.raises(DatasetError, match=r"masks/train_r_1\.png is not the 8-bit alpha of .*train_r_1\.png"):
        nerf_core.load_dataset(out)


def test_the_export_trains_as_its_capture(tmp_path, exported):
    """Equal steps, equal seed: training on the COLMAP folder scores what training on the capture does
    (the film restored, the frames in the capture's order). 33.45 dB both, vmgrid at 400 steps on 64 px."""
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds, out, _ = exported
    scores = []
    for src, run in ((ds, "r1"), (out, "r2")):
        summary = train(TrainConfig(dataset=str(src), out=str(tmp_path / run), method="test-grid", max_steps=20,
                                    batch_rays=256, seed=0, stdout_events=False, show_bar=False, eval_views=2))
        scores.append(summary["metrics"]["psnr"])
    assert scores[1] == pytest.approx(scores[0], abs=1e-4)
