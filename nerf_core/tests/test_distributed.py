"""Data-parallel training under torchrun (``nerf_core.engine.distributed``, ``nerf_core.engine.replicas``).

The end-to-end test runs the real command line, ``python -m torch.distributed.run --nproc_per_node 2
-m nerf_core train ...``, with 2 CPU ranks on gloo; the ranks print a sha256 of their model's
state (``NERF_CORE_DDP_CHECKSUM=1``), which the test compares across ranks and against its own hash
of the checkpoint rank 0 wrote.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from nerf_core.engine import distributed
from nerf_core.tests.conftest import REPO_ROOT
from nerf_core.utils.interrupts import DeferredInterrupts

# vmgrid small enough for a few steps a second on one thread, with an occupancy update every 2 steps
# and one growth (16 -> 24 cells) half-way through a 12-step budget: the parts that must stay equal.
VMGRID_SMALL = ["--method", "vmgrid", "--batch-rays", "256", "--set", "res_init=16", "--set", "res_final=24",
                "--set", "upsample_at=[0.5]", "--set", "min_stage_steps=2", "--set", "occ_every=2",
                "--set", "occ_res=16", "--no-bar", "--log-every", "1", "--seed", "3"]


def _env() -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", NERF_CORE_DDP_CHECKSUM="1", PYTHONPATH=str(REPO_ROOT))
    for k in distributed.ENV_VARS:  # the test process itself must not look like a rank
        env.pop(k, None)
    return env


def _torchrun(*args: str) -> list[str]:
    return [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
            "-m", "nerf_core", "train", "--device", "cpu", *args]


def _checksums(stderr: str) -> dict[int, tuple[int, str]]:
    """{rank: (step, sha256)} from the ranks' ``ddp-checksum`` lines."""
    found = re.findall(r"ddp-checksum rank=(\d+) step=(\d+) sha256=([0-9a-f]{64})", stderr)
    return {int(r): (int(s), h) for r, s, h in found}


def _checkpoint_hash(path: Path) -> str:
    """sha256 of a checkpoint's model state, computed here independently of the trainer: sorted keys,
    each key and a NUL, then the tensor's bytes."""
    state = torch.load(path, map_location="cpu", weights_only=True)["model"]
    h = hashlib.sha256()
    for key in sorted(state):
        h.update(key.encode() + b"\0")
        h.update(state[key].contiguous().numpy().tobytes())
    return h.hexdigest()


def _events(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "progress.jsonl").read_text().splitlines() if line.strip()]


def test_two_ranks_train_resume_cancel_and_eval(dataset_factory, tmp_path):
    ds = dataset_factory(tmp_path / "ds", n_train=6, n_test=2, w=24, h=20, depth=False)
    run = tmp_path / "run"

    # 1. a new run of 12 steps on 2 ranks
    p = subprocess.run(_torchrun(str(ds), "--out", str(run), "--max-steps", "12", "--eval-views", "1", *VMGRID_SMALL),
                       env=_env(), capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    events = _events(run)
    assert [e["event"] for e in events].count("start") == 1  # rank 1 wrote nothing
    assert sum(1 for line in p.stdout.splitlines() if '"event": "start"' in line) == 1
    assert events[-1]["event"] == "done" and events[-1]["step"] == 12
    config = json.loads((run / "config.json").read_text())
    assert config["world_size"] == 2 and config["rays_per_step"] == 512
    sums = _checksums(p.stderr)
    assert sorted(sums) == [0, 1], p.stderr[-2000:]
    assert sums[0] == sums[1] == (12, _checkpoint_hash(run / "checkpoints" / "latest.pt"))
    ckpt = torch.load(run / "checkpoints" / "latest.pt", map_location="cpu", weights_only=True)
    assert ckpt["method_state"]["resolution"] == 24 and ckpt["model"]["field.density_planes_cl"].shape[1] == 24  # grown
    assert float(ckpt["model"]["occupancy.density_ema"].abs().sum()) > 0  # the occupancy grid was updated

    # 2. the checkpoint loads without torchrun
    e = subprocess.run([sys.executable, "-m", "nerf_core", "eval", str(run), "--views", "1", "--no-bar"],
                       env=_env(), capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
    assert e.returncode == 0, e.stderr[-2000:]
    assert json.loads(e.stdout.strip().splitlines()[-1])["step"] == 12

    # 3. --resume on 2 ranks, cancelled with SIGINT to torchrun once it is past step 15. With a time
    # budget the learning rate follows the elapsed time, so the ranks stay equal only if they agree on it.
    proc = subprocess.Popen(_torchrun(str(ds), "--out", str(run), "--resume", "--max-steps", "100000",
                                      "--max-seconds", "600", *VMGRID_SMALL),
                            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if any(ev["event"] == "step" and ev["step"] >= 16 for ev in _events(run)):
                break
            time.sleep(0.2)
        assert proc.poll() is None, "the resumed run ended before it was cancelled"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    events = _events(run)
    starts = [ev for ev in events if ev["event"] == "start"]
    assert len(starts) == 2 and starts[1]["resumed_from"] == 12 and starts[1]["world_size"] == 2
    assert events[-1]["event"] == "error" and "interrupted at step" in events[-1]["message"]
    assert "checkpoint saved" in events[-1]["message"]
    stopped = torch.load(run / "checkpoints" / "latest.pt", map_location="cpu", weights_only=True)["step"]
    assert stopped >= 16 and f"interrupted at step {stopped};" in events[-1]["message"]
    sums = _checksums(err)
    assert sorted(sums) == [0, 1], err[-2000:]
    # both ranks stopped after the same step, with the same model, and that is the model rank 0 saved
    assert sums[0] == sums[1] == (stopped, _checkpoint_hash(run / "checkpoints" / "latest.pt"))

    # 4. the cancelled run resumes (here in one process) and finishes
    r = subprocess.run([sys.executable, "-m", "nerf_core", "train", str(ds), "--out", str(run), "--resume",
                        "--max-steps", str(stopped + 3), "--eval-views", "0", "--no-bar"],
                       env=_env(), capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "trained on 2 rank(s) and continues on 1" in r.stderr
    done = _events(run)[-1]
    assert done["event"] == "done" and done["step"] == stopped + 3
    assert json.loads((run / "config.json").read_text())["world_size"] == 1


# ---------------------------------------------------------------- the pieces, in one process


def test_without_torchrun_env_there_is_no_process_group():
    ctx = distributed.init_from_env({})
    assert (ctx.active, ctx.rank, ctx.world_size, ctx.is_main) == (False, 0, 1, True)
    one = {"RANK": "0", "WORLD_SIZE": "1", "LOCAL_RANK": "0", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29500"}
    assert not distributed.init_from_env(one).active  # torchrun --nproc_per_node 1: the single-process path
    assert not torch.distributed.is_initialized()
    assert ctx.agree(True) and not ctx.agree(False)
    assert ctx.place(torch.device("cpu")) == torch.device("cpu")
    with pytest.raises(ValueError, match="RANK, WORLD_SIZE and LOCAL_RANK must be integers"):
        distributed.init_from_env(dict(one, WORLD_SIZE="two"))


def test_stream_seeds_are_stable_and_distinct():
    a = distributed.stream_seed(0, "batches", 0, 5, 0)
    assert a == distributed.stream_seed(0, "batches", 0, 5, 0)
    others = {distributed.stream_seed(0, "batches", 1, 5, 0), distributed.stream_seed(0, "batches", 0, 6, 0),
              distributed.stream_seed(0, "batches", 0, 5, 1), distributed.stream_seed(1, "batches", 0, 5, 0),
              distributed.stream_seed(0, "render", 0, 5, 0)}
    assert a not in others and len(others) == 5
    assert all(0 <= s < 2 ** 63 for s in others | {a})


def test_state_checksum_sees_one_changed_value():
    a, b = torch.nn.Linear(3, 2), torch.nn.Linear(3, 2)
    b.load_state_dict(a.state_dict())
    assert distributed.state_checksum(a) == distributed.state_checksum(b)
    with torch.no_grad():
        b.bias[1] = torch.nextafter(b.bias[1], torch.tensor(1e9))  # the smallest possible change
    assert distributed.state_checksum(a) != distributed.state_checksum(b)


def test_deferred_interrupts_hold_a_signal_until_asked():
    before = signal.getsignal(signal.SIGINT)
    with DeferredInterrupts() as stop:
        assert not stop.requested()
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler runs between bytecodes of this thread
        assert stop.requested() and stop.signal == "SIGINT"
    assert signal.getsignal(signal.SIGINT) is before
    with pytest.raises(KeyboardInterrupt):  # a signal nobody checked is raised when the block ends
        with DeferredInterrupts():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
    with DeferredInterrupts(reraise=False):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
    with DeferredInterrupts(enabled=False):  # the single-process trainer: nothing changes
        assert signal.getsignal(signal.SIGINT) is before


def _average_worker(rank: int, store: str, out: str) -> None:
    torch.distributed.init_process_group("gloo", init_method=f"file://{store}", rank=rank, world_size=2)
    try:
        params = [torch.nn.Parameter(torch.zeros(2)), torch.nn.Parameter(torch.zeros(3)),
                  torch.nn.Parameter(torch.zeros(1))]
        params[0].grad = torch.tensor([1.0, 2.0]) if rank == 0 else torch.tensor([3.0, 4.0])
        if rank == 1:
            params[1].grad = torch.tensor([6.0, 6.0, 6.0])  # rank 0 has no gradient for it
        extra = distributed.average_gradients(params, 2, [rank + 1.0, 10.0])
        grads = [None if p.grad is None else p.grad.tolist() for p in params]
        Path(out).write_text(json.dumps({"grads": grads, "extra": extra}))
    finally:
        torch.distributed.destroy_process_group()


def test_average_gradients_over_two_ranks(tmp_path):
    outs = [tmp_path / f"rank{r}.json" for r in range(2)]
    torch.multiprocessing.start_processes(_worker_entry, args=(str(tmp_path / "store"), str(tmp_path)), nprocs=2,
                                          start_method="spawn")
    for out in outs:
        got = json.loads(out.read_text())
        assert got["grads"][0] == [2.0, 3.0]  # (1 + 3) / 2, (2 + 4) / 2
        assert got["grads"][1] == [3.0, 3.0, 3.0]  # (0 + 6) / 2: zeros where a rank had no gradient
        assert got["grads"][2] is None  # no rank had one: stays None, as in one process
        assert got["extra"] == [3.0, 20.0]  # summed, not averaged


def _worker_entry(rank: int, store: str, folder: str) -> None:
    _average_worker(rank, store, str(Path(folder) / f"rank{rank}.json"))
