"""Dataset loading round trips (both layouts, PNG/EXR, depth, masks) and every bad-input error."""
import json

import numpy as np
import pytest
import torch
from PIL import Image

from nerf_core.contract.errors import DatasetError
from nerf_core.data.loading import load_cameras, load_dataset
from nerf_core.image.io import read_exr


def _meta(ds, split="train"):
    return json.loads((ds / f"transforms_{split}.json").read_text())


def _write_meta(ds, meta, split="train"):
    (ds / f"transforms_{split}.json").write_text(json.dumps(meta))


def test_synthetic_round_trip(sphere_dataset):
    ds = load_dataset(sphere_dataset)
    assert ds.layout == "synthetic"
    assert {k: len(v) for k, v in ds.splits.items()} == {"train": 8, "val": 1, "test": 2}
    tr = ds.splits["train"]
    meta = _meta(sphere_dataset)
    # Stored once, as uint8 RGBA: no float copies of every image.
    assert tr.images.dtype == torch.uint8 and tr.images.shape == (8, 20, 24, 4)
    assert float(tr.cameras.cx[0]) == pytest.approx(meta["cx"]) and float(tr.cameras.cy[3]) == pytest.approx(meta["cy"])
    assert float(tr.cameras.fx[0]) == pytest.approx(meta["fl_x"], rel=1e-6)
    np.testing.assert_allclose(tr.cameras.c2w[2].numpy(), np.array(meta["frames"][2]["transform_matrix"]), atol=1e-6)
    # the declared box, grown so that surfaces on its faces lie inside it (``scene_box.pad_box_for_faces``)
    assert np.allclose(ds.aabb.numpy(), [[-1.025] * 3, [1.025] * 3]) and (ds.near, ds.far) == (1.0, 5.0)
    assert "surfaces on its faces" in ds.aabb_source
    z = read_exr(sphere_dataset / "train" / "r_1_depth.exr")["Z"]
    np.testing.assert_allclose(tr.depth[1].numpy(), z)
    png = np.asarray(Image.open(sphere_dataset / "train" / "r_1.png"))
    rgb, alpha = tr.image(1, (1.0, 1.0, 1.0))
    np.testing.assert_allclose(alpha.numpy(), png[..., 3] / 255.0)
    transparent = png[..., 3] == 0
    assert transparent.any() and (~transparent).any()
    assert torch.all(rgb[torch.from_numpy(transparent)] == 1.0)  # composited onto white
    np.testing.assert_allclose(rgb[torch.from_numpy(~transparent)].numpy(), png[~transparent][:, :3] / 255.0, atol=1e-6)
    # Per-batch compositing onto a random background gives the same answer as the full image.
    v, j, i = torch.tensor([1, 1]), torch.tensor([0, 10]), torch.tensor([0, 12])
    bg = torch.tensor([[0.2, 0.3, 0.4], [0.9, 0.1, 0.5]])
    px, a = tr.pixels(v, j, i, bg)
    full, _ = tr.image(1, (0.2, 0.3, 0.4))
    np.testing.assert_allclose(px[0].numpy(), full[0, 0].numpy(), atol=1e-6)


def test_nerfstudio_layout_matches_synthetic(tmp_path, dataset_factory):
    syn = load_dataset(dataset_factory(tmp_path / "a", layouts=("synthetic",)))
    ns = load_dataset(dataset_factory(tmp_path / "b", layouts=("nerfstudio",)))
    assert ns.layout == "nerfstudio"
    for name in ("train", "val", "test"):
        a, b = syn.splits[name], ns.splits[name]
        assert len(a) == len(b)
        np.testing.assert_allclose(a.cameras.c2w.numpy(), b.cameras.c2w.numpy())
        for f in ("fx", "fy", "cx", "cy"):
            np.testing.assert_allclose(getattr(a.cameras, f).numpy(), getattr(b.cameras, f).numpy(), rtol=1e-6)
        assert torch.equal(a.images, b.images) and torch.equal(a.depth, b.depth)


def test_frame_intrinsics_that_contradict_the_top_level_are_named(tmp_path, dataset_factory):
    # instant-ngp takes a frame's own fl_x, nerfstudio's parser the top level's for every frame: one
    # file, two cameras, and train said nothing about which it used.
    ds = dataset_factory(tmp_path / "ns", layouts=("nerfstudio",))
    assert not any("beside the top-level one" in n for n in load_dataset(ds).notes)
    path = ds / "transforms.json"
    meta = json.loads(path.read_text())
    top = meta["fl_x"]
    for fr in meta["frames"]:
        fr["fl_x"] = top * 1.5
    path.write_text(json.dumps(meta))
    loaded = load_dataset(ds)
    note = next(n for n in loaded.notes if "beside the top-level one" in n)
    assert "'fl_x'" in note and "nerfstudio's parser uses the top-level value" in note
    assert float(loaded.splits["train"].cameras.fx[0]) == pytest.approx(top * 1.5)  # the frame's own, as said


def test_nerfstudio_without_split_lists_holds_out_every_eighth(tmp_path, dataset_factory):
    ds_path = dataset_factory(tmp_path / "ns", n_train=14, n_val=1, n_test=1, layouts=("nerfstudio",))
    meta = json.loads((ds_path / "transforms.json").read_text())
    for key in ("train_filenames", "val_filenames", "test_filenames"):
        del meta[key]
    # Per-frame intrinsics override the global ones.
    meta["frames"][5]["fl_x"] = 99.0  # train/r_5.png: sorted position 10, not held out
    (ds_path / "transforms.json").write_text(json.dumps(meta))
    ds = load_dataset(ds_path)
    names = sorted(f["file_path"] for f in meta["frames"])
    held = {names[k] for k in range(0, 16, 8)}
    assert {str(f.file_path) for f in ds.splits["test"].frames} == held
    assert not held & {f.file_path for f in ds.splits["train"].frames}
    assert len(ds.splits["train"]) == 14
    assert any("every 8th" in n for n in ds.notes)
    by_name = {f.file_path: k for k, f in enumerate(ds.splits["train"].frames)}
    k = by_name[meta["frames"][5]["file_path"]]
    assert float(ds.splits["train"].cameras.fx[k]) == pytest.approx(99.0)
    assert float(ds.splits["train"].cameras.fx[(k + 1) % 14]) == pytest.approx(meta["fl_x"])


def test_exr_images_and_png_depth_in_millimetres(tmp_path, dataset_factory):
    ds_path = dataset_factory(tmp_path / "exr", exr_images=True, layouts=("nerfstudio",))
    ds = load_dataset(ds_path)
    tr = ds.splits["train"]
    assert tr.images.dtype == torch.float32 and tr.has_alpha
    # Replace one depth by a 16-bit PNG in millimetres (nerfstudio's convention).
    meta = json.loads((ds_path / "transforms.json").read_text())
    fr = meta["frames"][0]
    z = read_exr(ds_path / fr["depth_file_path"])["Z"]
    Image.fromarray(np.round(z * 1000).astype(np.uint16)).save(ds_path / "d0.png")
    fr["depth_file_path"] = "d0.png"
    (ds_path / "transforms.json").write_text(json.dumps(meta))
    ds2 = load_dataset(ds_path)
    np.testing.assert_allclose(ds2.splits["train"].depth[0].numpy(), z, atol=6e-4)
    # instant-ngp says how many metres one count is (integer_depth_scale); it was read as millimetres.
    scale = 8 / 65535
    Image.fromarray(np.round(z / scale).astype(np.uint16)).save(ds_path / "d0.png")
    (ds_path / "transforms.json").write_text(json.dumps({**meta, "integer_depth_scale": scale}))
    np.testing.assert_allclose(load_dataset(ds_path).splits["train"].depth[0].numpy(), z, atol=scale)
    # nerfstudio also reads .npy depth, scaled like its PNGs (depth_unit_scale_factor, 1e-3 by default);
    # it was refused as "cannot identify image file".
    np.save(ds_path / "d0.npy", z * 1000)
    fr["depth_file_path"] = "d0.npy"
    (ds_path / "transforms.json").write_text(json.dumps(meta))
    np.testing.assert_allclose(load_dataset(ds_path).splits["train"].depth[0].numpy(), z, rtol=1e-6)
    np.save(ds_path / "d0.npy", z[:, :-1])  # the wrong size is named like any other depth map's
    with pytest.raises(DatasetError, match=r"field 'depth_file_path': .*d0.npy is 23x20, image is 24x20"):
        load_dataset(ds_path)


def test_masks_black_means_ignore(sphere_dataset):
    meta = _meta(sphere_dataset)
    mask = np.full((20, 24), 255, np.uint8)
    mask[:, :12] = 0
    Image.fromarray(mask).save(sphere_dataset / "mask0.png")
    meta["frames"][0]["mask_path"] = "mask0.png"
    _write_meta(sphere_dataset, meta)
    tr = load_dataset(sphere_dataset).splits["train"]
    assert tr.masks.dtype == torch.bool
    seen = tr.images[0, :, :12, 3] > 0  # the sphere's pixels in the masked-out columns
    assert seen.any() and (~seen).any()
    assert not tr.masks[0, :, :12][seen].any() and tr.masks[0, :, 12:].all() and tr.masks[1].all()
    # A transparent pixel shows empty space whatever the mask says: it still teaches free space.
    assert tr.masks[0, :, :12][~seen].all()


def test_downscale_halves_images_and_intrinsics(sphere_dataset):
    full = load_dataset(sphere_dataset).splits["train"]
    half = load_dataset(sphere_dataset, downscale=2).splits["train"]
    assert half.images.shape == (8, 10, 12, 4) and half.depth.shape == (8, 10, 12)
    assert float(half.cameras.cx[0]) == pytest.approx(float(full.cameras.cx[0]) / 2)
    assert float(half.cameras.fx[0]) == pytest.approx(float(full.cameras.fx[0]) / 2)


@pytest.mark.parametrize("declared", [True, False], ids=["w_h_given", "camera_angle_x_only"])
def test_downscale_by_a_factor_that_does_not_divide_the_size_keeps_the_cameras(tmp_path, dataset_factory, declared):
    # The loader crops 35x27 to 32x24 and box-filters by 4, so pixel u of the result averages file
    # pixels [4u, 4u + 4): every intrinsic divides by 4. Scaling by (35 // 4) / 35 instead put cx at
    # 4.0 rather than 4.375, and with w/h given made square pixels non-square (fx 11.1, fy 10.8).
    ds = dataset_factory(tmp_path / "odd", w=35, h=27, layouts=("synthetic",))
    if not declared:
        for split in ("train", "val", "test"):
            path = ds / f"transforms_{split}.json"
            meta = json.loads(path.read_text())
            for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
                meta.pop(key, None)
            path.write_text(json.dumps(meta))
    full = load_dataset(ds).splits["train"].cameras
    quarter = load_dataset(ds, downscale=4).splits["train"]
    assert quarter.images.shape[1:3] == (6, 8)
    for name in ("fx", "fy", "cx", "cy"):
        assert float(getattr(quarter.cameras, name)[0]) == pytest.approx(float(getattr(full, name)[0]) / 4), name
    # render --downscale 4 of the same cameras: eval's sizes and cameras, so its metrics line up
    rendered = full.downscaled(4)
    assert (int(rendered.width[0]), int(rendered.height[0])) == (8, 6)
    assert float(rendered.cx[0]) == pytest.approx(float(quarter.cameras.cx[0]))


def test_missing_aabb_is_estimated_with_a_note(tmp_path, dataset_factory):
    ds = load_dataset(dataset_factory(tmp_path / "noaabb", aabb=False))
    assert "no 'aabb'" in ds.aabb_source and ds.notes
    lo, hi = ds.aabb
    assert torch.all(lo < -0.6) and torch.all(hi > 0.6)  # the sphere (radius 0.6) is inside
    assert torch.all(hi - lo < 6.0)  # and it does not swallow the cameras (radius 3)
    cams, frames = load_cameras(tmp_path / "noaabb", "test")
    assert len(frames) == 2 and int(cams.width[0]) == 24


# ---------------------------------------------------------------- bad input


def _expect(ds_path, *names, **kw):
    with pytest.raises(DatasetError) as info:
        load_dataset(ds_path, **kw)
    msg = str(info.value)
    for n in names:
        assert n in msg, msg
    return msg


def test_missing_image_names_file_and_frame(sphere_dataset):
    (sphere_dataset / "train" / "r_3.png").unlink()
    _expect(sphere_dataset, "transforms_train.json", "frame 3", "r_3", "file_path")


@pytest.mark.parametrize("change, hint", [
    ("upper_case", "r_1.PNG exists there (file names are case-sensitive)"),
    ("jpg", "r_1.jpg exists there: write the file name with its extension"),
    ("backslash", "written with '\\'"),
    ("folder", "is a folder, not a file"),
    ("dangling_link", "is a link to"),
    ("names_its_folder", "train.png not found; train there is a folder: file_path must name an image in it"),
])
def test_a_missing_image_says_what_is_there_instead(sphere_dataset, change, hint):
    meta = _meta(sphere_dataset)
    image = sphere_dataset / "train" / "r_1.png"
    if change == "upper_case":
        image.rename(image.with_name("r_1.PNG"))
    elif change == "jpg":
        image.rename(image.with_name("r_1.jpg"))
    elif change == "backslash":
        meta["frames"][1]["file_path"] = ".\\train\\r_1"
        _write_meta(sphere_dataset, meta)
    elif change == "folder":
        image.unlink()
        image.mkdir()
    elif change == "names_its_folder":  # "./train": the split's folder, which the extension hint misread
        meta["frames"][1]["file_path"] = "./train"
        _write_meta(sphere_dataset, meta)
    else:
        image.unlink()
        image.symlink_to(sphere_dataset / "gone.png")
    msg = _expect(sphere_dataset, "frame 1", "file_path")
    assert hint in msg, msg


def test_nerfstudio_with_only_train_filenames_says_nothing_is_evaluated(tmp_path, dataset_factory):
    ds = dataset_factory(tmp_path / "ns", layouts=("nerfstudio",))
    path = ds / "transforms.json"
    meta = json.loads(path.read_text())
    names = [f["file_path"] for f in meta["frames"]]
    for key in ("val_filenames", "test_filenames"):
        meta.pop(key, None)
    meta["train_filenames"] = names[:-1]
    path.write_text(json.dumps(meta))
    loaded = load_dataset(ds)
    assert len(loaded.splits["train"]) == len(names) - 1
    assert any("nothing is evaluated" in n and "1 frame(s) in no list" in n for n in loaded.notes), loaded.notes


def test_unreadable_image_is_named(sphere_dataset):
    (sphere_dataset / "test" / "r_1.png").write_bytes(b"\x89PNG garbage")
    _expect(sphere_dataset, "transforms_test.json", "frame 1", "r_1.png", "cannot read")


def test_images_of_different_sizes_in_one_split(sphere_dataset):
    Image.new("RGBA", (12, 10)).save(sphere_dataset / "train" / "r_2.png")
    _expect(sphere_dataset, "frame 2", "r_2.png", "12x10", "24x20")


@pytest.mark.parametrize("bad, words", [
    (float("nan"), ["NaN"]),
    ("singular", ["singular"]),
    ("scaled", ["scaled"]),
])
def test_bad_pose_is_named(sphere_dataset, bad, words):
    meta = _meta(sphere_dataset)
    m = np.array(meta["frames"][4]["transform_matrix"])
    if bad == "singular":
        m[:3, 1] = 0
    elif bad == "scaled":
        m[:3, :3] *= 1.5
    else:
        m[0, 0] = bad
    meta["frames"][4]["transform_matrix"] = m.tolist()
    (sphere_dataset / "transforms_train.json").write_text(json.dumps(meta).replace("NaN", "NaN"))
    _expect(sphere_dataset, "transforms_train.json", "frame 4", "transform_matrix", *words)


def test_image_without_alpha_among_rgba_is_named(sphere_dataset):
    img = Image.open(sphere_dataset / "train" / "r_5.png").convert("RGB")
    img.save(sphere_dataset / "train" / "r_5.png")
    _expect(sphere_dataset, "frame 5", "r_5.png", "alpha")


def test_random_background_needs_alpha(tmp_path, dataset_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train
    from nerf_core.errors import TrainError

    ds = dataset_factory(tmp_path / "rgb")
    for p in (ds / "train").glob("r_*.png"):
        Image.open(p).convert("RGB").save(p)
    with pytest.raises(TrainError, match="r_0.png.*alpha"):
        train(TrainConfig(dataset=str(ds), out=str(tmp_path / "run"), method="test-grid", max_steps=2,
                          background="random", stdout_events=False, show_bar=False))


def test_empty_split_is_named(sphere_dataset):
    meta = _meta(sphere_dataset, "train")
    meta["frames"] = []
    _write_meta(sphere_dataset, meta, "train")
    _expect(sphere_dataset, "transforms_train.json", "empty")


def test_held_out_splits_that_are_empty_or_cameras_only_are_noted_not_refused(sphere_dataset):
    # BlenderNeRF writes test poses without images (or, for 3DGS, "frames": []); 3DGS trains on them,
    # train refused both ("image not found", "split 'test' is empty").
    meta = _meta(sphere_dataset, "val")
    meta["frames"] = []
    _write_meta(sphere_dataset, meta, "val")
    for k in range(2):
        (sphere_dataset / "test" / f"r_{k}.png").unlink()
    ds = load_dataset(sphere_dataset)
    assert len(ds.splits["val"]) == 0 and len(ds.splits["test"]) == 0 and len(ds.splits["train"]) == 8
    assert any("transforms_val.json: no frames" in n for n in ds.notes)
    assert any("transforms_test.json: none of its 2 images exists (a split of cameras only)" in n for n in ds.notes)
    (sphere_dataset / "train" / "r_3.png").unlink()  # a missing train image is still an error
    _expect(sphere_dataset, "r_3", "not found")


def test_single_view_dataset_is_refused(tmp_path, dataset_factory):
    _expect(dataset_factory(tmp_path / "one", n_train=1), "train split has 1 view")


def test_invalid_json_and_missing_folder(tmp_path, sphere_dataset):
    (sphere_dataset / "transforms_test.json").write_text("{ not json")
    _expect(sphere_dataset, "transforms_test.json", "line 1")
    _expect(tmp_path / "nowhere", "nowhere", "not found")


def _json_text_with_frames_twice(meta, second_frames):
    head = json.dumps({k: v for k, v in meta.items() if k != "frames"})[:-1]
    return head + ', "frames": ' + json.dumps(meta["frames"]) + ', "frames": ' + json.dumps(second_frames) + "}"


def test_a_key_written_twice_with_two_values_is_refused(sphere_dataset):
    # Python's json keeps the last "frames" silently: a merge gone wrong trained on 2 of 8 views.
    meta = _meta(sphere_dataset)
    (sphere_dataset / "transforms_train.json").write_text(_json_text_with_frames_twice(meta, meta["frames"][:2]))
    _expect(sphere_dataset, "transforms_train.json", "key 'frames' appears twice")
    # the same value twice is harmless
    (sphere_dataset / "transforms_train.json").write_text(_json_text_with_frames_twice(meta, meta["frames"]))
    assert len(load_dataset(sphere_dataset).splits["train"]) == len(meta["frames"])


def test_integers_beyond_a_float_are_named_not_a_traceback(sphere_dataset):
    def written_with(field_edit, placeholder, digits):
        meta = _meta(sphere_dataset)
        field_edit(meta, placeholder)
        text = json.dumps(meta).replace(json.dumps(placeholder), digits, 1)
        (sphere_dataset / "transforms_train.json").write_text(text)

    # 400 digits: past float64's range (an OverflowError traceback in numpy before)
    written_with(lambda m, v: m["frames"][1]["transform_matrix"][0].__setitem__(3, v), 123456.5, "9" * 400)
    _expect(sphere_dataset, "frame 1", "transform_matrix", "too large for a float")
    # 5001 digits: past Python's int-string limit, a message that named no file or field
    written_with(lambda m, v: m.__setitem__("w", v), 123456.5, "7" * 5001)
    _expect(sphere_dataset, "transforms_train.json", "'w'")


def test_a_utf8_byte_order_mark_is_read(sphere_dataset):
    path = sphere_dataset / "transforms_train.json"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())  # what Windows editors save
    assert len(load_dataset(sphere_dataset).splits["train"]) == 8


def test_a_held_out_split_file_given_as_the_dataset_says_what_trains(sphere_dataset):
    ds = load_dataset(sphere_dataset / "transforms_test.json")
    assert len(ds.splits["train"]) == 8
    assert any("transforms_test.json is given as the dataset" in n and "training uses transforms_train.json" in n
               for n in ds.notes)
    assert not any("given as the dataset" in n for n in load_dataset(sphere_dataset / "transforms_train.json").notes)


def test_declared_size_must_match_the_images(sphere_dataset):
    meta = _meta(sphere_dataset)
    meta["w"] = 48
    _write_meta(sphere_dataset, meta)
    _expect(sphere_dataset, "frame 0", "'w'/'h'", "48x20", "24x20")


def test_instant_ngp_scale_and_offset_are_named_as_not_applied(tmp_path, dataset_factory):
    # instant-ngp fits its unit cube with them; the poses as written are the scene's. They were
    # dropped without a word.
    ds_path = dataset_factory(tmp_path / "ngp", layouts=("nerfstudio",))
    meta = json.loads((ds_path / "transforms.json").read_text())
    (ds_path / "transforms.json").write_text(json.dumps({**meta, "scale": 0.33, "offset": [0.5, 0.5, 0.5]}))
    notes = load_dataset(ds_path).notes
    assert any("instant-ngp's 'scale' and 'offset' are not applied: poses are read as written" in n for n in notes)


def test_a_declared_box_grows_by_the_face_pad_so_a_floor_on_its_face_lies_inside():
    from nerf_core.data.scene_box import FACE_PAD, pad_box_for_faces

    box = torch.tensor([[-1.0, -2.0, 0.0], [1.0, 2.0, 1.0]])
    grown = pad_box_for_faces(box)
    assert torch.allclose(grown, torch.tensor([[-1.025, -2.05, -0.0125], [1.025, 2.05, 1.0125]]))
    assert FACE_PAD == 0.0125  # 2 cells of the default 160-cell grid (measured: docs/BENCHMARKS.md)
