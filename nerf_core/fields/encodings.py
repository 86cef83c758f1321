"""Input encodings for coordinate MLPs. Each is an ``nn.Module`` with an ``out_dim`` attribute.

- :class:`IdentityEncoding`: the raw input (the blurry baseline; MLPs are biased to low frequencies).
- :class:`PositionalEncoding`: NeRF's sin/cos at frequencies 2^k * pi (k = 0..n_freqs-1).
- :class:`FourierFeatures`: Gaussian random Fourier features (Tancik et al. 2020), B ~ N(0, sigma^2).
"""
from __future__ import annotations

import math

import torch
from torch import nn

Tensor = torch.Tensor


class IdentityEncoding(nn.Module):
    """(..., in_dim) -> (..., in_dim)."""

    def __init__(self, in_dim: int):
        super().__init__()
        self.in_dim = in_dim
        self.out_dim = in_dim

    def forward(self, x: Tensor) -> Tensor:
        return x


class PositionalEncoding(nn.Module):
    """(..., in_dim) -> (..., out_dim) with out_dim = in_dim * (2 * n_freqs + include_input).

    Frequencies are ``2^k * pi`` for k in [min_freq_log2, min_freq_log2 + n_freqs), so inputs in
    [-1, 1] see periods from 2 down to 2^(1 - max_k).
    """

    def __init__(self, in_dim: int, n_freqs: int, include_input: bool = True, min_freq_log2: int = 0):
        super().__init__()
        self.in_dim, self.n_freqs, self.include_input = in_dim, n_freqs, include_input
        freqs = math.pi * 2.0 ** torch.arange(min_freq_log2, min_freq_log2 + n_freqs, dtype=torch.float32)
        self.register_buffer("freqs", freqs, persistent=False)
        self.out_dim = in_dim * (2 * n_freqs + int(include_input))

    def forward(self, x: Tensor) -> Tensor:
        if self.n_freqs == 0:
            return x if self.include_input else x[..., :0]
        xb = (x.unsqueeze(-1) * self.freqs.to(x)).flatten(-2)  # (..., in_dim * n_freqs)
        parts = [x] if self.include_input else []
        parts += [torch.sin(xb), torch.cos(xb)]
        return torch.cat(parts, dim=-1)


class FourierFeatures(nn.Module):
    """Gaussian random Fourier features: [sin(2 pi B x), cos(2 pi B x)], B (n_features, in_dim) ~ N(0, sigma^2).

    ``seed`` makes B reproducible; B is a buffer so it travels with checkpoints.
    (..., in_dim) -> (..., 2 * n_features [+ in_dim]).
    """

    def __init__(
        self, in_dim: int, n_features: int = 128, sigma: float = 10.0, seed: int = 0, include_input: bool = False
    ):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.register_buffer("B", torch.randn(n_features, in_dim, generator=g) * sigma)
        self.include_input = include_input
        self.out_dim = 2 * n_features + (in_dim if include_input else 0)

    def forward(self, x: Tensor) -> Tensor:
        proj = 2 * math.pi * x @ self.B.to(x).t()
        parts = [x] if self.include_input else []
        return torch.cat(parts + [torch.sin(proj), torch.cos(proj)], dim=-1)


def direction_encoding(n_freqs: int, view_dependent: bool = True, use_pe: bool = True) -> nn.Module:
    """The encoding of the view direction that a colour head reads: (..., 3) -> (..., out_dim).

    The one home of the rule that switches view dependence off: with ``view_dependent`` False the
    encoding has ``out_dim`` 0 and returns an empty (..., 0) tensor, so the colour head has no input
    that depends on the direction, and its colour is the same from every side by construction (a
    diffuse, Lambertian-looking model: NeRF's ablation of the direction input). ``n_freqs`` 0 is *not*
    that: the raw direction still goes in. ``use_pe`` False: the raw direction (``nerf-nope``).
    """
    if not view_dependent:
        return PositionalEncoding(in_dim=3, n_freqs=0, include_input=False)
    return PositionalEncoding(3, n_freqs) if use_pe else IdentityEncoding(3)


def build_encoding(kind: str, in_dim: int, **kw) -> nn.Module:
    """``kind`` in {"none", "pe", "fourier"}; extra keywords go to the encoding's constructor."""
    if kind in ("none", "identity"):
        return IdentityEncoding(in_dim)
    if kind in ("pe", "positional"):
        return PositionalEncoding(in_dim, **kw)
    if kind in ("fourier", "rff"):
        return FourierFeatures(in_dim, **kw)
    raise ValueError(f"unknown encoding {kind!r}; choose none, pe or fourier")
