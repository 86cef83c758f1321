"""nerf_core.contract: stdlib + numpy only, and its rules."""
import os
import subprocess
import sys

from nerf_core import contract


def test_imports_with_torch_blocked():
    # The add-on imports the contract inside Blender, where torch must never load.
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ImportError('torch blocked')\n"
            "sys.meta_path.insert(0, Block())\n"
            "import nerf_core.contract as c\n"
            "assert 'torch' not in sys.modules\n"
            "print(c.latest_checkpoint('R'))\n")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == os.path.join("R", "checkpoints", "latest.pt")


def test_run_paths():
    assert contract.step_checkpoint("R", 12) == os.path.join("R", "checkpoints", "step_0000012.pt")
    assert contract.preview_path("R", 3) == os.path.join("R", "previews", "step_0000003.png")
    assert contract.config_path("R") == os.path.join("R", "config.json")


def test_budget_fraction():
    assert contract.budget_fraction(50, 10.0, 100, 40.0) == 0.5  # steps run out first
    assert contract.budget_fraction(10, 30.0, 100, 40.0) == 0.75  # seconds run out first
    assert contract.budget_fraction(500, None, 100, None) == 1.0  # clamped
    assert contract.budget_fraction(5, 1.0, None, None) is None
    assert contract.budget_fraction(None, None, 100, 10) is None


def test_parse_event_line():
    assert contract.parse_event_line('{"event": "step", "step": 3}\n') == {"event": "step", "step": 3}
    for bad in ("", "warning: x", '{"event": 3}', '{"step": 1}', '{"event": "st', "[1]"):
        assert contract.parse_event_line(bad) is None


def test_parse_json_line_keeps_objects_without_an_event():
    # eval prints its metrics as a plain JSON object: a line the benchmark reads, not an event.
    assert contract.parse_json_line(' {"psnr": 24.5}\n') == {"psnr": 24.5}
    assert contract.parse_json_line('{"event": 3}') == {"event": 3}
    for bad in ("", "warning: x", '{"event": "st', "[1]", '"text"'):
        assert contract.parse_json_line(bad) is None


def test_json_safe_nulls_every_non_finite_float():
    import json

    nan, inf = float("nan"), float("inf")
    value = {"a": nan, "b": [1.5, -inf, {"c": inf}], "d": (2, nan), "e": "nan", "f": 3}
    assert contract.json_safe(value) == {"a": None, "b": [1.5, None, {"c": None}], "d": [2, None], "e": "nan", "f": 3}
    json.dumps(contract.json_safe(value), allow_nan=False)  # strict JSON now: would raise otherwise
    assert contract.json_safe(nan) is None and contract.json_safe(True) is True


# -- intrinsics: the one focal-length rule ---------------------------------------------------------
def test_resolve_intrinsics_precedence_by_hand():
    import math

    import pytest

    angle = 2 * math.atan(0.5)  # tan(angle / 2) = 0.5: fx = 0.5 * w / 0.5 = w
    top = {"camera_angle_x": angle, "w": 100, "h": 60}
    assert contract.resolve_intrinsics(top, {}) == pytest.approx((100, 100, 50, 30, 100, 60))
    # A frame's value overrides the file's; fl_x beats camera_angle_x; fy falls back to fx.
    assert contract.resolve_intrinsics(top, {"fl_x": 80.0, "cy": 20.0}) == pytest.approx((80, 80, 50, 20, 100, 60))
    assert contract.resolve_intrinsics({"fl_x": 120.0, "w": 100, "h": 60}, {"camera_angle_x": angle})[0] == 120.0
    assert contract.resolve_intrinsics({"fl_y": 70.0}, {}, (40, 30)) == pytest.approx((70, 70, 20, 15, 40, 30))
    assert contract.resolve_intrinsics({"fl_x": 70.0, "fl_y": 90.0, "w": 8, "h": 6}, None)[:2] == (70.0, 90.0)
    # The declared size beats the image's; the image's fills in when the JSON has none.
    assert contract.resolve_intrinsics(top, {}, (7, 7))[4:] == (100.0, 60.0)
    assert contract.resolve_intrinsics({"camera_angle_x": angle}, {}, (10, 4)) == pytest.approx((10, 10, 5, 2, 10, 4))
    with pytest.raises(contract.DatasetError, match=r"cams.json: camera 2: fields 'w' and 'h'"):
        contract.resolve_intrinsics({"fl_x": 5.0}, {}, None, "cams.json: camera 2")
    with pytest.raises(contract.DatasetError, match="no focal length"):
        contract.resolve_intrinsics({"w": 4, "h": 4}, {"cx": 2.0})
    with pytest.raises(contract.DatasetError, match=r"frame 3: field 'camera_angle_x'.*\(0, pi\)"):
        contract.resolve_intrinsics(top, {"camera_angle_x": 3.5}, None, "frame 3")
    assert contract.focal_from_fov(contract.fov_from_focal(42.0, 64), 64) == pytest.approx(42.0)


# -- output names ----------------------------------------------------------------------------------
def test_output_stems_follow_render_naming_and_never_collide():
    frames = [{"file_path": "./train/r_0"}, {"file_path": "./test/r_0"}, {"name": "A", "file_path": "x/b.png"},
              [[1, 0, 0, 0]] * 4, {"file_path": "images/R_0.png"}, {"file_path": ""}]
    assert contract.output_stems(frames) == ["r_0", "r_0_1", "A", "view_003", "R_0_2", "view_005"]
    assert contract.unique_stems(["a", "a", "a_1"]) == ["a", "a_1", "a_1_1"]
    # Names that are no file names: '.' and '..' wrote hidden '..png' files, NUL raised "embedded null
    # byte", and 300 characters passed the file system's limit (255 bytes) with the depth file's suffix.
    odd = [{"name": "."}, {"name": ".."}, {"name": "a\0b"}, {"name": "x" * 300}, {"name": ".hidden"}]
    assert contract.output_stems(odd) == ["view_000", "view_001", "a_b", "x" * contract.MAX_STEM_CHARS, "hidden"]
    assert contract.render_files("r_0") == {"image": "r_0.png", "depth": "r_0_depth.exr", "error_map": "errors/r_0.png"}
    # ... and in bytes: 200 'é' cut to 120 characters were 240 bytes, 84 CJK characters 252 (the
    # depth file's temporary name failed after the PNG was written); a lone surrogate is no name.
    for name in ("x" + "é" * 200, "カメラ" * 28, "a\ud800b"):
        stem = contract.output_stems([{"name": name}])[0]
        assert len(stem.encode("utf-8")) <= contract.MAX_STEM_BYTES and stem, name
    assert contract.output_stems([{"name": "a\ud800b"}]) == ["a_b"]


def test_evenly_spaced_by_hand():
    assert contract.evenly_spaced(10, 4) == [0, 3, 6, 9]
    assert contract.evenly_spaced(100, 8) == [0, 14, 28, 42, 57, 71, 85, 99]  # round(k * 99 / 7)
    assert contract.evenly_spaced(5, 10) == [0, 1, 2, 3, 4]
    assert (
        contract.evenly_spaced(7, 1) == [0]
        and contract.evenly_spaced(0, 3) == []
        and contract.evenly_spaced(3, 0) == []
    )


# -- transforms files ------------------------------------------------------------------------------
def test_read_transforms_names_file_frame_and_field(tmp_path):
    import json

    import pytest

    eye = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
    (tmp_path / "train").mkdir()
    (tmp_path / "train" / "r_0.png").write_bytes(b"")
    path = tmp_path / "transforms_train.json"
    path.write_text(json.dumps({"camera_angle_x": 0.7, "frames": [
        {"file_path": "./train/r_0", "transform_matrix": eye, "depth_path": "../d.exr", "w": 8, "h": 6}]}))
    (fr,) = contract.read_transforms(path)
    assert fr.image == (tmp_path / "train" / "r_0.png").resolve() and fr.stem == "r_0"
    assert fr.intrinsics == {"camera_angle_x": 0.7, "w": 8.0, "h": 6.0} and fr.outside == ["depth_path"]
    assert fr.depth == (tmp_path.parent / "d.exr").resolve() and fr.c2w[2, 3] == 4.0
    bad = dict(json.loads(path.read_text()))
    bad["frames"][0]["transform_matrix"] = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]
    path.write_text(json.dumps(bad))
    with pytest.raises(
        contract.DatasetError, match=r"transforms_train.json: frame 0 \(./train/r_0\): field 'transform_matrix'.*scaled"
    ):
        contract.read_transforms(path)


def test_angle_only_caveats_name_shift_pixel_aspect_and_mixed_lenses():
    from nerf_core.contract.intrinsics import angle_only_caveats as caveats

    def angle_only_caveats(cams):  # (fx, fy, cx, cy, w, h) per view, as the intrinsics dicts hold them
        return caveats([dict(zip(("fl_x", "fl_y", "cx", "cy", "w", "h"), c), camera_angle_x=1.0) for c in cams])

    centred = (100.0, 100.0, 32.0, 24.0, 64, 48)
    assert angle_only_caveats([centred, centred]) == []
    assert angle_only_caveats([]) == []
    # Half a pixel off the centre is rounding, not a shift.
    assert angle_only_caveats([(100.0, 100.0, 32.4, 24.0, 64, 48)]) == []
    shifted = (100.0, 100.0, 20.0, 30.0, 64, 48)  # principal point 12 px left, 6 px down
    ((field, msg),) = angle_only_caveats([shifted])
    assert field == "cx/cy" and "(-12.00, +6.00) px in 1 of 1 view(s)" in msg and "TensoRF" in msg
    tall = (100.0, 50.0, 32.0, 24.0, 64, 48)  # Blender pixel aspect 1:2
    ((field, msg),) = angle_only_caveats([tall, tall])
    assert field == "fl_y" and "fl_y 50 differs from fl_x 100 in 2 of 2 view(s)" in msg
    zoom = (140.0, 140.0, 32.0, 24.0, 64, 48)
    ((field, msg),) = angle_only_caveats([centred, zoom, centred])
    assert field == "fl_x" and "2 different cameras" in msg and "nerfstudio-data" in msg
    assert [f for f, _ in angle_only_caveats([centred, shifted, tall])] == ["cx/cy", "fl_y", "fl_x"]
