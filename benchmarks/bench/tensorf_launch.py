"""Run TensoRF's official training, unmodified, from its checkout, and time it the way we time ours.

    python -m bench.tensorf_launch --tensorf DIR --dataset DS --logdir DIR --result JSON [--iters 5000]
                                   [--eval-every 1000] [--device cuda|cpu] [--quick]

(run with ``benchmarks/`` and ``scripts/`` on ``PYTHONPATH``; ``benchmarks/bench_gpu_tensorf.py`` starts it as a
subprocess.)

It imports TensoRF's ``train`` module from ``--tensorf`` and calls its ``reconstruction(args)``, with
the arguments ``bench.tensorf_config.build_argv`` makes from TensoRF's ``configs/lego.txt``. No line of
TensoRF changes; three names in its modules are wrapped from outside:

- ``train.tqdm`` (the iteration loop's bar) by ``TimedLoop``: the clock starts at the first iteration
  and stops after the last (the device synchronised each time), so data loading and ray set-up are not
  training time, as in ours;
- ``train.evaluation`` by ``TimedEval``: each test evaluation is timed and its seconds are taken off
  the training time; it runs with ``compute_extra_metrics=False`` (PSNR only: TensoRF's SSIM and
  LPIPS would download network weights) and with the run's device (the in-loop call leaves TensoRF's
  default ``'cuda'``);
- ``renderer.imageio`` by ``PngOnlyImageio``: test renders as PNG, no mp4 videos.

Missing optional modules get stand-ins (``bench.tensorf_standins``); the result names them.
The result JSON: ``train_seconds`` (loop time less evaluations), ``setup_seconds``, ``points`` (one
per evaluation: iteration, training seconds, PSNR, eval wall), ``final``, ``steps_per_s``,
``rays_per_s``, ``standins``, ``argv``, ``device``.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time

from bench import tensorf_config, tensorf_standins


class Clock:
    """Seconds since start, the device synchronised first so queued kernels count where they ran."""

    def __init__(self, cuda: bool):
        self.cuda = cuda
        self.t0 = time.perf_counter()

    def now(self) -> float:
        if self.cuda:
            import torch

            torch.cuda.synchronize()
        return time.perf_counter() - self.t0


class TimedLoop:
    """Stands in for ``tqdm`` around TensoRF's iteration loop: records when it starts and ends."""

    def __init__(self, clock: Clock, state: dict, report_every: int):
        self.clock, self.state, self.report_every = clock, state, max(1, report_every)

    def __call__(self, iterable, *args, **kwargs):
        self.iterable = iterable
        return self

    def __iter__(self):
        n = len(self.iterable)
        self.state["loop_start"] = self.clock.now()
        for i in self.iterable:
            self.state["iteration"] = i
            yield i
            if (i + 1) % self.report_every == 0:
                secs = self.clock.now() - self.state["loop_start"] - self.state["eval_seconds"]
                print(f"tensorf: iteration {i + 1}/{n}, {secs:.1f} s of training", flush=True)
        self.state["loop_end"] = self.clock.now()

    def set_description(self, *args, **kwargs):
        pass


class TimedEval:
    """Wraps TensoRF's ``evaluation``: PSNR only, on the run's device, its time kept off the training."""

    def __init__(self, evaluation, clock: Clock, state: dict, device):
        self.evaluation, self.clock, self.state, self.device = evaluation, clock, state, device

    def __call__(self, *args, **kwargs):
        kwargs["compute_extra_metrics"] = False
        kwargs["device"] = self.device
        start = self.clock.now()
        psnrs = self.evaluation(*args, **kwargs)
        wall = self.clock.now() - start
        final = "loop_end" in self.state  # the evaluation after the loop, else one inside it
        trained = (self.state["loop_end"] if final else start) - self.state["loop_start"] - self.state["eval_seconds"]
        if not final:
            self.state["eval_seconds"] += wall
        point = {"iteration": self.state.get("iteration", -1) + 1, "seconds": round(trained, 3),
                 "psnr": float(sum(psnrs) / len(psnrs)) if psnrs else None, "n_views": len(psnrs),
                 "eval_wall": round(wall, 3), "final": final}
        self.state["points"].append(point)
        print(f"tensorf: test PSNR {point['psnr']:.2f} dB after {point['iteration']} iterations, "
              f"{point['seconds']:.1f} s of training ({wall:.1f} s to evaluate)", flush=True)
        return psnrs


def import_tensorf(tensorf_dir: str):
    """TensoRF's ``train`` and ``renderer`` modules, imported from ``tensorf_dir`` (stand-ins first)."""
    if not os.path.isfile(os.path.join(tensorf_dir, "train.py")) or not os.path.isfile(
            os.path.join(tensorf_dir, tensorf_config.CONFIG)):
        raise tensorf_config.ConfigError(f"--tensorf {tensorf_dir}: no train.py and {tensorf_config.CONFIG} there "
                                         "(a checkout of apchenstu/TensoRF)")
    standins = tensorf_standins.install()
    sys.path.insert(0, os.path.abspath(tensorf_dir))
    train = importlib.import_module("train")
    renderer = importlib.import_module("renderer")
    return train, renderer, standins


def run(a) -> dict:
    """Train TensoRF as ``a`` says and return the result (see the module docstring)."""
    import numpy as np
    import torch

    width, downsample = tensorf_config.check_dataset(a.dataset)
    if a.device == "cuda" and not torch.cuda.is_available():
        raise tensorf_config.ConfigError("--device cuda: this torch sees no CUDA device")
    train, renderer, standins = import_tensorf(a.tensorf)
    if str(train.device) != a.device:
        raise tensorf_config.ConfigError(f"TensoRF chose {train.device} but --device is {a.device}: set "
                                         "CUDA_VISIBLE_DEVICES='' for a CPU run on a CUDA machine")
    config = tensorf_config.read_config(os.path.join(a.tensorf, tensorf_config.CONFIG))
    argv = tensorf_config.build_argv(config, os.path.abspath(a.dataset), os.path.abspath(a.logdir), "tensorf",
                                     a.iters, downsample, a.eval_every, quick=a.quick)
    # train.py's __main__ block, which reconstruction() does not run
    torch.set_default_dtype(torch.float32)
    torch.manual_seed(20211202)
    np.random.seed(20211202)
    args = importlib.import_module("opt").config_parser(argv)
    clock = Clock(a.device == "cuda")
    state = {"eval_seconds": 0.0, "points": []}
    train.tqdm = TimedLoop(clock, state, report_every=max(1, a.iters // 10))
    train.evaluation = TimedEval(renderer.evaluation, clock, state, train.device)
    renderer.imageio = tensorf_standins.PngOnlyImageio
    t_start = clock.now()
    train.reconstruction(args)
    if "loop_end" not in state:
        raise RuntimeError("TensoRF's reconstruction() returned without running its iteration loop")
    train_seconds = state["loop_end"] - state["loop_start"] - state["eval_seconds"]
    finals = [p for p in state["points"] if p["final"]]
    # an in-loop evaluation after the last iteration repeats the final one: keep the final
    done = {p["iteration"] for p in finals}
    state["points"] = [p for p in state["points"] if p["final"] or p["iteration"] not in done]
    result = {
        "iters": a.iters, "train_seconds": round(train_seconds, 3),
        "setup_seconds": round(state["loop_start"] - t_start, 3),
        "eval_seconds_in_loop": round(state["eval_seconds"], 3),
        "points": state["points"], "final": finals[-1] if finals else None,
        "steps_per_s": a.iters / train_seconds, "rays_per_step": args.batch_size,
        "rays_per_s": a.iters * args.batch_size / train_seconds,
        "standins": standins, "argv": argv, "device": str(train.device), "image_width": width,
        "config": {k: getattr(args, k) for k in ("n_iters", "batch_size", "N_voxel_init", "N_voxel_final",
                                                 "upsamp_list", "update_AlphaMask_list", "n_lamb_sigma",
                                                 "n_lamb_sh", "model_name", "shadingMode")},
    }
    if a.device == "cuda":
        result["max_memory_gib"] = round(torch.cuda.max_memory_allocated() / 2 ** 30, 2)
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.tensorf_launch", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tensorf", required=True, help="checkout of apchenstu/TensoRF")
    ap.add_argument("--dataset", required=True, help="synthetic-layout dataset (RGBA PNGs)")
    ap.add_argument("--logdir", required=True, help="TensoRF's basedir (its run folder goes inside)")
    ap.add_argument("--result", required=True, help="JSON file to write")
    ap.add_argument("--iters", type=int, default=5000)
    ap.add_argument("--eval-every", type=int, default=1000,
                    help="test evaluation every N iterations (0: only the final)")
    ap.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    ap.add_argument("--quick", action="store_true", help="tiny grid and batch (CPU plumbing tests)")
    a = ap.parse_args(argv)
    try:
        result = run(a)
    except (tensorf_config.ConfigError, tensorf_standins.MissingRequired) as exc:
        print(f"tensorf_launch: {exc}", file=sys.stderr)
        return 2
    with open(a.result, "w", encoding="utf-8") as fh:
        json.dump(result, fh, indent=1)
    print(f"tensorf: {a.iters} iterations in {result['train_seconds']:.1f} s of training "
          f"({result['steps_per_s']:.1f} it/s); stand-ins: {', '.join(result['standins']) or 'none'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
