"""The steps of ``VMGrid.render_rays`` after sampling: visible samples with grad, compositing, the
regularisers, and the training statistics kept on the device.

Each function takes the ``VMGrid`` model as its first argument. A training step should read nothing
back to the host that it does not need to decide its shapes: on a GPU every read waits for the
device. So the running opacity of the training rays stays a device tensor (``track_opacity``), read
by the host only on the method's periodic steps (``read_opacity``), and the near-camera gradient
scaling asks the host only now and then (``grad_scaling.NearCameraGate``).
"""
from __future__ import annotations

import torch

from nerf_core.utils import profiling
from nerf_core.volume import grad_scaling, volrend

Tensor = torch.Tensor


def track_opacity(model, acc: Tensor) -> None:
    """Fold the mean opacity of this batch's rays ``acc`` (n_rays,) into the model's running mean on the
    device (``model._acc_dev``, float64: the same numbers as the host's running mean it replaces)."""
    if acc.numel() == 0:
        return
    prev = model._acc_dev
    if prev is None or model._acc_read != model._acc_ema:  # the host's value was set (replicas, a test)
        prev = torch.tensor(model._acc_ema, dtype=torch.float64, device=acc.device)
    model._acc_dev = 0.9 * prev + 0.1 * acc.detach().mean().double()
    model._acc_read = model._acc_ema


def read_opacity(model) -> float:
    """The running mean opacity, brought to the host (``model._acc_ema``, which ``formed`` reads)."""
    if model._acc_dev is not None:
        model._acc_ema = model._acc_read = float(model._acc_dev)
    return model._acc_ema


def visible_with_grad(model, t0, t1, ridx, pts, n_rays, training):
    """The samples still visible (T > 1e-4) and their weights, with grad.

    Early ray termination: find the visible samples without grad, then recompute their density
    with grad. Returns (t0, t1, ridx, pts, weights, gradient scales near the cameras or None)."""
    with torch.no_grad():
        sig = torch.cat([model._density(pts[i:i + model.render_step_chunk])
                         for i in range(0, max(1, pts.shape[0]), model.render_step_chunk)])
        with profiling.stage("rendering"):
            trans, _ = volrend.render_transmittance_from_density_packed(t0, t1, sig, ridx, n_rays)
        keep = (trans > 1e-4).nonzero().squeeze(-1)
    t0, t1, ridx, pts = (x.index_select(0, keep) for x in (t0, t1, ridx, pts))
    sigma = model._density(pts)
    gscale = model._near_gate.scales(0.5 * (t0 + t1), model._reach()) if training else None
    if gscale is not None:  # cameras inside the box: even out the gradient near each lens
        sigma = grad_scaling.scale_gradient(sigma, gscale)
    with profiling.stage("rendering"):
        weights, _, _ = volrend.render_weight_from_density_packed(t0, t1, sigma, ridx, n_rays)
    return t0, t1, ridx, pts, weights, gscale


def composite(model, t0, t1, ridx, pts, weights, gscale, color_fn, rays_d, n_rays, background) -> dict:
    """Colour the samples that can matter and add them up: {"rgb", "depth", "acc", "n_samples"}."""
    with profiling.stage("rendering"):
        # Colour only where it can matter: most surviving samples are transparent space before a
        # surface. Rays that are still almost transparent (all of them at initialisation) get colour
        # at every sample: treating unevaluated samples as black would teach the density only to
        # darken rays, and a field on a random background would then never become opaque.
        # (The ray opacity is the output's own ``acc``, detached: the same sums, made once.)
        acc = volrend.accumulate_along_rays_packed(weights, ridx, n_rays)
    vis = (weights.detach() > model.opts.color_weight) | (acc.detach().index_select(0, ridx) < 0.05)
    # Gathers stay outside the stage marks: the profile charges them to "other_forward".
    # One index for every gather: boolean masks would each search the mask again.
    vis = vis.nonzero().squeeze(-1)
    ridx_vis, mids = ridx.index_select(0, vis), (0.5 * (t0 + t1)).unsqueeze(-1)
    pts_vis, weights_vis = pts.index_select(0, vis), weights.index_select(0, vis)
    dirs_vis = rays_d.index_select(0, ridx_vis)
    with profiling.stage("field"):
        rgb_s = color_fn(pts_vis, dirs_vis)
    if gscale is not None:
        rgb_s = grad_scaling.scale_gradient(rgb_s, gscale.index_select(0, vis))
    with profiling.stage("rendering"):
        rgb = volrend.accumulate_along_rays_packed(weights_vis, ridx_vis, n_rays, rgb_s)
        depth = volrend.accumulate_along_rays_packed(weights, ridx, n_rays, mids).squeeze(-1)
        depth = depth / acc.clamp_min(1e-6)
        rgb = volrend.composite_background(rgb, acc, background.to(rgb.dtype))
    return {"rgb": rgb, "depth": depth, "acc": acc, "n_samples": int(ridx.shape[0])}


def regularisers(model, weights, t0, t1, ridx, n_rays):
    """The training step's extra loss: L1 and TV on the density planes, the distortion loss; 0.0
    when none applies."""
    aux = 0.0
    o = model.opts
    # The L1 prior waits until geometry has formed (``formed``: the occupancy grid prunes, or nearly
    # every ray is stopped). Before that the rendering gradient on the nearly transparent field is
    # tiny, and Adam scales every parameter's step to the same size whatever its gradient, so L1
    # alone would drive both factors of the VM products to zero: a saddle (d(plane*line) = 0 there)
    # that training never leaves, seen as a run stuck at its initial PSNR for its whole budget.
    use_l1 = o.l1_weight > 0 and model.formed()  # formed() reads the occupancy grid
    with profiling.stage("field"):
        if use_l1:
            aux = aux + o.l1_weight * model.field.density_l1()
        if o.tv_weight > 0:
            aux = aux + o.tv_weight * model.field.density_tv()
    if o.dist_weight > 0:
        scale = float((model.aabb[1] - model.aabb[0]).norm())
        with profiling.stage("rendering"):
            dist = volrend.distortion_loss_packed(weights, t0 / scale, t1 / scale, ridx, n_rays)
        aux = aux + o.dist_weight * dist.mean()
    return aux
