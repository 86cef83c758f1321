"""``nerf``, ``nerf-nope`` and ``nerf-noview``: the classic MLP NeRF, sampled where the scene is.

The network is Mildenhall et al.'s: positional encoding, a ReLU trunk with a skip connection, a density
head and a view-dependent colour head (``fields.mlp.NeRFMLP``). On a 2-core CPU a sample costs what it
costs (the MLP runs near the matmul FLOP limit), so the only way to train faster is to evaluate fewer
samples. Two samplers, chosen by the ``sampler`` option:

``"occupancy"`` (default; nerfacc's recipe for an MLP):
    1. an occupancy grid over the box (``nerf_core.volume.occupancy``) holds a running maximum of the MLP's own
       density, refreshed every ``occ_every`` steps while training;
    2. each ray marches at a fixed step (``march_steps`` per box diagonal, ``warmup_step_scale`` times
       coarser until the grid first prunes) and keeps only samples in occupied cells
       (``sampling.occupied_samples``);
    3. every kept sample goes through the network once, with grad while training. Early ray
       termination (a no-grad density pass first, then only samples with T > 1e-4 again with grad) is
       the ``train_ert`` option. Its pass costs about a third of a training pass, so it pays only
       once surfaces are sharp: while an MLP's density is still a soft fog (the multi demo scene after
       300 steps) it dropped 7 % of the samples (48.5 -> 45.2 a ray), while on the highfreq cube it
       keeps 2.9 of 16 samples a ray. By default ("auto") training measures the share it keeps, on
       every ``ert_probe_every``-th step while it is off, and uses it while that share is below
       ``ERT_WORTH`` (``_use_ert``). On highfreq at 200 px, 5 min of one core: 26.29 dB and 4017 steps
       with it, against 20.67 dB and 1750 steps without;
    4. at render time (no gradients) rays are also terminated early, front to back in rounds of
       ``render_round_size`` samples (``ray_termination.visible_samples``): the trunk runs on the
       samples up to where each ray turns opaque, and the colour head, from the trunk's features kept
       meanwhile, only on the samples still visible (``_render_visible``).
    One network, so every sample's cost buys the picture.

``"hierarchical"`` (the paper's): ``n_coarse`` stratified samples through a coarse network, then
    ``n_fine`` more by inverse-CDF sampling of its weights through a fine network, both supervised.

``nerf-nope`` is the same class with raw coordinates instead of the encoding; nothing else differs,
so comparing the two isolates the encoding. ``nerf-noview`` is the same class with a colour head blind
to the view direction, which isolates what the direction input buys (highlights, reflections).

Old checkpoints (before the ``sampler`` option) hold a coarse and a fine network and no grid: they
load as ``hierarchical`` with the softplus density they were trained with (``load_state_dict``).
"""
from __future__ import annotations

import math

import torch

from nerf_core.fields.mlp import NeRFMLP
from nerf_core.image.losses import masked_mse
from nerf_core.methods.base import RadianceModel, density_length
from nerf_core.methods.nerf_options import NeRFOptions
from nerf_core.methods.registry import register
from nerf_core.utils import profiling
from nerf_core.volume import grad_scaling, marching, ray_termination, sampling, volrend
from nerf_core.volume.occupancy import OccupancyGrid

Tensor = torch.Tensor


@register("nerf")
class NeRF(RadianceModel):
    """Mildenhall et al. 2020; its options are ``NeRFOptions`` (why each default, with measurements:
    docs/METHODS.md)."""

    # 1024 rays a step keeps the per-step overhead (sampling, the optimiser) small against the MLP work
    # of ~20 k samples. The rate is twice the paper's 5e-4 (not A/B-tested against it); on highfreq at
    # 200 px, 5 min of one core, 3e-3 gave 20.1 dB and 4096 rays 19.9 dB against 20.0 dB for these.
    Options = NeRFOptions
    default_lr = 1e-3
    default_batch_rays = 1024
    warmup_steps = 50
    options_before = {"density_unit": "scene"}

    def __init__(self, aabb: Tensor, **options):
        super().__init__(aabb, **options)
        o: NeRFOptions = self.opts
        net = dict(use_pe=o.use_pe, pos_freqs=o.pos_freqs, dir_freqs=o.dir_freqs, width=o.width, depth=o.depth,
                   skip=o.skip, density_activation=o.density_activation,
                   length_unit=density_length(self.aabb, o.density_unit), view_dependent=o.view_dependent)
        self._net_options = net
        # ``coarse`` is the only network of the occupancy sampler (the name keeps checkpoints loadable).
        self.coarse = NeRFMLP(self.aabb, **net)
        self.fine = None
        self.occupancy = None
        if o.sampler == "hierarchical":
            self.fine = NeRFMLP(self.aabb, **net) if o.n_fine > 0 else None
        else:
            self.occupancy = OccupancyGrid(self.aabb, o.occ_res)
        self.render_chunk = 1 << 16  # samples per no-grad network call (bounds activation memory)
        # Samples per ray per front-to-back round of early termination (rendering, and the no-grad pass
        # of training): an MLP sample costs far more than a round's bookkeeping, so rounds are short.
        self.render_round_size = 8
        self._ert_keep = None  # share of samples the last early-termination pass kept (None: not measured)
        self._ert_wait = 0  # training renders until "auto" measures that share again while it is off

    @classmethod
    def size_options(cls, fine_res, texture, fine_share):
        # Highest frequency 2^(L-1) pi on [-1, 1]: period 2^(2-L) of the box half-size; stop at ~2 cells.
        pos_freqs = int(max(4, min(12, math.ceil(math.log2(max(2.0, fine_res))))))
        width = 64 if texture < 0.35 else 128
        opts, reasons = dict(width=width), []
        if cls.parse_options({}).use_pe:  # without the encoding (nerf-nope) there are no frequencies to size
            opts["pos_freqs"] = pos_freqs
            reasons.append(
                f"{pos_freqs} positional-encoding frequencies: the finest period matches ~2 pixel footprints"
            )
        reasons.append(f"MLP width {width} from the texture probe")
        return opts, reasons

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        # A checkpoint from before the occupancy sampler: a coarse and a fine network, no grid.
        if self.opts.sampler == "occupancy" and any(k.startswith("fine.") for k in state_dict) \
                and not any(k.startswith("occupancy.") for k in state_dict):
            self.opts.sampler = "hierarchical"
            self.opts.density_activation = "softplus"  # the only one there was
            self._net_options["density_activation"] = "softplus"
            self.occupancy = None
            self.coarse = NeRFMLP(self.aabb, **self._net_options).to(self.aabb.device)
            self.fine = NeRFMLP(self.aabb, **self._net_options).to(self.aabb.device)
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    # ------------------------------------------------------------------ occupancy sampler

    def occupancy_grid(self):
        return self.occupancy  # None where the method marches without one (the hierarchical sampler)

    def step_size(self) -> float:
        """Marching step in scene units: ``march_steps`` per box diagonal, coarser until the grid prunes."""
        diag = float((self.aabb[1] - self.aabb[0]).norm())
        step = diag / float(self.opts.march_steps)
        # the coarse step only makes rays across a wholly occupied box cheap; a grid the capture carved to
        # a shell (``train --depth``) is marched finely at once, since the coarse step would jump over it
        grid = self.occupancy
        pruned = grid is not None and (grid.learnt_fraction < 0.95 or grid.shell_only)
        return step if pruned else step * float(self.opts.warmup_step_scale)

    def training_hook(self, step, frac) -> bool:
        if self.occupancy is not None and step > 0 and step % self.opts.occ_every == 0:
            self.update_occupancy()
        return False

    @torch.no_grad()
    def update_occupancy(self) -> None:
        """Refresh the grid from the network's density at a jittered point in every cell. The threshold
        uses the fine step, so cells whose samples would stay transparent are skipped once pruning starts."""
        diag = float((self.aabb[1] - self.aabb[0]).norm())
        self.occupancy.update(self._density_chunked, diag / float(self.opts.march_steps),
                              alpha_threshold=float(self.opts.occ_alpha), decay=float(self.opts.occ_decay))

    def _density_chunked(self, pts: Tensor) -> Tensor:
        """(m, 3) -> (m,) density without grad, in chunks, marked as the profile's ``field`` stage."""
        with profiling.stage("field"):
            return marching.chunked(self.coarse.density, pts, self.render_chunk)

    def _render_occupancy(self, rays_o, rays_d, near, far, background, training: bool):
        n_rays = rays_o.shape[0]
        n_evaluated = None  # samples the network ran on, when that is not the samples composited
        with profiling.stage("sampling"):
            t0, t1, ridx = sampling.occupied_samples(rays_o, rays_d, near, far, self.step_size(),
                                                     self.occupancy.query, jitter=training, max_samples=4096,
                                                     near_fn=self.occupancy.query_near,
                                                     near_reach=self.occupancy.near_reach())
            mids = 0.5 * (t0 + t1)
            pts = rays_o[ridx] + rays_d[ridx] * mids.unsqueeze(-1)
        if training:
            if self._use_ert():  # early ray termination without grad; survivors again with grad
                n_before = ridx.shape[0]
                t0, t1, ridx, mids, pts = self._visible(t0, t1, ridx, mids, pts, n_rays)
                self._ert_keep = ridx.shape[0] / max(1, n_before)
            dirs = rays_d[ridx]
            with profiling.stage("field"):
                sigma, rgb = self.coarse(pts, dirs)
            scale = grad_scaling.near_camera_scales(mids, grad_scaling.reach_for_box(self.aabb, self.opts.grad_reach))
            if scale is not None:  # cameras inside the box: even out the gradient near each lens
                sigma, rgb = grad_scaling.scale_gradient(sigma, scale), grad_scaling.scale_gradient(rgb, scale)
            with profiling.stage("rendering"):
                weights, _, _ = volrend.render_weight_from_density_packed(t0, t1, sigma, ridx, n_rays)
        else:
            t0, t1, ridx, mids, weights, rgb, n_evaluated = self._render_visible(
                t0, t1, ridx, mids, pts, rays_d, n_rays
            )
        out = marching.composite(weights, ridx, t0, t1, n_rays, background, rgb)
        # Rendering reports what it cost (``render_rays_chunked`` sizes its calls from it).
        out["n_samples"] = int(ridx.shape[0]) if n_evaluated is None else n_evaluated
        return out

    # The early-termination pass costs at most about a third of a training pass over the same samples
    # (density only, no backward, and none behind opaque points), so it pays while it keeps less than
    # about two thirds of them.
    ERT_WORTH = 0.6

    def _use_ert(self) -> bool:
        """Whether this training render terminates rays early (``train_ert``; "auto": see the module
        docstring). Called once per training render; counts down to the next measurement."""
        mode = self.opts.train_ert
        if mode != "auto":
            return bool(mode)
        if self._ert_keep is not None and self._ert_keep < self.ERT_WORTH:
            return True
        self._ert_wait -= 1
        if self._ert_wait > 0:
            return False
        self._ert_wait = int(self.opts.ert_probe_every)
        return True

    @torch.no_grad()
    def _render_visible(self, t0, t1, ridx, mids, pts, rays_d, n_rays):
        """Rendering without gradients: the packed samples (k,) -> those still visible (T > 1e-4) as
        (t0, t1, ridx, mids), their weights (n,), colours (n, 3) and how many samples the trunk ran
        on; the same as one pass over every sample up to 1e-4 of a ray's colour. The trunk runs front to
        back until each ray is opaque; the features of the samples it ran on are kept per round, so the
        colour head needs no second trunk pass (memory: ``width`` floats per evaluated sample, about 8 MB
        per CPU call)."""
        rounds = []  # (sample positions, features) of every round

        def density(sel: Tensor) -> Tensor:
            out = []
            with profiling.stage("field"):
                for i in range(0, max(1, sel.shape[0]), self.render_chunk):
                    s = sel[i:i + self.render_chunk]
                    sigma, h = self.coarse.density_and_features(pts[s])
                    rounds.append((s, h))
                    out.append(sigma)
            return torch.cat(out)

        keep, weights = ray_termination.visible_samples(t0, t1, ridx, n_rays, density, t_min=1e-4,
                                                        round_size=self.render_round_size)
        # The kept samples' features in packed order: each round's survivors, sorted by position.
        pos = torch.cat([s[keep[s]] for s, _ in rounds]) if rounds else ridx.new_zeros(0)
        feats = (
            torch.cat([h[keep[s]] for s, h in rounds]) if rounds else pts.new_zeros(0, self.coarse.feature.in_features)
        )
        feats = feats.index_select(0, torch.argsort(pos))
        kept = keep.nonzero().squeeze(-1)
        t0, t1, ridx, mids = (x.index_select(0, kept) for x in (t0, t1, ridx, mids))
        with profiling.stage("field"):
            rgb = torch.cat([self.coarse.color_from_features(feats[i:i + self.render_chunk],
                                                             rays_d.index_select(0, ridx[i:i + self.render_chunk]))
                             for i in range(0, max(1, feats.shape[0]), self.render_chunk)])
        return t0, t1, ridx, mids, weights, rgb, int(sum(p.shape[0] for p, _ in rounds))

    @torch.no_grad()
    def _visible(self, t0, t1, ridx, mids, pts, n_rays):
        """The packed samples (same tuple) whose transmittance is still above 1e-4, found front to back
        (``ray_termination.visible_samples``): no density is evaluated behind a ray's opaque point."""
        keep, _ = marching.visible_front_to_back(t0, t1, ridx, n_rays, lambda sel: self._density_chunked(pts[sel]),
                                                 round_size=self.render_round_size)
        return tuple(x.index_select(0, keep) for x in (t0, t1, ridx, mids, pts))

    # ------------------------------------------------------------------ hierarchical sampler

    def _render_dense(self, net: NeRFMLP, rays_o, rays_d, edges, background, training: bool = False):
        t_starts, t_ends = edges[:, :-1], edges[:, 1:]
        mids = 0.5 * (t_starts + t_ends)
        pts = rays_o.unsqueeze(1) + rays_d.unsqueeze(1) * mids.unsqueeze(-1)  # (n_rays, n_samples, 3)
        dirs = rays_d.unsqueeze(1).expand_as(pts)
        flat_pts, flat_dirs = pts.reshape(-1, 3), dirs.reshape(-1, 3)  # a copy: ``dirs`` is expanded
        with profiling.stage("field"):
            sigma, rgb = net(flat_pts, flat_dirs)
        # Cameras inside the box: even out the gradient near each lens (see nerf_core.volume.grad_scaling).
        # Rays that miss the box have empty intervals at t = 0 and carry no weight: leave them out.
        dist = torch.where(t_ends > t_starts, mids, torch.full_like(mids, float("inf")))
        scale = grad_scaling.near_camera_scales(dist.reshape(-1), grad_scaling.reach_for_box(
            self.aabb, self.opts.grad_reach)) if training else None
        if scale is not None:
            sigma, rgb = grad_scaling.scale_gradient(sigma, scale), grad_scaling.scale_gradient(rgb, scale)
        n, s = mids.shape
        with profiling.stage("rendering"):
            return volrend.render_rays_dense(t_starts, t_ends, sigma.reshape(n, s), rgb.reshape(n, s, 3), background)

    def _render_hierarchical(self, rays_o, rays_d, near, far, background, training):
        o = self.opts
        with profiling.stage("sampling"):
            edges = sampling.stratified_samples(near, far, o.n_coarse, jitter=training)
        coarse = self._render_dense(self.coarse, rays_o, rays_d, edges, background, training)
        n_samples = rays_o.shape[0] * o.n_coarse
        if self.fine is None:
            return {"rgb": coarse["rgb"], "depth": coarse["depth"], "acc": coarse["acc"], "n_samples": n_samples}
        with profiling.stage("sampling"):
            new_t = sampling.importance_samples(edges, coarse["weights"], o.n_fine, deterministic=not training)
            fine_edges = sampling.merge_edges(edges, new_t)
        fine = self._render_dense(self.fine, rays_o, rays_d, fine_edges, background, training)
        n_samples += rays_o.shape[0] * (fine_edges.shape[1] - 1)
        return {"rgb": fine["rgb"], "depth": fine["depth"], "acc": fine["acc"], "rgb_coarse": coarse["rgb"],
                "n_samples": n_samples}

    @torch.no_grad()
    def density_at(self, pts: Tensor) -> Tensor:
        return (self.fine if self.fine is not None else self.coarse).density(pts)

    @torch.no_grad()
    def sampled_at(self, pts: Tensor) -> Tensor:
        # the occupancy sampler marches where its grid is occupied; the hierarchical one everywhere
        return super().sampled_at(pts) if self.occupancy is None else self.occupancy.query(pts)

    @torch.no_grad()
    def colour_at(self, pts: Tensor, dirs: Tensor) -> Tensor:
        return (self.fine if self.fine is not None else self.coarse)(pts, dirs)[1]

    def loss(self, out, target, weight):
        """The base loss, plus the hierarchical sampler's coarse network's colour error (the paper's)."""
        if "rgb_coarse" not in out:
            return super().loss(out, target, weight)
        mse = masked_mse(out["rgb"], target, weight)
        loss = mse + masked_mse(out["rgb_coarse"], target, weight)
        return (loss + out["aux_loss"] if out.get("aux_loss") is not None else loss), mse

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        if self.occupancy is not None:
            return self._render_occupancy(rays_o, rays_d, near, far, background, training)
        return self._render_hierarchical(rays_o, rays_d, near, far, background, training)


@register("nerf-nope")
class NeRFNoPE(NeRF):
    """``nerf`` fed raw coordinates (no positional encoding): the known-blurry baseline that shows why
    the encoding matters. Same options as ``nerf``; ``use_pe`` is forced off."""

    forced_options = {"use_pe": False}


@register("nerf-noview")
class NeRFNoView(NeRF):
    """``nerf`` whose colour ignores the view direction (``view_dependent`` forced off): the paper's
    ablation showing that the direction input is what reproduces highlights. Same options as ``nerf``."""

    forced_options = {"view_dependent": False}
