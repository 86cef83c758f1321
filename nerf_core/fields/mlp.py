"""The classic NeRF MLP: (x, d) -> (sigma, rgb) with a skip connection and a view-dependent head
(or one blind to the direction, ``view_dependent=False``)."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from nerf_core.fields.encodings import IdentityEncoding, PositionalEncoding, direction_encoding

Tensor = torch.Tensor

DENSITY_ACTIVATIONS = ("softplus", "exp")


class NeRFMLP(nn.Module):
    """Mildenhall et al.'s network, with configurable width/depth.

    Args:
        pos_freqs, dir_freqs: positional-encoding frequencies for positions and directions; 0 with
            ``use_pe=False`` gives the no-encoding baseline (raw coordinates).
        width, depth: hidden width and number of trunk layers; ``skip`` re-injects the encoded input
            after that layer (the original uses 8 x 256 with the skip after layer 4).
        aabb: (2, 3) box; positions are mapped to [-1, 1] inside it before encoding, so the encoding's
            frequencies mean the same thing for every scene scale.
        length_unit: scene units per unit of length the network's density is measured in (the box
            unit, ``scene_box.box_length_unit``, for scale-free training; 1: per scene unit). The
            returned density is per scene unit either way.
        view_dependent: False: the colour head gets no direction input (``encodings.direction_encoding``).
    """

    def __init__(self, aabb: Tensor, use_pe: bool = True, pos_freqs: int = 10, dir_freqs: int = 4,
                 width: int = 128, depth: int = 4, skip: int = 2, density_activation: str = "softplus",
                 length_unit: float = 1.0, view_dependent: bool = True):
        super().__init__()
        self.inv_length_unit = 1.0 / float(length_unit)
        if density_activation not in DENSITY_ACTIVATIONS:
            raise ValueError(
                f"density_activation must be one of {', '.join(DENSITY_ACTIVATIONS)}, got {density_activation!r}"
            )
        self.density_activation = density_activation
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3).clone())
        self.pos_enc = PositionalEncoding(3, pos_freqs) if use_pe else IdentityEncoding(3)
        self.dir_enc = direction_encoding(dir_freqs, view_dependent, use_pe)
        self.skip = skip
        layers, d_in = [], self.pos_enc.out_dim
        for i in range(depth):
            if i == skip and i > 0:
                d_in += self.pos_enc.out_dim
            layers.append(nn.Linear(d_in, width))
            d_in = width
        self.trunk = nn.ModuleList(layers)
        self.sigma_head = nn.Linear(width, 1)
        self.feature = nn.Linear(width, width)
        self.rgb_head = nn.Sequential(
            nn.Linear(width + self.dir_enc.out_dim, width // 2), nn.ReLU(), nn.Linear(width // 2, 3)
        )

    def normalize(self, x: Tensor) -> Tensor:
        return (x - self.aabb[0]) / (self.aabb[1] - self.aabb[0]) * 2 - 1

    def _trunk(self, x: Tensor) -> Tensor:
        ex = self.pos_enc(self.normalize(x))
        h = ex
        for i, layer in enumerate(self.trunk):
            if i == self.skip and i > 0:
                h = torch.cat([h, ex], dim=-1)
            h = F.relu(layer(h))
        return h

    def _activate(self, raw: Tensor) -> Tensor:
        # softplus rather than ReLU: a ReLU density that starts negative everywhere never recovers.
        # exp (Instant-NGP's choice) reaches the large densities of a hard surface from raw values of a
        # few units instead of hundreds, so surfaces, and the texture on them, sharpen sooner. Both are
        # shifted by -1, so that a fresh network starts as the same thin fog (~0.3-0.4 per unit length).
        if self.density_activation == "exp":
            sigma = torch.exp((raw - 1.0).clamp(-15.0, 15.0))
        else:
            sigma = F.softplus(raw - 1.0)
        return sigma * self.inv_length_unit if self.inv_length_unit != 1.0 else sigma

    def density(self, x: Tensor) -> Tensor:
        """(m, 3) positions -> (m,) densities >= 0."""
        return self._activate(self.sigma_head(self._trunk(x)).squeeze(-1))

    def density_and_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(m, 3) positions -> densities (m,) and the trunk's features (m, width), which
        ``color_from_features`` turns into colour without running the trunk again."""
        h = self._trunk(x)
        return self._activate(self.sigma_head(h).squeeze(-1)), h

    def color_from_features(self, h: Tensor, d: Tensor) -> Tensor:
        """Trunk features (m, width) and unit directions (m, 3) -> rgb (m, 3) in [0, 1]."""
        return torch.sigmoid(self.rgb_head(torch.cat([self.feature(h), self.dir_enc(d)], dim=-1)))

    def forward(self, x: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        """(m, 3) positions and unit directions -> sigma (m,), rgb (m, 3) in [0, 1]."""
        sigma, h = self.density_and_features(x)
        return sigma, self.color_from_features(h, d)
