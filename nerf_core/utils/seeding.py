"""Seeding and the RNG state a checkpoint carries, so that ``--resume`` continues the same random stream.

Every random source the trainer touches is covered: python's ``random``, numpy's global RNG, torch's
CPU (and CUDA) RNG, and the dedicated generator that draws the ray batches.
"""
from __future__ import annotations

import random

import numpy as np
import torch


def seed_everything(seed: int) -> None:
    """Seed python, numpy and torch from one integer (numpy takes it modulo 2**32)."""
    random.seed(seed)
    np.random.seed(seed % (2 ** 32))
    torch.manual_seed(seed)


def rng_state(gen: torch.Generator) -> dict:
    """Every RNG's state as tensors and plain Python data, so that a checkpoint holding it loads with
    ``torch.load(weights_only=True)`` (a numpy array would need numpy's unpickling globals)."""
    kind, key, pos, has_gauss, gauss = np.random.get_state()
    state = {"python": random.getstate(),  # (version, tuple of ints, float or None): plain data already
             "numpy": {"bit_generator": str(kind), "key": torch.from_numpy(key.astype(np.int64)), "pos": int(pos),
                       "has_gauss": int(has_gauss), "cached_gaussian": float(gauss)},
             "torch": torch.get_rng_state(), "batches": gen.get_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict, gen: torch.Generator) -> None:
    """Restore what ``rng_state`` saved (also the numpy tuple of checkpoints older than that format)."""
    random.setstate(state["python"])
    nps = state["numpy"]
    if isinstance(nps, dict):
        key = np.asarray(torch.as_tensor(nps["key"]).numpy(), dtype=np.uint32)
        np.random.set_state((nps["bit_generator"], key, nps["pos"], nps["has_gauss"], nps["cached_gaussian"]))
    else:  # checkpoints from before the weights-only format stored np.random.get_state() as it is
        np.random.set_state(nps)
    torch.set_rng_state(state["torch"])
    gen.set_state(state["batches"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
