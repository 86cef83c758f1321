"""``check``: a valid dataset passes; each convention violation is reported with its file/frame/field."""
import json

import numpy as np
import pytest
from PIL import Image

from nerf_core.check.dataset import check_dataset
from nerf_core.cli.main import main


def _edit(path, fn):
    meta = json.loads(path.read_text())
    fn(meta)
    path.write_text(json.dumps(meta))


def _errors(ds):
    report = check_dataset(ds)
    return report, [str(p) for p in report.errors]


def _paint_views(ds, views, rgba):
    """Fill each (split, index) view's image with one RGBA colour; then check ``ds`` (``_errors``)."""
    for split, k in views:
        path = ds / split / f"r_{k}.png"
        Image.new("RGBA", Image.open(path).size, rgba).save(path)
    return _errors(ds)


def _has(errors, *words):
    return any(all(w in e for w in words) for e in errors)


def test_valid_dataset_passes_and_exits_zero(sphere_dataset, capsys):
    report, errors = _errors(sphere_dataset)
    assert errors == []
    # The shifted principal point is legal but camera_angle_x-only loaders ignore it: a warning.
    assert any("cx/cy" in str(w) and "transforms_train.json" in str(w) for w in report.warnings)
    assert main(["check", str(sphere_dataset)]) == 0
    assert "valid" in capsys.readouterr().out


def _scale(meta):
    m = np.array(meta["frames"][2]["transform_matrix"])
    m[:3, :3] *= 2.0
    meta["frames"][2]["transform_matrix"] = m.tolist()


def _ext(meta):
    meta["frames"][1]["file_path"] = "./train/r_1.png"


def _shift_out(meta):
    meta["cx"] = 500.0


def _angle(meta):
    meta["camera_angle_x"] = 0.5


CASES = {
    "missing camera_angle_x": (
        "transforms_train.json",
        lambda m: m.pop("camera_angle_x"),
        ["transforms_train.json", "camera_angle_x", "missing"],
    ),
    "missing fl_x": ("transforms_test.json", lambda m: m.pop("fl_x"), ["transforms_test.json", "'fl_x'", "missing"]),
    "missing h": ("nerfstudio/transforms.json", lambda m: m.pop("h"), ["transforms.json", "'h'"]),
    "scaled matrix": (
        "transforms_train.json",
        _scale,
        ["transforms_train.json", "frame 2", "transform_matrix", "scaled"],
    ),
    "extension in file_path": (
        "transforms_train.json",
        _ext,
        ["transforms_train.json", "frame 1", "file_path", "extension"],
    ),
    "cx outside": ("transforms_val.json", _shift_out, ["transforms_val.json", "'cx'", "outside"]),
    "inconsistent angle": ("transforms_train.json", _angle, ["transforms_train.json", "camera_angle_x", "fl_x"]),
    "aabb_scale": (
        "nerfstudio/transforms.json",
        lambda m: m.update(aabb_scale=3),
        ["transforms.json", "aabb_scale", "power of two"],
    ),
    "aabb_scale too big": ("transforms_train.json", lambda m: m.update(aabb_scale=256), ["aabb_scale"]),
    "nerfstudio name without extension": (
        "nerfstudio/transforms.json",
        lambda m: m["frames"][0].update(file_path="../train/r_0"),
        ["transforms.json", "frame 0", "file_path", "extension"],
    ),
    "split list names unknown file": (
        "nerfstudio/transforms.json",
        lambda m: m["test_filenames"].append("test/zzz.png"),
        ["transforms.json", "test_filenames", "zzz.png"],
    ),
    "missing depth file": (
        "transforms_test.json",
        lambda m: m["frames"][1].update(depth_file_path="nope.exr"),
        ["transforms_test.json", "frame 1", "depth_file_path", "nope.exr"],
    ),
    # nerfstudio-data takes the top-level value for every frame and never reads the frame's own.
    "nerfstudio frame intrinsics hidden by the top level": (
        "nerfstudio/transforms.json",
        lambda m: m["frames"][2].update(fl_x=m["fl_x"] * 1.5),
        ["transforms.json", "frame 2", "fl_x", "top-level", "nerfstudio-data uses for every frame"],
    ),
    "bad aabb": (
        "transforms_train.json",
        lambda m: m.update(aabb=[[0, 0, 0], [0, 0, 0]]),
        ["transforms_train.json", "aabb"],
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_violation_is_named(sphere_dataset, case, capsys):
    fname, fn, words = CASES[case]
    _edit(sphere_dataset / fname, fn)
    report, errors = _errors(sphere_dataset)
    assert _has(errors, *words), errors
    assert main(["check", str(sphere_dataset)]) == 1
    assert "INVALID" in capsys.readouterr().out


def test_image_problems_are_named(sphere_dataset):
    Image.open(sphere_dataset / "train" / "r_3.png").convert("RGB").save(sphere_dataset / "train" / "r_3.png")
    Image.new("RGBA", (10, 10)).save(sphere_dataset / "train" / "r_4.png")
    (sphere_dataset / "test" / "r_0.png").unlink()
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "transforms_train.json", "frame 3", "r_3.png", "RGBA")
    assert _has(errors, "transforms_train.json", "frame 4", "10x10", "24x20")
    assert _has(errors, "transforms_test.json", "frame 0", "does not exist")
    assert _has(errors, "transforms.json", "test/r_0.png", "does not exist")


def test_views_that_show_nothing_are_warned_about(sphere_dataset):
    # A camera path through the subject, or one looking away, leaves views transparent everywhere:
    # valid files, but a held-out view of nothing measures nothing.
    report, errors = _errors(sphere_dataset)
    assert not [w for w in report.warnings if "shows nothing" in str(w)]
    report, errors = _paint_views(sphere_dataset, (("test", 1), ("train", 2)), (40, 90, 200, 0))
    assert errors == []
    empty = [str(w) for w in report.warnings if "shows nothing" in str(w)]
    assert len(empty) == 2
    assert _has(empty, "transforms_test.json", "frame 1", "measures nothing")
    assert _has(empty, "transforms_train.json", "frame 2") and not _has(empty, "train", "measures nothing")


def test_opaque_views_that_are_black_everywhere_are_warned_about(sphere_dataset):
    # Cameras standing inside a closed object (the 'inside' layout on a single object), or a scene with
    # its lights off, render black opaque images: valid files that teach nothing. check was silent.
    for split in ("train", "val", "test"):  # an opaque capture: the sphere on a grey world
        for path in (sphere_dataset / split).glob("*.png"):
            im = Image.open(path).convert("RGBA")
            grey = Image.new("RGBA", im.size, (128, 128, 128, 255))
            Image.alpha_composite(grey, im).save(path)
    report, errors = _errors(sphere_dataset)
    assert errors == [] and not [w for w in report.warnings if "shows nothing" in str(w)]
    report, errors = _paint_views(sphere_dataset, (("test", 0), ("train", 3)), (1, 0, 1, 255))
    assert errors == []
    black = [str(w) for w in report.warnings if "opaque and black everywhere" in str(w)]
    assert len(black) == 2, report.warnings
    assert _has(black, "transforms_test.json", "frame 0", "measures nothing", "is the scene lit")
    assert _has(black, "transforms_train.json", "frame 3") and not _has(black, "train", "measures nothing")
    # a dark view that still shows something (one pixel at 2/255) is not called black
    path = sphere_dataset / "train" / "r_3.png"
    px = np.zeros((20, 24, 4), np.uint8)
    px[..., 3], px[5, 5, 0] = 255, 2
    Image.fromarray(px).save(path)
    report, _ = _errors(sphere_dataset)
    assert len([w for w in report.warnings if "opaque and black everywhere" in str(w)]) == 1


def test_for_training_another_tools_dataset_is_valid_and_what_train_refuses_is_not(sphere_dataset, capsys):
    # The original NeRF scenes give camera_angle_x only and no nerfstudio/ folder: 19 errors as an
    # export of ours, yet train reads them; the add-on's Train ran check first and refused them all.
    import shutil

    for split in ("train", "val", "test"):
        _edit(sphere_dataset / f"transforms_{split}.json",
              lambda m: [m.pop(k) for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")])
    shutil.rmtree(sphere_dataset / "nerfstudio")
    strict = check_dataset(sphere_dataset)
    assert not strict.ok and strict.trainable and "train reads this dataset as it is" in strict.format()
    report = check_dataset(sphere_dataset, for_training=True)
    assert report.ok and any("(conventions of an export)" in str(w) for w in report.warnings)
    assert main(["check", str(sphere_dataset), "--for-training"]) == 0 and "valid" in capsys.readouterr().out
    Image.new("RGBA", (10, 10)).save(sphere_dataset / "train" / "r_4.png")  # what train refuses stays an error
    report = check_dataset(sphere_dataset, for_training=True)
    assert not report.ok and _has([str(p) for p in report.errors], "frame 4", "10x10")
    assert not report.trainable and "train reads" not in check_dataset(sphere_dataset).format()


def test_for_training_names_a_problem_once(sphere_dataset):
    # A missing image, or a matrix entry written as text, breaks both the conventions and the loader;
    # --for-training turned the first into a warning and listed the loader's error beside it.
    import shutil

    def only_once(report, frame, word):
        lines = [str(p) for p in report.errors + report.warnings]
        assert _has([str(p) for p in report.errors], frame, word), lines
        assert sum(f"{frame} " in line for line in lines) == 1, lines

    clean = sphere_dataset.parent / "clean"
    shutil.copytree(sphere_dataset, clean)
    _edit(sphere_dataset / "transforms_train.json", lambda m: m["frames"][1].update(file_path="./train/missing"))
    only_once(check_dataset(sphere_dataset, for_training=True), "frame 1", "not found")
    shutil.copy(clean / "transforms_train.json", sphere_dataset / "transforms_train.json")
    _edit(sphere_dataset / "transforms_train.json", lambda m: m["frames"][2]["transform_matrix"][0].__setitem__(0, "x"))
    only_once(check_dataset(sphere_dataset, for_training=True), "frame 2", "'x'")
    # what is only a convention stays a warning
    shutil.copy(clean / "transforms_train.json", sphere_dataset / "transforms_train.json")
    _edit(sphere_dataset / "transforms_train.json", lambda m: m.pop("fl_x"))
    report = check_dataset(sphere_dataset, for_training=True)
    assert report.ok and _has([str(p) for p in report.warnings], "fl_x", "(conventions of an export)")


def test_a_lone_transforms_json_is_checked_as_the_one_file_layout(tmp_path, dataset_factory):
    """instant-ngp's and nerfstudio's own layout: transforms.json is the dataset. check called it a
    stray JSON, asked for nerfstudio/transforms.json beside it, and never looked at its frames."""
    ds = dataset_factory(tmp_path / "ns", layouts=("nerfstudio",))
    report, errors = _errors(ds)
    assert not any("beside transforms_{train,val,test}.json" in e or "stray JSON" in e for e in errors), errors
    assert not _has(errors, "nerfstudio/transforms.json"), errors
    assert _has(errors, "transforms_train.json", "missing", "one-file layout")
    _edit(ds / "transforms.json", lambda m: m["frames"][1].update(file_path="train/gone.png"))
    _, errors = _errors(ds)
    assert _has(errors, "transforms.json: frame 1 (train/gone.png)", "does not exist"), errors


def test_our_nerfstudio_folder_is_checked_as_part_of_its_dataset(sphere_dataset, capsys):
    """`check DATASET/nerfstudio` (the folder nerfstudio is given) on an export of ours said the file was
    a stray JSON and that DATASET/nerfstudio/nerfstudio/transforms.json and the split files were missing."""
    report = check_dataset(sphere_dataset / "nerfstudio")
    assert report.ok and report.root == sphere_dataset, report.format()
    assert "holds the nerfstudio-data file of the dataset" in report.notes[0]
    _edit(sphere_dataset / "nerfstudio" / "transforms.json", lambda m: m.update(cy=m["cy"] + 2))
    assert main(["check", str(sphere_dataset / "nerfstudio")]) == 1
    out = capsys.readouterr().out
    assert out.startswith("NOTE") and "nerfstudio/transforms.json: frame 0" in out and "differs" in out


def test_image_depth_and_format_are_read_from_the_file(sphere_dataset):
    """Pillow opens a 16-bit RGBA PNG as 8-bit "RGBA", so check passed it while refusing an LA PNG; the
    original NeRF loader divides it by 255 (values up to 257). A JPEG under a .png name was "RGB 8-bit"."""
    import struct
    import zlib

    rgba = np.asarray(Image.open(sphere_dataset / "train" / "r_0.png").convert("RGBA")).astype(">u2") * 257
    h, w = rgba.shape[:2]  # Pillow cannot write 16-bit RGBA: the PNG by hand (filter 0 on every row)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    raw = b"".join(b"\x00" + row.tobytes() for row in rgba)
    (sphere_dataset / "train" / "r_0.png").write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 6, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    Image.open(sphere_dataset / "train" / "r_1.png").convert("RGB").save(sphere_dataset / "train" / "r_1.png", "JPEG")
    Image.open(sphere_dataset / "train" / "r_2.png").convert("LA").save(sphere_dataset / "train" / "r_2.png")
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "frame 0", "RGBA 16-bit", "must be RGBA 8-bit"), errors
    assert _has(errors, "frame 1", "a JPEG image (RGB 8-bit) under a .png name"), errors
    assert _has(errors, "frame 2", "LA 8-bit"), errors


def test_held_out_cameras_must_not_be_training_cameras(sphere_dataset):
    train = json.loads((sphere_dataset / "transforms_train.json").read_text())
    _edit(sphere_dataset / "transforms_test.json",
          lambda m: m["frames"][1].update(transform_matrix=train["frames"][5]["transform_matrix"]))
    _edit(sphere_dataset / "transforms_val.json", lambda m: m["frames"][0].update(file_path="./train/r_2"))
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "transforms_test.json", "frame 1", "train frame 5", "transform_matrix")
    assert _has(errors, "transforms_val.json", "frame 0", "train frame 2")


def test_stray_json_and_missing_files(sphere_dataset):
    (sphere_dataset / "manifest.json").write_text("{}")
    (sphere_dataset / "transforms_val.json").unlink()
    (sphere_dataset / "nerfstudio" / "transforms.json").unlink()
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "manifest.json", "instant-ngp")
    assert _has(errors, "transforms_val.json", "missing")
    assert _has(errors, "transforms.json", "missing", "nerfstudio")


def test_intrinsics_must_agree_between_layouts(sphere_dataset):
    _edit(sphere_dataset / "nerfstudio" / "transforms.json", lambda m: m.update(cy=m["cy"] + 2))
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "transforms.json", "frame 0", "cy", "differs")


def test_nerfstudio_file_at_the_root_is_refused_for_instant_ngp(sphere_dataset):
    """instant-ngp loads every *.json of the folder: transforms.json beside the split files doubles
    every frame (and trains on the test views), so it belongs in nerfstudio/."""
    (sphere_dataset / "nerfstudio" / "transforms.json").rename(sphere_dataset / "transforms.json")
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "transforms.json", "instant-ngp", "twice", "nerfstudio/transforms.json")
    assert _has(errors, "nerfstudio/transforms.json", "missing")


def test_nerfstudio_paths_resolve_against_their_own_folder(sphere_dataset):
    # "train/r_1.png" would be right at the root, but nerfstudio reads it from nerfstudio/train/r_1.png
    _edit(sphere_dataset / "nerfstudio" / "transforms.json",
          lambda m: (m["frames"][1].update(file_path="train/r_1.png"),
                     m["train_filenames"].__setitem__(1, "train/r_1.png")))
    _, errors = _errors(sphere_dataset)
    assert _has(errors, "nerfstudio/transforms.json", "frame 1", "train/r_1.png", "does not exist")


def test_invalid_json_and_json_report(sphere_dataset, capsys):
    (sphere_dataset / "transforms_test.json").write_text("{oops")
    assert main(["check", str(sphere_dataset), "--json"]) == 1
    rep = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert not rep["ok"] and any("transforms_test.json" in e and "invalid JSON" in e for e in rep["errors"])


def test_a_scene_off_the_synthetic_scale_is_warned_about_once(sphere_dataset):
    report, errors = _errors(sphere_dataset)
    assert not [w for w in report.warnings if "synthetic" in str(w)]

    def grow(meta):  # the same scene, five times larger: legal, and read right by loaders that read aabb
        meta["aabb"] = (np.asarray(meta["aabb"]) * 5).tolist()
        meta["near"], meta["far"] = meta["near"] * 5, meta["far"] * 5
        for fr in meta["frames"]:
            m = np.asarray(fr["transform_matrix"])
            m[:3, 3] *= 5
            fr["transform_matrix"] = m.tolist()

    for name in ("transforms_train.json", "transforms_val.json", "transforms_test.json", "nerfstudio/transforms.json"):
        _edit(sphere_dataset / name, grow)
    report, errors = _errors(sphere_dataset)
    scale = [str(w) for w in report.warnings if "synthetic" in str(w)]
    assert len(scale) == 1 and "transforms_train.json" in scale[0] and "near 2, far 6" in scale[0], scale
    assert "8 of 8 train cameras lie 15-15 units" in scale[0] and "aabb reaches" in scale[0]


def test_check_takes_a_transforms_file_as_train_does(sphere_dataset):
    # `train DS/transforms_train.json` trains; check called the same path "not a folder".
    report = check_dataset(sphere_dataset / "transforms_train.json")
    assert [str(e) for e in report.errors] == []


def test_a_byte_order_mark_is_a_warning_for_other_tools(sphere_dataset):
    path = sphere_dataset / "transforms_train.json"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    report = check_dataset(sphere_dataset)
    assert [str(e) for e in report.errors] == []
    assert any("byte-order mark" in str(w) for w in report.warnings)


def test_an_image_with_another_extension_is_checked_as_train_reads_it(sphere_dataset):
    # check looked for "r_1.webp.png" where train reads r_1.webp: one rule (resolve_image) now.
    image = sphere_dataset / "train" / "r_1.png"
    Image.open(image).save(image.with_suffix(".webp"), lossless=True)
    image.unlink()
    _edit(sphere_dataset / "transforms_train.json",
          lambda m: m["frames"][1].__setitem__("file_path", "./train/r_1.webp"))
    report, errors = _errors(sphere_dataset)
    assert not any(".webp.png" in e for e in errors + [str(w) for w in report.warnings])
    assert _has(errors, "frame 1", "'./train/r_1.webp' has an extension")
