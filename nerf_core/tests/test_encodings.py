"""Encodings: shapes and values, and the 2D toy that shows why positional encoding matters."""
import math

import torch
from torch import nn

from nerf_core.fields.encodings import FourierFeatures, IdentityEncoding, PositionalEncoding, build_encoding


def test_positional_encoding_values_and_dims():
    pe = PositionalEncoding(3, n_freqs=4)
    assert pe.out_dim == 3 * (2 * 4 + 1)
    x = torch.tensor([[0.25, 0.0, -0.5]])
    y = pe(x)
    assert y.shape == (1, pe.out_dim)
    assert torch.allclose(y[0, :3], x[0])
    # sin(2^k pi x) for the first coordinate at k = 0..3: sin(pi/4), sin(pi/2), sin(pi), sin(2pi).
    sins = y[0, 3:3 + 12].reshape(3, 4)[0]
    assert torch.allclose(sins, torch.tensor([math.sin(math.pi / 4), 1.0, 0.0, 0.0]), atol=1e-6)
    assert PositionalEncoding(2, 3, include_input=False).out_dim == 12


def test_fourier_features_are_seeded_and_sized():
    a, b = FourierFeatures(2, 32, sigma=5.0, seed=3), FourierFeatures(2, 32, sigma=5.0, seed=3)
    assert torch.equal(a.B, b.B) and a.out_dim == 64
    x = torch.rand(10, 2)
    y = a(x)
    assert y.shape == (10, 64) and torch.allclose(y[:, :32] ** 2 + y[:, 32:] ** 2, torch.ones(10, 32), atol=1e-5)
    assert not torch.equal(a.B, FourierFeatures(2, 32, sigma=5.0, seed=4).B)
    assert IdentityEncoding(2).out_dim == 2 and isinstance(build_encoding("none", 2), IdentityEncoding)


def _toy_image(n=48):
    """High-frequency procedural image (n, n, 3): a rotated stripe pattern plus a fine checkerboard."""
    ys, xs = torch.meshgrid(torch.linspace(0, 1, n), torch.linspace(0, 1, n), indexing="ij")
    r = 0.5 + 0.5 * torch.sin(2 * math.pi * (7 * xs + 3 * ys))
    g = 0.5 + 0.5 * torch.sin(2 * math.pi * 5 * torch.hypot(xs - 0.4, ys - 0.6))
    b = ((torch.floor(xs * 8) + torch.floor(ys * 8)) % 2) * 0.8 + 0.1
    coords = torch.stack([xs, ys], -1) * 2 - 1
    return coords.reshape(-1, 2), torch.stack([r, g, b], -1).reshape(-1, 3)


def _fit(enc: nn.Module, x_tr, y_tr, x_te, y_te, steps=300) -> float:
    torch.manual_seed(0)
    net = nn.Sequential(
        enc, nn.Linear(enc.out_dim, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 3), nn.Sigmoid()
    )
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(steps):
        loss = (net(x_tr) - y_tr).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return -10 * math.log10((net(x_te) - y_te).square().mean().item())


def test_positional_encoding_beats_raw_coordinates_on_held_out_pixels():
    """Train on a checkerboard half of the pixels, test on the other half (interpolation, not memory).

    Measured (seeded): none ~9.7 dB, PE ~18.8 dB, RFF ~19.3 dB; the stated margin is 3 dB. RFF's sigma is
    in cycles per unit of the [-1, 1] input: much above the image's own frequencies (sigma 4+) it
    memorises the training pixels and interpolates no better than raw coordinates.
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny MLP: one thread is faster than two fighting over a shared CPU
    n = 48
    x, y = _toy_image(n)
    ij = torch.arange(n * n)
    train = ((ij // n) + (ij % n)) % 2 == 0
    args = (x[train], y[train], x[~train], y[~train])
    none = _fit(IdentityEncoding(2), *args)
    pe = _fit(PositionalEncoding(2, n_freqs=5), *args)
    rff = _fit(FourierFeatures(2, 64, sigma=1.5, seed=0), *args)
    torch.set_num_threads(threads)
    print(f"held-out PSNR: none {none:.2f} dB, PE {pe:.2f} dB, RFF {rff:.2f} dB")
    assert pe >= none + 3.0, (none, pe)
    assert rff >= none + 3.0, (none, rff)
