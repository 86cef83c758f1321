"""Fixtures for the tests of the benchmarks: ``benchmarks/`` and ``scripts/`` on sys.path, and a tiny dataset.

The benchmarks import their package as ``bench`` (``benchmarks/bench``) with ``benchmarks/`` on sys.path and
the scripts' shared start-up (``scripts/_bootstrap.py``) with ``scripts/`` on it, as
``python benchmarks/benchmark.py`` does; the tests import them the same way.
"""
from __future__ import annotations

import json
import math
import os
import sys

import numpy as np
import pytest
from PIL import Image

BENCHMARKS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _folder in (os.path.join(os.path.dirname(BENCHMARKS), "scripts"), BENCHMARKS):
    if _folder not in sys.path:
        sys.path.insert(0, _folder)


def write_tiny_dataset(root, n_train=6):
    """A 4x4-pixel dataset at ``root`` (a pathlib.Path): ``n_train`` train and 2 test views on a circle of
    radius 4 around a [-1, 1]^3 box, each image a 2x2 opaque white square on a transparent film."""
    root.mkdir()
    for split, n in (("train", n_train), ("test", 2)):
        (root / split).mkdir()
        frames = []
        for k in range(n):
            a = 2 * math.pi * k / n
            c2w = np.eye(4)
            c2w[:3, 3] = [4 * math.cos(a), 4 * math.sin(a), 0.0]
            alpha = np.zeros((4, 4), np.uint8)
            alpha[1:3, 1:3] = 255
            Image.fromarray(np.dstack([alpha] * 4)).save(root / split / f"r_{k}.png")
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": c2w.tolist()})
        meta = {"camera_angle_x": 0.7, "w": 4, "h": 4, "fl_x": 5.0, "fl_y": 5.0, "cx": 2.0, "cy": 2.0,
                "aabb": [[-1, -1, -1], [1, 1, 1]], "frames": frames}
        (root / f"transforms_{split}.json").write_text(json.dumps(meta))
    (root / "transforms.json").write_text("{}")
    (root / "nerfstudio").mkdir()
    (root / "nerfstudio" / "transforms.json").write_text("{}")
    return root


@pytest.fixture
def tiny_dataset():
    """``write_tiny_dataset`` as a fixture: ``tiny_dataset(tmp_path / "src", n_train=8)``."""
    return write_tiny_dataset
