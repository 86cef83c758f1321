"""The step profile (``bench.profiler``) of every built-in method, on a tiny dataset: a few real steps."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from bench import profiler


def looking_dataset(root, n_views=4, size=8):
    """``n_views`` ``size``-pixel views from a circle of radius 3 looking at the centre of a [-1, 1]^3 box,
    each a centred opaque square on a transparent film (every ray the profile draws crosses the box)."""
    (root / "train").mkdir(parents=True)
    frames = []
    for k in range(n_views):
        a = 2 * math.pi * k / n_views
        eye = np.array([3 * math.cos(a), 3 * math.sin(a), 1.0])
        back = eye / np.linalg.norm(eye)  # the camera looks down its -z axis, at the origin
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, np.cross(back, right), back], axis=1)
        c2w[:3, 3] = eye
        rgba = np.zeros((size, size, 4), np.uint8)
        rgba[size // 4: 3 * size // 4, size // 4: 3 * size // 4] = [200, 80, 40, 255]
        Image.fromarray(rgba).save(root / "train" / f"r_{k}.png")
        frames.append({"file_path": f"./train/r_{k}", "transform_matrix": c2w.tolist()})
    meta = {"w": size, "h": size, "fl_x": size, "fl_y": size, "cx": size / 2, "cy": size / 2,
            "aabb": [[-1, -1, -1], [1, 1, 1]], "frames": frames}
    (root / "transforms_train.json").write_text(json.dumps(meta))
    return root


def builtin_methods() -> list[str]:
    from nerf_core.methods.registry import available_methods

    return [m for m in available_methods() if not m.startswith("test-")]  # not nerf_core/tests' stand-ins


@pytest.mark.parametrize("method", builtin_methods())
def test_profile_splits_real_steps_into_the_reported_stages(tmp_path, method):
    """Every method marks its stages: one added without marks would show its forward time as other_forward."""
    ds = looking_dataset(tmp_path / "ds")
    prof = profiler.profile_method(str(ds), method, steps=2, n_rays=16)
    assert list(prof["seconds"]) == list(profiler.STAGES)
    # Every stage is reached: the methods' marks (sampling, field, rendering) and the driver's own.
    for stage in profiler.STAGES:
        assert prof["seconds"][stage] > 0, stage
    assert math.isclose(sum(prof["shares"].values()), 1.0, rel_tol=1e-9)
    assert prof["seconds_per_step"] == pytest.approx(sum(prof["seconds"].values()) / 2)
    assert (prof["method"], prof["steps"], prof["rays"]) == (method, 2, 16)
