"""The declared model interface (``methods.base.RadianceModel``): a new method is one class in one file,
typed options checked in one place, run state kept apart from the options, one ``load_weights``."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from nerf_core.methods.base import RadianceModel
from nerf_core.methods.nerf_options import NeRFOptions
from nerf_core.methods.registry import build_model, method_class, saved_options, saved_run_state
from nerf_core.methods.vmgrid_options import VMGridOptions

REPO_ROOT = Path(__file__).resolve().parents[2]
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])

# A whole method in one file: typed options, the training defaults it changes, render_rays, a loss
# term of its own, and the registry line. Nothing else in the library is touched.
TOY = '''
import dataclasses

import torch

from nerf_core import RadianceModel, register
from nerf_core.methods.options import MethodOptions, option


@dataclasses.dataclass
class ToyOptions(MethodOptions):
    samples: int = option(16, "samples per ray", low=1, high=256)
    smooth: float = option(0.0, "weight of a smoothness loss on the grid")


@register("toy")
class Toy(RadianceModel):
    Options = ToyOptions
    default_lr = 0.05
    default_batch_rays = 256

    def __init__(self, aabb, **options):
        super().__init__(aabb, **options)
        self.grid = torch.nn.Parameter(torch.zeros(4, 6, 6, 6))

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        n, s = rays_o.shape[0], self.opts.samples
        t = near[:, None] + (far - near)[:, None] * (torch.arange(s, device=rays_o.device) + 0.5) / s
        pts = rays_o[:, None] + rays_d[:, None] * t[..., None]
        unit = (pts - self.aabb[0]) / (self.aabb[1] - self.aabb[0]) * 2 - 1
        feat = torch.nn.functional.grid_sample(self.grid[None], unit.view(1, n, s, 1, 3), align_corners=True)
        feat = feat[0, :, :, :, 0].permute(1, 2, 0)
        sigma, rgb = torch.nn.functional.softplus(feat[..., 0] * 10), torch.sigmoid(feat[..., 1:])
        alpha = 1 - torch.exp(-sigma * ((far - near) / s)[:, None])
        trans = torch.cumprod(torch.cat([torch.ones(n, 1), 1 - alpha + 1e-10], -1), -1)[:, :-1]
        w = alpha * trans
        acc = w.sum(-1)
        out = {"rgb": (w[..., None] * rgb).sum(1) + (1 - acc)[:, None] * background,
               "depth": (w * t).sum(-1) / acc.clamp_min(1e-6), "acc": acc, "n_samples": n * s}
        if training:
            out["smoothness"] = (self.grid[:, 1:] - self.grid[:, :-1]).abs().mean()
        return out

    def loss(self, out, target, weight):
        loss, mse = super().loss(out, target, weight)
        return loss + self.opts.smooth * out["smoothness"], mse
'''


def _cli(*args, cwd, plugin_dir):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), str(plugin_dir)]),
               NERF_CORE_PLUGINS="toy_method", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "nerf_core", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=300)


def test_a_method_in_one_file_trains_renders_and_evaluates_through_the_cli(sphere_dataset, tmp_path):
    plugins = tmp_path / "plugins"
    plugins.mkdir()
    (plugins / "toy_method.py").write_text(TOY)
    run = tmp_path / "run"
    proc = _cli("train", str(sphere_dataset), "--out", str(run), "--method", "toy", "--max-steps", "30",
                "--set", "samples=12", "--set", "smooth=0.01", "--no-bar", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    start = next(json.loads(line) for line in proc.stdout.splitlines() if '"start"' in line)
    assert start["model"]["options"] == {"samples": 12, "smooth": 0.01}
    config = json.loads((run / "config.json").read_text())
    assert config["lr"] == 0.05 and config["batch_rays"] == 256  # the method's own training defaults
    proc = _cli("render", str(run), "--out", str(tmp_path / "renders"), "--no-bar", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "renders").glob("*.png"))
    proc = _cli("eval", str(run), "--no-bar", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1])["psnr"] > 10
    # An option out of its declared bounds is refused before a run folder is made, naming it.
    proc = _cli("train", str(sphere_dataset), "--out", str(tmp_path / "bad"), "--method", "toy", "--set",
                "samples=0", "--max-steps", "2", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 2 and "toy: option 'samples' must be in [1, 256], got 0" in proc.stderr
    assert not (tmp_path / "bad").exists()
    proc = _cli("methods", "toy", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0 and "samples = 16\n    samples per ray" in proc.stdout



# A method that owns its whole step, in one file: its own batcher (one view per step, half the rays it
# is asked for), its own optimiser (SGD with a state layout Adam's would refuse: a count per row of each
# parameter) and its own optimizer_step, which reads what the step rendered.
TOY_STEP = TOY.replace('@register("toy")', '@register("toy-step")').replace("class Toy(", "class ToyStep(") + """

from nerf_core.cameras.rays import rays_for_pixels
from nerf_core.data.batcher import Batcher, RayBatch
from nerf_core.optim import TrainingOptimizer


class OneView(Batcher):
    def __init__(self, split, background, gen, device):
        self.split, self.gen, self.device = split, gen, device

    def sample(self, n, frac=1.0):
        n = n // 2
        view = torch.randint(0, len(self.split), (1,), generator=self.gen).expand(n)
        j = torch.randint(0, self.split.height, (n,), generator=self.gen)
        i = torch.randint(0, self.split.width, (n,), generator=self.gen)
        bg = torch.ones(n, 3)
        rgb, _ = self.split.pixels(view, j, i, bg)
        o, d, _ = rays_for_pixels(self.split.cameras, view, i, j)
        return RayBatch(o, d, bg, rgb, None)


class CountingSGD(TrainingOptimizer, torch.optim.SGD):
    def __init__(self, groups):
        super().__init__(groups, momentum=0.9)

    def state_shape(self, key, param):
        return {"rows": (param.shape[0],), "rays": ()}.get(key, tuple(param.shape))


ToyStep.make_batcher = lambda self, split, background, gen, device, *extra: OneView(split, background, gen, device)
ToyStep.make_optimizer = lambda self, lr: CountingSGD(self.optimizer_groups(lr))


def optimizer_step(self, opt, out):
    opt.step()
    for group in opt.param_groups:
        for p in group["params"]:
            st = opt.state[p]
            st["rows"] = st.get("rows", torch.zeros(p.shape[0])) + 1
            st["rays"] = st.get("rays", torch.zeros(())) + out["rgb"].shape[0]


ToyStep.optimizer_step = optimizer_step
"""


def test_a_method_with_its_own_batcher_and_optimiser_trains_resumes_renders_and_evaluates(sphere_dataset, tmp_path):
    plugins = tmp_path / "plugins"
    plugins.mkdir()
    (plugins / "toy_method.py").write_text(TOY_STEP)
    run = tmp_path / "run"
    proc = _cli("train", str(sphere_dataset), "--out", str(run), "--method", "toy-step", "--max-steps", "20",
                "--checkpoint-every", "10", "--no-bar", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    state = torch.load(run / "checkpoints" / "latest.pt", weights_only=True)["optimizer"]["state"]
    # The method's optimizer_step ran every step, on its own batcher's 128 rays (half of batch_rays 256).
    assert {float(s["rays"]) for s in state.values()} == {20 * 128.0}
    assert all(torch.equal(s["rows"], torch.full_like(s["rows"], 20.0)) for s in state.values())
    assert all("momentum_buffer" in s for s in state.values())  # SGD's, not Adam's moments
    # The optimiser checks its own saved layout: --resume keeps it rather than starting afresh.
    proc = _cli("train", str(sphere_dataset), "--out", str(run), "--resume", "--max-steps", "30", "--no-bar",
                cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    assert "afresh" not in proc.stderr
    state = torch.load(run / "checkpoints" / "latest.pt", weights_only=True)["optimizer"]["state"]
    assert {float(s["rays"]) for s in state.values()} == {30 * 128.0}
    proc = _cli("render", str(run), "--out", str(tmp_path / "renders"), "--no-bar", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    proc = _cli("eval", str(run), "--no-bar", cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1])["psnr"] > 5
    # A damaged count is refused by that same check, naming the file: the trainer starts SGD afresh.
    ckpt = torch.load(run / "checkpoints" / "latest.pt", weights_only=True)
    first = next(iter(ckpt["optimizer"]["state"].values()))
    first["rows"] = torch.zeros(3)
    for name in ("latest.pt", *[p.name for p in (run / "checkpoints").glob("step_*.pt")]):
        torch.save(ckpt, run / "checkpoints" / name)
    proc = _cli("train", str(sphere_dataset), "--out", str(run), "--resume", "--max-steps", "31", "--no-bar",
                cwd=tmp_path, plugin_dir=plugins)
    assert proc.returncode == 0, proc.stderr
    assert "optimiser state 'rows' of parameter" in proc.stderr and "starting CountingSGD afresh" in proc.stderr


@pytest.mark.parametrize("name, options, words", [
    ("vmgrid", {"res_init": 1}, "option 'res_init' must be in [2, 2048], got 1"),
    ("vmgrid", {"occ_alpha": 1.0}, "option 'occ_alpha' must be in (0, 1), got 1.0"),
    ("vmgrid", {"upsample_at": [0.2, 1.5]}, "option 'upsample_at' must be a list of numbers in (0, 1)"),
    ("vmgrid", {"occ_probe": "mean"}, "option 'occ_probe' must be one of \"max\", \"random\""),
    ("vmgrid", {"resolution": 64}, "unknown options ['resolution']"),  # run state, not an option
    ("nerf", {"pos_freqs": 200}, "option 'pos_freqs' must be in [0, 20], got 200"),
    ("nerf", {"train_ert": "yes"}, "option 'train_ert' must be one of \"auto\", true, false"),
    ("nerf", {"width": 64.5}, "option 'width' must be a whole number, got 64.5"),
    ("nerf", {"skip": 5, "depth": 4}, "option 'skip' (5) must be at most 'depth' (4)"),
])
def test_options_are_checked_by_their_declared_fields(name, options, words):
    with pytest.raises(ValueError) as err:
        build_model(name, BOX, **options)
    assert words in str(err.value)


def test_each_option_has_a_one_line_doc_and_variants_fix_theirs():
    for options in (VMGridOptions, NeRFOptions):
        docs = options.docs()
        assert docs and all(doc and "\n" not in doc for doc in docs.values())
    assert build_model("nerf-nope", BOX, use_pe=True).opts.use_pe is False
    assert build_model("vmgrid-noview", BOX, res_init=8, res_final=16).opts.view_dependent is False
    # An option the method declares is seen by has_option through its Options, not a dict of defaults.
    assert "unbounded" in method_class("vmgrid").Options.declared()


def test_the_grid_size_is_run_state_saved_apart_from_the_options():
    model = build_model("vmgrid", BOX, res_init=8, res_final=16, upsample_at=[0.5], min_stage_steps=0,
                        density_rank=2, app_rank=2, mlp_width=8, occ_res=8)
    assert model.run_state() == {"resolution": 8, "res_final_budget": None}
    model.field.upsample(16)
    assert model.run_state()["resolution"] == 16 and "resolution" not in model.options
    # A checkpoint written before the run state had its own entry kept it among the options.
    old = {"options": {**model.options, "resolution": 16, "res_final_budget": 24}}
    assert saved_run_state("vmgrid", old) == {"resolution": 16, "res_final_budget": 24}
    assert "resolution" not in saved_options("vmgrid", old["options"])
    new = {"method_state": {"resolution": 16, "res_final_budget": None}, "options": old["options"]}
    assert saved_run_state("vmgrid", new) == {"resolution": 16, "res_final_budget": None}
    fresh = build_model("vmgrid", BOX, **saved_options("vmgrid", old["options"]))
    fresh.restore_run_state(saved_run_state("vmgrid", old))
    fresh.load_state_dict(model.state_dict())  # the grid's size comes with the weights
    assert fresh.field.resolution == 16 and fresh.res_final_budget == 24
    with pytest.raises(ValueError, match="run state .resolution. must be a whole number in 8..320"):
        fresh.restore_run_state({"resolution": 10 ** 6})


def test_load_weights_is_the_same_for_a_loader_and_for_resume():
    from nerf_core.runs.weights import load_weights, model_from_checkpoint

    grown = build_model("vmgrid", BOX, res_init=8, res_final=16, density_rank=2, app_rank=2, mlp_width=8, occ_res=8)
    grown.field.upsample(16)
    ckpt = {"method": "vmgrid", "options": grown.options, "method_state": grown.run_state(), "aabb": BOX,
            "model": grown.state_dict()}
    loaded = model_from_checkpoint(ckpt, torch.device("cpu"))
    resumed = build_model("vmgrid", BOX, **grown.options)
    assert load_weights(resumed, ckpt) is None  # no optimiser state in this checkpoint
    for model in (loaded, resumed):
        assert model.field.resolution == 16
        assert all(torch.equal(v, grown.state_dict()[k]) for k, v in model.state_dict().items())


def test_render_batch_does_the_interval_and_the_background():
    class Flat(RadianceModel):
        def render_rays(self, rays_o, rays_d, near, far, background, training):
            self.seen = (near, far, background)
            n = rays_o.shape[0]
            return {"rgb": background, "depth": far, "acc": torch.zeros(n)}

    model = Flat(BOX)
    o = torch.tensor([[0.0, 0.0, -3.0]]).repeat(2, 1)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    out = model.render_batch(o, d, torch.tensor([0.2, 0.3, 0.4]), near=0.5, far=10.0)
    near, far, bg = model.seen
    assert torch.allclose(near[0], torch.tensor(2.0)) and torch.allclose(far[0], torch.tensor(4.0))
    assert bg.shape == (2, 3) and torch.equal(out["rgb"][1], torch.tensor([0.2, 0.3, 0.4]))
    loss, mse = model.loss({"rgb": torch.zeros(2, 3), "aux_loss": torch.tensor(1.0)}, torch.ones(2, 3), None)
    assert float(mse) == pytest.approx(1.0) and float(loss) == pytest.approx(2.0)


def test_open_run_renders_with_the_runs_own_bounds_and_background(trained_run):
    import nerf_core

    path = trained_run["run"]
    run = nerf_core.open_run(path, device="cpu")
    assert isinstance(run, nerf_core.Run) and run.config.near == json.loads(
        (Path(path) / "config.json").read_text())["near"]
    test = run.dataset.split("test")
    out = run.render(test.cameras, 0)
    model, config, _ = nerf_core.load_run(path, torch.device("cpu"))
    same = nerf_core.render_view(model, test.cameras, 0, background=tuple(config["eval_background"]),
                                 near=config["near"], far=config["far"])
    assert torch.equal(out["rgb"], same["rgb"]) and out["rgb"].shape == (test.height, test.width, 3)


def test_the_train_flags_are_generated_from_the_config_fields():
    from nerf_core.cli.main import build_parser
    from nerf_core.cli.train import config_from_args
    from nerf_core.engine.config import TrainConfig

    a = build_parser().parse_args(["train", "ds", "--out", "r"])
    assert config_from_args(a) == TrainConfig(dataset="ds", out="r")  # every default declared once
    a = build_parser().parse_args(["train", "ds", "--out", "r", "--no-bar", "--eval-at", "60,30", "--set", "x=1"])
    cfg = config_from_args(a)
    assert (cfg.show_bar, cfg.eval_at, cfg.options) == (False, [30.0, 60.0], {"x": 1})


def test_no_method_module_documents_its_options_twice():
    # The long reasons behind the defaults live in docs/METHODS.md, not in the methods' docstrings.
    text = textwrap.dedent((REPO_ROOT / "nerf_core" / "methods" / "vmgrid.py").read_text())
    assert "diffuse 42.10 / 41.89" not in text
    assert "diffuse 42.10 / 41.89" in (REPO_ROOT / "docs" / "METHODS.md").read_text()
