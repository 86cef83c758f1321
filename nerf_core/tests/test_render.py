"""``render``: RGBA PNG + planar-depth EXR per camera with the right sizes, renders.json, no overwrite."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from nerf_core.cameras.rays import Cameras
from nerf_core.cli.main import main
from nerf_core.image.io import read_exr
from nerf_core.methods.base import RadianceModel
from nerf_core.image.pixel_filter import PixelFilter
from nerf_core.render.cameras import cameras_from_file
from nerf_core.render.frame import render_view


def test_render_writes_png_and_exr_of_the_right_size(trained_run, tmp_path, capsys):
    ds, run, out = trained_run["dataset"], trained_run["run"], tmp_path / "renders"
    assert main(["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out), "--no-bar"]) == 0
    meta = json.loads((out / "renders.json").read_text())
    assert [f["file_path"] for f in meta["frames"]] == ["r_0.png", "r_1.png"]
    test_meta = json.loads((ds / "transforms_test.json").read_text())
    for f, src in zip(meta["frames"], test_meta["frames"]):
        img = Image.open(out / f["file_path"])
        assert img.mode == "RGBA" and img.size == (24, 20)
        z = read_exr(out / f["depth_file_path"])["Z"]
        assert z.shape == (20, 24) and z.dtype == np.float32
        np.testing.assert_allclose(f["transform_matrix"], src["transform_matrix"], atol=1e-6)
        assert (f["w"], f["h"]) == (24, 20) and f["cx"] == pytest.approx(test_meta["cx"])
    assert meta["step"] == 30 and meta["method"] == "test-grid"
    # A second render into the same folder is refused, naming the files, and changes nothing.
    before = (out / "r_0.png").stat().st_mtime_ns
    assert main(["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out), "--no-bar"]) == 2
    err = capsys.readouterr().err
    assert "r_0.png" in err and "--overwrite" in err
    assert (out / "r_0.png").stat().st_mtime_ns == before
    assert main(["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out),
                 "--overwrite", "--downscale", "2", "--no-bar"]) == 0
    assert Image.open(out / "r_0.png").size == (12, 10)


def test_an_interrupted_overwrite_leaves_no_renders_json_of_the_old_images(trained_run, tmp_path, monkeypatch):
    # Ctrl-C during render --overwrite left the previous renders.json (its run, step and PSNRs)
    # describing a folder of new images.
    import nerf_core.render.views as render_mod

    ds, run, out = trained_run["dataset"], trained_run["run"], tmp_path / "renders"
    args = ["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out), "--no-bar"]
    assert main(args) == 0 and (out / "renders.json").is_file()
    real, calls = render_mod.render_view, []

    def interrupted_after_one(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(render_mod, "render_view", interrupted_after_one)
    with pytest.raises(KeyboardInterrupt):
        render_mod.render_to_dir(*_run_and_cameras(run, ds), out, overwrite=True, show_progress=False)
    assert not (out / "renders.json").exists()


def _run_and_cameras(run, ds):
    from nerf_core.render.cameras import camera_views
    from nerf_core.runs.checkpoints import load_run

    model, _config, _ckpt = load_run(run, "cpu")
    cams, stems, _frames = camera_views(ds / "transforms_test.json", "test")
    return model, cams, stems


@pytest.mark.parametrize("cameras", ["dataset", "run's dataset", "other split", "another dataset"])
def test_render_never_writes_over_the_datasets_own_images(trained_run, tmp_path, capsys, cameras):
    import shutil

    ds = Path(shutil.copytree(trained_run["dataset"], tmp_path / "ds"))
    run = trained_run["run"]
    before = {p: p.read_bytes() for p in ds.rglob("*.png")}
    args = ["render", str(run), "--out", str(ds / "test"), "--overwrite", "--no-bar"]
    if cameras == "dataset":
        args += ["--cameras", str(ds)]
    elif cameras == "another dataset":  # the run's own cameras, into a second capture's test folder
        args = ["render", str(run), "--out", str(ds / "test"), "--overwrite", "--no-bar"]
    elif cameras == "other split":  # test cameras rendered into the train images' folder
        args = ["render", str(run), "--cameras", str(ds), "--out", str(ds / "train"), "--overwrite", "--no-bar"]
    else:  # no --cameras: the run's own dataset (the shared fixture's), rendered into that dataset
        ds = trained_run["dataset"]
        before = {p: p.read_bytes() for p in ds.rglob("*.png")}
        args[3] = str(ds / "test")
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "dataset's own file" in err and "r_0.png" in err and "frame 0" in err and "Traceback" not in err
    assert {p: p.read_bytes() for p in ds.rglob("*.png")} == before


@pytest.mark.parametrize("layout", ["synthetic", "nerfstudio"])
def test_render_into_a_dataset_root_is_refused_and_a_subfolder_is_not(trained_run, tmp_path, capsys, layout):
    """renders.json at a dataset's root is read as a transforms file by instant-ngp: refused before
    anything is written, naming the folder, the transforms file found there and a subfolder to use."""
    import shutil

    ds = Path(shutil.copytree(trained_run["dataset"], tmp_path / "ds"))
    if layout == "nerfstudio":  # a nerfstudio-layout root: transforms.json only
        for f in ds.glob("transforms_*.json"):
            f.rename(tmp_path / f.name)
        (ds / "transforms.json").write_text("{}")
    before = sorted(p.relative_to(ds) for p in ds.rglob("*"))
    assert main(["render", str(trained_run["run"]), "--out", str(ds), "--no-bar"]) == 2
    err = capsys.readouterr().err
    found = "transforms_train.json" if layout == "synthetic" else "transforms.json"
    assert f"--out {ds}: this is a dataset folder (it holds {found})" in err and str(ds / "renders") in err
    assert "Traceback" not in err
    assert sorted(p.relative_to(ds) for p in ds.rglob("*")) == before
    if layout == "synthetic":
        assert main(["render", str(trained_run["run"]), "--out", str(ds / "renders"), "--no-bar"]) == 0
        assert (ds / "renders" / "renders.json").is_file()


def test_render_png_alpha_and_depth_agree_with_the_model(trained_run, tmp_path):
    from nerf_core.runs.checkpoints import load_run

    run, ds = trained_run["run"], trained_run["dataset"]
    model, cfg, _ = load_run(run, torch.device("cpu"))
    cams, stems = cameras_from_file(ds, "test")
    # render draws through the run's film filter (the dataset records none: Blender's default)
    res = render_view(model, cams, 0, background=(0.0, 0.0, 0.0), near=cfg["near"], far=cfg["far"],
                      pixel_filter=PixelFilter())
    out = tmp_path / "r"
    assert main(["render", str(run), "--cameras", str(ds), "--split", "test", "--out", str(out), "--no-bar"]) == 0
    png = np.asarray(Image.open(out / "r_0.png")).astype(np.float32) / 255
    np.testing.assert_allclose(png[..., 3], res["acc"].numpy(), atol=1 / 255 + 1e-6)
    z = read_exr(out / "r_0_depth.exr")["Z"]
    np.testing.assert_allclose(z, res["z_depth"].numpy(), atol=1e-5)


def test_render_from_a_json_list_of_cameras(trained_run, tmp_path):
    ds = trained_run["dataset"]
    train_meta = json.loads((ds / "transforms_train.json").read_text())
    cams = [{"transform_matrix": f["transform_matrix"], "fl_x": 20.0, "cx": 8.0, "cy": 6.0, "w": 16, "h": 12,
             "name": f"cam{k}"} for k, f in enumerate(train_meta["frames"][:2])]
    cams.append(train_meta["frames"][3]["transform_matrix"])  # a bare matrix uses the top-level intrinsics
    path = tmp_path / "cams.json"
    path.write_text(json.dumps({"camera_angle_x": 0.8, "w": 10, "h": 8, "cameras": cams}))
    out = tmp_path / "r"
    assert main(["render", str(trained_run["run"]), "--cameras", str(path), "--out", str(out), "--no-bar"]) == 0
    assert Image.open(out / "cam1.png").size == (16, 12)
    assert Image.open(out / "view_002.png").size == (10, 8)
    assert read_exr(out / "view_002_depth.exr")["Z"].shape == (8, 10)


def test_bad_camera_files_are_named(trained_run, tmp_path, capsys):
    path = tmp_path / "cams.json"
    path.write_text(
        json.dumps([{"transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "fl_x": 10}])
    )
    assert main(["render", str(trained_run["run"]), "--cameras", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "cams.json" in err and "camera 0" in err and "'w'" in err and "Traceback" not in err


def test_render_view_chunks_give_the_same_image(trained_run):
    from nerf_core.runs.checkpoints import load_run

    model, cfg, _ = load_run(trained_run["run"], torch.device("cpu"))
    cams = Cameras.create(np.eye(4)[None] @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1.0]]),
                          15.0, 15.0, 7.0, 5.0, 14, 10)
    a = render_view(model, cams, 0, chunk=37)
    b = render_view(model, cams, 0, chunk=100000)
    assert a["rgb"].shape == (10, 14, 3)
    torch.testing.assert_close(a["rgb"], b["rgb"])


class _Wall(RadianceModel):
    """A fake model: every ray hits at distance 2 (opaque) except rays going left (transparent)."""

    def __init__(self):
        super().__init__(torch.tensor([[-10.0, -10, -10], [10, 10, 10]]))

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        n = rays_o.shape[0]
        acc = (rays_d[:, 0] >= 0).float()
        rgb = torch.tensor([0.2, 0.4, 0.6]) * acc[:, None] + background * (1 - acc[:, None])
        return {"rgb": rgb, "depth": torch.full((n,), 2.0), "acc": acc}


def test_depth_is_planar_and_empty_pixels_are_zero(tmp_path):
    from nerf_core.render.views import render_to_dir

    # 3x1 image, fx = 1, cx = 1.5: pixel centres at x = -1, 0, +1 -> angles 45 deg left, 0, 45 deg right.
    cams = Cameras.create(np.eye(4)[None], 1.0, 1.0, 1.5, 0.5, 3, 1)
    render_to_dir(_Wall(), cams, ["v"], tmp_path, show_progress=False)
    z = read_exr(tmp_path / "v_depth.exr")["Z"]
    np.testing.assert_allclose(z[0], [0.0, 2.0, 2.0 / math.sqrt(2.0)], atol=1e-6)
    png = np.asarray(Image.open(tmp_path / "v.png"))
    assert png[0, 0, 3] == 0 and png[0, 1, 3] == 255
    np.testing.assert_array_equal(png[0, 2, :3], [51, 102, 153])  # straight colour, not premultiplied


def test_render_metrics_equal_eval_for_the_same_view_and_checkpoint(trained_run, tmp_path):
    """renders.json's PSNR / SSIM are eval's numbers (same functions, same background compositing),
    although render draws onto black and eval onto the run's eval background."""
    from nerf_core.data.loading import load_dataset
    from nerf_core.evaluation.evaluate import evaluate_split
    from nerf_core.image.metrics import error_heatmap
    from nerf_core.runs.checkpoints import load_run

    run, ds = trained_run["run"], trained_run["dataset"]
    out = tmp_path / "r"
    assert main(["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out), "--no-bar"]) == 0
    meta = json.loads((out / "renders.json").read_text())
    model, cfg, _ = load_run(run, torch.device("cpu"))
    split = load_dataset(ds, splits=("test",)).split("test")
    bg = cfg.get("eval_background", [1.0, 1.0, 1.0])
    ev = evaluate_split(
        model, split, background=bg, near=cfg.get("near"), far=cfg.get("far"), pixel_filter=PixelFilter()
    )
    assert meta["metrics_background"] == pytest.approx(bg)
    assert [f["file_path"] for f in meta["frames"]] == [f"{e['name']}.png" for e in ev["per_view"]]
    for frame, e in zip(meta["frames"], ev["per_view"]):
        assert 5.0 < e["psnr"] < 60.0  # a real comparison, not a perfect or empty one
        assert frame["psnr"] == pytest.approx(e["psnr"], abs=1e-3)
        assert frame["ssim"] == pytest.approx(e["ssim"], abs=1e-5)
        assert frame["error_map"] == f"errors/{e['name']}.png"
        assert Path(frame["ground_truth"]) == (ds / "test" / f"{e['name']}.png").resolve()
        heat = np.asarray(Image.open(out / frame["error_map"]))
        assert heat.shape == (split.height, split.width, 3)
    # The heat-map is the mean absolute error of those two images on the fixed colour scale.
    res = render_view(model, split.cameras, 0, background=bg, near=cfg.get("near"), far=cfg.get("far"),
                      pixel_filter=PixelFilter())
    gt, _ = split.image(0, bg)
    want = (np.clip(error_heatmap(res["rgb"], gt), 0, 1) * 255 + 0.5).astype(np.uint8)
    got = np.asarray(Image.open(out / meta["frames"][0]["error_map"]))
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1


def test_render_of_cameras_without_images_has_no_metrics(trained_run, tmp_path):
    ds = trained_run["dataset"]
    meta = json.loads((ds / "transforms_test.json").read_text())
    for fr in meta["frames"]:
        fr["file_path"] = "./novel/" + fr["file_path"].split("/")[-1]  # no such images
    cams = tmp_path / "novel.json"
    cams.write_text(json.dumps(meta))
    out = tmp_path / "r"
    assert main(["render", str(trained_run["run"]), "--cameras", str(cams), "--out", str(out), "--no-bar"]) == 0
    frames = json.loads((out / "renders.json").read_text())["frames"]
    assert frames and all("psnr" not in f and "error_map" not in f and "metrics_skipped" not in f for f in frames)
    assert not (out / "errors").exists()


def test_render_and_eval_report_their_rendering_time(trained_run, run_copy, tmp_path, capsys):
    # renders.json and eval's summary carry the time spent rendering (nothing else), the rays rendered
    # (with --pixel-filter none one a pixel: 2 test views of 24 x 20) and their ratio; benchmarks/bench_render.py
    # reads them.
    ds, run, out = trained_run["dataset"], trained_run["run"], tmp_path / "timed"
    assert main(["render", str(run), "--cameras", str(ds / "transforms_test.json"), "--out", str(out), "--no-bar",
                 "--pixel-filter", "none"]) == 0
    meta = json.loads((out / "renders.json").read_text())
    assert meta["rays"] == 2 * 24 * 20
    assert all(f["render_seconds"] > 0 for f in meta["frames"])
    assert meta["render_seconds"] == pytest.approx(sum(f["render_seconds"] for f in meta["frames"]))
    assert meta["rays_per_s"] == pytest.approx(meta["rays"] / meta["render_seconds"])
    capsys.readouterr()
    # (a copy of the run: eval records its scores in metrics.json, which other tests compare with training's)
    assert main(["eval", str(run_copy), "--split", "test", "--no-bar", "--pixel-filter", "none"]) == 0
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert last["rays"] == 2 * 24 * 20 and last["render_seconds"] > 0
    assert last["rays_per_s"] == pytest.approx(last["rays"] / last["render_seconds"])


class _Counting(RadianceModel):
    """A fake model reporting ``per_ray`` samples per ray (``None``: no ``n_samples``); records call sizes
    and the ray intervals ``render_batch`` handed it."""

    def __init__(self, per_ray):
        super().__init__(torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
        self.per_ray, self.calls, self.nears = per_ray, [], []

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        n = rays_o.shape[0]
        self.calls.append(n)
        self.nears.append(near)
        out = {"rgb": rays_d.abs(), "depth": near + 1.0, "acc": torch.full((n,), 0.5)}
        if self.per_ray is not None:
            out["n_samples"] = n * self.per_ray
        return out


def test_cpu_calls_are_sized_by_the_samples_the_method_reports():
    from nerf_core.render import frame as r

    m = 3000
    rays_d = torch.nn.functional.normalize(torch.randn(m, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    rays_o = torch.zeros(m, 3)
    bg = torch.ones(3)
    # 128 samples per ray: after the first call (at most cpu_call_rays rays), 16384 / 128 = 128 rays a call.
    heavy = _Counting(128)
    res = r.render_rays_chunked(heavy, rays_o, rays_d, bg, 0.25, 3.0, chunk=8192)
    assert heavy.calls[0] == RadianceModel.cpu_call_rays == 512
    assert set(heavy.calls[1:-1]) == {r.CPU_SAMPLES_PER_CALL // 128} and sum(heavy.calls) == m
    torch.testing.assert_close(res["rgb"], rays_d.abs())
    # Each call's interval is the model's (the box clipped to near), for exactly the rays of that call.
    near = torch.cat(heavy.nears)
    torch.testing.assert_close(near, torch.full((m,), 0.25))
    torch.testing.assert_close(res["depth"], near + 1.0)
    # Very many samples per ray: never below CPU_MIN_CALL_RAYS; no samples at all: the cap.
    huge = _Counting(10 ** 6)
    r.render_rays_chunked(huge, rays_o, rays_d, bg)
    assert set(huge.calls[1:-1]) == {r.CPU_MIN_CALL_RAYS}
    for model in (_Counting(0), _Counting(None)):
        r.render_rays_chunked(model, rays_o, rays_d, bg)
        assert set(model.calls[:-1]) == {512}
    # ``chunk`` stays the upper bound (memory).
    small = _Counting(1)
    r.render_rays_chunked(small, rays_o, rays_d, bg, chunk=100)
    assert max(small.calls) == 100
    # A model with cheap samples raises its own ray cap; the samples rule still applies.
    light = _Counting(4)
    light.cpu_call_rays = 2048
    r.render_rays_chunked(light, rays_o, rays_d, bg)
    assert light.calls[:2] == [2048, 3000 - 2048]
    light8 = _Counting(64)
    light8.cpu_call_rays = 2048
    r.render_rays_chunked(light8, rays_o, rays_d, bg)
    assert light8.calls[0] == 2048 and set(light8.calls[1:-1]) == {r.CPU_SAMPLES_PER_CALL // 64}


@pytest.mark.parametrize("factor", ["inf", "100000"])
def test_render_refuses_a_downscale_that_leaves_no_pixel(trained_run, tmp_path, capsys, factor):
    out = tmp_path / "r"
    assert main(["render", str(trained_run["run"]), "--out", str(out), "--downscale", factor, "--no-bar"]) == 2
    err = capsys.readouterr().err
    assert "--downscale" in err and "20 px" in err and "Traceback" not in err
    assert not out.exists()
