"""benchmarks/bench_ddp.py: the steady part of a run's steps and the commands it starts."""
from __future__ import annotations

import bench_ddp
import pytest


def test_bench_ddp_measures_the_steady_part_and_builds_the_commands():
    # 100 steps: the first 10 at 1 s each (start-up, growth), then 0.25 s each -> 4 steps/s when steady
    events = [{"event": "start"}]
    elapsed = 0.0
    for step in range(1, 101):
        elapsed += 1.0 if step <= 10 else 0.25
        if step % 10 == 0 or step == 1:
            events.append({"event": "step", "step": step, "elapsed": elapsed})
    events.append({"event": "done", "step": 100, "elapsed": elapsed, "metrics": {"psnr": 21.5}})
    m = bench_ddp.measure(events, steps=100)
    assert m["steps_per_s"] == pytest.approx(4.0) and m["psnr"] == 21.5 and m["steps"] == 100

    args = bench_ddp.parse_args(["--out", "X", "--steps", "50", "--batch-rays", "512"])
    one, two = bench_ddp.command(args, 1, "DS", "R1"), bench_ddp.command(args, 2, "DS", "R2")
    assert one[1:4] == ["-m", "nerf_core", "train"] and "torch.distributed.run" not in one
    assert two[1:6] == ["-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
    for cmd in (one, two):
        assert cmd[cmd.index("--max-steps") + 1] == "50" and cmd[cmd.index("--batch-rays") + 1] == "512"
