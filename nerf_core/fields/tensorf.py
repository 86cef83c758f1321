"""A TensoRF-style vector-matrix (VM) factorised radiance field, in pure PyTorch.

A 3D feature grid is written as a sum of outer products of a 2D plane and a 1D line per axis pair:
    f(x, y, z) = sum_r P^XY_r(x, y) L^Z_r(z) + P^XZ_r(x, z) L^Y_r(y) + P^YZ_r(y, z) L^X_r(x)
which costs O(R N^2) memory instead of O(N^3). Density is the plain sum of its components; colour
features go through a linear "basis" then a tiny MLP together with the encoded view direction.

Why it suits a 2-core CPU: each sample costs a few bilinear lookups and a small matmul, the optimiser
touches ~3 R N^2 numbers instead of N^3, and the three planes of a kind are stacked into one tensor
(3, R, N, N) so that one ``grid_sample`` call (whose CPU backward is parallel over the batch
dimension only) serves all three.

The grid covers the scene box with ``resolution`` cells per axis (voxels are stretched on a
non-cubic box; cheaper than ragged planes, see above).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from nerf_core.fields.encodings import direction_encoding
from nerf_core.fields.vm_lookup import VMLookup, dense_density
from nerf_core.image.losses import l1_sparsity, total_variation_2d
from nerf_core.utils.derived_cache import DerivedCache

Tensor = torch.Tensor

# Plane i spans axes _PLANE_AXES[i]; its line runs along _LINE_AXIS[i].
_PLANE_AXES = ((0, 1), (0, 2), (1, 2))
_LINE_AXIS = (2, 1, 0)


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
            return nn.Parameter(init_scale * torch.randn(*shape, generator=g))

        self.density_planes = rnd(3, density_rank, n, n)  # (3, Rs, N, N)
        self.density_lines = rnd(3, density_rank, n, 1)  # (3, Rs, N, 1)
        self.app_planes = rnd(3, app_rank, n, n)
        self.app_lines = rnd(3, app_rank, n, 1)
        self.basis = nn.Linear(3 * app_rank, app_dim, bias=False)
        self.view_enc = direction_encoding(view_freqs, view_dependent)
        self.mlp = nn.Sequential(
            nn.Linear(app_dim + self.view_enc.out_dim, mlp_width), nn.ReLU(inplace=True),
            nn.Linear(mlp_width, mlp_width), nn.ReLU(inplace=True),
            nn.Linear(mlp_width, 3),
        )
        nn.init.constant_(self.mlp[-1].bias, 0.0)
        self._lookup: DerivedCache[VMLookup] = DerivedCache(follow_optimizers=True)  # never saved

    # ------------------------------------------------------------------ parameters

    def grid_parameters(self) -> list[nn.Parameter]:
        return [self.density_planes, self.density_lines, self.app_planes, self.app_lines]

    def network_parameters(self) -> list[nn.Parameter]:
        return list(self.basis.parameters()) + list(self.mlp.parameters())

    @torch.no_grad()
    def upsample(self, resolution: int) -> None:
        """Resample planes and lines to ``resolution`` (bilinear / linear); replaces the Parameters."""
        n = int(resolution)
        for name in ("density_planes", "app_planes"):
            p = getattr(self, name)
            setattr(self, name, nn.Parameter(F.interpolate(p.data, size=(n, n), mode="bilinear", align_corners=True)))
        for name in ("density_lines", "app_lines"):
            p = getattr(self, name)
            setattr(self, name, nn.Parameter(F.interpolate(p.data, size=(n, 1), mode="bilinear", align_corners=True)))
        self.resolution = n

    def voxel_size(self) -> float:
        """Mean cell edge in scene units (cells are stretched on a non-cubic box)."""
        return float(((self.aabb[1] - self.aabb[0]) / (self.resolution - 1)).mean())

    # ------------------------------------------------------------------ evaluation

    def _coords(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Plane and line sampling grids for ``grid_sample``: (3, m, 1, 2) each."""
        u = (x - self.aabb[0]) / (self.aabb[1] - self.aabb[0]) * 2 - 1  # (m, 3) in [-1, 1]
        plane = torch.stack([u[:, list(a)] for a in _PLANE_AXES])  # (3, m, 2)
        line_c = torch.stack([u[:, a] for a in _LINE_AXIS])  # (3, m)
        line = torch.stack([torch.zeros_like(line_c), line_c], dim=-1)  # x=0 (width 1), y=coordinate
        return plane.unsqueeze(2), line.unsqueeze(2)

    @staticmethod
    def _vm(planes: Tensor, lines: Tensor, pc: Tensor, lc: Tensor) -> Tensor:
        """(3, R, m): plane * line products of each component at m points."""
        p = F.grid_sample(planes, pc, mode="bilinear", align_corners=True).squeeze(-1)  # (3, R, m)
        l_ = F.grid_sample(lines, lc, mode="bilinear", align_corners=True).squeeze(-1)
        return p * l_

    def density(self, x: Tensor) -> Tensor:
        """(m, 3) positions -> (m,) density per scene unit."""
        if x.shape[0] == 0:
            return x.new_zeros(0)
        pc, lc = self._coords(x)
        raw = self._vm(self.density_planes, self.density_lines, pc, lc).sum(dim=(0, 1))
        return self.density_scale * F.softplus(raw + self.density_shift)

    def color(self, x: Tensor, d: Tensor) -> Tensor:
        """(m, 3) positions and unit directions -> (m, 3) colours in [0, 1]."""
        if x.shape[0] == 0:
            return x.new_zeros(0, 3)
        pc, lc = self._coords(x)
        f = self._vm(self.app_planes, self.app_lines, pc, lc)  # (3, Ra, m)
        feat = self.basis(f.reshape(-1, f.shape[-1]).t())  # (m, app_dim)
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
