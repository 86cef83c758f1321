"""Guards: what happens when training meets bad or degenerate input.

Each test drives the public CLI (``python -m nerf_core ...``) or public classes on a tiny synthetic
dataset (a coloured sphere, 16x16 pixels), and asserts the behaviour users need: a run either
continues sensibly or stops with one clear message naming the file/field, never a traceback, and
never overwrites existing data.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

REPO_ROOT = Path(__file__).resolve().parents[2]
# Few, small steps: these tests check behaviour, not quality, and the CPU is shared.
FAST = ["--max-steps", "4", "--batch-rays", "128", "--no-bar"]
SIZE = 16


# ---------------------------------------------------------------- a tiny analytic scene


def _look_at(eye: np.ndarray) -> np.ndarray:
    """camera-to-world (4, 4) of an OpenGL camera at ``eye`` looking at the origin, +Z up."""
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -fwd, eye
    return c2w


def _sphere_image(c2w: np.ndarray, focal: float, radius: float = 0.6) -> np.ndarray:
    """(SIZE, SIZE, 4) uint8 RGBA of a sphere at the origin coloured by its normal, transparent elsewhere."""
    j, i = np.mgrid[0:SIZE, 0:SIZE]
    d = np.stack([(i + 0.5 - SIZE / 2) / focal, -(j + 0.5 - SIZE / 2) / focal, -np.ones_like(i, float)], -1)
    d = d @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = c2w[:3, 3]
    b = d @ o
    disc = b ** 2 - (o @ o - radius ** 2)
    hit = disc > 0
    t = -b - np.sqrt(np.where(hit, disc, 0))
    n = (o + t[..., None] * d) / radius
    rgb = np.where(hit[..., None], 0.5 + 0.5 * n, 0.0)
    return (np.dstack([rgb, hit.astype(float)]) * 255).round().astype(np.uint8)


def make_dataset(root: Path, n_train: int = 12, n_test: int = 2, pixels=None, aabb=None) -> Path:
    """A synthetic-layout dataset; ``pixels(c2w, focal) -> RGBA uint8`` overrides the sphere."""
    root.mkdir(parents=True)
    fov = 0.8
    focal = 0.5 * SIZE / math.tan(0.5 * fov)
    render = pixels or _sphere_image
    for split, n, offset in (("train", n_train, 0.0), ("val", 1, 0.37), ("test", n_test, 0.5)):
        (root / split).mkdir()
        frames = []
        for k in range(n):
            a = 2 * math.pi * (k + offset) / max(n, 1)
            eye = np.array([3 * math.cos(a), 3 * math.sin(a), 1.0 + 0.5 * math.sin(3 * a)])
            c2w = _look_at(eye)
            Image.fromarray(render(c2w, focal), "RGBA").save(root / split / f"r_{k}.png")
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": c2w.tolist()})
        meta = {"camera_angle_x": fov, "fl_x": focal, "fl_y": focal, "cx": SIZE / 2, "cy": SIZE / 2,
                "w": SIZE, "h": SIZE, "aabb": aabb if aabb is not None else [[-1, -1, -1], [1, 1, 1]],
                "near": 1.0, "far": 5.0, "frames": frames}
        (root / f"transforms_{split}.json").write_text(json.dumps(meta))
    return root


def nerf_core(*args, timeout: float = 300, plugins: str = "") -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), plugins]))}
    if plugins:
        env["NERF_CORE_PLUGINS"] = "guard_methods"
    return subprocess.run([sys.executable, "-m", "nerf_core", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO_ROOT, env=env, timeout=timeout)


def events(proc: subprocess.CompletedProcess) -> list[dict]:
    out = []
    for line in proc.stdout.splitlines():
        if line.startswith("{"):
            try:
                out.append(json.loads(line))
            except ValueError:
                pass
    return out


def assert_clear_failure(proc: subprocess.CompletedProcess, *must_name: str) -> str:
    """Non-zero exit, an ``error`` event or stderr line naming every ``must_name``, and no traceback."""
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0, f"expected a failure, got exit 0:\n{text[-2000:]}"
    assert "Traceback" not in text, f"a traceback reached the user:\n{text[-3000:]}"
    errors = [e["message"] for e in events(proc) if e.get("event") == "error"]
    # The error event for train; for check, its report (stdout) lists every problem.
    plain = "\n".join(l for l in text.splitlines() if not l.startswith("{"))
    message = errors[-1] if errors else plain.strip()
    for name in must_name:
        assert name in message, f"the message should name {name!r}: {message!r}"
    return message


@pytest.fixture(scope="module")
def sphere(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("guards") / "sphere")


# ---------------------------------------------------------------- degenerate inputs


def test_single_view_is_refused_clearly_or_trains(tmp_path):
    ds = make_dataset(tmp_path / "one", n_train=1)
    proc = nerf_core("train", ds, "--out", tmp_path / "run", *FAST)
    if proc.returncode == 0:
        done = [e for e in events(proc) if e.get("event") == "done"]
        assert done, "exit 0 without a done event"
    else:
        message = assert_clear_failure(proc)
        assert "view" in message and ("train" in message or "transforms_train.json" in message), message


def _train_and_eval(ds: Path, run: Path) -> dict:
    """Train a few steps; every loss finite, a done event, and the final test evaluation's metrics."""
    proc = nerf_core("train", ds, "--out", run, *FAST)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    evs = events(proc)
    steps = [e for e in evs if e.get("event") == "step"]
    assert steps and all(e.get("loss") is not None and math.isfinite(e["loss"]) for e in steps), steps[-3:]
    assert not [e for e in evs if e.get("event") == "rollback"], "clean data must not need a rollback"
    done = [e for e in evs if e.get("event") == "done"]
    assert done, "no done event"
    return done[-1]["metrics"]


def test_all_transparent_images_are_refused_clearly(tmp_path):
    # Nothing to learn: once a run that trained to exit 0 (finite, but a model of nothing).
    ds = make_dataset(tmp_path / "clear", pixels=lambda c2w, f: np.zeros((SIZE, SIZE, 4), np.uint8))
    proc = nerf_core("train", ds, "--out", tmp_path / "run", *FAST)
    message = assert_clear_failure(proc)
    assert "train images are fully transparent" in message and "transforms_train.json" in message, message


def test_all_black_images_are_refused_clearly(tmp_path):
    black = np.zeros((SIZE, SIZE, 4), np.uint8)
    black[..., 3] = 255
    ds = make_dataset(tmp_path / "black", pixels=lambda c2w, f: black)
    message = assert_clear_failure(nerf_core("train", ds, "--out", tmp_path / "run", *FAST))
    assert "train images are opaque and black everywhere" in message and "transforms_train.json" in message, message


def test_nearly_black_images_train_without_nan(tmp_path):
    dim = np.full((SIZE, SIZE, 4), 3, np.uint8)  # 3/255: a dark scene, not a black one
    dim[..., 3] = 255
    ds = make_dataset(tmp_path / "dim", pixels=lambda c2w, f: dim)
    metrics = _train_and_eval(ds, tmp_path / "run")
    assert metrics.get("psnr") is not None and math.isfinite(metrics["psnr"]), metrics


def test_a_tiny_subject_is_named_before_training(tmp_path):
    """A 170-degree lens left the subject 0.2 % of each frame: the log said "100.0 % of the pixels are
    transparent" and the run's whole-image PSNR counted the empty film. Now check and train say so."""
    from nerf_core.data.backgrounds import SMALL_SUBJECT_SHARE, percent_text, small_subject_note

    speck = np.zeros((SIZE, SIZE, 4), np.uint8)
    speck[7, 7] = [200, 100, 50, 255]  # one pixel of 256: 0.4 %
    ds = make_dataset(tmp_path / "speck", pixels=lambda c2w, f: speck)
    proc = nerf_core("check", ds, "--for-training")  # this helper's test cameras repeat train ones
    assert proc.returncode == 0 and "the subject covers only 0.4 % of the train pixels" in proc.stdout, proc.stdout
    assert "99.6 % of the pixels are at least partly transparent" in proc.stdout, proc.stdout
    proc = nerf_core("train", ds, "--out", tmp_path / "run", *FAST)
    assert proc.returncode == 0 and "note: the subject covers only 0.4 %" in proc.stderr, proc.stderr
    # the sphere of the other tests fills enough; opaque images have no subject to measure
    assert (
        small_subject_note(torch.from_numpy(np.stack([_sphere_image(_look_at(np.array([0, -3.0, 0])), 20.0)]))) is None
    )
    assert small_subject_note(torch.full((2, 8, 8, 4), 255, dtype=torch.uint8)) is None
    assert SMALL_SUBJECT_SHARE == 0.02
    assert [percent_text(v) for v in (1.0, 0.99996, 0.5, 2e-5, 0.0)] == [
        "100.0 %",
        "99.996 %",
        "50.0 %",
        "0.002 %",
        "0.0 %",
    ]


def test_degenerate_scene_box_is_named(tmp_path):
    ds = make_dataset(tmp_path / "flat", aabb=[[0, 0, 0], [0, 0, 0]])
    check = nerf_core("check", ds)
    assert_clear_failure(check, "aabb")
    assert_clear_failure(nerf_core("train", ds, "--out", tmp_path / "run", *FAST), "aabb")
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_missing_dataset_and_broken_image_are_named(tmp_path, sphere):
    missing = tmp_path / "nowhere"
    assert_clear_failure(nerf_core("train", missing, "--out", tmp_path / "run1", *FAST), str(missing))
    ds = make_dataset(tmp_path / "broken", n_train=3)
    (ds / "train" / "r_1.png").write_bytes(b"not a png at all")
    assert_clear_failure(nerf_core("train", ds, "--out", tmp_path / "run2", *FAST), "r_1.png")


def test_existing_run_is_never_overwritten(tmp_path, sphere):
    run = tmp_path / "run"
    run.mkdir()
    keep = run / "my_notes.txt"
    keep.write_text("precious")
    assert_clear_failure(nerf_core("train", sphere, "--out", run, *FAST), str(run.name))
    assert keep.read_text() == "precious"
    assert sorted(p.name for p in run.iterdir()) == ["my_notes.txt"]


# ---------------------------------------------------------------- recovery inside training

PLUGIN = '''
"""Test-only methods registered through NERF_CORE_PLUGINS: a constant colour that turns NaN on cue."""
import torch
from nerf_core import RadianceModel, register


class _Poisoned(RadianceModel):
    default_lr = 1e-2
    poison_from = 3   # training forward passes from which the output is NaN ...
    poison_until = 3  # ... up to and including this one

    def __init__(self, aabb, **options):
        super().__init__(aabb, **options)
        self.colour = torch.nn.Parameter(torch.zeros(3))
        self.calls = 0  # not state: a rollback does not rewind it, so the poison passes

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        n = rays_o.shape[0]
        rgb = torch.sigmoid(self.colour).expand(n, 3)
        if training:
            self.calls += 1
            if self.poison_from <= self.calls <= self.poison_until:
                rgb = rgb * float("nan")
        return {"rgb": rgb, "depth": 0.5 * (near + far), "acc": torch.ones(n, device=rays_o.device)}


@register("guard-nan-once")
class NaNOnce(_Poisoned):
    pass


@register("guard-nan-always")
class NaNAlways(_Poisoned):
    poison_until = 10 ** 9
'''


@pytest.fixture(scope="module")
def plugin_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("plugins")
    (d / "guard_methods.py").write_text(PLUGIN)
    return d


def test_nan_step_is_rolled_back_and_training_finishes(tmp_path, sphere, plugin_dir):
    proc = nerf_core("train", sphere, "--out", tmp_path / "run", "--method", "guard-nan-once", "--max-steps", "8",
                     "--batch-rays", "64", "--log-every", "1", "--eval-views", "0", "--no-bar", plugins=str(plugin_dir))
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    evs = events(proc)
    rollbacks = [e for e in evs if e.get("event") == "rollback"]
    assert len(rollbacks) == 1, rollbacks
    assert "nan" in rollbacks[0]["reason"].lower(), rollbacks[0]
    first_lr = next(e["lr"] for e in evs if e.get("event") == "step")
    assert rollbacks[0]["lr"] < first_lr * 1.0001, "a rollback should not raise the learning rate"
    steps = [e for e in evs if e.get("event") == "step"]
    assert steps[-1]["step"] == 8 and all(math.isfinite(e["loss"]) for e in steps)
    assert any(e.get("event") == "done" for e in evs)


def test_run_that_keeps_diverging_stops_with_a_clear_message(tmp_path, sphere, plugin_dir):
    proc = nerf_core("train", sphere, "--out", tmp_path / "run", "--method", "guard-nan-always", "--max-steps", "20",
                     "--batch-rays", "64", "--eval-views", "0", "--no-bar", plugins=str(plugin_dir))
    message = assert_clear_failure(proc)
    assert "diverged" in message or "NaN" in message or "nan" in message, message
    # Whatever was trained before the failure stays on disk for inspection, and the run can be named.
    assert (tmp_path / "run" / "config.json").is_file()



def test_occupancy_grid_that_empties_reopens():
    from nerf_core.volume.occupancy import OccupancyGrid

    grid = OccupancyGrid(torch.tensor([[-1.0, -1, -1], [1, 1, 1]]), resolution=8)
    grid.update(lambda pts: torch.zeros(pts.shape[0]), step_size=0.01)
    assert grid.binary.all(), "an all-zero density must not leave an empty grid (rays would see nothing)"
    # A blob at the centre: after the update only cells near it stay occupied.
    grid.update(lambda pts: 100.0 * (pts.norm(dim=-1) < 0.3).float(), step_size=0.01, decay=0.0)
    frac = grid.occupied_fraction
    assert 0 < frac < 0.5, frac
    assert bool(grid.query(torch.zeros(1, 3))) and not bool(grid.query(torch.tensor([[0.95, 0.95, 0.95]])))


def _fast_model_with_grid(aabb):
    from nerf_core.methods.catalog import DEFAULT_METHOD
    from nerf_core.methods.registry import build_model
    from nerf_core.volume.occupancy import OccupancyGrid

    model = build_model(DEFAULT_METHOD, aabb)
    grids = [m for m in model.modules() if isinstance(m, OccupancyGrid)]
    return model, grids


def _rays(ds: Path, n: int = 128):
    """Random training rays (o, d, near, far, rgb on white) of ``ds`` from its JSON (contract pixel rule)."""
    meta = json.loads((ds / "transforms_train.json").read_text())
    rng = np.random.default_rng(0)
    f = meta["fl_x"]
    rows = []
    for fr in meta["frames"]:
        c2w = np.asarray(fr["transform_matrix"])
        img = np.asarray(Image.open(ds / (fr["file_path"] + ".png")), np.float32) / 255
        for _ in range(n // len(meta["frames"]) + 1):
            i, j = rng.integers(0, SIZE, 2)
            d = c2w[:3, :3] @ np.array([(i + 0.5 - SIZE / 2) / f, -(j + 0.5 - SIZE / 2) / f, -1.0])
            px = img[j, i]
            rows.append((c2w[:3, 3], d / np.linalg.norm(d), px[:3] * px[3] + (1 - px[3])))
    o, d, c = (torch.tensor(np.stack(x), dtype=torch.float32) for x in zip(*rows[:n]))
    # Clip to the box [-1, 1]^3 as the trainer does (cameras are outside it).
    with torch.no_grad():
        t0, t1 = (-1 - o) / d, (1 - o) / d
        near = torch.minimum(t0, t1).amax(-1).clamp_min(1.0)
        far = torch.maximum(t0, t1).amin(-1).clamp(min=near + 1e-3)
    return o, d, near, far, c


def test_training_recovers_after_the_occupancy_grid_empties(sphere):
    torch.manual_seed(0)
    aabb = torch.tensor([[-1.0, -1, -1], [1, 1, 1]])
    model, grids = _fast_model_with_grid(aabb)
    if not grids:
        pytest.fail("the default fast method has no OccupancyGrid submodule; this guard has nothing to check")
    o, d, near, far, target = _rays(sphere)
    bg = torch.ones_like(target)
    opt = torch.optim.Adam(model.param_groups(getattr(model, "default_lr", 1e-3)))

    def step(k):
        if model.training_hook(k, k / 200):
            nonlocal opt
            opt = torch.optim.Adam(model.param_groups(getattr(model, "default_lr", 1e-3)))
        out = model.render_rays(o, d, near, far, bg, training=True)
        loss = torch.mean((out["rgb"] - target) ** 2) + out.get("aux_loss", 0.0)
        opt.zero_grad()
        loss.backward()
        opt.step()
        return float(loss.detach())

    first = [step(k) for k in range(16)]
    # Empty the grid by hand (what a density collapse does): every sample is skipped.
    for g in grids:
        g.binary.fill_(False)
    with torch.no_grad():
        out = model.render_rays(o, d, near, far, bg, training=False)
        empty_loss = float(torch.mean((out["rgb"] - target) ** 2))
    assert torch.isfinite(out["rgb"]).all() and torch.allclose(out["rgb"], bg), "an empty grid renders background"
    # Training continues: the next occupancy update (the trainer calls training_hook every step)
    # reopens cells around what the field had learnt, and the loss is again below background-only.
    after = [step(k) for k in range(16, 40)]
    assert all(math.isfinite(x) for x in first + after)
    assert any(g.binary.any() for g in grids), "the grid never reopened"
    assert after[-1] < 0.8 * empty_loss, (empty_loss, first[-1], after[-5:])
