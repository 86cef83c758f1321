"""Trainer: run folder and events, resume, refusal to overwrite, NaN rollback, determinism, budgets."""
import json
import math

import pytest
import torch

from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.errors import TrainError
from nerf_core.runs.events import read_events


def _cfg(ds, run, **kw):
    base = dict(dataset=str(ds), out=str(run), method="test-grid", max_steps=20, batch_rays=128, seed=0,
                stdout_events=False, show_bar=False, log_every=5, eval_views=1)
    base.update(kw)
    return TrainConfig(**base)


def _steps(run):
    return [e for e in read_events(run / "progress.jsonl") if e["event"] == "step"]


def test_short_run_writes_the_run_folder_and_events(trained_run):
    run = trained_run["run"]
    assert (run / "config.json").is_file() and (run / "metrics.json").is_file()
    assert (run / "checkpoints" / "latest.pt").is_file() and (run / "checkpoints" / "step_0000030.pt").is_file()
    assert list((run / "previews").glob("step_*.png"))
    events = read_events(run / "progress.jsonl")
    kinds = [e["event"] for e in events]
    # Other tests share this run and `nerf_core eval` appends its own "eval" events after training's "done".
    assert kinds[0] == "start" and "done" in kinds
    done_at = kinds.index("done")
    assert set(kinds[done_at + 1:]) <= {"eval"}
    events, kinds = events[:done_at + 1], kinds[:done_at + 1]
    assert {"step", "preview", "checkpoint", "eval"} <= set(kinds)
    start = events[0]
    for key in ("run", "method", "max_steps", "max_seconds", "device", "n_params"):
        assert key in start
    assert start["method"] == "test-grid" and start["n_params"] == 4 * 12 ** 3
    step = [e for e in events if e["event"] == "step"][-1]
    for key in ("step", "loss", "psnr", "lr", "elapsed", "eta", "samples_per_s"):
        assert key in step, key
    assert step["step"] == 30 and step["eta"] == 0.0
    first = [e for e in events if e["event"] == "step"][0]
    assert step["loss"] < first["loss"]  # it learns
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["method"] == "test-grid" and cfg["seed"] == 0 and cfg["background_used"] == "random"
    assert cfg["versions"]["torch"] == torch.__version__
    # The per-split record: later `eval --split val` calls change only the top-level "latest" keys.
    metrics = json.loads((run / "metrics.json").read_text())["splits"]["test"]
    assert metrics["split"] == "test" and metrics["n_views"] == 2 and 0 < metrics["ssim"] <= 1
    assert "depth_mae" in metrics
    done = events[-1]
    assert done["checkpoint"].endswith("latest.pt") and done["metrics"]["psnr"] == pytest.approx(metrics["psnr"])


def test_existing_run_is_refused_and_overwrite_removes_only_trainer_files(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "notes.txt").write_text("mine")
    with pytest.raises(TrainError, match="not empty.*--resume.*--overwrite"):
        train(_cfg(sphere_dataset, run))
    assert sorted(p.name for p in run.iterdir()) == ["notes.txt"]
    train(_cfg(sphere_dataset, run, max_steps=3, overwrite=True))
    first_ckpt = torch.load(run / "checkpoints" / "latest.pt", weights_only=False)
    (run / "previews" / "my_drawing.png").write_bytes(b"x")
    train(_cfg(sphere_dataset, run, max_steps=2, overwrite=True))
    assert (run / "notes.txt").read_text() == "mine" and (run / "previews" / "my_drawing.png").exists()
    assert not (run / "checkpoints" / "step_0000003.pt").exists()  # the old run's files are gone
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=False)["step"] == 2 != first_ckpt["step"]
    starts = [e for e in read_events(run / "progress.jsonl") if e["event"] == "start"]
    assert len(starts) == 1  # the progress log was restarted, not appended to


def test_resume_continues_from_the_checkpoint(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=10))
    out = train(_cfg(sphere_dataset, run, max_steps=25, resume=True))
    assert out["step"] == 25
    events = read_events(run / "progress.jsonl")
    starts = [e for e in events if e["event"] == "start"]
    assert starts[-1]["resumed_from"] == 10 and starts[-1]["max_steps"] == 25
    steps_after = [e["step"] for e in events[events.index(starts[-1]):] if e["event"] == "step"]
    assert steps_after[0] == 11 and steps_after[-1] == 25
    ck = torch.load(run / "checkpoints" / "latest.pt", weights_only=False)
    assert ck["step"] == 25 and ck["elapsed"] > 0 and "batches" in ck["rng"]
    with pytest.raises(TrainError, match="latest.pt.*nothing to resume"):
        train(_cfg(sphere_dataset, tmp_path / "fresh", resume=True))
    with pytest.raises(TrainError, match="method 'test-grid'"):
        train(_cfg(sphere_dataset, run, method="test-nan", resume=True, max_steps=30))


@pytest.mark.parametrize("device", [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA"))])
def test_same_seed_gives_identical_losses(sphere_dataset, tmp_path, device):
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        train(_cfg(sphere_dataset, tmp_path / name, max_steps=12, log_every=1, eval_views=0, seed=seed, device=device))
    la, lb, lc = ([e["loss"] for e in _steps(tmp_path / name)] for name in "abc")
    assert len(la) == 12 and la != lc
    if device == "cpu":
        assert la == lb  # bit for bit
    else:
        # CUDA's atomic adds (grid_sample's backward) sum in no fixed order: equal to float rounding.
        assert la == pytest.approx(lb, rel=1e-5) and la != pytest.approx(lc, rel=1e-3)


def test_nan_loss_rolls_back_lowers_lr_and_continues(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    out = train(_cfg(sphere_dataset, run, method="test-nan", options={"nan_at": 150}, max_steps=160,
                     log_every=10, eval_views=0))
    events = read_events(run / "progress.jsonl")
    rb = [e for e in events if e["event"] == "rollback"]
    assert len(rb) == 1 and "nan" in rb[0]["reason"].lower()
    assert rb[0]["step"] == 149 and rb[0]["restored_step"] == 100  # last snapshot
    base_lr = 0.05
    assert rb[0]["lr"] == pytest.approx(base_lr * 0.5)
    assert out["step"] == 160 and out["rollbacks"] == 1 and math.isfinite(out["loss"])
    steps = [e for e in events if e["event"] == "step"]
    assert all(math.isfinite(e["loss"]) for e in steps)
    assert events[-1]["event"] == "done"


def test_repeated_nan_gives_up_with_an_error_event(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    with pytest.raises(TrainError, match="diverged"):
        train(_cfg(sphere_dataset, run, method="test-nan", options={"nan_at": 3, "nan_times": 1000},
                   max_steps=50, max_rollbacks=2))
    events = read_events(run / "progress.jsonl")
    assert [e["event"] for e in events].count("rollback") == 2
    assert events[-1]["event"] == "error" and "diverged" in events[-1]["message"]


def test_time_budget_stops_training(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    out = train(_cfg(sphere_dataset, run, max_steps=None, max_seconds=0.5, eval_views=0))
    assert out["elapsed"] >= 0.5 and out["step"] > 0
    start = read_events(run / "progress.jsonl")[0]
    assert start["max_steps"] is None and start["max_seconds"] == 0.5
    # The bar and ETA follow the time budget: the last step event has nothing left.
    assert _steps(run)[-1]["eta"] == 0.0


def test_progress_file_and_bad_options(sphere_dataset, tmp_path):
    extra = tmp_path / "events.jsonl"
    train(_cfg(sphere_dataset, tmp_path / "run", max_steps=3, progress=str(extra)))
    kinds = [e["event"] for e in read_events(extra)]
    assert kinds[0] == "start" and kinds[-1] == "done"
    with pytest.raises(TrainError, match="res_typo"):
        train(_cfg(sphere_dataset, tmp_path / "run2", options={"res_typo": 3}))
    with pytest.raises(TrainError, match="contradict"):
        train(_cfg(sphere_dataset, tmp_path / "run3", resume=True, overwrite=True))


def test_default_method_trains_end_to_end(tmp_path, dataset_factory):
    """The library's real default method runs a few steps through this trainer and evaluates."""
    from nerf_core.methods import catalog

    ds = dataset_factory(tmp_path / "ds", n_train=4, n_test=1, w=16, h=12)
    out = train(_cfg(ds, tmp_path / "run", method=None, max_steps=3, batch_rays=256))
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["method"] == getattr(catalog, "DEFAULT_METHOD", cfg["method"])
    assert out["step"] == 3 and math.isfinite(out["metrics"]["psnr"])


def test_size_auto_records_its_reasons(sphere_dataset, tmp_path):
    """``--size auto`` asks nerf_core.methods.sizing (real default method) and records why in config and start event."""
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, method=None, size="auto", max_steps=1, batch_rays=64, eval_views=0))
    cfg = json.loads((run / "config.json").read_text())
    start = read_events(run / "progress.jsonl")[0]
    assert cfg["size_reasons"] and start["size_reasons"] == cfg["size_reasons"]
    assert all(isinstance(r, str) and r for r in cfg["size_reasons"])


@pytest.mark.parametrize("half_box, given, expect", [
    (0.3, {}, True),  # the sphere (radius 0.6) pokes out of a +-0.3 box: its edge pixels lie beyond it
    (1.0, {}, False),  # the whole sphere inside: nothing beyond the box
    (0.3, {"unbounded": False}, False),  # --set unbounded=false wins
])
def test_a_cut_out_with_opaque_pixels_beyond_the_box_is_contracted(sphere_dataset, tmp_path, half_box, given, expect):
    from nerf_core.check.dataset import check_dataset
    from nerf_core.data.loading import load_dataset
    from nerf_core.data.scene_box import BEYOND_BOX_SHARE, beyond_box_share

    for split in ("train", "val", "test"):
        path = sphere_dataset / f"transforms_{split}.json"
        meta = json.loads(path.read_text())
        meta["aabb"] = [[-half_box] * 3, [half_box] * 3]
        path.write_text(json.dumps(meta))
    data = load_dataset(sphere_dataset, splits=("train",))
    share = beyond_box_share(data.split("train"), data.aabb)
    assert (share >= BEYOND_BOX_SHARE) == (half_box < 0.6)
    # `check` foretells the decision by the same rule, with the box and the background it rests on.
    report = check_dataset(sphere_dataset)
    assert report.ok and any(line.startswith("scene box [[-0.3") for line in report.plan) is (half_box == 0.3)
    assert any(line.startswith("background: random") for line in report.plan)
    assert any("unbounded=true" in line and "opaque where their ray misses" in line
               for line in report.plan) is (half_box < 0.6)
    assert ("TRAIN   vmgrid (the default method) will model the world beyond the box" in report.format()) is (
        half_box < 0.6
    )
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, method="vmgrid", max_steps=1, batch_rays=64, eval_views=0, options=given))
    cfg = json.loads((run / "config.json").read_text())
    start = read_events(run / "progress.jsonl")[0]
    assert start["model"]["options"]["unbounded"] is expect
    assert any(r.startswith("unbounded=true") for r in cfg["size_reasons"]) is (expect and not given)


def test_a_dataset_that_says_objects_reach_beyond_its_box_is_contracted(sphere_dataset, tmp_path):
    # An opaque capture cannot show by its alpha that a floor runs past the box; the capture says so.
    from nerf_core.check.dataset import check_dataset
    from nerf_core.contract.errors import DatasetError
    from nerf_core.data.loading import load_dataset

    path = sphere_dataset / "transforms_train.json"
    meta = json.loads(path.read_text())
    meta["beyond_box"] = ["Plane"]
    path.write_text(json.dumps(meta))
    assert load_dataset(sphere_dataset, splits=("train",)).beyond_box == ["Plane"]
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, method="vmgrid", max_steps=1, batch_rays=64, eval_views=0))
    start = read_events(run / "progress.jsonl")[0]
    assert start["model"]["options"]["unbounded"] is True
    assert any("'beyond_box' says Plane" in r for r in start["size_reasons"])
    assert any("'beyond_box' says Plane" in line for line in check_dataset(sphere_dataset).plan)
    meta["beyond_box"] = "Plane"
    path.write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="transforms_train.json: field 'beyond_box' must be a list"):
        load_dataset(sphere_dataset, splits=("train",))


def test_nan_gradient_with_finite_loss_also_rolls_back(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    out = train(_cfg(sphere_dataset, run, method="test-nan", options={"nan_at": 8, "nan_in": "grad"},
                     max_steps=12, eval_views=0))
    rb = [e for e in read_events(run / "progress.jsonl") if e["event"] == "rollback"]
    assert len(rb) == 1 and "gradient" in rb[0]["reason"] and rb[0]["restored_step"] == 0
    assert out["step"] == 12
    # The model that finished has finite weights (the NaN step was never applied).
    state = torch.load(run / "checkpoints" / "latest.pt", weights_only=False)["model"]
    assert all(torch.isfinite(v).all() for v in state.values())


def test_ctrl_c_saves_a_checkpoint_that_resumes(sphere_dataset, tmp_path, monkeypatch):
    from nerf_core.methods.registry import method_class

    cls = method_class("test-grid")

    def hook(self, step, frac):
        if step == 7 and not getattr(self, "_interrupted", False):
            self._interrupted = True
            raise KeyboardInterrupt
        return False

    monkeypatch.setattr(cls, "training_hook", hook)
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(_cfg(sphere_dataset, run, max_steps=15))
    events = read_events(run / "progress.jsonl")
    assert events[-1]["event"] == "error" and "interrupted at step 7" in events[-1]["message"]
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=False)["step"] == 7
    monkeypatch.undo()
    assert train(_cfg(sphere_dataset, run, max_steps=15, resume=True))["step"] == 15


def test_a_second_ctrl_c_during_the_interrupted_runs_save_does_not_lose_it(sphere_dataset, tmp_path, monkeypatch):
    import os
    import signal

    from nerf_core.engine.callbacks import CheckpointEvery
    from nerf_core.methods.registry import method_class

    def hook(self, step, frac):
        if step == 7:
            raise KeyboardInterrupt
        return False

    save = CheckpointEvery.save

    def impatient_save(self, trainer):
        os.kill(os.getpid(), signal.SIGINT)  # pressed again while the checkpoint is being written
        return save(self, trainer)

    monkeypatch.setattr(method_class("test-grid"), "training_hook", hook)
    monkeypatch.setattr(CheckpointEvery, "save", impatient_save)
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(_cfg(sphere_dataset, run, max_steps=15))
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=False)["step"] == 7
    assert not list((run / "checkpoints").glob("*.tmp"))
    assert "checkpoint saved" in read_events(run / "progress.jsonl")[-1]["message"]


def test_white_then_random_background(sphere_dataset):
    from nerf_core.data.backgrounds import AUTO_WHITE_FRACTION
    from nerf_core.data.batcher import RayBatcher as _Batcher
    from nerf_core.data.loading import load_dataset

    split = load_dataset(sphere_dataset).splits["train"]
    b = _Batcher(split, "white-then-random", torch.Generator().manual_seed(0), torch.device("cpu"))
    early = b.sample(512, frac=AUTO_WHITE_FRACTION / 2)
    late = b.sample(512, frac=AUTO_WHITE_FRACTION)
    assert torch.all(early.background == 1.0)
    assert late.background.std() > 0.2  # one random colour per ray
    # Transparent pixels show exactly the background they were composited onto.
    rand = _Batcher(split, "random", torch.Generator().manual_seed(1), torch.device("cpu")).sample(4096)
    assert ((rand.target - rand.background).abs().amax(-1) < 1e-6).float().mean() > 0.3


def test_eval_at_evaluates_at_training_times_inside_one_run(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    # Reached marks fire once each (a mark beyond --max-seconds is refused up front:
    # test_flags_checked_together.py).
    train(_cfg(sphere_dataset, run, max_steps=None, max_seconds=1.5, eval_at=[0.2, 0.6]))
    evals = [e for e in read_events(run / "progress.jsonl") if e["event"] == "eval" and "eval_wall" in e]
    assert len(evals) == 2
    assert evals[0]["elapsed"] >= 0.2 and evals[1]["elapsed"] >= 0.6
    assert evals[0]["step"] < evals[1]["step"]
    for e in evals:
        assert e["split"] == "test" and e["n_views"] == 1 and math.isfinite(e["psnr"]) and e["n_params"] > 0
    assert [e["eval_at"] for e in evals] == [[0.2], [0.6]]


def test_a_step_that_crosses_several_eval_marks_evaluates_once(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    # No step is shorter than 10 ns, so one step crosses both of the first two marks.
    train(_cfg(sphere_dataset, run, max_steps=None, max_seconds=1.0, eval_at=[0.3, 0.30000001, 0.6]))
    evals = [e for e in read_events(run / "progress.jsonl") if e["event"] == "eval" and "eval_wall" in e]
    assert [e["eval_at"] for e in evals] == [[0.3, 0.30000001], [0.6]]
    assert evals[0]["step"] < evals[1]["step"]


@pytest.mark.parametrize("method", ["vmgrid", "nerf"])
def test_a_batch_that_misses_the_scene_trains_on(tmp_path, dataset_factory, method):
    """Rays that all miss the box render pure background: a constant loss with no gradient. Regression:
    the trainer called ``loss.backward()`` on it and stopped with autograd's "does not require grad"."""
    ds = dataset_factory(tmp_path / "ds", n_train=3, n_test=1, w=8, h=6)
    for split in ("train", "val", "test"):  # a box far behind every camera
        path = ds / f"transforms_{split}.json"
        meta = json.loads(path.read_text())
        meta["aabb"] = [[40.0, 40.0, 40.0], [41.0, 41.0, 41.0]]
        for key in ("near", "far"):  # with them, the dataset is refused before training (near_far_problem)
            meta.pop(key)
        path.write_text(json.dumps(meta))
    out = train(_cfg(ds, tmp_path / "run", method=method, max_steps=3, batch_rays=32, eval_views=0))
    assert out["step"] == 3


def test_vmgrid_evaluation_during_training_sees_the_current_weights(sphere_dataset, tmp_path):
    """Regression: vmgrid's no-grad lookup tables were cached by the grids' version counters, which the
    trainer's fused Adam does not move, so every preview and evaluation after the first rendered the
    grids as they were then (about 1 dB low after 5 minutes). The final evaluation in the training
    process must equal ``eval`` of the checkpoint it wrote."""
    from nerf_core.evaluation.evaluate import evaluate_run

    run = tmp_path / "run"
    # A preview every 10 steps builds the tables early; 30 more steps of training follow.
    out = train(_cfg(sphere_dataset, run, method="vmgrid", max_steps=40, batch_rays=256, preview_every=10,
                     options={"res_init": 16, "res_final": 16, "upsample_at": [], "occ_res": 16}))
    logged = [e for e in read_events(run / "progress.jsonl") if e["event"] == "eval"][-1]
    again = evaluate_run(run, max_views=1)
    assert logged["step"] == out["step"] == 40
    assert again["psnr"] == pytest.approx(logged["psnr"], abs=1e-4)


def test_a_run_that_would_train_nothing_is_an_error(sphere_dataset, tmp_path, monkeypatch):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=6, eval_views=0))
    before = (run / "checkpoints" / "latest.pt").read_bytes()
    # Resuming a run whose budget is already met used to rewrite its checkpoints and exit 0.
    with pytest.raises(TrainError, match=r"already at step 6 .* meets --max-steps 4; nothing is left to train"):
        train(_cfg(sphere_dataset, run, max_steps=4, eval_views=0, resume=True))
    assert (run / "checkpoints" / "latest.pt").read_bytes() == before
    # A time budget spent before the first step (on an opaque capture, by fitting the world) is not a
    # finished run either: a loop that finds its budget gone at once stands in for that prefit.
    from nerf_core.engine.trainer import Trainer

    monkeypatch.setattr(Trainer, "_train_loop", lambda self, batcher, stop: None)
    with pytest.raises(TrainError, match=r"nothing was trained: the budget \(--max-seconds 0.5\) ran out"):
        train(_cfg(sphere_dataset, tmp_path / "run2", max_steps=None, max_seconds=0.5, eval_views=0))
    assert not (tmp_path / "run2" / "checkpoints" / "latest.pt").exists()


def test_the_default_batch_is_the_methods_and_four_times_that_on_cuda():
    from nerf_core.engine.model_setup import CUDA_BATCH_SCALE, default_batch_rays

    from nerf_core.methods.base import RadianceModel

    class WithDefault(RadianceModel):
        default_batch_rays = 2048

    class WithoutDefault(RadianceModel):
        pass

    cpu, cuda = torch.device("cpu"), torch.device("cuda", 0)  # a device name: no GPU is needed
    BOX_2 = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert CUDA_BATCH_SCALE == 4
    assert default_batch_rays(WithDefault(BOX_2), cpu) == 2048 and default_batch_rays(WithDefault(BOX_2), cuda) == 8192
    assert (
        default_batch_rays(WithoutDefault(BOX_2), cpu) == 1024
        and default_batch_rays(WithoutDefault(BOX_2), cuda) == 4096
    )


def test_a_run_records_the_batch_it_chose(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=2, batch_rays=None, eval_views=0, device="cpu"))
    config = json.loads((run / "config.json").read_text())
    assert config["batch_rays"] == 1024 and config["rays_per_step"] == 1024  # test-grid has no default


@pytest.mark.parametrize("eval_views, eval_seconds, why", [(1, None, "as --eval-views 1 asks"),
                                                          (None, 0.0, "at full resolution to stay within 0 s")])
def test_the_final_evaluation_says_why_it_scored_fewer_views(sphere_dataset, tmp_path, capsys, eval_views,
                                                             eval_seconds, why):
    """A run that scores 1 of the held-out views says whether --eval-views or the time budget cut it:
    the time budget is not consulted when a count is given, and a note blaming it sent users to the
    wrong flag."""
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=2, eval_views=eval_views, eval_seconds=eval_seconds))
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["n_views"] == 1 < metrics["n_views_total"]
    assert f"evaluated 1 of {metrics['n_views_total']} test views {why};" in metrics["note"]
    assert metrics["note"] in capsys.readouterr().err
