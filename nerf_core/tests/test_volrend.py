"""Volume rendering against closed forms."""
import math

import pytest
import torch

from nerf_core.volume import volrend


def _slab(n_rays, n_samples, length, sigma):
    edges = torch.linspace(0, length, n_samples + 1).expand(n_rays, -1)
    return edges[:, :-1], edges[:, 1:], torch.full((n_rays, n_samples), float(sigma))


def test_constant_density_slab_transmits_exp_minus_sigma_d():
    t0, t1, sig = _slab(2, 64, 1.5, 0.8)
    w, T, a = volrend.render_weight_from_density(t0, t1, sig)
    # Transmittance in front of sample i is exp(-sigma * t_start_i); the whole slab lets exp(-sigma d) through.
    assert torch.allclose(T, torch.exp(-0.8 * t0), atol=1e-6)
    assert torch.allclose(1 - w.sum(-1), torch.full((2,), math.exp(-0.8 * 1.5)), atol=1e-6)
    assert torch.allclose(a, torch.full_like(a, 1 - math.exp(-0.8 * 1.5 / 64)), atol=1e-6)


def test_single_opaque_sample_returns_its_colour_and_depth():
    t0 = torch.tensor([[0.0, 1.0, 2.0, 3.0]])
    t1 = t0 + 1.0
    sig = torch.tensor([[0.0, 0.0, 1e4, 0.0]])
    rgbs = torch.tensor([[[1.0, 0, 0], [0, 1.0, 0], [0.2, 0.4, 0.6], [0, 0, 1.0]]])
    out = volrend.render_rays_dense(t0, t1, sig, rgbs, background=torch.ones(1, 3))
    assert torch.allclose(out["rgb"], torch.tensor([[0.2, 0.4, 0.6]]), atol=1e-5)
    assert out["acc"].item() == pytest.approx(1.0, abs=1e-6)
    assert out["depth"].item() == pytest.approx(2.5, abs=1e-4)


def test_weights_sum_to_opacity_and_background_fills_the_rest():
    torch.manual_seed(0)
    t0, t1, _ = _slab(5, 16, 2.0, 0.0)
    sig = torch.rand(5, 16) * 2
    rgbs = torch.rand(5, 16, 3)
    bg = torch.rand(5, 3)
    out = volrend.render_rays_dense(t0, t1, sig, rgbs, bg)
    w = out["weights"]
    # Opacity = 1 - transmittance through everything = 1 - exp(-sum sigma delta).
    expected_acc = 1 - torch.exp(-(sig * (t1 - t0)).sum(-1))
    assert torch.allclose(w.sum(-1), out["acc"]) and torch.allclose(out["acc"], expected_acc, atol=1e-6)
    expected_rgb = (w[..., None] * rgbs).sum(1) + (1 - expected_acc)[:, None] * bg
    assert torch.allclose(out["rgb"], expected_rgb, atol=1e-6)


def test_empty_ray_shows_the_background():
    t0, t1, sig = _slab(3, 8, 1.0, 0.0)
    bg = torch.tensor([[0.1, 0.2, 0.3]]).expand(3, 3)
    out = volrend.render_rays_dense(t0, t1, sig, torch.rand(3, 8, 3), bg)
    assert torch.allclose(out["rgb"], bg) and torch.all(out["acc"] == 0)


def test_half_precision_inputs_give_float32_weights():
    t0, t1, sig = _slab(2, 256, 4.0, 0.5)
    w, T, _ = volrend.render_weight_from_density(t0.half(), t1.half(), sig.half())
    assert w.dtype == torch.float32 and T.dtype == torch.float32
    # float32 accumulation keeps the slab's closed form to the precision of the half inputs.
    assert (1 - w.sum(-1)).sub(math.exp(-2.0)).abs().max() < 2e-3


def test_packed_matches_dense():
    torch.manual_seed(1)
    n_rays, n_s = 4, 10
    t0, t1, _ = _slab(n_rays, n_s, 3.0, 0.0)
    sig = torch.rand(n_rays, n_s) * 3
    rgbs = torch.rand(n_rays, n_s, 3)
    dense = volrend.render_rays_dense(t0, t1, sig, rgbs, torch.zeros(n_rays, 3))
    # Drop a ragged subset of samples with zero density (they contribute nothing), then pack.
    keep = torch.rand(n_rays, n_s) > 0.3
    sig_k = torch.where(keep, sig, torch.zeros_like(sig))
    dense_k = volrend.render_rays_dense(t0, t1, sig_k, rgbs, torch.zeros(n_rays, 3))
    ridx = torch.arange(n_rays)[:, None].expand(-1, n_s)[keep]
    w, T, _ = volrend.render_weight_from_density_packed(t0[keep], t1[keep], sig[keep], ridx, n_rays)
    assert torch.allclose(w, dense_k["weights"][keep], atol=1e-6)
    rgb = volrend.accumulate_along_rays_packed(w, ridx, n_rays, rgbs[keep])
    acc = volrend.accumulate_along_rays_packed(w, ridx, n_rays)
    assert torch.allclose(rgb, dense_k["rgb"], atol=1e-6) and torch.allclose(acc, dense_k["acc"], atol=1e-6)
    # A ray with no samples at all is fully transparent.
    w0, _, _ = volrend.render_weight_from_density_packed(t0[keep], t1[keep], sig[keep], ridx, n_rays + 1)
    assert volrend.accumulate_along_rays_packed(w0, ridx, n_rays + 1)[-1] == 0
    assert dense["acc"].shape == (n_rays,)


def test_packed_gradients_flow_to_densities():
    sig = torch.tensor([0.5, 1.0, 2.0, 0.3], requires_grad=True)
    t0 = torch.tensor([0.0, 0.5, 0.0, 0.5])
    ridx = torch.tensor([0, 0, 1, 1])
    w, _, _ = volrend.render_weight_from_density_packed(t0, t0 + 0.5, sig, ridx, 2)
    volrend.accumulate_along_rays_packed(w, ridx, 2).sum().backward()
    # d(acc)/d(sigma_i) = delta * T_end > 0 for every sample.
    assert torch.all(sig.grad > 0)
    expected = 0.5 * math.exp(-(0.5 + 1.0) * 0.5)  # ray 0: d acc / d sigma_0 = delta * exp(-sum sigma delta)
    assert sig.grad[0].item() == pytest.approx(expected, rel=1e-5)


def test_distortion_loss_matches_the_double_sum_by_hand():
    from nerf_core.volume.volrend import distortion_loss_packed

    # Ray 0: weights 0.5 and 0.25 at midpoints 1 and 3 (intervals of length 1); ray 1: no samples;
    # ray 2: one sample of weight 0.8 on an interval of length 0.5.
    t0 = torch.tensor([0.5, 2.5, 1.0])
    t1 = torch.tensor([1.5, 3.5, 1.5])
    w = torch.tensor([0.5, 0.25, 0.8])
    ridx = torch.tensor([0, 0, 2])
    got = distortion_loss_packed(w, t0, t1, ridx, 3)
    # ray 0: sum_ij w_i w_j |m_i - m_j| = 2 * 0.5 * 0.25 * 2 = 0.5; intra = (0.25 + 0.0625) / 3
    ray0 = 0.5 + (0.25 + 0.0625) / 3
    ray2 = 0.64 * 0.5 / 3
    assert torch.allclose(got, torch.tensor([ray0, 0.0, ray2]))
