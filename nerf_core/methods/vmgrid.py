"""``vmgrid``: the fast method. A TensoRF-style VM-factorised grid (``fields.tensorf``) trained
coarse-to-fine, with an occupancy grid skipping empty space from the first few steps and rays
terminated once they are opaque.

Per batch of rays:
1. march each ray at half a voxel, keep only samples in occupied cells (``sampling.occupied_samples``);
2. without grad, evaluate density at those samples and drop everything behind transmittance < 1e-4
   (early ray termination: inside objects and behind surfaces costs nothing more);
3. with grad, recompute density on the survivors, compositing weights (packed ``volrend``), and evaluate
   the colour MLP only where a sample's weight exceeds 1e-4.
Rendering without grad (``render``, ``eval``) keeps the same samples, evaluates density front to back
(``ray_termination``) and reads the field through lookup tables laid out for reading
(``fields.vm_lookup``): 1.41x the rays/s on the multi demo scene at one thread, images equal to 5e-5.

Coarse-to-fine: the planes start at ``res_init`` and are resampled up to ``res_final`` at fixed fractions
of the training budget (the fraction the trainer hands to ``training_hook``, ``contract.budget_fraction``);
``training_hook`` returns True then so the trainer rebuilds its optimiser.
The current size is run state, not an option (``run_state``): a model built from a checkpoint's
options starts at ``res_init`` and grows to the checkpoint's size when its weights load.
"""
from __future__ import annotations

import math

import torch

from nerf_core.contract.numbers import is_whole
from nerf_core.fields import tensorf, vm_products
from nerf_core.fields.tensorf import TensorVMField
from nerf_core.fields.vm_touched import TouchedRows
from nerf_core.methods import fixed_step, growth
from nerf_core.methods.base import RadianceModel, density_length
from nerf_core.methods.registry import register
from nerf_core.methods.sample_budget import SampleBudget
from nerf_core.methods.vmgrid_options import VMGridOptions
from nerf_core.optim import RowSparseAdam
from nerf_core.utils import profiling
from nerf_core.utils.running_mean import RunningMean
from nerf_core.volume import grad_scaling, marching, padded, sampling, volrend
from nerf_core.volume.contraction import outer_box, squeeze_into_outer_box
from nerf_core.volume.occupancy import OccupancyGrid

Tensor = torch.Tensor


@register("vmgrid")
class VMGrid(RadianceModel):
    """The fast method; its options are ``VMGridOptions`` (why each default, with measurements:
    docs/METHODS.md). Its run state is the current plane size (``field.resolution``, grown by
    ``training_hook``) and ``res_final_budget``, the size a long run chose for its last stage."""

    Options = VMGridOptions
    default_lr = 1e-3
    # 2048 rays keep a step short enough for frequent occupancy updates and growth decisions, while
    # amortising the per-step Python overhead; grids need little LR warm-up.
    default_batch_rays = 2048
    warmup_steps = 20
    # Evaluation calls of up to 2048 rays on the CPU (and still about CPU_SAMPLES_PER_CALL samples,
    # ``render.frame``). With the tight occupancy grid a ray has ~9 samples, so 512-ray calls were
    # mostly per-call overhead: trained multi, 4 test views, 2048 against 512 rays a call, median of 3:
    # 86.9k against 78.0k rays/s at one thread, 91.6k against 78.6k at two (images unchanged).
    cpu_call_rays = 2048
    options_before = {"density_unit": "scene"}
    # Stored channels-last (``tensorf``): planes (3, N, N, R) grow along N, N; lines (3, N, R) along N.
    growing = {"field.density_planes_cl": (1, 2), "field.density_lines_cl": (1,),
               "field.app_planes_cl": (1, 2), "field.app_lines_cl": (1,)}

    def __init__(self, aabb: Tensor, **options):
        super().__init__(aabb, **options)
        self.opts: VMGridOptions
        self._budget_known = True  # False once a hook had no budget fraction: the size rule then stays off
        self.res_final_budget = None  # the last stage's size, once a long run chose it (``growth``)
        self._build(self.opts)

    def _build(self, o: VMGridOptions) -> None:
        # Density shift from alpha_init at the *initial* grid's step, so a rebuilt model gets the same one.
        extent = (self.aabb[1] - self.aabb[0]).double()
        step0 = o.step_ratio * float((extent / (o.res_init - 1)).mean())
        sigma0 = -math.log1p(-o.alpha_init) / step0
        # 25 per box unit: the grids' raw values stay a few units for an opaque surface at any scale.
        density_scale = 25.0 / density_length(self.aabb, o.density_unit)
        shift = math.log(math.expm1(sigma0 / density_scale))  # softplus^-1
        # With contraction the grids span the contracted world (twice the box); points are warped into it.
        self.contracted = bool(o.unbounded)
        field_box = outer_box(self.aabb) if self.contracted else self.aabb
        self.field = TensorVMField(field_box, resolution=o.res_init, density_rank=o.density_rank,
                                   app_rank=o.app_rank, app_dim=o.app_dim, mlp_width=o.mlp_width,
                                   view_freqs=o.view_freqs, seed=o.seed, density_shift=shift,
                                   density_scale=density_scale, view_dependent=o.view_dependent)
        self.occupancy = OccupancyGrid(field_box, o.occ_res)
        # The sparse grid optimiser updates only the cells the step's lookups read: the field records them.
        # Its gradients go into buffers zeroed where they were written, unless the TV prior writes everywhere.
        self.field.touched = TouchedRows(sinks=o.tv_weight == 0) if o.grid_optimizer == "sparse" else None
        self.render_step_chunk = 1 << 18  # samples per no-grad density chunk at eval time
        self.render_round_size = 32  # samples per ray per front-to-back round when rendering without grad
        # Running mean opacity of the training rays (see ``formed``): fed on the device every step, read
        # by the host on the periodic steps only (``RunningMean``).
        self.opacity = RunningMean(0.0)
        self._near_gate, self._reach_units = grad_scaling.NearCameraGate(), None
        self._last_growth_step = 0
        # ``sample_budget``: the fixed-shape step's sizes (made with the first batch), and the marching
        # step they were measured at (a finer step rescales them at once, ``SampleBudget.rescale``)
        self.budget, self._budget_step, self._box_cpu = None, None, None

    # ------------------------------------------------------------------ schedule

    def resolution_schedule(self) -> list[int]:
        """Plane sizes after each growth, log-spaced from res_init to res_final."""
        o = self.opts
        k = len(o.upsample_at)
        if k == 0:
            return []
        a, b = math.log(o.res_init), math.log(o.res_final)
        sizes = [int(round(math.exp(a + (b - a) * (i + 1) / k))) for i in range(k)]
        if self.res_final_budget is not None:  # a long run's last stage (``growth.budget_resolution``)
            sizes[-1] = max(sizes[-1], int(self.res_final_budget))
        return sizes

    def pruned(self) -> bool:
        """True once the occupancy grid has started skipping space (it starts fully occupied)."""
        return self.occupancy.learnt_fraction < 0.95  # of the cells the capture did not show empty

    # Share of training rays that must be stopped by the scene before geometry counts as formed in a
    # box with no empty space to prune: an interior, where every ray ends on a wall. An object scene's
    # rays that miss the object keep this far lower, so the occupancy grid decides there as before.
    OPAQUE_RAYS = 0.9

    def formed(self) -> bool:
        """True once coarse geometry exists: the occupancy grid prunes, or nearly every ray is stopped.

        Everything that waits for geometry (the fine marching step, growth, the L1 prior) asks this.
        Pruning alone never happens in a room, whose box is walls and air seen from inside: on the
        interior demo scene the occupancy grid was still 100 % occupied after 150 s, so the run kept
        the coarse warm-up step and never started the L1 prior.
        """
        return self.pruned() or self.opacity.value > self.OPAQUE_RAYS

    def replica_stats(self) -> dict[str, float]:
        # The opacity gates ``formed()``, hence the marching step, the L1 prior and growth.
        return {"acc_ema": self.opacity.read()}

    def set_replica_stats(self, stats: dict[str, float]) -> None:
        self.opacity.set(stats["acc_ema"])

    def step_size(self) -> float:
        """Marching step in scene units: ``step_ratio`` voxels, coarser until the occupancy grid prunes
        (or was carved from the capture).

        Before the first prune every ray crosses the whole box (~100+ samples each); a coarser step
        then makes the first few dozen steps cheap while the field finds the coarse geometry. Density
        is per unit length, so nothing learnt is invalidated when the step refines.
        """
        s = self.opts.step_ratio * self.field.voxel_size()
        # A grid carved from the capture (``train --depth``) down to a shell is marched finely at once
        # (``OccupancyGrid.shell_only``). Where the carving left most of the box, the fine step would make
        # every early step cross it finely: highfreq lost 2.1 dB at 60 s when any carving counted.
        return s if self.formed() or self.occupancy.shell_only else s * self.opts.warmup_step_scale

    def training_hook(self, step, frac) -> bool:
        o = self.opts
        # Frequent occupancy updates early (geometry appears fast and must not be pruned for long),
        # sparser later when the grid is stable.
        every = o.occ_every if step < 50 * o.occ_every else 2 * o.occ_every
        if step > 0 and step % every == 0:  # periodic steps may wait for the device: read what it keeps
            self.opacity.read()
            if self.budget is not None:
                self.budget.adapt()
            self._near_gate.recheck()
            self.update_occupancy()
        if frac is None:  # no budget given: growth follows an assumed ``budget_steps``
            frac = step / o.budget_steps
            self._budget_known = False
        if self.res_final_budget is None and o.upsample_at and frac >= o.upsample_at[-1] and step > 0:
            # The last stage is due: steps so far over the share spent predicts the run's steps from
            # the rate measured over a third of it (growth included), far better than a start-up probe.
            predicted = step / frac if self._budget_known else 0.0
            self.res_final_budget = growth.budget_resolution(o.res_final, predicted, o.budget_growth_steps,
                                                             o.res_budget_max)
        target = o.res_init
        for f, r in zip(o.upsample_at, self.resolution_schedule()):
            if frac >= f:
                target = r
        # Growing multiplies the cost of every sample's backward pass: wait until empty space is being
        # skipped and each stage has had some steps to fit, even when the time budget says go.
        since = step - self._last_growth_step
        ready = since >= o.min_stage_steps and (self.formed() or since >= 4 * o.min_stage_steps)
        if target > self.field.resolution and ready:
            self._last_growth_step = step
            self.field.upsample(self._next_resolution())
            return True
        return False

    def _next_resolution(self) -> int:
        """Grow one stage at a time (a late stage jumping straight to res_final would be too costly at once)."""
        for r in self.resolution_schedule():
            if r > self.field.resolution:
                return r
        return self.field.resolution

    @torch.no_grad()
    def update_occupancy(self) -> None:
        cell_max = None
        o = self.opts
        if o.occ_probe == "max":
            with profiling.stage("field"):
                cell_max = self.field.density_cell_max(self.occupancy.resolution)
        self.occupancy.update(None if cell_max is not None else self._density, self.step_size(),
                              alpha_threshold=float(o.occ_alpha), decay=float(o.occ_decay),
                              dilate=bool(o.occ_dilate_formed) or not self.formed(), cell_density=cell_max)

    def _density_of(self, pts: Tensor, lookup):
        """sample indices (j,) -> density (j,) at those of the field-space points ``pts`` (k, 3), in
        chunks of ``render_step_chunk`` samples, read from the field's ``lookup`` tables (the no-grad
        render path's ``density_fn``)."""
        def density(sel: Tensor) -> Tensor:
            with profiling.stage("field"):
                return torch.cat([lookup.density(pts[sel[i:i + self.render_step_chunk]])
                                  for i in range(0, max(1, sel.shape[0]), self.render_step_chunk)])
        return density

    def _density(self, pts: Tensor) -> Tensor:
        """Field density (m,) at field-space points (m, 3), marked as the profile's ``field`` stage."""
        with profiling.stage("field"):
            return self.field.density(pts)

    # ------------------------------------------------------------------ sizing

    # Density rank of every auto-sized grid. Geometry did not call for more in the calibration
    # (``nerf_core.methods.sizing``): on the thin-rods scene, rank 16 scored 33.94 dB against 33.96 dB for rank 8
    # (5 min of one core).
    AUTO_DENSITY_RANK = 8

    @classmethod
    def size_options(cls, fine_res, texture, fine_share):
        res_final = int(max(32, min(320, round(fine_res / 8) * 8)))
        # Start at two thirds of the final size but no finer than 48: coarser starts lose the first
        # minute (24 dB at 18 cells vs 29 dB at 48 on the fine checker), finer ones prune later.
        res_init = int(max(16, min(48, round(res_final * 2 / 3 / 8) * 8)))
        app_rank = int(round((8 + 8 * texture) / 4) * 4)
        rank = cls.AUTO_DENSITY_RANK
        # A long run may grow up to the pixel footprint's resolution (``fine_res`` undone of the coarse-
        # texture halving), never finer: cells finer than a pixel footprint are not supervised.
        footprint_res = fine_res / (0.5 + 0.5 * fine_share)
        res_max = int(max(res_final, min(320, round(footprint_res / 8) * 8)))
        opts = dict(
            res_final=res_final, res_init=res_init, app_rank=app_rank, density_rank=rank, res_budget_max=res_max
        )
        reasons = [f"grid grows {res_init} -> {res_final} cells per axis (no finer than the pixel footprint"
                   + (", coarser for coarse texture" if fine_share < 1 else "") + ")",
                   f"appearance rank {app_rank} (8-16) from the texture probe, density rank {rank}",
                   growth.explain(res_final, cls.Options().budget_growth_steps, res_max)]
        return opts, reasons

    # ------------------------------------------------------------------ optimisation

    def param_groups(self, lr: float) -> list[dict]:
        grids = {"params": self.field.grid_parameters(), "lr": lr * self.opts.grid_lr_scale, "name": "grids"}
        if self.field.touched is not None:
            grids["row_sparse"] = True  # each cell's R components are one row (``RowSparseAdam``)
        return [grids, {"params": self.field.network_parameters(), "lr": lr, "name": "networks"}]

    def occupancy_grid(self):
        # with contraction the grid spans the contracted world, which the capture's rays do not index
        return None if self.contracted else self.occupancy

    def make_optimizer(self, lr: float):
        if self.field.touched is None:
            return super().make_optimizer(lr)
        return RowSparseAdam(self.optimizer_groups(lr), eps=self.adam_eps, bias=self.opts.sparse_bias)

    def optimizer_step(self, opt, out) -> None:
        """Dense Adam, or the sparse one over the cells this step's lookups read; the L1 prior then
        acts on those cells too (its gradient is added here, on them alone, instead of over the grid)."""
        touched = self.field.touched
        if touched is None:
            opt.step()
            return
        f = self.field
        names = ("density_planes_cl", "density_lines_cl", "app_planes_cl", "app_lines_cl")  # grid_parameters' order
        rows = {p: touched.rows(name) for name, p in zip(names, f.grid_parameters())}
        # d/dx of l1_weight * mean|x| (``image.losses.l1_sparsity``) is l1_weight / numel * sign(x)
        l1 = ({p: self.opts.l1_weight / p.numel() for p in (f.density_planes_cl, f.density_lines_cl)}
              if self.opts.l1_weight > 0 and self.formed() else None)
        opt.step(rows={p: idx for p, idx in rows.items() if idx is not None}, l1=l1)

    def replica_masks(self) -> list:
        return [] if self.field.touched is None else self.field.touched.masks_for_replicas()

    def run_state(self) -> dict:
        return {"resolution": self.field.resolution, "res_final_budget": self.res_final_budget}

    def restore_run_state(self, state) -> None:
        """Take back the last stage's size, checked against what the options allow: growth never goes
        below res_init nor past max(res_final, res_budget_max) (``growth.budget_resolution``), so a
        checkpoint's 2048 under options that allow 320 would jump a resumed run to ~10 GB of grids. The
        grid's own size comes with the weights: ``load_state_dict`` resizes to the stored planes."""
        o = self.opts
        ranges = {"resolution": (o.res_init, max(o.res_final, o.res_budget_max)),
                  "res_final_budget": (o.res_final, max(o.res_final, o.res_budget_max))}
        for name, (low, high) in ranges.items():
            value = state.get(name)
            if value is not None and not (is_whole(value) and low <= value <= high):
                raise ValueError(f"vmgrid: run state {name!r} must be a whole number in {low}..{high} (what the "
                                 f"run's options res_init, res_final and res_budget_max allow), got {value!r}")
        budget = state.get("res_final_budget")
        self.res_final_budget = None if budget is None else int(budget)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        # The one place vmgrid's grids change size on loading: a checkpoint saved after growth has bigger
        # planes than a fresh build, a rollback snapshot from before a growth smaller ones.
        state_dict = tensorf.upgrade_state_dict(dict(state_dict), "field.")
        key = "field.density_planes_cl"  # (3, N, N, R)
        if key in state_dict and state_dict[key].dim() == 4 and state_dict[key].shape[1] != self.field.resolution:
            self.field.upsample(int(state_dict[key].shape[1]))
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def kernels(self, device: torch.device) -> dict:
        if device.type != "cpu":
            return {"vm_products": f"grid_sample ({device.type})"}
        how, why = vm_products.backend()
        return {"vm_products": "the native CPU kernel" if how == "native"
                else f"grid_sample, a slower fallback ({why})"}

    def upgrade_checkpoint(self, weights: dict, optimizer_state=None) -> tuple:
        """Checkpoints saved before the grids were stored channels-last (``tensorf.upgrade_checkpoint``)."""
        return tensorf.upgrade_checkpoint(weights, optimizer_state)

    # ------------------------------------------------------------------ rendering

    @torch.no_grad()
    def density_at(self, pts: Tensor) -> Tensor:
        return self.field.lookup().density(self.warp(pts))

    @torch.no_grad()
    def colour_at(self, pts: Tensor, dirs: Tensor) -> Tensor:
        return self.field.lookup().color(self.warp(pts), dirs)

    @torch.no_grad()
    def sampled_at(self, pts: Tensor) -> Tensor:
        # the rule ``_samples`` marches by: a sample is taken where the occupancy grid says occupied
        return self.occupancy.query(self.warp(pts))

    def detail_resolution(self) -> int:
        """The planes' size (halved when the grid spans the contracted world, twice the box)."""
        res = int(self.field.resolution)
        return max(2, res // 2) if self.contracted else res

    def warp(self, pts: Tensor) -> Tensor:
        """World points (m, 3) -> the field's coordinates (contracted when ``unbounded`` is on)."""
        return squeeze_into_outer_box(pts, self.aabb) if self.contracted else pts

    def ray_interval(self, rays_o, rays_d, near=None, far=None):
        if not self.contracted:
            return super().ray_interval(rays_o, rays_d, near, far)
        # The whole ray from ``near`` on: contracted_samples ends it far out, uniform in disparity.
        t0 = torch.full(rays_o.shape[:1], float(near or 0.0), dtype=rays_d.dtype, device=rays_d.device)
        return t0, torch.full_like(t0, float("inf"))

    def rays_per_step(self, batch_rays: int) -> int:
        """``batch_rays`` rays, or with ``sample_budget`` as many as fill it (at most 4x ``batch_rays``)."""
        if not self.opts.sample_budget or self.contracted:
            return batch_rays
        step = self.step_size()
        n_steps = self._steps_per_ray(step)
        if self.budget is None:
            run = int(2 * self.occupancy.near_reach() / step) + 1
            self.budget, self._budget_step = SampleBudget(self.opts.sample_budget, 4 * batch_rays, n_steps, run), step
        elif step != self._budget_step:  # the marching step changed (geometry formed, the grid grew)
            self.budget.rescale(self._budget_step / step)
            self._budget_step = step
        return self.budget.rays

    def _steps_per_ray(self, step: float) -> int:
        if self._box_cpu is None:  # the box is fixed: read once (on a GPU a read waits for the device)
            self._box_cpu = self.aabb.detach().cpu()
        return padded.steps_for_box(self._box_cpu, step, 4096)

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        n_rays = rays_o.shape[0]
        if training and self.budget is not None and torch.is_grad_enabled() and n_rays:
            return self._render_fixed(rays_o, rays_d, near, far, background)
        t0, t1, ridx = self._samples(rays_o, rays_d, near, far, training)
        pts = self.warp(sampling.ray_points(rays_o, rays_d, ridx, 0.5 * (t0 + t1)))
        gscale = None
        if torch.is_grad_enabled():
            if self.field.touched is not None:
                self.field.touched.clear()  # the cells this render reads, and only those, are stepped
            # Early ray termination: find the visible samples without grad, then recompute their density
            # with grad (and even out the gradient near each lens when cameras are inside the box).
            with torch.no_grad():
                sigma = marching.chunked(self._density, pts, self.render_step_chunk)
            keep = marching.visible_after_one_pass(t0, t1, ridx, n_rays, sigma)
            t0, t1, ridx, pts = (x.index_select(0, keep) for x in (t0, t1, ridx, pts))
            sigma = self._density(pts)
            gscale = self._near_gate.scales(0.5 * (t0 + t1), self._reach()) if training else None
            if gscale is not None:
                sigma = grad_scaling.scale_gradient(sigma, gscale)
            with profiling.stage("rendering"):
                weights, _, _ = volrend.render_weight_from_density_packed(t0, t1, sigma, ridx, n_rays)
            color_fn = self.field.color
        else:
            # Nothing to differentiate (render, eval): the same kept samples and weights, without the
            # density of samples behind opaque surfaces or a second density pass over the survivors,
            # and every lookup from tables laid out for reading (``fields.vm_lookup``).
            lookup = self.field.lookup()
            color_fn = lookup.color
            keep, weights = marching.visible_front_to_back(t0, t1, ridx, n_rays, self._density_of(pts, lookup),
                                                           round_size=self.render_round_size)
            t0, t1, ridx, pts = (x.index_select(0, keep) for x in (t0, t1, ridx, pts))
        with profiling.stage("rendering"):  # the output's own opacity, summed once
            acc = volrend.accumulate_along_rays_packed(weights, ridx, n_rays)
        # Colour only where it can matter; one index for every gather (boolean masks would each search again).
        vis = marching.colour_where_it_matters(weights, acc, ridx, self.opts.color_weight)
        with profiling.stage("field"):
            rgb = color_fn(pts.index_select(0, vis), rays_d.index_select(0, ridx.index_select(0, vis)))
        if gscale is not None:
            rgb = grad_scaling.scale_gradient(rgb, gscale.index_select(0, vis))
        out = marching.composite(weights, ridx, t0, t1, n_rays, background, rgb, coloured=vis, acc=acc)
        out["n_samples"] = int(ridx.shape[0])
        if training:
            self.opacity.add(out["acc"])  # on the device; the host reads it on periodic steps
            aux = self._regularisers(weights, t0, t1, ridx, n_rays)
            if torch.is_tensor(aux):
                out["aux_loss"] = aux
        return out

    def _render_fixed(self, rays_o, rays_d, near, far, background):
        """The training render with every shape fixed before the step (``fixed_step``, ``sample_budget``)."""
        if self.field.touched is not None:
            self.field.touched.clear()
        reach = self._reach()
        out = fixed_step.render_fixed(rays_o, rays_d, near, far, background, self.budget, self._budget_step,
                                      self._steps_per_ray(self._budget_step), self.occupancy, self._density,
                                      self.field.color, self.opts.color_weight,
                                      lambda t: self._near_gate.scales(t, reach))
        self.opacity.add(out["acc"])
        aux = self._regularisers(out.pop("weights"), out.pop("t_starts"), out.pop("t_ends"), out.pop("ray_indices"),
                                 rays_o.shape[0])
        if torch.is_tensor(aux):
            out["aux_loss"] = aux
        return out

    def _regularisers(self, weights, t0, t1, ridx, n_rays):
        """The training step's extra loss: L1 and TV on the density planes, the distortion loss; 0.0
        when none applies."""
        aux = 0.0
        o = self.opts
        # The L1 prior waits until geometry has formed (``formed``: the occupancy grid prunes, or nearly
        # every ray is stopped). Before that the rendering gradient on the nearly transparent field is
        # tiny, and Adam scales every parameter's step to the same size whatever its gradient, so L1
        # alone would drive both factors of the VM products to zero: a saddle (d(plane*line) = 0 there)
        # that training never leaves, seen as a run stuck at its initial PSNR for its whole budget.
        # (The sparse grid optimiser applies it itself, at the touched cells: ``optimizer_step``.)
        use_l1 = o.l1_weight > 0 and self.field.touched is None and self.formed()
        with profiling.stage("field"):
            if use_l1:
                aux = aux + o.l1_weight * self.field.density_l1()
            if o.tv_weight > 0:
                aux = aux + o.tv_weight * self.field.density_tv()
        if o.dist_weight > 0:
            scale = float((self.aabb[1] - self.aabb[0]).norm())
            with profiling.stage("rendering"):
                dist = volrend.distortion_loss_packed(weights, t0 / scale, t1 / scale, ridx, n_rays)
            aux = aux + o.dist_weight * dist.mean()
        return aux

    def _samples(self, rays_o, rays_d, near, far, training):
        """Samples where the occupancy grid says something may be: (t0, t1, ray index), each (m,)."""
        step = self.step_size()
        with profiling.stage("sampling"):
            if self.contracted:
                return sampling.contracted_samples(rays_o, rays_d, near, self.aabb, step,
                                                   lambda p: self.occupancy.query(self.warp(p)),
                                                   jitter=training, max_samples=4096)
            return sampling.occupied_samples(rays_o, rays_d, near, far, step, self.occupancy.query,
                                             jitter=training, max_samples=4096,
                                             near_fn=self.occupancy.query_near,
                                             near_reach=self.occupancy.near_reach())

    def _reach(self) -> float:
        """Near-camera gradient reach in scene units (``grad_scaling``), computed once: the box is fixed."""
        if self._reach_units is None:
            self._reach_units = grad_scaling.reach_for_box(self.aabb, self.opts.grad_reach)
        return self._reach_units


@register("vmgrid-noview")
class VMGridNoView(VMGrid):
    """``vmgrid`` whose colour ignores the view direction (``view_dependent`` forced off): every point
    has one colour from every side, so highlights and reflections cannot be reproduced. Nothing else
    differs, so comparing the two isolates the direction input. Same options as ``vmgrid``."""

    forced_options = {"view_dependent": False}
