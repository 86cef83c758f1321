"""An occupancy grid over the scene box, used to skip empty space while marching rays.

The grid keeps, per cell, an exponential moving average (EMA) of the density seen there and a binary
"occupied" mask derived from it. ``update`` re-evaluates the density at a jittered point in every cell
(``density_fn`` is the model's own density), decays the EMA and re-thresholds. Cells next to occupied
cells are kept too (one-cell dilation): a cell that is never sampled gets no gradient, so being too
eager to prune would freeze geometry that is still forming.

If the threshold would empty the grid (density collapsed, or training just started with tiny
densities) the grid does not go blank: the threshold drops to the mean EMA, and if that still keeps
nothing every cell is marked occupied again, so rendering never gets stuck returning background.
"""
from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn

from nerf_core.utils import profiling
from nerf_core.utils.derived_cache import DerivedCache

Tensor = torch.Tensor


class OccupancyGrid(nn.Module):
    """Binary occupancy + density EMA on a ``resolution``^3 grid spanning ``aabb`` (2, 3).

    Every cell starts occupied. ``update(density_fn, step_size)`` refreshes the grid from the model's
    density; ``query(pts)`` maps points (m, 3) to (m,) bool (inside the box and in an occupied cell);
    ``query_near(pts)`` also says yes near an occupied cell; ``reset()`` marks everything occupied.

    Args:
        aabb: (2, 3) box [min corner, max corner] the grid spans; kept as the float32 buffer ``aabb``.
        resolution: cells per axis r; the buffers are ``density_ema`` (r, r, r) float32 and
            ``binary`` (r, r, r) bool, indexed [x, y, z].
    """

    def __init__(self, aabb: Tensor, resolution: int = 64):
        super().__init__()
        self.resolution = int(resolution)
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3).clone())
        r = self.resolution
        self.register_buffer("density_ema", torch.zeros(r, r, r))
        # Everything starts occupied: before the first update nothing is known about the scene.
        self.register_buffer("binary", torch.ones(r, r, r, dtype=torch.bool))
        # Cells the capture shows empty (``mark_known_free``; ``train --depth``): never occupied again.
        # Not saved in checkpoints: the trainer marks them again from the capture on ``--resume``.
        self.register_buffer("known_free", torch.zeros(r, r, r, dtype=torch.bool), persistent=False)
        self.n_resets = 0
        # The dilated mask ``query_near`` reads; the mask is never written by an optimiser.
        self._near: DerivedCache[Tensor] = DerivedCache(follow_optimizers=False)
        # The share of occupied cells, read from the device only when the mask changes (an update, a
        # load): methods ask for it several times a step (``VMGrid.formed``), and each read waits for a GPU.
        self._fraction: DerivedCache[float] = DerivedCache(follow_optimizers=False)
        self._learnt: DerivedCache[float] = DerivedCache(follow_optimizers=False)
        self._marked: DerivedCache[bool] = DerivedCache(follow_optimizers=False)
        self._box: DerivedCache[dict] = DerivedCache(follow_optimizers=False)  # ``_cell_index``'s terms
        # ``near_reach``: asked once a training step, read from the device only when the box changes
        self._reach: DerivedCache[float] = DerivedCache(follow_optimizers=False)

    @property
    def occupied_fraction(self) -> float:
        return self._fraction.get([self.binary], lambda: float(self.binary.float().mean()))

    # Occupied share of the box below which a grid carved from the capture is a shell (``shell_only``):
    # multi and thin keep 21-27 % after carving, highfreq (a cube that fills its box) 80 %.
    CARVED_SHELL = 0.5

    @property
    def shell_only(self) -> bool:
        """True when the capture carved the grid (``mark_known_free``) down to a shell around its
        surfaces, under ``CARVED_SHELL`` of the box: rays then cross only that shell, so a method marches
        it finely from step 0 (a coarse warm-up step would jump over it, and the rays are short)."""
        # both read from the device only when their tensors change (asked once a step)
        return self.occupied_fraction < self.CARVED_SHELL and self._marked.get(
            [self.known_free], lambda: bool(self.known_free.any()))

    @property
    def learnt_fraction(self) -> float:
        """The share of the cells that the capture did not show empty (``mark_known_free``) that are
        occupied: what training has pruned, and what a method's "has the grid started pruning" asks.
        Equal to ``occupied_fraction`` without a mark. With one, the box is mostly empty from step 0,
        but the field has learnt nothing yet: a method that took that for formed geometry would start
        its fine step, its sparsity prior and its growth on a field still at its initial density."""
        return self._learnt.get([self.binary, self.known_free], lambda: float(
            self.binary.sum() / (~self.known_free).sum().clamp_min(1)))

    def cell_size(self) -> Tensor:
        """(3,) size of one cell in scene units."""
        return (self.aabb[1] - self.aabb[0]) / self.resolution

    def _cell_index(self, pts: Tensor) -> tuple[Tensor, Tensor]:
        """Flat cell index (m,) of points (m, 3) and whether each point is inside the box (m,).

        Every sample of every ray passes through here (twice in a contracted scene), so it is written
        for few passes over (m, 3): the flat index is one matrix-vector product of the floored cell
        coordinates, exact in float32 up to 256^3 cells (float64 beyond). ``query`` on 470k points at
        one thread: 8 ms, against 24 ms with per-column arithmetic."""
        r = self.resolution
        dt = pts.dtype if r ** 3 <= 2 ** 24 else torch.float64
        # The box's corner, cells per unit and the strides are kept between calls (every sample of
        # every ray comes here: fewer ops a call, the same numbers).
        terms = self._box.get([self.aabb], dict)
        if (dt, pts.device) not in terms:
            lo_, hi_ = self.aabb[0], self.aabb[1]
            terms[(dt, pts.device)] = (lo_, r / (hi_ - lo_),
                                       torch.tensor([float(r * r), float(r), 1.0], dtype=dt, device=pts.device))
        lo, per_unit, strides = terms[(dt, pts.device)]
        u = (pts - lo) * per_unit  # in cells
        inside = (u.amin(dim=-1) >= 0) & (u.amax(dim=-1) <= r)
        flat = (u.clamp(0, r - 1).floor().to(dt) @ strides).long()
        # A NaN point (a ray run out to infinity along an axis it does not move on) has no cell: the
        # clamp after the conversion sends it to cell 0, and ``inside`` is False for it.
        return flat.clamp_(0, r ** 3 - 1), inside

    @torch.no_grad()
    def query(self, pts: Tensor) -> Tensor:
        """(m, 3) points -> (m,) bool: inside the box and in an occupied cell."""
        idx, inside = self._cell_index(pts)
        return self.binary.reshape(-1)[idx] & inside

    def near_reach(self) -> float:
        """How far from a point ``query_near`` looks: one cell along each axis covers every point
        within the smallest cell edge (a hair less, for rounding)."""
        return self._reach.get([self.aabb], lambda: 0.999 * float(self.cell_size().min()))

    @torch.no_grad()
    def query_near(self, pts: Tensor) -> Tensor:
        """(m, 3) points -> (m,) bool: an occupied cell lies within ``near_reach()`` of the point (its
        cell or one of the 26 around it; points outside the box count from the nearest cell). False
        means no point that near can be occupied (``sampling.occupied_samples`` skips on it)."""
        near = self._near.get([self.binary], lambda: F.max_pool3d(
            self.binary[None, None].float(), kernel_size=3, stride=1, padding=1)[0, 0] > 0)
        idx, _ = self._cell_index(pts)
        return near.reshape(-1)[idx]

    def cell_centers(self, jitter: bool) -> Tensor:
        """(resolution^3, 3) points, one per cell (uniformly random inside the cell if ``jitter``)."""
        r = self.resolution
        g = torch.arange(r, device=self.aabb.device, dtype=torch.float32)
        ijk = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), dim=-1).reshape(-1, 3)
        off = torch.rand_like(ijk) if jitter else torch.full_like(ijk, 0.5)
        return self.aabb[0] + (ijk + off) / r * (self.aabb[1] - self.aabb[0])

    @torch.no_grad()
    def mark_known_free(self, free: Tensor) -> None:
        """Mark the cells ``free`` (r, r, r) bool empty from now on (``volume.carving.free_cells``: what
        the capture's depth maps show empty), so that rays skip them from the first step; every later
        update keeps them empty."""
        if tuple(free.shape) != tuple(self.binary.shape):
            raise ValueError(f"mark_known_free: free must be {tuple(self.binary.shape)}, got {tuple(free.shape)}")
        self.known_free.copy_(free.to(self.known_free.device))
        self.binary &= ~self.known_free

    @torch.no_grad()
    def update(self, density_fn: Callable[[Tensor], Tensor] | None, step_size: float, alpha_threshold: float = 1e-3,
               decay: float = 0.95, chunk: int = 1 << 18, dilate: bool = True,
               cell_density: Tensor | None = None) -> None:
        """Re-evaluate density in every cell and refresh the binary mask.

        Args:
            density_fn: points (m, 3) -> densities (m,) (called without grad, in chunks) at one random
                point per cell; or None when ``cell_density`` gives each cell's density (r, r, r) instead
                (e.g. the field's largest value in the cell, ``TensorVMField.density_cell_max``).
            step_size: the marching step of the renderer; a cell is occupied when a sample there would
                have alpha = 1 - exp(-sigma * step_size) above ``alpha_threshold``.
            decay: EMA factor; the EMA takes max(decayed old value, new value) so that thin surfaces
                seen once are not forgotten at the next update.
        """
        # Charged to the profile's ``sampling`` stage (what the grid serves), ``density_fn``'s own
        # marks (``field``) excepted.
        with profiling.stage("sampling"):
            self._update(density_fn, step_size, alpha_threshold, decay, chunk, dilate, cell_density)

    def _update(self, density_fn, step_size: float, alpha_threshold: float, decay: float, chunk: int,
                dilate: bool, cell_density: Tensor | None) -> None:
        if cell_density is not None:
            sig = cell_density.reshape(-1).float()
        else:
            pts = self.cell_centers(jitter=True)
            sig = torch.cat([density_fn(pts[i:i + chunk]).reshape(-1).float() for i in range(0, pts.shape[0], chunk)])
        ema = torch.maximum(self.density_ema.reshape(-1) * decay, sig)
        self.density_ema.copy_(ema.reshape(self.density_ema.shape))
        sigma_thr = -torch.log1p(torch.tensor(-alpha_threshold)).item() / step_size
        thr = min(sigma_thr, float(ema.mean()))  # never demand more than the average cell
        occ = (self.density_ema > thr).float()
        if occ.sum() == 0:
            # Collapsed (all-zero density): reopen everything rather than render nothing forever.
            self.n_resets += 1
            self.binary.fill_(True)
            self.binary &= ~self.known_free
            return
        if dilate:
            occ = F.max_pool3d(occ[None, None], kernel_size=3, stride=1, padding=1)[0, 0]
        self.binary.copy_((occ > 0) & ~self.known_free)

    @torch.no_grad()
    def reset(self) -> None:
        """Mark every cell occupied again (but those known to be empty) and forget the density history."""
        self.density_ema.zero_()
        self.binary.fill_(True)
        self.binary &= ~self.known_free
