"""Fingerprints of seeded training runs, to prove that a restructuring changed no behaviour.

    python tools/seeded_identity.py OUT [--vmgrid-steps 200] [--nerf-steps 50]

Writes a 48x40 sphere dataset (16 train, 3 test views; ``nerf_core/tests/conftest.make_dataset``)
into OUT, trains vmgrid and nerf on it with seed 0 on one CPU thread, and prints one JSON line per
method: the test PSNR and SSIM and the sha256 of the trained weights. Run it on two commits (two
checkouts) and compare the lines: equal lines mean bit-identical training and evaluation.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def weights_sha256(checkpoint: Path) -> str:
    """sha256 over the checkpoint's weights, by name in sorted order (the tensors' raw bytes)."""
    import torch  # the scripts' own Python may lack torch until the command runs

    state = torch.load(checkpoint, map_location="cpu", weights_only=True)["model"]
    h = hashlib.sha256()
    for name in sorted(state):
        h.update(name.encode())
        h.update(state[name].detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def fingerprint(dataset: Path, run: Path, method: str, steps: int) -> dict:
    """Train ``method`` for ``steps`` seeded steps into ``run``; its test metrics and weight hash."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(REPO))
    cmd = [sys.executable, "-m", "nerf_core", "train", str(dataset), "--out", str(run), "--method", method,
           "--max-steps", str(steps), "--seed", "0", "--eval-views", "3", "--device", "cpu", "--no-bar"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
    if proc.returncode != 0:
        raise SystemExit(f"seeded_identity: {method}: train failed: {proc.stderr.strip().splitlines()[-1:]}")
    metrics = json.loads((run / "metrics.json").read_text())
    return {"method": method, "steps": steps, "psnr": metrics["psnr"], "ssim": metrics["ssim"],
            "weights_sha256": weights_sha256(run / "checkpoints" / "latest.pt")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="a new folder for the dataset and the runs")
    ap.add_argument("--vmgrid-steps", type=int, default=200)
    ap.add_argument("--nerf-steps", type=int, default=50)
    args = ap.parse_args(argv)
    out = Path(args.out)
    if out.exists():
        print(f"seeded_identity: error: {out} exists; name a new folder", file=sys.stderr)
        return 2
    sys.path.insert(0, str(REPO))
    from nerf_core.tests.conftest import make_dataset

    dataset = make_dataset(out / "ds", n_train=16, n_test=3, w=48, h=40, layouts=("synthetic",))
    for method, steps in (("vmgrid", args.vmgrid_steps), ("nerf", args.nerf_steps)):
        print(json.dumps(fingerprint(dataset, out / method, method, steps)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
