"""Reliability, round five, rules 3 and 4 (docs/RELIABILITY.md, "Round five"): every method option is
declared, bounded and checked together before the run folder is made; the run's config.json is read
with the transforms files' JSON reader and one declaration of its fields (``runs.record.RECORD_FIELDS``).
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from nerf_core.engine.config import TrainConfig
from nerf_core.errors import RunError, TrainError
from nerf_core.methods.options import OptionError
from nerf_core.methods.registry import build_model
from nerf_core.runs.record import check_run_config, read_run_record
from nerf_core.runs.weights import load_weights

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
SMALL = dict(res_init=8, res_final=16, upsample_at=[0.5], density_rank=2, app_rank=2, mlp_width=8, occ_res=8)


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest")
    return subprocess.run([sys.executable, "-m", "nerf_core", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO_ROOT, env=env, timeout=300)


def _one_line_error(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    for w in words:
        assert w in last, (w, last)
    return last


# ---------------------------------------------------------------------------------- 3. options


@pytest.mark.parametrize("setting, named", [
    ("step_ratio=1e-9", "--set step_ratio: vmgrid: option 'step_ratio' must be in [0.05, 64]"),
    ("alpha_init=1e-300", "--set alpha_init: vmgrid: option 'alpha_init' must be in [1e-08, 0.5)"),
    ("warmup_step_scale=1e-9", "--set warmup_step_scale: vmgrid: option 'warmup_step_scale' must be in [1, 64]"),
    ("seed=18446744073709551616", "--set seed: vmgrid: option 'seed' must be in [0, 9223372036854775807]"),
    ("res_init=64", "--set res_init: vmgrid: option 'res_init' (64) must be at most 'res_final' (32)"),
    ('environment={"width": 100000}', "--set environment: vmgrid: environment: option 'width' must be in [16, 8192]"),
])
def test_an_option_out_of_its_sane_range_is_named_before_the_run_folder_is_made(sphere_dataset, tmp_path, setting,
                                                                                  named):
    out = tmp_path / "run"
    extra = ["--set", "res_final=32"] if setting.startswith("res_init") else []
    proc = _cli("train", sphere_dataset, "--out", out, "--method", "vmgrid", "--max-steps", "2", "--no-bar",
                "--set", setting, *extra)
    _one_line_error(proc, named)
    assert not out.exists()  # fixing the option and running again needs no --overwrite


def test_an_unknown_old_name_is_reported_as_written(sphere_dataset, tmp_path):
    # ``contract`` is vmgrid's old name for ``unbounded``; nerf has neither, so the user's word is named
    proc = _cli("train", sphere_dataset, "--out", tmp_path / "run", "--method", "nerf", "--max-steps", "2",
                "--no-bar", "--set", "contract=true")
    last = _one_line_error(proc, "--set contract:", "unknown options ['contract']")
    assert "'unbounded'" not in last.split("known:")[0]
    with pytest.raises(OptionError, match=r"unknown options \['contract'\]"):
        build_model("nerf", BOX, contract=True)
    assert build_model("vmgrid", BOX, contract=True, **SMALL).opts.unbounded is True  # still read for vmgrid


def test_the_python_api_refuses_the_same_options_by_name():
    for options, name in [({"step_ratio": 1e-9}, "step_ratio"), ({"alpha_init": 1e-300}, "alpha_init"),
                          ({"warmup_step_scale": 1e-9}, "warmup_step_scale"), ({"seed": 2 ** 64}, "seed"),
                          ({"res_init": 40, "res_final": 32}, "res_init"),
                          ({"upsample_at": [0.5, 0.2]}, "upsample_at"),
                          ({"environment": {"width": 100000}}, "environment"),
                          ({"environment": {"width": 101}}, "environment"),
                          ({"environment": "big"}, "environment")]:
        with pytest.raises(OptionError) as err:
            build_model("vmgrid", BOX, **options)
        assert err.value.option == name, (options, err.value)
    with pytest.raises(OptionError, match="'warmup_step_scale' must be in"):
        build_model("nerf", BOX, warmup_step_scale=1e-9)
    cfg = TrainConfig(dataset="d", out="o", method="vmgrid", options={"alpha_init": 1e-300})
    with pytest.raises(TrainError, match=r"^--set alpha_init: vmgrid: option 'alpha_init'"):
        cfg.check()


def test_numpy_numbers_are_numbers():
    model = build_model("vmgrid", BOX, **{**SMALL, "res_init": np.int64(8), "res_final": np.int32(16)},
                        step_ratio=np.float32(0.5), unbounded=np.bool_(True), environment={"width": np.int64(64)})
    assert model.opts.res_init == 8 and type(model.opts.res_init) is int  # JSON-able in a checkpoint
    assert type(model.opts.step_ratio) is float and model.opts.unbounded is True
    assert model.options["environment"]["width"] == 64
    json.dumps(model.options)
    with pytest.raises(OptionError, match="must be a whole number, got 32.5"):
        build_model("vmgrid", BOX, res_init=np.float64(32.5))


def test_run_state_is_bounded_by_what_the_options_allow():
    model = build_model("vmgrid", BOX, **SMALL, res_budget_max=24)
    ckpt = {"model": model.state_dict(), "method": "vmgrid", "options": model.options,
            "method_state": {"resolution": 8, "res_final_budget": 2048}}
    fresh = build_model("vmgrid", BOX, **SMALL, res_budget_max=24)
    with pytest.raises(RunError, match=r"ck.pt: entry 'method_state': .*'res_final_budget' must be a whole number "
                                       r"in 16\.\.24"):
        load_weights(fresh, ckpt, "ck.pt")
    ckpt["method_state"]["res_final_budget"] = 24  # what budget_resolution may choose: taken back
    load_weights(fresh, ckpt, "ck.pt")
    assert fresh.res_final_budget == 24
    with pytest.raises(ValueError, match="'resolution' must be a whole number in 8..24"):
        fresh.restore_run_state({"resolution": 4})


# ---------------------------------------------------------------------------------- 4. config.json


def _edit_config(run, **fields):
    path = run / "config.json"
    cfg = json.loads(path.read_text())
    cfg.update(fields)
    path.write_text(json.dumps(cfg))


@pytest.mark.parametrize("fields, named", [
    ({"near": 100.0, "far": 200.0}, "fields 'near'/'far' (100.0 to 200.0) never reach the scene box"),
    ({"far": 1e300}, "field 'far' must be a number >= 0 within 1e+06 units"),
    ({"dataset_hash": 5}, "field 'dataset_hash' must be the hash of the dataset's transforms files"),
])
def test_eval_refuses_a_record_that_cannot_be_right(run_copy, fields, named):
    _edit_config(run_copy, **fields)
    _one_line_error(_cli("eval", run_copy, "--no-bar"), "config.json", named)


def test_a_key_written_twice_in_config_json_is_refused(run_copy):
    path = run_copy / "config.json"
    text = path.read_text()
    assert text.lstrip().startswith("{")
    path.write_text(text.replace("{", '{"downscale": 4, ', 1))  # and the file's own "downscale": 1 later
    with pytest.raises(RunError, match="key 'downscale' appears twice"):
        read_run_record(run_copy)
    _one_line_error(_cli("eval", run_copy, "--no-bar"), "config.json", "key 'downscale' appears twice")


def test_the_writer_checks_what_it_writes_by_the_readers_declaration(trained_run):
    cfg = json.loads((trained_run["run"] / "config.json").read_text())
    check_run_config(cfg, "config.json")  # what train wrote passes its own readers' rules
    for key in ("dataset", "dataset_hash", "method", "downscale", "eval_background", "near", "far", "aabb"):
        assert key in cfg, key  # each declared field is written
    for key, value in [("method", 3), ("aabb", [[0, 0, 0], [0, 1, 1]]), ("near", float("nan")), ("downscale", True)]:
        with pytest.raises(RunError, match=f"field '{key}' must be"):
            check_run_config({**cfg, key: value}, "config.json")
    record = read_run_record(trained_run["run"])
    assert record.aabb is not None and record.dataset_hash == cfg["dataset_hash"]


def test_a_config_with_numpy_numbers_is_stored_as_python_numbers():
    cfg = TrainConfig(dataset="d", out="o", method="vmgrid", max_steps=np.int64(5), seed=np.int32(3),
                      options={"res_final": np.int64(64), "upsample_at": [np.float32(0.5)]}, eval_at=[np.float64(2)])
    cfg.check()
    assert type(cfg.max_steps) is int and type(cfg.seed) is int and type(cfg.options["res_final"]) is int
    json.dumps(dataclasses.asdict(cfg))  # config.json and checkpoints can hold it


def test_every_number_option_has_a_ceiling():
    for options, name in [({"l1_weight": 1e9}, "l1_weight"), ({"occ_every": 10 ** 12}, "occ_every"),
                          ({"grid_lr_scale": 1e300}, "grid_lr_scale"), ({"grad_reach": 1e6}, "grad_reach")]:
        with pytest.raises(OptionError, match=f"option '{name}' must be"):
            build_model("vmgrid", BOX, **options)


def test_methods_lists_what_each_option_may_be(capsys):
    from nerf_core.cli.main import main

    assert main(["methods", "vmgrid"]) == 0
    out = capsys.readouterr().out
    assert "step_ratio = 0.5\n    marching step in voxels (in [0.05, 64])\n" in out
    assert '(one of "max", "random")' in out


def test_out_of_memory_advice_names_the_runs_own_options_first():
    from nerf_core.engine.report import failure_line

    line = failure_line(RuntimeError("CUDA out of memory. Tried to allocate 60 GiB"), 2048,
                        {"environment": {"width": 4096}, "res_final": 320})
    assert "this run sets --set environment={'width': 4096} res_final=320; lower --batch-rays (now 2048)" in line
    assert "step_ratio" in line and "\n" not in line
    assert "this run sets" not in failure_line(MemoryError(), 1024, {})
