"""Reliability, round four (docs/RELIABILITY.md, "Round four"): deletes that never leave the run,
every stop keeps the work, the Python API checks what the CLI checks, results that cannot be right
are not "done", change detection covers the images, protocols and messages."""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

import nerf_core
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.nerfstudio_frame import read_dataparser_transform
from nerf_core.engine.config import TrainConfig
from nerf_core.engine.rollback import take_snapshot
from nerf_core.engine.state import TrainState
from nerf_core.engine.trainer import train
from nerf_core.errors import TrainError
from nerf_core.render.server import valid_id
from nerf_core.runs.checkpoints import save_checkpoint
from nerf_core.runs.dataset_identity import dataset_changed_note

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _cfg(ds, run, **kw):
    base = dict(dataset=str(ds), out=str(run), method="test-grid", max_steps=4, batch_rays=32, seed=0,
                stdout_events=False, show_bar=False, log_every=2, eval_views=0)
    base.update(kw)
    return TrainConfig(**base)


def _env():
    return dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest", OMP_NUM_THREADS="1")


def _cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "nerf_core", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO_ROOT, env=_env(), timeout=300, **kw)


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    from nerf_core.tests.conftest import make_dataset

    return make_dataset(tmp_path_factory.mktemp("r4") / "ds", n_train=4, n_test=2, w=12, h=10)


# ---------------------------------------------------------------------------- 1. deletes never leave the run


def test_overwrite_never_deletes_through_a_linked_folder(ds, tmp_path):
    run = tmp_path / "run"
    train(_cfg(ds, run))
    outside = tmp_path / "somewhere"
    outside.mkdir()
    (outside / "precious.txt").write_text("mine")
    (run / "shared").symlink_to(outside)
    listed = json.loads((run / ".written.json").read_text()) + ["shared/precious.txt"]
    (run / ".written.json").write_text(json.dumps(listed))
    train(_cfg(ds, run, overwrite=True))  # a listed path through a link is not the run's: left alone
    assert (outside / "precious.txt").read_text() == "mine"
    assert (run / "checkpoints" / "latest.pt").is_file()
    (run / "shared").unlink()
    (run / "shared").mkdir()
    (run / "shared" / "inner").symlink_to(outside)
    listed[-1] = "shared/inner/precious.txt"
    (run / ".written.json").write_text(json.dumps(listed))
    train(_cfg(ds, run, overwrite=True))  # a link deeper down is skipped too, never followed
    assert (outside / "precious.txt").read_text() == "mine"


def test_resume_with_config_json_a_link_is_refused_naming_it(ds, tmp_path):
    run = tmp_path / "run"
    train(_cfg(ds, run))
    users = tmp_path / "users.json"
    users.write_text('{"mine": 1}')
    (run / "config.json").unlink()
    (run / "config.json").symlink_to(users)
    with pytest.raises(TrainError, match="config.json: is a symbolic link"):
        train(_cfg(ds, run, resume=True, max_steps=6))
    assert users.read_text() == '{"mine": 1}'


def test_checkpoints_as_a_file_is_named_a_file(ds, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoints").write_text("not a folder")
    with pytest.raises(TrainError, match="checkpoints: is a file"):
        train(_cfg(ds, run, resume=True))


# ---------------------------------------------------------------------------- 3. every stop keeps the work


def test_a_file_size_limit_names_the_checkpoint_and_keeps_the_previous_one(tmp_path):
    run = tmp_path / "run"
    save_checkpoint(run, {"model": {"w": torch.zeros(4)}, "step": 1}, 1, keep=3)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (20000, hard))
    try:
        with pytest.raises(TrainError, match=r"step_0000002\.pt: cannot write checkpoint: .*(ulimit|too large)"):
            save_checkpoint(run, {"model": {"w": torch.zeros(100000)}, "step": 2}, 2, keep=3)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old_handler)
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=True)["step"] == 1
    assert not list((run / "checkpoints").glob("*.tmp"))


def test_sighup_is_ignored_under_nohup_and_otherwise_stops_like_ctrl_c():
    from nerf_core.utils.interrupts import terminate_as_interrupt

    previous = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    try:
        restore = terminate_as_interrupt()
        with pytest.raises(KeyboardInterrupt, match="SIGHUP"):
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(1)
        restore()
        signal.signal(signal.SIGHUP, signal.SIG_IGN)  # nohup
        restore = terminate_as_interrupt()
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
        restore()
    finally:
        signal.signal(signal.SIGHUP, previous)


# ---------------------------------------------------------------------------- 4. the API checks what the CLI checks


@pytest.mark.parametrize("field, value, words", [
    ("log_every", 0, "log_every"), ("chunk", 0, "chunk"), ("preview_size", 0, "preview_size"),
    ("eval_views", -1, "eval_views"), ("options", None, "options"), ("max_steps", "5", "max_steps"),
    ("seed", 1.5, "seed"), ("show_bar", "yes", "show_bar"), ("dataset", None, "dataset"),
    ("out", "runs/\ud800", "lone surrogate"), ("eval_at", "10", "eval_at"), ("size", "big", "size"),
])
def test_train_config_refuses_bad_fields_before_the_run_folder_is_made(ds, tmp_path, field, value, words):
    run = tmp_path / "run"
    cfg = _cfg(ds, run, **{field: value})
    with pytest.raises(TrainError, match=words):
        train(cfg)
    assert not run.exists()


def test_train_refuses_what_is_no_train_config():
    with pytest.raises(TypeError, match="TrainConfig"):
        train({"dataset": "x", "out": "y"})


def _cams(**kw):
    args = dict(c2w=np.eye(4)[None], fx=10.0, fy=10.0, cx=5.0, cy=5.0, width=10, height=10)
    args.update(kw)
    return nerf_core.Cameras.create(**args)


@pytest.mark.parametrize(
    "kw, words",
    [
        (dict(c2w=np.full((1, 4, 4), np.nan)), "c2w holds NaN"),
        (dict(fx=-5.0), "fx"),
        (dict(width=0), "width"),
        (dict(c2w=np.diag([2.0, 2.0, 2.0, 1.0])[None]), "scaled"),
        (dict(c2w="eye"), "c2w"),
        (dict(fy=[1.0, 2.0]), "1 or 1"),
    ],
)
def test_cameras_refuse_what_the_loaders_refuse(kw, words):
    with pytest.raises((ValueError, TypeError), match=words):
        _cams(**kw)


@pytest.mark.parametrize("aabb, words", [
    ([[1, 1, 1], [-1, -1, -1]], "min < max"), ([[0, 0, 0], [float("nan"), 1, 1]], "aabb"), ("box", "aabb"),
])
def test_build_model_refuses_inverted_or_nan_boxes(aabb, words):
    with pytest.raises((ValueError, TypeError), match=words):
        nerf_core.build_model("test-grid", aabb)
    with pytest.raises(TypeError, match="name"):
        nerf_core.build_model(3, BOX)


@pytest.mark.parametrize("kw, words", [
    (dict(chunk=0), "chunk"), (dict(near=3.0, far=2.0), "far"), (dict(background="purple"), "background"),
    (dict(background=(2.0, 0.0, 0.0)), "background"), (dict(view=5), "view"), (dict(near=float("nan")), "near"),
])
def test_render_view_refuses_bad_arguments_before_rendering(kw, words):
    model = nerf_core.build_model("test-grid", BOX).eval()
    args = dict(view=0)
    args.update(kw)
    with pytest.raises((ValueError, TypeError), match=words):
        nerf_core.render_view(model, _cams(c2w=np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1.0]])),
                              **args)
    assert model.calls == 0


def test_psnr_refuses_broadcasting_eight_bit_and_nan():
    a = torch.rand(8, 8, 3)
    with pytest.raises(ValueError, match="same shape"):
        nerf_core.psnr(a, torch.rand(1, 1, 3))
    with pytest.raises(TypeError, match="255"):
        nerf_core.psnr((a * 255).to(torch.uint8), (a * 255).to(torch.uint8))
    with pytest.raises(ValueError, match="NaN"):
        nerf_core.psnr(a, torch.full_like(a, float("nan")))
    with pytest.raises(ValueError, match="mask"):
        nerf_core.psnr(a, a, mask=torch.ones(4, 4, dtype=torch.bool))
    assert nerf_core.psnr(a, a) == float("inf")


def test_ray_batcher_and_samples_refuse_unknown_names_and_zero_counts(ds):
    split = nerf_core.load_dataset(ds).split("train")
    with pytest.raises(ValueError, match="background"):
        nerf_core.RayBatcher(split, "purple", torch.Generator(), torch.device("cpu"))
    with pytest.raises(TypeError, match="split"):
        nerf_core.RayBatcher(None, "white", torch.Generator(), torch.device("cpu"))
    from nerf_core.volume import stratified_samples

    with pytest.raises(ValueError, match="n_samples"):
        stratified_samples(torch.zeros(3), torch.ones(3), 0, False)
    with pytest.raises(ValueError, match="far must be >= near"):
        stratified_samples(torch.ones(3), torch.zeros(3), 4, False)


def test_evaluate_run_refuses_zero_views_and_unknown_splits(tmp_path):
    with pytest.raises(ValueError, match="max_views"):
        nerf_core.evaluate_run(tmp_path, max_views=0)
    with pytest.raises(ValueError, match="split"):
        nerf_core.evaluate_run(tmp_path, split="tset")


def test_register_refuses_replacing_a_built_in_unless_asked():
    from nerf_core.methods import registry

    original = registry.method_class("vmgrid")
    with pytest.raises(ValueError, match="built-in"):
        nerf_core.register("vmgrid")
    with pytest.raises(ValueError, match="non-empty"):
        nerf_core.register("  ")
    with pytest.raises(TypeError, match="RadianceModel"):
        nerf_core.register("r4-not-a-class")(42)
    try:
        registered = nerf_core.register("vmgrid", replace=True)(type("Mine", (original,), {}))
        assert registry.method_class("vmgrid") is registered
    finally:
        registry._REGISTRY["vmgrid"] = original
        original.method_name = "vmgrid"


# ---------------------------------------------------------------------------- 5. a result that cannot be right


def test_non_finite_weights_stop_the_run_and_never_replace_a_checkpoint(tmp_path):
    model = nerf_core.build_model("test-grid", BOX)
    with torch.no_grad():
        model.grid[0, 0, 0, 0, 0] = float("inf")

    state = TrainState(step=7, elapsed=1.0)
    with pytest.raises(TrainError, match="'grid' is NaN or infinite at step 7"):
        take_snapshot(model, torch.optim.Adam(model.parameters()), state)
    run = tmp_path / "run"
    save_checkpoint(run, {"model": {"w": torch.zeros(2)}, "step": 1}, 1, keep=3)
    with pytest.raises(TrainError, match="'grid' turned NaN or infinite"):
        save_checkpoint(run, {"model": model.state_dict(), "step": 2}, 2, keep=3)
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=True)["step"] == 1


def test_an_absurd_dataparser_scale_is_refused(tmp_path):
    f = tmp_path / "dataparser_transforms.json"
    f.write_text(json.dumps({"transform": np.eye(4)[:3].tolist(), "scale": 1e-300}))
    with pytest.raises(DatasetError, match="'scale' is 1e-300"):
        read_dataparser_transform(f)


# ---------------------------------------------------------------------------- 6. change detection covers images


def test_replaced_test_image_is_named_by_eval_and_refused_by_resume(ds, tmp_path, dataset_factory):
    mine = dataset_factory(tmp_path / "ds", n_train=4, n_test=2, w=12, h=10)
    run = tmp_path / "run"
    train(_cfg(mine, run))
    config = json.loads((run / "config.json").read_text())
    assert dataset_changed_note(config) is None
    img = sorted((mine / "test").glob("*.png"))[0]
    data = img.read_bytes()
    img.write_bytes(data)  # the same bytes, written again: a new modification time
    os.utime(img, ns=(time.time_ns(), time.time_ns() + 5_000_000_000))
    note = dataset_changed_note(config)
    assert note and f"test/{img.name}" in note and "modification time" in note
    with pytest.raises(TrainError, match=f"test/{img.name}"):
        train(_cfg(mine, run, resume=True, max_steps=6))


# ---------------------------------------------------------------------------- 7. protocols and messages


def test_serve_refuses_non_finite_request_ids():
    import io

    from nerf_core.render.server import RenderServer

    assert not valid_id(float("nan")) and not valid_id(float("inf")) and not valid_id([1])
    assert valid_id(3) and valid_id("a") and valid_id(None) and valid_id(2.5)
    out = io.StringIO()
    server = RenderServer.__new__(RenderServer)  # no model needed: the id is refused before any rendering
    server.out = out
    assert server.handle('{"id": NaN, "c2w": []}') is True
    lines = out.getvalue().splitlines()
    assert len(lines) == 1
    event = json.loads(lines[0], parse_constant=lambda c: pytest.fail(f"not JSON: {c}"))
    assert event["event"] == "error" and event["id"] is None and "request id" in event["message"]


def test_lone_surrogate_paths_are_named():
    with pytest.raises(ValueError, match="path.*lone surrogate"):
        nerf_core.load_dataset("data/\ud800")
    with pytest.raises(ValueError, match="run.*lone surrogate"):
        nerf_core.load_run("runs/\udcff\ud800", torch.device("cpu"))


def test_dev_full_as_stdout_is_named():
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "nerf_core", "methods"], stdout=full, stderr=subprocess.PIPE,
                              text=True, cwd=REPO_ROOT, env=_env(), timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "/dev/full" in proc.stderr and "no space left" in proc.stderr
