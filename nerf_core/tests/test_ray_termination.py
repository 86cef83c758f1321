"""Front-to-back early ray termination (``nerf_core.volume.ray_termination``) keeps exactly the samples and
weights of the full pass, and ``vmgrid`` renders the same images with it as with its training path."""
import math

import pytest
import torch

from nerf_core.methods.registry import build_model
from nerf_core.volume import sampling, volrend
from nerf_core.volume.ray_termination import visible_samples

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


pytestmark = pytest.mark.usefixtures("one_thread")  # small batches (see conftest.one_thread)


def _full_pass(t0, t1, sigma, ridx, n_rays, t_min=1e-4):
    """The training path's rule: density everywhere, keep T > t_min, weights recomputed on the kept."""
    trans, _ = volrend.render_transmittance_from_density_packed(t0, t1, sigma, ridx, n_rays)
    keep = trans > t_min
    w, _, _ = volrend.render_weight_from_density_packed(t0[keep], t1[keep], sigma[keep], ridx[keep], n_rays)
    return keep, w


def _packed(counts, step=0.1):
    ridx = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    rank = torch.cat([torch.arange(c) for c in counts]).float()
    return rank * step, rank * step + step, ridx


def test_opaque_wall_stops_the_ray_and_nothing_behind_it_is_evaluated():
    # Ray 0: thin fog only (never opaque). Ray 1: a wall at sample 5 of 40 (sigma*delta = 50, T -> e^-50).
    # Ray 2: no samples. Ray 3: density rising slowly, opaque only after ~20 samples.
    counts = [30, 40, 0, 40]
    t0, t1, ridx = _packed(counts)
    sigma = torch.full((sum(counts),), 0.01)
    wall = counts[0] + 5
    sigma[wall] = 500.0
    r3 = sum(counts[:3])
    sigma[r3:r3 + 40] = torch.linspace(0.0, 12.0, 40)
    asked = []

    def density(sel):
        asked.append(sel.clone())
        return sigma[sel]

    keep, w = visible_samples(t0, t1, ridx, 4, density, round_size=4)
    ref_keep, ref_w = _full_pass(t0, t1, sigma, ridx, 4)
    assert torch.equal(keep, ref_keep)
    assert torch.allclose(w, ref_w, rtol=1e-6, atol=1e-9)
    seen = torch.cat(asked)
    assert seen.unique().numel() == seen.numel()  # no sample evaluated twice
    on_ray1 = seen[ridx[seen] == 1]
    # The wall's round (samples 4..7) is the last one evaluated on ray 1: 8 of its 40 samples.
    assert on_ray1.numel() == 8 and int(on_ray1.max()) == wall + 2
    # Ray 3 stops once its optical depth passes -ln(1e-4) = 9.21: far fewer than its 40 samples.
    depth3 = torch.cumsum(sigma[r3:r3 + 40] * 0.1, 0)
    first_dark = int((depth3 >= -math.log(1e-4)).nonzero()[0])
    assert (ridx[seen] == 3).sum() == 4 * (first_dark // 4 + 1) < 40
    assert (ridx[seen] == 0).sum() == counts[0]  # fog never stops a ray: every sample is needed


def test_random_rays_match_the_full_pass():
    g = torch.Generator().manual_seed(3)
    counts = torch.randint(0, 90, (64,), generator=g).tolist()
    t0, t1, ridx = _packed(counts, step=0.05)
    sigma = torch.rand(sum(counts), generator=g) ** 4 * 40.0
    keep, w = visible_samples(t0, t1, ridx, 64, lambda sel: sigma[sel], round_size=16)
    ref_keep, ref_w = _full_pass(t0, t1, sigma, ridx, 64)
    assert torch.equal(keep, ref_keep)
    assert torch.allclose(w, ref_w, rtol=1e-6, atol=1e-9)
    assert not keep.all()  # the case is not trivial: some samples lie behind opaque stretches


def test_no_samples_at_all():
    e = torch.zeros(0)
    keep, w = visible_samples(e, e, torch.zeros(0, dtype=torch.long), 5, lambda sel: e[sel])
    assert keep.shape == (0,) and w.shape == (0,)


def _sphere_rays(n_cams=4, size=16):
    f = size / (2 * math.tan(math.radians(20)))
    j, i = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    d_cam = torch.nn.functional.normalize(
        torch.stack([(i + 0.5 - size / 2) / f, -(j + 0.5 - size / 2) / f, -torch.ones(size, size)], -1).reshape(-1, 3),
        dim=-1,
    )
    os_, ds = [], []
    for k in range(n_cams):
        a = 2 * math.pi * k / n_cams
        eye = torch.tensor([3 * math.cos(a), 3 * math.sin(a), 0.8])
        fwd = torch.nn.functional.normalize(-eye, dim=0)
        right = torch.nn.functional.normalize(torch.linalg.cross(fwd, torch.tensor([0.0, 0.0, 1.0])), dim=0)
        rot = torch.stack([right, torch.linalg.cross(right, fwd), -fwd], dim=1)
        ds.append(d_cam @ rot.T)
        os_.append(eye.expand(size * size, 3))
    o, d = torch.cat(os_), torch.cat(ds)
    b = (o * d).sum(-1)
    disc = b * b - (o * o).sum(-1) + 0.36
    hit = disc > 0
    t = -b - disc.clamp_min(0).sqrt()
    rgb = torch.where(
        hit[:, None], 0.5 + 0.5 * torch.nn.functional.normalize(o + t[:, None] * d, dim=-1), torch.ones(1, 3)
    )
    near, far, _ = sampling.ray_aabb_intersect(o, d, BOX)
    return o, d, near, far, rgb


def test_vmgrid_renders_the_same_image_without_grad_with_less_density_work():
    torch.manual_seed(0)
    o, d, near, far, rgb = _sphere_rays()
    model = build_model("vmgrid", BOX, res_init=16, res_final=24, upsample_at=[0.3], density_rank=8, app_rank=8,
                        mlp_width=32, occ_res=16, min_stage_steps=20)
    opt = torch.optim.Adam(model.param_groups(3e-3))
    for step in range(80):
        if model.training_hook(step, step / 80):
            opt = torch.optim.Adam(model.param_groups(3e-3))
        idx = torch.randint(0, o.shape[0], (256,))
        out = model.render_rays(o[idx], d[idx], near[idx], far[idx], torch.ones(256, 3), True)
        loss = (out["rgb"] - rgb[idx]).square().mean() + out.get("aux_loss", 0.0)
        opt.zero_grad()
        loss.backward()
        opt.step()
    model.eval()
    evaluated = []
    # The training path reads the field itself, the no-grad path its lookup tables (cached, so the
    # instance patched here is the one render_rays gets).
    lookup = model.field.lookup()
    density, lookup_density = model.field.density, lookup.density

    def counting(fn):
        def count(x):
            evaluated.append(x.shape[0])
            return fn(x)
        return count

    model.field.density = counting(density)
    lookup.density = counting(lookup_density)
    bg = torch.ones_like(rgb)
    with torch.enable_grad():  # the training path: full first pass, density recomputed on the survivors
        ref = model.render_rays(o, d, near, far, bg, False)
    full = sum(evaluated)
    evaluated.clear()
    with torch.no_grad():
        out = model.render_rays(o, d, near, far, bg, False)
    psnr = -10 * math.log10((ref["rgb"].detach() - rgb).square().mean().item())
    assert psnr > 18, psnr  # a model that learnt the sphere, so rays do stop at its surface
    for k in ("rgb", "acc", "depth"):
        assert (out[k] - ref[k].detach()).abs().max().item() < 1e-5, k
    assert out["n_samples"] == ref["n_samples"]
    assert sum(evaluated) < 0.8 * full, (sum(evaluated), full)
    # Per-ray results do not depend on how many rays a call holds (render.render_rays_chunked reads
    # the method's cpu_call_rays): one call of all 1024 rays against calls of 100.
    from nerf_core.render.frame import render_rays_chunked
    with torch.no_grad():
        whole = render_rays_chunked(model, o, d, bg)  # the model's own interval: the box, as near/far here
        model.cpu_call_rays = 100
        split = render_rays_chunked(model, o, d, bg)
    for k in ("rgb", "acc", "depth"):
        assert (whole[k] - split[k]).abs().max().item() < 1e-5, k
    assert (whole["rgb"] - out["rgb"]).abs().max().item() < 1e-5
