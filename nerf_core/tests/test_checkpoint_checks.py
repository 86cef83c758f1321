"""What a checkpoint holds is checked against what it loads into (runs/checkpoint_checks.py), by every
command that loads one: mis-shaped optimiser state or weights, NaN weights, bad scalar entries and a
checkpoint of another method end in one clear line (or, for the optimiser, a fresh Adam with a
note), never in a crash, heap corruption or traceback."""
import os
import subprocess
import sys

import pytest
import torch

from nerf_core.methods.base import RadianceModel

from nerf_core.errors import RunError
from nerf_core.runs.checkpoint_checks import check_entries, check_rng, check_weights
from nerf_core.runs.checkpoints import read_checkpoint

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CRASHED = (139, -11, 134, -6)  # SIGSEGV and SIGABRT (heap corruption), as exit codes or signals


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "nerf_core", *args], capture_output=True, text=True, cwd=REPO_ROOT,
                          env=env, timeout=300)


def _edit_checkpoints(run, edit):
    """Apply ``edit(ckpt)`` to every checkpoint of ``run`` (latest.pt and the step files)."""
    for path in sorted((run / "checkpoints").glob("*.pt")):
        ckpt = torch.load(path, weights_only=True)
        edit(ckpt)
        torch.save(ckpt, path)


def _resume(run, trained_run):
    return _cli("train", str(trained_run["dataset"]), "--out", str(run), "--resume", "--max-steps", "34", "--no-bar")


def _one_clear_line(proc, *words):
    assert proc.returncode not in CRASHED, f"crashed ({proc.returncode}): {proc.stderr[-800:]}"
    assert proc.returncode == 2, proc.stdout[-500:] + proc.stderr[-800:]
    assert "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in proc.stderr, proc.stderr


def _misshape_adam(ckpt):
    state = ckpt["optimizer"]["state"]
    for moments in state.values():
        moments["exp_avg"] = torch.zeros(3)
        moments["exp_avg_sq"] = torch.zeros(7, 7)


def test_misshaped_adam_state_never_reaches_the_fused_optimiser(trained_run, run_copy):
    _edit_checkpoints(run_copy, _misshape_adam)
    proc = _resume(run_copy, trained_run)
    assert proc.returncode not in CRASHED, f"crashed ({proc.returncode}): {proc.stderr[-800:]}"
    assert proc.returncode == 0, proc.stderr[-800:]
    assert "optimiser state 'exp_avg' of parameter 0 has shape (3,)" in proc.stderr
    assert "starting Adam afresh" in proc.stderr


def test_nan_adam_state_starts_adam_afresh(trained_run, run_copy):
    def nan_moments(ckpt):
        for moments in ckpt["optimizer"]["state"].values():
            moments["exp_avg_sq"] = torch.full_like(moments["exp_avg_sq"], float("nan"))

    _edit_checkpoints(run_copy, nan_moments)
    proc = _resume(run_copy, trained_run)
    assert proc.returncode == 0, proc.stderr[-800:]
    assert "NaN or infinite" in proc.stderr and "starting Adam afresh" in proc.stderr


@pytest.mark.parametrize("command", ["eval", "render", "resume"])
def test_misshaped_weights_are_refused_by_every_command(trained_run, run_copy, tmp_path, command):
    _edit_checkpoints(run_copy, lambda ck: ck["model"].__setitem__("grid", torch.zeros(1, 4, 5, 5, 5)))
    if command == "eval":
        proc = _cli("eval", str(run_copy), "--no-bar")
    elif command == "render":
        proc = _cli("render", str(run_copy), "--out", str(tmp_path / "views"), "--no-bar")
    else:
        proc = _resume(run_copy, trained_run)
    _one_clear_line(proc, "weight 'grid' has shape (1, 4, 5, 5, 5)", "latest.pt" if command != "resume" else ".pt")


def test_serve_refuses_misshaped_weights_with_one_fatal_event(run_copy):
    _edit_checkpoints(run_copy, lambda ck: ck["model"].__setitem__("grid", torch.zeros(1, 4, 5, 5, 5)))
    proc = _cli("serve", str(run_copy))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert '"fatal": true' in proc.stdout and "has shape (1, 4, 5, 5, 5)" in proc.stdout


def test_nan_weights_are_not_rendered_or_scored(run_copy):
    _edit_checkpoints(run_copy, lambda ck: ck["model"]["grid"].view(-1)[:5].fill_(float("nan")))
    metrics_before = (run_copy / "metrics.json").read_bytes()
    _one_clear_line(_cli("eval", str(run_copy), "--no-bar"), "weight 'grid' holds NaN or infinite values")
    assert (run_copy / "metrics.json").read_bytes() == metrics_before  # no score of a broken model filed


@pytest.mark.parametrize("entry, value, words", [
    ("step", "three", "entry 'step' must be a whole number >= 0"),
    ("step", -50, "entry 'step' must be a whole number >= 0"),
    ("elapsed", float("nan"), "entry 'elapsed' must be a finite number"),
    ("lr_scale", 0.0, "entry 'lr_scale' must be a number in (0, 1]"),
    ("rng", {"python": None}, "entry 'rng' must hold the random states"),
])
def test_bad_scalar_entries_stop_resume_with_the_entry_named(trained_run, run_copy, entry, value, words):
    _edit_checkpoints(run_copy, lambda ck: ck.__setitem__(entry, value))
    proc = _resume(run_copy, trained_run)
    _one_clear_line(proc, words, "no checkpoint loads")


def test_a_damaged_latest_falls_back_to_the_complete_step_file(trained_run, run_copy):
    latest = run_copy / "checkpoints" / "latest.pt"
    ckpt = torch.load(latest, weights_only=True)
    ckpt["step"] = -50
    torch.save(ckpt, latest)
    proc = _resume(run_copy, trained_run)
    assert proc.returncode == 0, proc.stderr[-800:]
    assert "resuming from" in proc.stderr and "entry 'step'" in proc.stderr


def test_resume_refuses_a_checkpoint_of_another_method(trained_run, run_copy):
    _edit_checkpoints(run_copy, lambda ck: ck.__setitem__("method", "test-nan"))
    config_before = (run_copy / "config.json").read_bytes()
    proc = _resume(run_copy, trained_run)
    _one_clear_line(proc, "belongs to another run", "method 'test-nan'")
    assert (run_copy / "config.json").read_bytes() == config_before


# -- the checks themselves, against hand-made values -------------------------------------------------

def test_growth_is_allowed_only_where_the_method_declares_it():
    class Grows(RadianceModel):
        growing = ("planes",)

        def __init__(self):
            super().__init__(torch.tensor([[-1.0] * 3, [1.0] * 3]))
            self.planes = torch.nn.Parameter(torch.zeros(3, 8, 16, 16))
            self.mlp = torch.nn.Linear(4, 2)

    model = Grows()
    weights = {k: v.detach().clone() for k, v in model.state_dict().items()}
    check_weights(model, weights, "ck")  # as built
    check_weights(model, {**weights, "planes": torch.zeros(3, 8, 64, 64)}, "ck")  # grown
    with pytest.raises(RunError, match=r"weight 'planes' has shape .*\(a grid may grow, but not so\)"):
        check_weights(model, {**weights, "planes": torch.zeros(3, 9, 64, 64)}, "ck")  # more channels: no
    with pytest.raises(RunError, match=r"weight 'mlp.weight' has shape \(2, 5\)"):
        check_weights(model, {**weights, "mlp.weight": torch.zeros(2, 5)}, "ck")
    with pytest.raises(RunError, match=r"missing \['mlp.bias'\]"):
        check_weights(model, {k: v for k, v in weights.items() if k != "mlp.bias"}, "ck")
    with pytest.raises(RunError, match="is torch.float64, the model holds torch.float32"):
        check_weights(model, {**weights, "mlp.bias": torch.zeros(2, dtype=torch.float64)}, "ck")


def test_optimizer_state_is_checked_against_the_parameters():
    from nerf_core.optim import Adam

    model = torch.nn.Linear(3, 2)
    opt = Adam([{"params": list(model.parameters()), "lr": 1e-3}], eps=1e-15)
    model(torch.ones(1, 3)).sum().backward()
    opt.step()
    good = opt.state_dict()
    opt.check_state(good, "ck")
    bad = {"state": {0: {**good["state"][0], "exp_avg": torch.zeros(5)}, 1: good["state"][1]},
           "param_groups": good["param_groups"]}
    with pytest.raises(RunError, match=r"'exp_avg' of parameter 0 has shape \(5,\); it must be \(2, 3\)"):
        opt.check_state(bad, "ck")
    with pytest.raises(RunError, match="parameters per group"):
        opt.check_state({"state": {}, "param_groups": [{"params": [0]}]}, "ck")
    with pytest.raises(RunError, match="state for parameter 7"):
        opt.check_state({"state": {7: {}}, "param_groups": good["param_groups"]}, "ck")


def test_entries_and_rng_state(trained_run):
    ckpt = read_checkpoint(trained_run["run"] / "checkpoints" / "latest.pt")
    check_entries(ckpt, "ck", for_resume=True)
    check_rng(ckpt["rng"], "ck")
    with pytest.raises(RunError, match="entry 'rollbacks' must be a whole number"):
        check_entries({**ckpt, "rollbacks": True}, "ck")
    with pytest.raises(RunError, match=r"missing entries \['optimizer'\]"):
        check_entries({k: v for k, v in ckpt.items() if k != "optimizer"}, "ck", for_resume=True)
    with pytest.raises(RunError, match="field 'torch' must be a generator state"):
        check_rng({**ckpt["rng"], "torch": torch.zeros(3)}, "ck")


def test_grids_of_two_resolutions_are_refused():
    """vmgrid's planes are stored (3, N, N, R): a crafted checkpoint with non-square planes, or planes and
    lines of two sizes, must be refused by name before any kernel indexes it."""
    from nerf_core.methods.registry import build_model

    model = build_model("vmgrid", torch.tensor([[-1.0] * 3, [1.0] * 3]), res_init=16)
    weights = {k: v.detach().clone() for k, v in model.state_dict().items()}
    r = weights["field.density_planes_cl"].shape[-1]
    grown = {
        **weights,
        "field.density_planes_cl": torch.zeros(3, 24, 24, r),
        "field.density_lines_cl": torch.zeros(3, 24, r),
        "field.app_planes_cl": torch.zeros(3, 24, 24, weights["field.app_planes_cl"].shape[-1]),
        "field.app_lines_cl": torch.zeros(3, 24, weights["field.app_lines_cl"].shape[-1]),
    }
    check_weights(model, grown, "ck")  # grown together: fine
    with pytest.raises(RunError, match="one resolution"):
        check_weights(model, {**grown, "field.density_planes_cl": torch.zeros(3, 24, 30, r)}, "ck")
    with pytest.raises(RunError, match="one resolution"):
        check_weights(
            model, {**grown, "field.app_lines_cl": torch.zeros(3, 20, grown["field.app_lines_cl"].shape[-1])}, "ck"
        )
