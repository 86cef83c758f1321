"""``nerf`` and ``nerf-nope``: the classic MLP NeRF with coarse-to-fine hierarchical sampling.

CPU sizing: the original 8 x 256 network with 64 + 128 samples per ray runs ~22k samples/s forward +
backward on a 2-core CPU, i.e. ~115 rays/s, far too slow to learn anything in minutes. The default
here is 4 x 128 (about 7x fewer FLOPs per sample) with 32 coarse + 64 fine samples; it keeps every
ingredient of the method (positional encoding, skip connection, view-dependent head, two networks,
inverse-CDF resampling) so the comparison with ``nerf-nope`` and with grid methods stays meaningful.
Use ``width=256, depth=8, skip=4, n_coarse=64, n_fine=128`` for the paper's configuration.
"""
from __future__ import annotations

import math

import torch

from .. import grad_scaling, profiling, sampling, volrend
from ..fields.mlp import NeRFMLP
from .base import RadianceModel, register

Tensor = torch.Tensor


@register("nerf")
class NeRF(RadianceModel):
    """Mildenhall et al. 2020. Options (all JSON-able): ``width``, ``depth``, ``skip``, ``pos_freqs``,
    ``dir_freqs``, ``n_coarse``, ``n_fine``, ``use_pe``, ``density_noise`` (std of the noise added to raw
    density while training, a regulariser from the paper; 0 disables it), ``grad_reach`` (share of the box
    diagonal within which a camera's samples learn with distance-scaled gradients, ``nerf_core.grad_scaling``;
    0 disables it)."""

    default_lr = 5e-4
    default_batch_rays = 1024
    defaults = dict(width=128, depth=4, skip=2, pos_freqs=10, dir_freqs=4, n_coarse=32, n_fine=64, use_pe=True,
                    grad_reach=grad_scaling.DEFAULT_REACH_SHARE)

    def __init__(self, aabb: Tensor, **options):
        unknown = set(options) - set(self.defaults)
        if unknown:
            raise ValueError(f"{self.method_name}: unknown options {sorted(unknown)}; known: {sorted(self.defaults)}")
        opts = {**self.defaults, **options}
        super().__init__(aabb, **opts)
        net = dict(use_pe=opts["use_pe"], pos_freqs=opts["pos_freqs"], dir_freqs=opts["dir_freqs"],
                   width=opts["width"], depth=opts["depth"], skip=opts["skip"])
        self.coarse = NeRFMLP(self.aabb, **net)
        self.fine = NeRFMLP(self.aabb, **net) if opts["n_fine"] > 0 else None

    @classmethod
    def size_options(cls, fine_res, texture, fine_share):
        # Highest frequency 2^(L-1) pi on [-1, 1]: period 2^(2-L) of the box half-size; stop at ~2 cells.
        pos_freqs = int(max(4, min(12, math.ceil(math.log2(max(2.0, fine_res))))))
        width = 64 if texture < 0.35 else 128
        opts, reasons = dict(width=width), []
        if cls.defaults["use_pe"]:  # without the encoding (nerf-nope) there are no frequencies to size
            opts["pos_freqs"] = pos_freqs
            reasons.append(f"{pos_freqs} positional-encoding frequencies: the finest period matches ~2 pixel footprints")
        reasons.append(f"MLP width {width} from the texture probe")
        return opts, reasons

    def _render(self, net: NeRFMLP, rays_o, rays_d, edges, background, training: bool = False):
        t_starts, t_ends = edges[:, :-1], edges[:, 1:]
        mids = 0.5 * (t_starts + t_ends)
        pts = rays_o.unsqueeze(1) + rays_d.unsqueeze(1) * mids.unsqueeze(-1)  # (n_rays, n_samples, 3)
        dirs = rays_d.unsqueeze(1).expand_as(pts)
        flat_pts, flat_dirs = pts.reshape(-1, 3), dirs.reshape(-1, 3)  # a copy: ``dirs`` is expanded
        with profiling.stage("field"):
            sigma, rgb = net(flat_pts, flat_dirs)
        # Cameras inside the box: even out the gradient near each lens (see nerf_core.grad_scaling).
        # Rays that miss the box have empty intervals at t = 0 and carry no weight: leave them out.
        dist = torch.where(t_ends > t_starts, mids, torch.full_like(mids, float("inf")))
        scale = grad_scaling.near_camera_scales(dist.reshape(-1), grad_scaling.reach_for_box(
            self.aabb, self.options["grad_reach"])) if training else None
        if scale is not None:
            sigma, rgb = grad_scaling.scale_gradient(sigma, scale), grad_scaling.scale_gradient(rgb, scale)
        n, s = mids.shape
        with profiling.stage("rendering"):
            return volrend.render_rays_dense(t_starts, t_ends, sigma.reshape(n, s), rgb.reshape(n, s, 3), background)

    def render_rays(self, rays_o, rays_d, near, far, background, training):
        o = self.options
        with profiling.stage("sampling"):
            edges = sampling.stratified_samples(near, far, o["n_coarse"], jitter=training)
        coarse = self._render(self.coarse, rays_o, rays_d, edges, background, training)
        n_samples = rays_o.shape[0] * o["n_coarse"]
        if self.fine is None:
            return {"rgb": coarse["rgb"], "depth": coarse["depth"], "acc": coarse["acc"], "n_samples": n_samples}
        with profiling.stage("sampling"):
            new_t = sampling.importance_samples(edges, coarse["weights"], o["n_fine"], deterministic=not training)
            fine_edges = sampling.merge_edges(edges, new_t)
        fine = self._render(self.fine, rays_o, rays_d, fine_edges, background, training)
        n_samples += rays_o.shape[0] * (fine_edges.shape[1] - 1)
        return {"rgb": fine["rgb"], "depth": fine["depth"], "acc": fine["acc"], "rgb_coarse": coarse["rgb"],
                "n_samples": n_samples}


@register("nerf-nope")
class NeRFNoPE(NeRF):
    """``nerf`` fed raw coordinates (no positional encoding): the known-blurry baseline that shows why
    the encoding matters. Same options as ``nerf``; ``use_pe`` is forced off."""

    defaults = {**NeRF.defaults, "use_pe": False}

    def __init__(self, aabb: Tensor, **options):
        options["use_pe"] = False
        super().__init__(aabb, **options)
