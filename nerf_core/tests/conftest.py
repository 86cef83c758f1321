"""Fixtures for nerf_core's pipeline tests: tiny test-local methods and small datasets written on the fly.

The methods here are registered under ``test-*`` names so that the pipeline tests neither wait for
nor depend on the real methods in ``nerf_core/methods``. Subprocess tests load them with
``NERF_CORE_PLUGINS=nerf_core.tests.conftest``.
"""
from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path
from typing import Optional

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from nerf_core.cameras.rays import Cameras, rays_for_view
from nerf_core.image.io import write_exr, write_png
from nerf_core.methods.base import RadianceModel
from nerf_core.methods.registry import register
from nerf_core.render.run import Run
from nerf_core.runs.record import RunRecord

REPO_ROOT = Path(__file__).resolve().parents[2]


@register("test-grid")
class TinyGrid(RadianceModel):
    """A dense (res^3) grid of density + RGB, sampled uniformly along each ray; fast on a CPU."""

    default_lr = 0.05

    def __init__(self, aabb, res: int = 12, n_samples: int = 24, **extra):
        # Like the real methods, reject unknown options (only subclasses' own options pass through).
        unknown = set(extra) - set(getattr(self, "extra_options", ()))
        if unknown:
            raise ValueError(f"{self.method_name}: unknown options {sorted(unknown)}")
        super().__init__(aabb, res=res, n_samples=n_samples, **extra)
        self.grid = torch.nn.Parameter(torch.zeros(1, 4, res, res, res))
        with torch.no_grad():
            self.grid[:, 1:] = 0.1 * torch.randn(1, 3, res, res, res)
        self.calls = 0

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        self.calls += 1
        n, s = rays_o.shape[0], self.options["n_samples"]
        dev = rays_o.device  # the trainer picks CUDA when there is one: make every tensor there
        u = (torch.arange(s, dtype=rays_o.dtype, device=dev) + 0.5) / s
        if training:
            u = u + (torch.rand(n, s, device=dev) - 0.5) / s
        t = near[:, None] + (far - near)[:, None] * u  # (n, s)
        pts = rays_o[:, None] + rays_d[:, None] * t[..., None]
        unit = (pts - self.aabb[0]) / (self.aabb[1] - self.aabb[0]) * 2 - 1
        feat = F.grid_sample(self.grid, unit.view(1, n, s, 1, 3), align_corners=True)  # (1, 4, n, s, 1)
        feat = feat[0, :, :, :, 0].permute(1, 2, 0)  # (n, s, 4)
        sigma = F.softplus(feat[..., 0] * 10.0)
        rgb = torch.sigmoid(feat[..., 1:])
        delta = ((far - near) / s)[:, None].expand(n, s)
        alpha = 1 - torch.exp(-sigma * delta)
        trans = torch.cumprod(torch.cat([torch.ones(n, 1, device=dev), 1 - alpha + 1e-10], -1), -1)[:, :-1]
        w = alpha * trans
        acc = w.sum(-1)
        out_rgb = (w[..., None] * rgb).sum(1) + (1 - acc)[:, None] * background
        depth = (w * t).sum(-1) / acc.clamp_min(1e-6)
        return {"rgb": out_rgb, "depth": depth, "acc": acc, "n_samples": n * s}


@register("test-nan")
class NaNOnce(TinyGrid):
    """TinyGrid whose ``nan_at``-th training call returns NaN colours (to exercise rollback)."""

    extra_options = ("nan_at", "nan_times", "nan_in")

    def __init__(self, aabb, nan_at: int = 5, nan_times: int = 1, nan_in: str = "loss", **options):
        super().__init__(aabb, nan_at=nan_at, nan_times=nan_times, nan_in=nan_in, **options)
        self.training_calls = 0

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        out = super().render_rays(rays_o, rays_d, near, far, background, training)
        if training:
            self.training_calls += 1
            start = self.options["nan_at"]
            if start <= self.training_calls < start + self.options["nan_times"]:
                if self.options["nan_in"] == "loss":
                    out["rgb"] = out["rgb"] * float("nan")
                else:
                    # Finite forward, NaN backward: the gradient of sqrt at 0 times 0.
                    zero = (self.grid.sum() * 0.0).clamp_min(0.0) * 0.0
                    out["aux_loss"] = torch.sqrt(zero)
        return out


# ----------------------------------------------------------------------------------------------
# datasets


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenGL camera-to-world (4, 4) at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = eye - target
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


def render_sphere(c2w, fx, fy, cx, cy, w, h, radius=0.6, lens=None):
    """Analytic render of a sphere at the origin: RGBA uint8 (h, w, 4) and planar depth (h, w) (0 = miss).
    ``lens``: a ``contract.Lens`` the camera distorts with (None: a pinhole)."""
    cams = Cameras.create(c2w[None], fx, fy, cx, cy, w, h, lenses=[lens])
    o, d, z_per_t = rays_for_view(cams, 0)
    o = o.expand_as(d).double()
    d = d.double()
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - radius ** 2
    disc = b * b - c
    hit = disc > 0
    t = -b - torch.sqrt(disc.clamp_min(0))
    p = o + d * t[:, None]
    n = p / radius
    rgb = ((n * 0.5 + 0.5).clamp(0, 1) * 255).round().to(torch.uint8)
    rgba = torch.zeros(h * w, 4, dtype=torch.uint8)
    rgba[hit, :3] = rgb[hit]
    rgba[hit, 3] = 255
    depth = torch.where(hit, t * z_per_t.double(), torch.zeros_like(t)).float()
    return rgba.reshape(h, w, 4).numpy(), depth.reshape(h, w).numpy()


def make_dataset(
    root: Path,
    n_train: int = 8,
    n_val: int = 1,
    n_test: int = 2,
    w: int = 24,
    h: int = 20,
    shift=(1.5, -1.0),
    layouts=("synthetic", "nerfstudio"),
    depth: bool = True,
    exr_images: bool = False,
    aabb: bool = True,
    lens: Optional[dict] = None,
) -> Path:
    """Write a small sphere dataset (cameras on a ring at radius 3) in the requested layouts.

    With both layouts nerfstudio's ``transforms.json`` goes to ``nerfstudio/`` (paths ``../...``), as the
    capture writes it; with "nerfstudio" alone it is the dataset root's only JSON. ``lens``: the lens
    fields (``camera_model``, ``k1``...) that every camera has, written at the top level.
    """
    from nerf_core.contract.lens import parse_lens

    lens_obj = parse_lens(lens, None)[0] if lens else None
    root = Path(root)
    fov = 0.9
    fx = fy = 0.5 * w / math.tan(0.5 * fov)
    cx, cy = w / 2 + shift[0], h / 2 + shift[1]
    counts = {"train": n_train, "val": n_val, "test": n_test}
    total = sum(counts.values())
    frames = {}
    k = 0
    for split, count in counts.items():
        frames[split] = []
        (root / split).mkdir(parents=True, exist_ok=True)
        for i in range(count):
            ang = 2 * math.pi * k / total
            elev = 0.3 + 0.2 * math.sin(3 * ang)
            eye = 3.0 * np.array([math.cos(ang) * math.cos(elev), math.sin(ang) * math.cos(elev), math.sin(elev)])
            c2w = look_at(eye)
            rgba, z = render_sphere(c2w, fx, fy, cx, cy, w, h, lens=lens_obj)
            stem = f"r_{i}"
            fr = {"file_path": f"./{split}/{stem}", "transform_matrix": c2w.tolist()}
            if exr_images:
                write_exr(
                    root / split / f"{stem}.exr",
                    {c: rgba[..., j].astype(np.float32) / 255 for j, c in enumerate("RGBA")},
                )
                fr["file_path"] = f"./{split}/{stem}.exr"
            else:
                write_png(root / split / f"{stem}.png", rgba)
            if depth:
                write_exr(root / split / f"{stem}_depth.exr", {"Z": z})
                fr["depth_file_path"] = f"{split}/{stem}_depth.exr"
            frames[split].append(fr)
            k += 1
    intr = {"camera_angle_x": fov, "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": w, "h": h, **(lens or {})}
    scene = {"aabb": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], "near": 1.0, "far": 5.0} if aabb else {}
    if "synthetic" in layouts:
        for split in counts:
            (root / f"transforms_{split}.json").write_text(
                json.dumps({**intr, **scene, "frames": frames[split]}, indent=1)
            )
    if "nerfstudio" in layouts:
        ext = ".exr" if exr_images else ".png"
        ns_frames, lists = [], {}
        for split in counts:
            lists[f"{split}_filenames"] = []
            for fr in frames[split]:
                name = fr["file_path"][2:]
                name = name if name.endswith(ext) else name + ext
                ns_frames.append({**fr, "file_path": name})
                lists[f"{split}_filenames"].append(name)
        ns = {k: v for k, v in intr.items() if k != "camera_angle_x"}
        ns_dir = root
        if "synthetic" in layouts:
            ns_dir = root / "nerfstudio"
            ns_dir.mkdir(exist_ok=True)
            up = lambda p: "../" + p  # noqa: E731
            ns_frames = [{**fr, **{k: up(v) for k, v in fr.items() if k in ("file_path", "depth_file_path")}}
                         for fr in ns_frames]
            lists = {k: [up(v) for v in names] for k, names in lists.items()}
        (ns_dir / "transforms.json").write_text(json.dumps({**ns, **scene, "frames": ns_frames, **lists}, indent=1))
    return root


@pytest.fixture
def sphere_dataset(tmp_path) -> Path:
    return make_dataset(tmp_path / "ds")


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    """One short training run shared by the eval/render/CLI tests (read-only for them)."""
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train

    base = tmp_path_factory.mktemp("shared")
    ds = make_dataset(base / "ds", n_train=8, n_test=2)
    run = base / "run"
    summary = train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=30, batch_rays=256,
                                seed=0, stdout_events=False, show_bar=False, log_every=10, eval_views=2))
    return {"dataset": ds, "run": run, "summary": summary}


@pytest.fixture
def run_copy(trained_run, tmp_path):
    """A private copy of the shared trained run (the shared one is read-only for tests)."""
    run = tmp_path / "run"
    shutil.copytree(trained_run["run"], run)
    return run


@pytest.fixture
def dataset_factory():
    """``make_dataset`` for tests that need a variant (imported through a fixture because
    ``from conftest import`` is ambiguous when several test folders have a conftest.py)."""
    return make_dataset


@pytest.fixture
def one_thread():
    """torch on one thread for the test. Small batches gain little from a second thread and, on a
    shared CPU, OpenMP barriers make two threads several times slower than one. Use it as
    ``pytestmark = pytest.mark.usefixtures("one_thread")``."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def api_example(dataset, run) -> str:
    """The example of docs/API.md ('## Example', the first ```python block) with its DATASET and RUN
    lines pointed at ``dataset`` and ``run``: test_api runs it from the checkout, test_wheel_install
    from an installed wheel, so the page's example is what both prove."""
    text = (REPO_ROOT / "docs" / "API.md").read_text(encoding="utf-8")
    m = re.search(r"^## Example\s*$(.*?)^```python\n(.*?)^```", text, flags=re.M | re.S)
    assert m, "docs/API.md has no ```python block under '## Example'"
    assert "\n## " not in m.group(1), "the ```python block is not the first thing under '## Example'"
    code = m.group(2)
    for line, value in (('DATASET = "scene_dataset"', f"DATASET = {str(dataset)!r}"),
                        ('RUN = "runs/scene"', f"RUN = {str(run)!r}")):
        assert line in code.splitlines(), f"the example must begin with {line!r} (the tests replace it)"
        code = code.replace(line, value, 1)
    return code


@pytest.fixture
def api_example_code():
    """``api_example`` as a fixture (see ``dataset_factory`` for why not an import)."""
    return api_example


def opened_run(model, config: Optional[dict] = None, step: int = 7, method: str = "sphere", path="run") -> Run:
    """A ``Run`` around ``model``, as ``open_run`` gives it, with ``config`` as its config.json (no dataset
    by default): for export tests that replace the loader (``use_model``)."""
    config = {"dataset": None, **(config or {})}
    record = RunRecord(path=Path(path) / "config.json", dataset=config.get("dataset"),
                       dataset_hash=config.get("dataset_hash"), method=method, near=None, far=None,
                       eval_background=(1.0, 1.0, 1.0), downscale=1, aabb=None, raw=config)
    return Run(Path(path), model, record, {"step": step, "method": method})


def use_model(monkeypatch, model, **kw) -> None:
    """Make ``export`` open ``model`` whatever the run folder (``run_export.open_run`` replaced); ``kw``
    go to ``opened_run``. ``monkeypatch`` None: replaced for good (a child process's script)."""
    from nerf_core.export import run_export

    def fake(run, device=None, checkpoint=None):
        return opened_run(model, path=run, **kw)
    if monkeypatch is None:
        run_export.open_run = fake
    else:
        monkeypatch.setattr(run_export, "open_run", fake)
