"""A TensoRF-style vector-matrix (VM) factorised radiance field, in pure PyTorch.

A 3D feature grid is written as a sum of outer products of a 2D plane and a 1D line per axis pair:
    f(x, y, z) = sum_r P^XY_r(x, y) L^Z_r(z) + P^XZ_r(x, z) L^Y_r(y) + P^YZ_r(y, z) L^X_r(x)
which costs O(R N^2) memory instead of O(N^3). Density is the plain sum of its components; colour
features go through a linear "basis" then a tiny MLP together with the encoded view direction.

Why it suits a 2-core CPU: each sample costs a few bilinear lookups and a small matmul, and the
optimiser touches ~3 R N^2 numbers instead of N^3. The three planes of a kind are stacked into one
tensor (3, R, N, N) and read together by ``vm_products`` (a native CPU kernel whose backward is
parallel over the 3 R component images, or ``grid_sample`` elsewhere).

The grid covers the scene box with ``resolution`` cells per axis (voxels are stretched on a
non-cubic box; cheaper than ragged planes, see above).
"""
from __future__ import annotations

from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

from nerf_core.fields.encodings import direction_encoding
from nerf_core.fields.vm_lookup import VMLookup, dense_density
from nerf_core.fields.vm_products import (
    lines_from_stored,
    lines_to_stored,
    planes_from_stored,
    planes_to_stored,
    vm_products,
)
from nerf_core.fields.vm_touched import TouchedRows
from nerf_core.image.losses import l1_sparsity, total_variation_2d
from nerf_core.utils.derived_cache import DerivedCache

Tensor = torch.Tensor


# Parameter names: the grids are stored channels-last under these names (see TensorVMField).
GRID_NAMES = ("density_planes", "density_lines", "app_planes", "app_lines")
STORED = {name: name + "_cl" for name in GRID_NAMES}


def _stored_view(name: str, from_stored) -> property:
    """A read-only property ``name``: the stored Parameter ``STORED[name]`` as a tensorf-order view."""
    return property(lambda self: from_stored(getattr(self, STORED[name])),
                    doc=f"{name} in tensorf's order, a view of the stored ``{STORED[name]}``")


def upgrade_state_dict(state: dict, prefix: str = "") -> dict:
    """A state dict saved before the grids were stored channels-last (keys ``density_planes`` ...,
    shapes (3, R, N, N) and (3, R, N, 1)) in the current layout (keys ``density_planes_cl`` ...,
    shapes (3, N, N, R) and (3, N, R)); a current one is returned unchanged. The old and new keys
    differ, so the layout is never guessed from shapes (R may equal N). Changes ``state`` in place."""
    for name in GRID_NAMES:
        old = state.pop(prefix + name, None)
        if old is not None and prefix + STORED[name] not in state:
            convert = planes_to_stored if name.endswith("planes") else lines_to_stored
            state[prefix + STORED[name]] = convert(old) if old.dim() == 4 else old  # check_weights names odd shapes
    return state


def upgrade_checkpoint(weights: dict, optimizer_state=None) -> tuple:
    """Checkpoints saved before the grids were stored channels-last: keys ``field.density_planes``
    ... in (3, R, N, N) / (3, R, N, 1) order become ``field.density_planes_cl`` ... in (3, N, N, R) /
    (3, N, R) order, and so do the Adam moments of the ``grids`` group (same parameter order)."""
    old = [f"field.{name}" in weights for name in GRID_NAMES]
    if not any(old):
        return weights, optimizer_state
    weights = upgrade_state_dict(dict(weights), "field.")
    if not (isinstance(optimizer_state, dict) and isinstance(optimizer_state.get("state"), dict)
            and isinstance(optimizer_state.get("param_groups"), list)):
        return weights, optimizer_state
    state = dict(optimizer_state["state"])
    for group in optimizer_state["param_groups"]:
        if not (isinstance(group, dict) and group.get("name") == "grids"):
            continue
        for pid, name in zip(group.get("params", []), GRID_NAMES):
            moments = state.get(pid)
            if not isinstance(moments, dict):
                continue
            convert = planes_to_stored if name.endswith("planes") else lines_to_stored
            state[pid] = {k: convert(v) if isinstance(v, torch.Tensor) and v.dim() == 4 else v
                          for k, v in moments.items()}
    return weights, {**optimizer_state, "state": state}


class TensorVMField(nn.Module):
    """VM-factorised density and appearance grids with a small view-dependent colour MLP.

    Args:
        aabb: (2, 3) scene box.
        resolution: cells per axis of the planes and lines (grown during training with :meth:`upsample`).
        density_rank, app_rank: components per plane for density and appearance.
        app_dim: width of the appearance feature after the basis matrix.
        mlp_width: hidden width of the colour MLP (two hidden layers).
        view_freqs: positional-encoding frequencies of the view direction (0: the raw direction only).
        view_dependent: False: the colour MLP gets no direction input, so colour is the same from every
            side (``encodings.direction_encoding``).
        density_shift, density_scale: sigma = density_scale * softplus(raw + density_shift); the raw
            features start near 0, so the shift sets the initial density (see ``vmgrid``'s alpha_init).
    """

    def __init__(self, aabb: Tensor, resolution: int = 64, density_rank: int = 16, app_rank: int = 48,
                 app_dim: int = 27, mlp_width: int = 64, view_freqs: int = 2, density_shift: float = -10.0,
                 density_scale: float = 25.0, init_scale: float = 0.1, seed: int = 0,
                 view_dependent: bool = True):
        super().__init__()
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3).clone())
        self.resolution = int(resolution)
        self.density_shift, self.density_scale = float(density_shift), float(density_scale)
        g = torch.Generator().manual_seed(seed)
        n = self.resolution

        def rnd(*shape):
            return init_scale * torch.randn(*shape, generator=g)

        # Drawn in tensorf's (3, R, N, N) order, so a seed gives the same numbers as before the layout
        # change; stored channels-last.
        self._set_grids(rnd(3, density_rank, n, n), rnd(3, density_rank, n, 1), rnd(3, app_rank, n, n),
                        rnd(3, app_rank, n, 1))
        self.basis = nn.Linear(3 * app_rank, app_dim, bias=False)
        self.view_enc = direction_encoding(view_freqs, view_dependent)
        self.mlp = nn.Sequential(
            nn.Linear(app_dim + self.view_enc.out_dim, mlp_width), nn.ReLU(inplace=True),
            nn.Linear(mlp_width, mlp_width), nn.ReLU(inplace=True),
            nn.Linear(mlp_width, 3),
        )
        nn.init.constant_(self.mlp[-1].bias, 0.0)
        self._lookup: DerivedCache[VMLookup] = DerivedCache(follow_optimizers=True)  # never saved
        self._box: DerivedCache[tuple] = DerivedCache(follow_optimizers=False)  # (min corner, extent) of aabb
        # The cells each lookup with grad reads, for a row-sparse optimiser (``fields.vm_touched``); None:
        # nobody asks, nothing is recorded.
        self.touched: Optional[TouchedRows] = None

    # ------------------------------------------------------------------ parameters
    #
    # The grids are stored channels-last: ``density_planes_cl`` (3, N, N, Rs), ``density_lines_cl``
    # (3, N, Rs), ``app_planes_cl``, ``app_lines_cl``, so that the R components of one cell sit side by
    # side. That is the layout ``vm_products``'s CPU kernel reads and scatters into, and the parameters
    # stay plain contiguous tensors, which fused Adam needs (it copies any other layout every step).
    # Everything else reads them through the properties below, in tensorf's (3, R, N, N) and
    # (3, R, N, 1) order, as views (no copies).

    density_planes = _stored_view("density_planes", planes_from_stored)
    density_lines = _stored_view("density_lines", lines_from_stored)
    app_planes = _stored_view("app_planes", planes_from_stored)
    app_lines = _stored_view("app_lines", lines_from_stored)

    def _set_grids(self, density_planes: Tensor, density_lines: Tensor, app_planes: Tensor, app_lines: Tensor):
        """Replace the four grid Parameters from (3, R, N, N) planes and (3, R, N, 1) lines."""
        self.density_planes_cl = nn.Parameter(planes_to_stored(density_planes))
        self.density_lines_cl = nn.Parameter(lines_to_stored(density_lines))
        self.app_planes_cl = nn.Parameter(planes_to_stored(app_planes))
        self.app_lines_cl = nn.Parameter(lines_to_stored(app_lines))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        upgrade_state_dict(state_dict, prefix)  # checkpoints saved before the channels-last layout
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def grid_parameters(self) -> list[nn.Parameter]:
        return [self.density_planes_cl, self.density_lines_cl, self.app_planes_cl, self.app_lines_cl]

    def network_parameters(self) -> list[nn.Parameter]:
        return list(self.basis.parameters()) + list(self.mlp.parameters())

    @torch.no_grad()
    def upsample(self, resolution: int) -> None:
        """Resample planes and lines to ``resolution`` (bilinear / linear); replaces the Parameters."""
        n = int(resolution)

        # From contiguous (3, R, N, N) copies: the same interpolation, to the bit, as before the layout change.
        def plane(p):
            return F.interpolate(p.detach().contiguous(), size=(n, n), mode="bilinear", align_corners=True)

        def line(p):
            return F.interpolate(p.detach().contiguous(), size=(n, 1), mode="bilinear", align_corners=True)

        self._set_grids(plane(self.density_planes), line(self.density_lines), plane(self.app_planes),
                        line(self.app_lines))
        self.resolution = n

    def voxel_size(self) -> float:
        """Mean cell edge in scene units (cells are stretched on a non-cubic box). Read once per size:
        the marching step asks every training step, and a read from a GPU waits for it."""
        key = (self.resolution, self.aabb._version, self.aabb.device)
        if getattr(self, "_voxel_key", None) != key:
            self._voxel_key = key
            self._voxel = float(((self.aabb[1] - self.aabb[0]) / (self.resolution - 1)).mean())
        return self._voxel

    # ------------------------------------------------------------------ evaluation

    def _unit(self, x: Tensor) -> Tensor:
        """(m, 3) positions -> (m, 3) coordinates in [-1, 1] over the box (grid_sample's convention)."""
        # The corner and extent are kept between calls (three ops fewer each, the same numbers).
        lo, ext = self._box.get([self.aabb], lambda: (self.aabb[0], self.aabb[1] - self.aabb[0]))
        return (x - lo) / ext * 2 - 1

    def density(self, x: Tensor) -> Tensor:
        """(m, 3) positions -> (m,) density per scene unit."""
        if x.shape[0] == 0:
            return x.new_zeros(0)
        u = self._unit(x)
        sink = self._mark("density_planes_cl", "density_lines_cl", u)
        raw = vm_products(self.density_planes, self.density_lines, u, sink).sum(dim=(1, 2))
        return self.density_scale * F.softplus(raw + self.density_shift)

    def app_features(self, x: Tensor) -> Tensor:
        """(m, 3) positions -> (m, 3 Ra) plane-line products of the appearance grid (the basis input)."""
        u = self._unit(x)
        sink = self._mark("app_planes_cl", "app_lines_cl", u)
        return vm_products(self.app_planes, self.app_lines, u, sink).reshape(x.shape[0], -1)

    def _mark(self, planes_key: str, lines_key: str, u: Tensor) -> Optional[tuple]:
        """Record the cells a lookup with grad reads (``touched``, when a row-sparse optimiser asks);
        returns the gradient buffers the kernel adds into, or None (a fresh zero grid)."""
        if self.touched is None or not torch.is_grad_enabled() or not self.density_planes_cl.requires_grad:
            return None
        planes, lines = getattr(self, planes_key), getattr(self, lines_key)
        sinks = self.touched.sink(planes_key, planes), self.touched.sink(lines_key, lines)
        self.touched.mark(planes_key, lines_key, u, self.resolution)
        return None if sinks[0] is None else sinks

    def color(self, x: Tensor, d: Tensor) -> Tensor:
        """(m, 3) positions and unit directions -> (m, 3) colours in [0, 1]."""
        if x.shape[0] == 0:
            return x.new_zeros(0, 3)
        feat = self.basis(self.app_features(x))  # (m, app_dim)
        return torch.sigmoid(self.mlp(torch.cat([feat, self.view_enc(d)], dim=-1)))

    def lookup(self) -> VMLookup:
        """Lookup tables of the current weights for rendering without gradients (``vm_lookup``):
        the same densities and colours as :meth:`density` and :meth:`color`, several times faster.
        Cached until a grid parameter is replaced (growth), changed in place (loading) or written by
        an optimiser step (``derived_cache``), so a render rebuilds them once, not per call."""
        return self._lookup.get(self.grid_parameters(), lambda: VMLookup(self))

    @torch.no_grad()
    def density_cell_max(self, cells: int) -> Tensor:
        """(cells, cells, cells) [x, y, z]: for each cell of a ``cells``^3 grid over the box, the
        largest density at the nodes of the field cells it overlaps: a bound that no point in the cell
        exceeds (for the occupancy grid: no random probe that can miss a thin surface). Density is a
        monotone function of the trilinearly interpolated raw value (``vm_lookup.dense_density``),
        whose largest value in a field cell is at one of its corners."""
        raw = dense_density(self.density_planes, self.density_lines).permute(2, 1, 0)  # [x, y, z]
        n = self.resolution
        for axis in range(3):
            parts = []
            for c in range(cells):
                lo = (c * (n - 1)) // cells
                hi = -((-(c + 1) * (n - 1)) // cells)  # ceil
                parts.append(raw.narrow(axis, lo, hi - lo + 1).amax(dim=axis, keepdim=True))
            raw = torch.cat(parts, dim=axis)
        return self.density_scale * F.softplus(raw + self.density_shift)

    def density_l1(self) -> Tensor:
        """Mean absolute value of the density factors (a sparsity prior that clears floaters)."""
        return l1_sparsity(self.density_planes, self.density_lines)

    def density_tv(self) -> Tensor:
        """Total variation of the density planes (smoothness prior)."""
        return total_variation_2d(self.density_planes)
