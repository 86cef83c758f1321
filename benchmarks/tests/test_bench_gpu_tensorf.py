"""benchmarks/bench_gpu_tensorf.py without TensoRF or a GPU: flags, TensoRF's command line and schedule,
the stand-ins, the timing hooks, parsing our events, and the report (--report-only).

The whole run against TensoRF's real code takes a checkout of it: with ``NERF_BENCH_TENSORF=DIR`` set,
``test_quick_run_against_tensorf`` runs ``--quick`` on the CPU (about a minute); else it is skipped.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
from PIL import Image

import bench_gpu_tensorf as cli
from bench import gpu_compare, tensorf_config, tensorf_launch, tensorf_standins

LEGO = """dataset_name = blender
n_iters = 30000
batch_size = 4096
N_voxel_init = 2097156 # 128**3
upsamp_list = [2000,3000,4000,5500,7000]
update_AlphaMask_list = [2000,4000]
n_lamb_sigma = [16,16,16]
model_name = TensorVMSplit
L1_weight_inital = 8e-5
"""


def test_schedule_halved_for_5000_iterations_and_lists_repeat_their_flag(tmp_path):
    (tmp_path / "lego.txt").write_text(LEGO)
    config = tensorf_config.read_config(str(tmp_path / "lego.txt"))
    assert config["N_voxel_init"] == 2097156 and config["model_name"] == "TensorVMSplit"
    assert tensorf_config.scaled_schedule(config, 5000) == {"upsamp_list": [1000, 1500, 2000, 2750, 3500],
                                                            "update_AlphaMask_list": [1000, 2000]}
    argv = tensorf_config.build_argv(config, "/d", "/b", "x", 5000, 4.0, 1000)
    pairs = list(zip(argv[::2], argv[1::2]))
    assert [v for k, v in pairs if k == "--n_lamb_sigma"] == ["16", "16", "16"]
    assert ("--n_iters", "5000") in pairs and ("--downsample_train", "4.0") in pairs
    assert ("--N_vis", "-1") in pairs and ("--vis_every", "1000") in pairs and ("--render_test", "1") in pairs
    with pytest.raises(tensorf_config.ConfigError, match="too few"):
        tensorf_config.scaled_schedule(config, 5)


def test_dataset_check_names_what_tensorf_cannot_read(tmp_path, tiny_dataset):
    ds = tmp_path / "ds"
    tiny_dataset(ds)
    assert tensorf_config.check_dataset(str(ds)) == (4, 200.0)
    Image.new("RGB", (4, 4)).save(ds / "train" / "r_0.png")
    with pytest.raises(tensorf_config.ConfigError, match=r"r_0.png: mode RGB.*RGBA"):
        tensorf_config.check_dataset(str(ds))


def test_standins_match_kornia_and_torchvision_formulas():
    grid = tensorf_standins.create_meshgrid(2, 3, normalized_coordinates=False)
    assert grid.shape == (1, 2, 3, 2) and grid[0, 1, 2].tolist() == [2.0, 1.0]
    try:
        import kornia
    except ImportError:
        kornia = None
    if kornia is not None:  # the stand-in is kornia's formula: equal where kornia is installed
        assert torch.equal(grid, kornia.create_meshgrid(2, 3, False))
        assert torch.equal(tensorf_standins.create_meshgrid(5, 7), kornia.create_meshgrid(5, 7))
    im = Image.fromarray(np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4), "RGBA")
    t = tensorf_standins.ToTensor()(im)
    assert t.shape == (4, 2, 3) and t[1, 0, 2].item() == pytest.approx(9 / 255)


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def now(self):
        return self.t


def test_timing_hooks_take_evaluations_off_the_training_seconds():
    clock, state = FakeClock(), {"eval_seconds": 0.0, "points": []}
    loop = tensorf_launch.TimedLoop(clock, state, report_every=100)(range(4))

    def evaluation(*args, **kwargs):
        assert kwargs["compute_extra_metrics"] is False and kwargs["device"] == "cpu"
        clock.t += 5.0  # evaluating takes 5 s
        return [20.0, 22.0]

    ev = tensorf_launch.TimedEval(evaluation, clock, state, "cpu")
    for i in loop:
        clock.t += 1.0  # an iteration takes 1 s
        if i == 1:
            ev(compute_extra_metrics=True)
    ev()
    assert state["loop_end"] - state["loop_start"] - state["eval_seconds"] == 4.0
    mid, final = state["points"]
    assert (mid["iteration"], mid["seconds"], mid["psnr"], mid["final"]) == (2, 2.0, 21.0, False)
    assert (final["iteration"], final["seconds"], final["final"]) == (4, 4.0, True)


def _ours_events():
    ev = [{"event": "start"}]
    ev += [{"event": "step", "step": s, "elapsed": s / 100} for s in range(50, 1001, 50)]
    ev += [{"event": "eval", "split": "test", "psnr": 30.0, "elapsed": 3.0, "step": 300, "eval_wall": 1.0},
           {"event": "eval", "split": "test", "psnr": 33.0, "elapsed": 6.0, "step": 600, "eval_wall": 1.0},
           {"event": "eval", "split": "test", "psnr": 35.0, "step": 1000, "n_views": 20},
           {"event": "done", "step": 1000, "elapsed": 10.0}]
    return ev


def test_our_events_give_points_speed_and_the_headline():
    ours = gpu_compare.summarise_ours(_ours_events(), {"rays_per_step": 8192, "method": "vmgrid"})
    assert [p["seconds"] for p in ours["points"]] == [3.0, 6.0, 10.0] and ours["final"]["psnr"] == 35.0
    assert ours["steps_per_s"] == 100 and ours["rays_per_s"] == 819200
    assert ours["steps_per_s_late"] == pytest.approx(100)
    tensorf = {"iters": 5000, "train_seconds": 40.0, "final": {"psnr": 32.5, "seconds": 40.0, "iteration": 5000},
               "points": [{"psnr": 32.5, "seconds": 40.0, "iteration": 5000, "final": True}]}
    h = gpu_compare.headline({"ours": ours, "tensorf": tensorf})
    assert h["ours_seconds_to_tensorf_psnr"] == 6.0 and h["time_ratio"] == 0.15 and h["speed_target_met"]
    assert h["rays_target_met"] is False


def test_flags_are_checked_and_report_only_redraws(tmp_path, capsys, tiny_dataset):
    ds = tmp_path / "ds"
    tiny_dataset(ds)
    out = tmp_path / "out"

    def problem(*flags):
        return cli.check_args(cli.parse_args(list(flags)))

    assert "--dataset is required" in problem("--out", str(out))
    assert "no train.py" in problem("--out", str(out), "--dataset", str(ds), "--tensorf", str(tmp_path))
    assert "(0, --ours-seconds 30)" in problem("--out", str(out), "--dataset", str(ds), "--skip-tensorf",
                                               "--ours-seconds", "30", "--eval-at", "10,30")
    assert cli.parse_args(["--out", "x", "--ours-seconds", "45"]).eval_at == "10,20,30"
    out.mkdir()
    ours = gpu_compare.summarise_ours(_ours_events(), {"rays_per_step": 8192})
    (out / "results.json").write_text(json.dumps({"machine": {"device_name": "NVIDIA H200", "torch": "2.11.0"},
                                                  "ours": ours, "commands": ["python -m nerf_core train ..."]}))
    assert "--overwrite" in problem("--out", str(out), "--dataset", str(ds), "--skip-tensorf")
    assert problem("--out", str(out), "--dataset", str(ds), "--skip-ours", "--skip-tensorf") != ""
    assert cli.main(["--out", str(out), "--report-only"]) == 0
    md = (out / "summary.md").read_text()
    assert "NVIDIA H200" in md and "819,200 rays/s" in md and "| ours (final) | 10.0 | 1000 | 35.00 |" in md
    assert (out / "psnr_vs_seconds.png").is_file() or "matplotlib is not installed" in md


@pytest.mark.skipif(not os.environ.get("NERF_BENCH_TENSORF"), reason="set NERF_BENCH_TENSORF to a TensoRF checkout")
def test_quick_run_against_tensorf(tmp_path):
    import importlib.util

    path = os.path.join(os.path.dirname(__file__), "..", "..", "nerf_core", "tests", "conftest.py")
    spec = importlib.util.spec_from_file_location("nerf_core_test_fixtures", path)
    fixtures = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fixtures)  # nerf_core's dataset maker: 20 px, square, centred (TensoRF's loader)
    fixtures.make_dataset(tmp_path / "ds", n_train=8, n_test=2, w=20, h=20, shift=(0, 0),
                          layouts=("synthetic",), depth=False)
    out = tmp_path / "out"
    assert cli.main(["--dataset", str(tmp_path / "ds"), "--tensorf", os.environ["NERF_BENCH_TENSORF"],
                     "--out", str(out), "--device", "cpu", "--quick"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["tensorf"]["final"]["psnr"] > 0 and results["ours"]["final"]["psnr"] > 0
