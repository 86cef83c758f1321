"""The rules a ``Cameras`` holds to, checked where one is made from a user's arrays (the public
boundary: ``Cameras(...)``, ``Cameras.create``): the loaders' own rules (``contract.check_pose``,
the focal range of ``contract.transforms``), raised as ValueError/TypeError naming the field."""
from __future__ import annotations

import numpy as np
import torch

from nerf_core.contract.errors import PoseError
from nerf_core.contract.poses import check_pose
from nerf_core.contract.transforms import MAX_FOCAL_PX, MIN_FOCAL_PX
from nerf_core.utils.arguments import tensor

MAX_SIDE = (1 << 31) - 1  # pixels on a side that int32 pixel indices hold (render.memory refuses far fewer)


def check_cameras(cams) -> None:
    """Refuse cameras no ray can be traced through (ValueError/TypeError naming ``Cameras.<field>``)."""
    f = "Cameras"
    c2w = tensor(f, "c2w", cams.c2w)
    if c2w.dim() != 3 or tuple(c2w.shape[1:]) != (4, 4):
        raise ValueError(f"{f}: c2w must have shape (n, 4, 4), got {tuple(c2w.shape)}")
    n = c2w.shape[0]
    for name in ("fx", "fy", "cx", "cy", "width", "height"):
        t = tensor(f, name, getattr(cams, name), floating=name not in ("width", "height"), ndim=1)
        if t.shape[0] != n:
            raise ValueError(f"{f}: {name} must have shape ({n},) like c2w, got {tuple(t.shape)}")
        if name in ("width", "height"):
            if t.is_floating_point() or t.dtype == torch.bool:
                raise TypeError(f"{f}: {name} must hold integers, got {t.dtype}")
            if n and not bool(((t >= 1) & (t <= MAX_SIDE)).all()):
                raise ValueError(f"{f}: {name} must be whole pixels in 1..{MAX_SIDE}, got {t.tolist()[:8]}")
        elif name in ("fx", "fy") and n and not bool(((t >= MIN_FOCAL_PX) & (t <= MAX_FOCAL_PX)).all()):
            bad = t[~((t >= MIN_FOCAL_PX) & (t <= MAX_FOCAL_PX))][0].item()
            raise ValueError(f"{f}: {name} (focal length in pixels) must lie in {MIN_FOCAL_PX:g}..{MAX_FOCAL_PX:g}, "
                             f"got {bad}")
    poses = c2w.detach().cpu().double().numpy()
    for i in range(n):
        try:
            check_pose(poses[i], where=f"{f}: c2w[{i}]")
        except PoseError as exc:
            raise ValueError(str(exc)) from None
    if cams.dist is not None:
        dist = tensor(f, "dist", cams.dist)
        if tuple(dist.shape) != (n, 6):
            raise ValueError(f"{f}: dist must have shape ({n}, 6), got {tuple(dist.shape)}")
        fish = cams.fisheye
        if not isinstance(fish, torch.Tensor) or fish.dtype != torch.bool or tuple(fish.shape) != (n,):
            raise ValueError(f"{f}: fisheye must be a ({n},) bool tensor beside dist")


def as_array(value, name: str):
    """``np.asarray(value)`` for ``Cameras.create``, TypeError naming the argument when it is no array."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise TypeError(f"Cameras.create: {name} must be an array of numbers") from None
    if arr.dtype == object or arr.dtype.kind in "USVb" and name != "lenses":
        raise TypeError(f"Cameras.create: {name} must be an array of numbers, got {arr.dtype}")
    return arr
