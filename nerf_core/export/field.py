"""The one place where export reads a trained model: density and colour at world points.

Every exporter (mesh, volume) calls ``density`` and ``colour`` here and nothing else of the model, so
a change of the methods' interface is a change of this module alone.

Units: both methods' fields return density per scene unit whatever their ``density_unit`` option
(``methods.base.density_length`` is folded into the field's scale), so the geometry needs no
conversion: an opacity of ``1 - exp(-sigma * length)`` over ``length`` scene units.
"""
from __future__ import annotations

import torch

from nerf_core.errors import RunError

Tensor = torch.Tensor


def _vmgrid_field(model):
    """(field lookup tables, world -> field coordinates) of a grid method, or None."""
    field = getattr(model, "field", None)
    if field is None or not hasattr(field, "lookup"):
        return None
    warp = getattr(model, "warp", lambda p: p)
    return field.lookup(), warp


def _mlp(model):
    """The network that renders a ``nerf`` model: its fine network when it has one."""
    return getattr(model, "fine", None) or getattr(model, "coarse", None)


def _unsupported(model) -> RunError:
    return RunError(f"method {getattr(model, 'method_name', type(model).__name__)!r}: export reads a grid "
                    "field (vmgrid) or a NeRF MLP (nerf), and this model has neither")


@torch.no_grad()
def density(model, pts: Tensor) -> Tensor:
    """Density per scene unit (m,) at world points (m, 3)."""
    grid = _vmgrid_field(model)
    if grid is not None:
        lookup, warp = grid
        return lookup.density(warp(pts))
    net = _mlp(model)
    if net is None:
        raise _unsupported(model)
    return net.density(pts)


@torch.no_grad()
def colour(model, pts: Tensor, dirs: Tensor) -> Tensor:
    """Colour (m, 3) in [0, 1] at world points (m, 3) seen along unit directions (m, 3)."""
    grid = _vmgrid_field(model)
    if grid is not None:
        lookup, warp = grid
        return lookup.color(warp(pts), dirs)
    net = _mlp(model)
    if net is None:
        raise _unsupported(model)
    return net(pts, dirs)[1]


def grid_resolution(model) -> int:
    """Samples per axis of the scene box that match the model's own detail: a grid method's plane size
    (halved when its grid spans the contracted world, twice the box), 256 for an MLP (its finest
    positional-encoding period is far below any grid that fits in memory)."""
    field = getattr(model, "field", None)
    if field is not None and hasattr(field, "resolution"):
        res = int(field.resolution)
        return max(2, res // 2) if getattr(model, "contracted", False) else res
    return 256


def models_the_world(model) -> bool:
    """True when the run models light from infinity or the world beyond its box (not geometry)."""
    return getattr(model, "environment", None) is not None or bool(getattr(model, "contracted", False))
