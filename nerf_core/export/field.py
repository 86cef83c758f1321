"""The one place where export reads a trained model: density and colour at world points.

Every exporter (mesh, volume) calls ``density`` and ``colour`` here and nothing else of the model. They
are the model's declared interface (``RadianceModel.density_at``, ``sampled_at``, ``colour_at``,
``detail_resolution``); a method that cannot be read at points is named in a RunError.

Units: both built-in methods return density per scene unit whatever their ``density_unit`` option
(``methods.base.density_length`` is folded into the field's scale), so the geometry needs no
conversion: an opacity of ``1 - exp(-sigma * length)`` over ``length`` scene units.
"""
from __future__ import annotations

import torch

from nerf_core.errors import RunError
from nerf_core.methods.base import RadianceModel

Tensor = torch.Tensor


@torch.no_grad()
def density(model: RadianceModel, pts: Tensor) -> Tensor:
    """Density per scene unit (m,) at world points (m, 3), zero where the renderer skips space
    (``RadianceModel.sampled_at``: an occupancy grid's empty cells). The renderer never sees the faint
    haze a field keeps there, so an export must not either: on the multi demo scene the exported volume
    otherwise lays a 3 % haze over the whole background that the NeRF's render does not have."""
    try:
        sigma = model.density_at(pts)
        return torch.where(model.sampled_at(pts), sigma, torch.zeros_like(sigma))
    except NotImplementedError as exc:
        raise RunError(f"export: {exc}; export reads methods that offer their field at points "
                       "(vmgrid, nerf)") from None


@torch.no_grad()
def colour(model: RadianceModel, pts: Tensor, dirs: Tensor) -> Tensor:
    """Colour (m, 3) in [0, 1] at world points (m, 3) seen along unit directions (m, 3)."""
    try:
        return model.colour_at(pts, dirs)
    except NotImplementedError as exc:
        raise RunError(f"export: {exc}; export reads methods that offer their field at points "
                       "(vmgrid, nerf)") from None


def grid_resolution(model: RadianceModel) -> int:
    """Samples per axis of the scene box that match the model's own detail: a grid method's plane size
    (halved when its grid spans the contracted world, twice the box), 256 for an MLP (its finest
    positional-encoding period is far below any grid that fits in memory)."""
    return model.detail_resolution()
