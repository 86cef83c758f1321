"""The world behind the scene: the learned environment, ``--background auto``, interiors and ``check``."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from nerf_core.cameras.rays import Cameras, ray_bounds, rays_for_view
from nerf_core.data import backgrounds
from nerf_core.data.loading import load_dataset
from nerf_core.data.scene_box import pad_box_for_interior
from nerf_core.fields.environment import EnvironmentMap, directions_to_uv, prefit, sample_latlong, size_for_focal
from nerf_core.image.io import read_png, write_png
from nerf_core.methods.registry import build_model
from nerf_core.render.frame import render_view

# ----------------------------------------------------------------------------------------------- texture


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenGL camera-to-world (4, 4) at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = (eye - target) / np.linalg.norm(eye - target)
    x = np.cross(up, z) / np.linalg.norm(np.cross(up, z))
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, eye
    return m


def test_lookup_wraps_around_in_longitude_and_is_exact_at_texel_centres():
    tex = torch.arange(3 * 4 * 8, dtype=torch.float32).reshape(3, 4, 8)
    w, h = 8, 4
    # Texel (row 1, column 5)'s centre: the lookup returns exactly its value.
    uv = torch.tensor([[(5 + 0.5) / w, (1 + 0.5) / h]])
    assert torch.allclose(sample_latlong(tex, uv)[0], tex[:, 1, 5])
    # Half-way between the last and the first column (u = 0 = 1): the mean of the two, from both sides.
    seam = torch.tensor([[0.0, 1.5 / h], [1.0, 1.5 / h]])
    want = 0.5 * (tex[:, 1, 0] + tex[:, 1, 7])
    out = sample_latlong(tex, seam)
    assert torch.allclose(out[0], want) and torch.allclose(out[1], want)


def test_directions_map_to_latitude_and_longitude():
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-2.0, 0.0, 0.0]])
    uv = directions_to_uv(d)
    assert uv[0, 1] == pytest.approx(0.0) and uv[1, 1] == pytest.approx(1.0)  # straight up / down
    assert uv[2].tolist() == pytest.approx([0.5, 0.5])  # +X on the horizon: the middle of the texture
    assert uv[3, 0] == pytest.approx(0.75)  # +Y a quarter turn later
    assert uv[4, 0] % 1.0 == pytest.approx(0.0, abs=1e-6) or uv[4, 0] == pytest.approx(1.0)  # -X at the seam


def test_texture_size_follows_the_pixel_footprint():
    assert size_for_focal(10.0) == 64  # 63 texels around: the floor
    assert size_for_focal(40.0) == 256  # 2 pi * 40 = 251
    assert size_for_focal(139.0) == 1024  # 873 -> nearest power of two
    assert size_for_focal(5000.0) == 1024  # capped


def _latitude_environment(width: int = 64, a: float = -1.5, b: float = 0.1) -> EnvironmentMap:
    """An environment whose finest level holds logit a + b * row (a linear function of latitude) and
    whose other levels are zero, so its colour has a closed form away from the poles."""
    env = EnvironmentMap(width=width, levels=3)
    with torch.no_grad():
        for t in env.textures:
            t.zero_()
        fine = env.textures[-1]
        rows = torch.arange(fine.shape[1], dtype=torch.float32)
        fine.copy_((a + b * rows)[None, :, None].expand_as(fine))
        fine[1] *= 0.5  # green and blue differ from red, so a channel mix-up shows
        fine[2] *= -1.0
    return env


def _closed_form(dirs: torch.Tensor, width: int = 64, a: float = -1.5, b: float = 0.1) -> torch.Tensor:
    h = width // 2
    v = torch.acos((dirs[:, 2] / dirs.norm(dim=-1)).clamp(-1, 1)) / math.pi
    row = v * h - 0.5  # bilinear interpolation of a linear function of the row is exact
    logit = a + b * row
    return torch.sigmoid(torch.stack([logit, 0.5 * logit, -logit], -1))


def test_an_empty_box_renders_exactly_the_environment():
    """Closed form: with no density anywhere, every pixel is env(direction), whatever the box."""
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    model = build_model("test-grid", aabb, environment={"width": 64, "levels": 3})
    model.environment = _latitude_environment()
    with torch.no_grad():
        model.grid[:, 0] = -100.0  # softplus(-1000) = 0: an empty box
    # A camera looking across the box horizontally: part of its rays cross the box, the rest miss it.
    cams = Cameras.create(look_at([3.0, 0.5, 0.2], target=[0.0, 0.0, 0.1]), 20.0, 20.0, 12.0, 10.0, 24, 20)
    res = render_view(model, cams, 0, background=(1.0, 1.0, 1.0))
    _, dirs, _ = rays_for_view(cams, 0)
    want = _closed_form(dirs).reshape(20, 24, 3)
    assert torch.allclose(res["rgb"], want, atol=1e-5)
    o, d, _ = rays_for_view(cams, 0)
    near, far = ray_bounds(o.expand_as(d), d, aabb)
    assert (far > near).any() and (far <= near).any()  # both kinds of ray were in the picture


def test_the_scene_occludes_the_environment():
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    model = build_model("test-grid", aabb, res=4, n_samples=64, environment={"width": 64, "levels": 3})
    model.environment = _latitude_environment()
    with torch.no_grad():
        model.grid[:, 0] = 100.0  # an opaque box
        model.grid[:, 1:] = 0.0  # of colour sigmoid(0) = 0.5
    cams = Cameras.create(look_at([3.0, 0.0, 0.0]), 20.0, 20.0, 12.0, 10.0, 24, 20)
    res = render_view(model, cams, 0)
    o, d, _ = rays_for_view(cams, 0)
    near, far = ray_bounds(o.expand_as(d), d, aabb)
    hit = (far > near).reshape(20, 24)
    assert torch.allclose(res["rgb"][hit], torch.full_like(res["rgb"][hit], 0.5), atol=1e-4)
    assert torch.allclose(res["rgb"][~hit], _closed_form(d).reshape(20, 24, 3)[~hit], atol=1e-5)


def test_prefit_learns_a_world_from_directions_alone():
    gen = torch.Generator().manual_seed(0)
    dirs = torch.randn(20000, 3, generator=gen)
    truth = _latitude_environment()
    with torch.no_grad():
        rgb = truth(dirs)
    env = EnvironmentMap(width=64, levels=3)
    with torch.no_grad():
        before = float(((env(dirs) - rgb) ** 2).mean())
    mse = prefit(env, dirs, rgb, steps=300, batch=4096, generator=gen)
    assert mse < before / 50
    assert -10 * math.log10(mse) > 35


# ------------------------------------------------------------------------------------------ auto mode


def _rgba(n=2, h=6, w=5, transparent=0):
    img = torch.full((n, h, w, 4), 255, dtype=torch.uint8)
    if transparent:
        img[:, :transparent, :, 3] = 0
    return img


@pytest.mark.parametrize("images, film, want", [
    (_rgba()[..., :3], None, "environment"),  # RGB photographs
    (_rgba(), None, "environment"),  # RGBA, but alpha 255 everywhere: an opaque render
    (_rgba(transparent=3), None, "random"),  # a cut-out on a transparent film
    (_rgba(transparent=3), False, "environment"),  # the capture says opaque: believe it
    (_rgba(transparent=3), True, "random"),
    (_rgba(), True, "environment"),  # declared transparent, but nothing is: nothing for random to do
])
def test_auto_background_follows_the_declaration_then_the_alpha(images, film, want):
    mode, why = backgrounds.choose(images, film)
    assert mode == want
    assert why  # the start event carries the reason


def _make_opaque(root: Path, film=None) -> Path:
    """Turn a sphere dataset into an opaque capture: every background pixel shows a sky colour that
    depends on the pixel's row (a world seen through the lens), alpha 255 everywhere."""
    for png in sorted(root.glob("*/*.png")):
        px = read_png(png).copy()
        a = px[..., 3:4].astype(np.float32) / 255.0
        rows = np.linspace(40, 200, px.shape[0], dtype=np.float32)[:, None, None]
        sky = np.concatenate([rows * 0.5, rows * 0.8, np.full_like(rows, 220.0)], -1) * np.ones_like(a)
        px[..., :3] = np.round(px[..., :3] * a + sky * (1 - a)).astype(np.uint8)
        px[..., 3] = 255
        write_png(png, px)
    for js in root.glob("transforms*.json"):
        meta = json.loads(js.read_text())
        if film is not None:
            meta["film_transparent"] = film
        js.write_text(json.dumps(meta))
    return root


def _start_event(run: Path) -> dict:
    events = [json.loads(l) for l in (run / "progress.jsonl").read_text().splitlines()]
    return next(e for e in events if e["event"] == "start")


def test_train_picks_the_environment_for_opaque_images_and_says_why(tmp_path, dataset_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds = _make_opaque(dataset_factory(tmp_path / "ds", depth=False))
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=3, batch_rays=64,
                      stdout_events=False, show_bar=False, eval_views=1))
    start = _start_event(run)
    assert start["background"] == "environment"
    assert "opaque" in start["background_reason"]
    assert start["model"]["options"]["environment"]["width"] >= 64
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["background_used"] == "environment"
    # The run renders opaque images with the learned world behind the scene.
    from nerf_core.render.views import render_run

    out = render_run(run, ds, tmp_path / "renders", show_progress=False).parent
    img = read_png(next(out.glob("*.png")))
    assert img.shape[-1] == 4 and (img[..., 3] == 255).all()


def test_train_keeps_random_backgrounds_for_cut_outs(tmp_path, dataset_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds = dataset_factory(tmp_path / "ds", depth=False)
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=3, batch_rays=64,
                      stdout_events=False, show_bar=False, eval_views=0))
    start = _start_event(run)
    assert start["background"] == "random"
    assert "environment" not in start["model"]["options"]


def test_a_declared_opaque_film_wins_over_the_alpha(tmp_path, dataset_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds = dataset_factory(tmp_path / "ds", depth=False)
    for js in ds.glob("transforms*.json"):
        meta = json.loads(js.read_text())
        meta["film_transparent"] = False
        js.write_text(json.dumps(meta))
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=2, batch_rays=64,
                      stdout_events=False, show_bar=False, eval_views=0))
    start = _start_event(run)
    assert start["background"] == "environment" and "film_transparent: false" in start["background_reason"]


def test_a_wrong_type_of_film_transparent_names_the_file_and_field(tmp_path, dataset_factory):
    from nerf_core.contract.errors import DatasetError

    ds = dataset_factory(tmp_path / "ds", depth=False, layouts=("synthetic",))
    meta = json.loads((ds / "transforms_train.json").read_text())
    meta["film_transparent"] = "no"
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=r"transforms_train.json: field 'film_transparent'"):
        load_dataset(ds)


# ------------------------------------------------------------------------------------------- interiors


def test_cameras_inside_the_box_pad_it_and_rays_start_at_the_camera(tmp_path, dataset_factory):
    ds = dataset_factory(tmp_path / "ds", depth=False, layouts=("synthetic",))
    room = [[-4.0, -4.0, -4.0], [4.0, 4.0, 4.0]]  # the cameras (radius 3) stand inside this box
    for js in ds.glob("transforms_*.json"):
        meta = json.loads(js.read_text())
        meta.update(aabb=room, near=0.0)
        js.write_text(json.dumps(meta))
    data = load_dataset(ds)
    assert torch.allclose(data.aabb, torch.tensor([[-4.4] * 3, [4.4] * 3]))  # 5 % of 8 units on each side
    assert any("inside the scene box" in n for n in data.notes)
    origins = data.split("train").cameras.origins
    assert ((origins > data.aabb[0]) & (origins < data.aabb[1])).all()
    o, d, _ = rays_for_view(data.split("train").cameras, 0)
    near, far = ray_bounds(o.expand_as(d), d, data.aabb, data.near, data.far)
    assert torch.all(near == 0)  # sampling starts at the camera, not at a box entry behind it
    assert torch.all(far > 1.0)


def test_an_object_box_is_not_padded():
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    out, note = pad_box_for_interior(box, torch.tensor([[3.0, 0.0, 0.0], [0.0, 3.0, 0.0]]))
    assert note is None and torch.equal(out, box)


# ----------------------------------------------------------------------------------------------- check


def test_check_warns_when_opaque_images_meet_a_fixed_background(tmp_path, dataset_factory):
    from nerf_core.check.dataset import check_dataset

    ds = _make_opaque(dataset_factory(tmp_path / "ds", depth=False))
    auto = check_dataset(ds)
    assert auto.ok and not [w for w in auto.warnings if "background" in str(w)]
    white = check_dataset(ds, background="white")
    msgs = [str(w) for w in white.warnings]
    assert white.ok and any("field 'background'" in m and "opaque" in m and "environment" in m for m in msgs)


def test_check_warns_when_the_declared_film_contradicts_the_images(tmp_path, dataset_factory):
    from nerf_core.check.dataset import check_dataset

    ds = _make_opaque(dataset_factory(tmp_path / "ds", depth=False), film=True)
    msgs = [str(w) for w in check_dataset(ds).warnings]
    assert any("film_transparent" in m and "transparent film" in m for m in msgs)
    cut = dataset_factory(tmp_path / "cut", depth=False)
    for js in cut.glob("transforms*.json"):
        meta = json.loads(js.read_text())
        meta["film_transparent"] = False
        js.write_text(json.dumps(meta))
    msgs = [str(w) for w in check_dataset(cut).warnings]
    assert any("film_transparent" in m and "opaque film" in m for m in msgs)
    # ... and with auto the declared opaque film picks the environment, so no background warning.
    assert not any("field 'background'" in m for m in msgs)


def test_a_resumed_run_keeps_the_background_it_started_with(tmp_path, dataset_factory):
    """Runs from before the environment (white on opaque images) must resume as they were trained."""
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    ds = _make_opaque(dataset_factory(tmp_path / "ds", depth=False))
    run = tmp_path / "run"
    common = dict(dataset=str(ds), out=str(run), method="test-grid", batch_rays=64, stdout_events=False,
                  show_bar=False, eval_views=0)
    train(TrainConfig(max_steps=2, background="white", **common))
    train(TrainConfig(max_steps=4, resume=True, **common))
    starts = [json.loads(l) for l in (run / "progress.jsonl").read_text().splitlines()]
    starts = [e for e in starts if e["event"] == "start"]
    assert [e["background"] for e in starts] == ["white", "white"]
    assert starts[1]["background_reason"] == "as recorded when the run started"


def test_an_opaque_interior_gets_random_colours_not_a_world():
    """Cameras inside the box: every ray should end on a wall, so nothing may be left to a world."""
    mode, why = backgrounds.choose(_rgba(), None, cameras_inside=True)
    assert mode == "random" and "inside" in why
    assert backgrounds.choose(_rgba(), False, cameras_inside=True)[0] == "random"
    # RGB photographs of a room cannot take random colours behind an alpha they do not have.
    assert backgrounds.choose(_rgba()[..., :3], None, cameras_inside=True)[0] == "environment"


def test_outward_cameras_without_a_box_get_one_holding_them_and_what_their_depth_shows(tmp_path):
    """Cameras at the origin looking outward at a wall ring of radius 3 (depth maps say so): the
    estimated box holds every camera and the walls, not just a stretch in front of the cameras."""
    from nerf_core.cameras.rays import Cameras as Cams
    from nerf_core.image.io import write_exr

    w = h = 16
    fx = 8.0
    frames = []
    (tmp_path / "train").mkdir()
    for k in range(8):
        ang = 2 * math.pi * k / 8
        eye = np.array([0.2 * math.cos(ang), 0.2 * math.sin(ang), 1.0])
        c2w = look_at(eye, target=eye + np.array([math.cos(ang), math.sin(ang), 0.0]))
        cams = Cams.create(c2w[None], fx, fx, w / 2, h / 2, w, h)
        o, d, z_per_t = rays_for_view(cams, 0)
        # Distance along each ray to the cylinder of radius 3 around the z axis.
        o2, d2 = o[..., :2].expand(d.shape[0], 2).double(), d[:, :2].double()
        a, b, c = (d2 * d2).sum(-1), 2 * (o2 * d2).sum(-1), (o2 * o2).sum(-1) - 9.0
        t = (-b + torch.sqrt(b * b - 4 * a * c)) / (2 * a)
        write_exr(tmp_path / "train" / f"r_{k}_depth.exr", {"Z": (t * z_per_t.double()).float().reshape(h, w).numpy()})
        write_png(tmp_path / "train" / f"r_{k}.png", np.full((h, w, 4), 200, np.uint8))
        frames.append({"file_path": f"./train/r_{k}", "transform_matrix": c2w.tolist(),
                       "depth_file_path": f"train/r_{k}_depth.exr"})
    (tmp_path / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 2 * math.atan(w / 2 / fx),
                                                                 "frames": frames}))
    data = load_dataset(tmp_path, splits=("train",))
    lo, hi = data.aabb
    assert any("depth maps" in n for n in data.notes)
    assert float(lo[0]) < -2.5 and float(hi[0]) > 2.5 and float(lo[1]) < -2.5 and float(hi[1]) > 2.5  # the walls
    assert float(hi[0]) < 4.0  # and not far beyond them


def test_vmgrid_counts_geometry_as_formed_when_every_ray_is_stopped_even_without_pruning():
    """A room has no empty space to prune: nearly opaque rays must still unlock the fine step and L1."""
    model = build_model("vmgrid", torch.tensor([[-3.0, -2.5, 0.0], [3.0, 2.5, 3.0]]))
    assert not model.pruned() and not model.formed()
    coarse = model.step_size()
    model.opacity.set(0.95)  # what render_rays tracks while training in a room
    assert model.formed() and not model.pruned()
    assert model.step_size() == pytest.approx(coarse / model.options["warmup_step_scale"])
