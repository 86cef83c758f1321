"""The world behind the scene: light from infinity, a colour per ray *direction* only.

A Blender world (an HDRI, a sky, a flat colour) is exactly that, so rays that leave the scene box,
or keep transmittance at the far bound, take their colour from an ``EnvironmentMap`` instead of a
fixed white or random colour: ``C = sum_i w_i c_i + (1 - sum_i w_i) * env(d)``.

Representation, chosen for a CPU budget:

* a pyramid of equirectangular (lat-long) RGB textures holding logits, summed and squashed by a
  sigmoid. One bilinear lookup per level costs a few hundred FLOPs per ray, nothing next to the
  scene's samples, and the gradient of a lookup touches 4 texels per level;
* the coarse levels (16 texels around) fit the overall colour of the world in a few dozen steps,
  the finest level then adds the photograph's detail. A single fine texture learns the same thing
  far slower, because each texel is seen by few rays;
* the finest level's texel spans about one training pixel (``size_for_focal``): a world seen through
  200 px images of a 40 degree lens cannot show finer detail, so more texels would only cost memory
  and optimiser time. It is capped at 1024 x 512, which is also the size of Blender's own
  studio-light HDRIs, because Adam's dense update of a 2048 x 1024 texture costs ~80 ms a step on a
  2-core CPU (1024: ~10 ms).

Spherical harmonics plus a small MLP (the other common choice) smooth a photograph away at any
affordable order, and an MLP on the direction spends FLOPs per ray that the CPU needs for the scene.

Direction convention (Blender's world frame, +Z up): ``u = atan2(y, x) / 2pi + 0.5`` across the
texture (it wraps around), ``v = acos(z) / pi`` down it (row 0 looks straight up).
"""
from __future__ import annotations

import math
import time

import torch
import torch.nn.functional as F
from torch import nn

from nerf_core.cameras.rays import rays_for_pixels
from nerf_core.image.metrics import mse_to_psnr as psnr_from_mse

Tensor = torch.Tensor

MAX_WIDTH = 1024  # finest texture width cap (see the module docstring)
MIN_WIDTH = 16
LEVEL_RATIO = 4  # each coarser level is 4x narrower


def size_for_focal(focal_px: float, cap: int = MAX_WIDTH) -> int:
    """Finest texture width whose texel spans about one pixel of a camera with focal ``focal_px``.

    One pixel at the image centre subtends ``1 / focal_px`` radians, so ``2 pi * focal_px`` texels go
    around the horizon; rounded to a power of two within [64, cap].
    """
    want = 2.0 * math.pi * max(float(focal_px), 1.0)
    return int(min(cap, max(64, 2 ** round(math.log2(want)))))


def directions_to_uv(dirs: Tensor) -> Tensor:
    """(n, 3) directions (any length) -> (n, 2) texture coordinates (u, v) in [0, 1]."""
    d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    u = torch.atan2(d[:, 1], d[:, 0]) / (2.0 * math.pi) + 0.5
    v = torch.acos(d[:, 2].clamp(-1.0, 1.0)) / math.pi
    return torch.stack([u, v], dim=-1)


def sample_latlong(texture: Tensor, uv: Tensor) -> Tensor:
    """Bilinear lookup of a (c, h, w) lat-long texture at (n, 2) ``uv``; returns (n, c).

    The texture wraps around in u (longitude): one column from the other side is padded onto each
    edge before the lookup, so a ray at u = 0.999 blends the last and first columns. v is clamped at
    the poles.
    """
    c, h, w = texture.shape
    padded = torch.cat([texture[:, :, -1:], texture, texture[:, :, :1]], dim=-1)[None]  # (1, c, h, w + 2)
    # Texel i's centre is at u = (i + 0.5) / w, i.e. at column i + 1.5 of the padded texture.
    gx = (uv[:, 0] * w + 1.0) / (w + 2.0) * 2.0 - 1.0
    gy = uv[:, 1] * 2.0 - 1.0
    grid = torch.stack([gx, gy], dim=-1).to(padded.dtype).view(1, 1, -1, 2)
    out = F.grid_sample(padded, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out.view(c, -1).t()


class EnvironmentMap(nn.Module):
    """Learned colour of light from infinity, as a function of direction.

    Options (JSON-able, stored in the checkpoint as ``options["environment"]``):
        width: finest texture width in texels (height = width / 2).
        levels: number of pyramid levels (each 4x narrower, down to 16 texels).
    """

    def __init__(self, width: int = 512, levels: int = 4):
        super().__init__()
        width = int(width)
        if width < MIN_WIDTH or width % 2:
            raise ValueError(f"environment width must be an even number >= {MIN_WIDTH}, got {width}")
        widths = []
        w = width
        while w >= MIN_WIDTH and len(widths) < max(1, int(levels)):
            widths.append(w)
            w //= LEVEL_RATIO
        self.options = {"width": width, "levels": len(widths)}
        # Coarsest first. Zero logits = mid grey everywhere until the images say otherwise.
        self.textures = nn.ParameterList([nn.Parameter(torch.zeros(3, max(1, w // 2), w)) for w in reversed(widths)])

    def forward(self, dirs: Tensor) -> Tensor:
        """(n, 3) ray directions -> (n, 3) colour in [0, 1]."""
        return self.at_uv(directions_to_uv(dirs.float()))

    def at_uv(self, uv: Tensor) -> Tensor:
        """(n, 2) texture coordinates (``directions_to_uv``) -> (n, 3) colour in [0, 1]."""
        return torch.sigmoid(sum(sample_latlong(t, uv) for t in self.textures))

    @torch.no_grad()
    def image(self, width: int | None = None) -> Tensor:
        """The learned world as an equirectangular (h, w, 3) image in [0, 1] (row 0 looks up)."""
        w = int(width or self.options["width"])
        h = max(1, w // 2)
        v = (torch.arange(h, dtype=torch.float32) + 0.5) / h
        u = (torch.arange(w, dtype=torch.float32) + 0.5) / w
        vv, uu = torch.meshgrid(v, u, indexing="ij")
        phi = (uu - 0.5) * 2.0 * math.pi
        theta = vv * math.pi
        dirs = torch.stack([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi), torch.cos(theta)], -1)
        return self.forward(dirs.reshape(-1, 3).to(self.textures[0].device)).reshape(h, w, 3).cpu()


def prefit(env: EnvironmentMap, dirs: Tensor, rgb: Tensor, steps: int = 200, batch: int = 8192, lr: float = 0.05,
           generator: torch.Generator | None = None) -> float:
    """Fit ``env`` to (m, 3) directions and (m, 3) colours of rays that miss the scene box; returns the
    final mean squared error.

    Why: a ray that misses the box sees the world and nothing else, so its pixel *is* the environment's
    colour in its direction. Fitting those first (a texture lookup per ray, milliseconds a step) means
    that when the scene starts training, the background behind the box is already there: otherwise the
    fastest way for the scene to explain the background seen through the box is fog in the box, which
    the occupancy grid then cannot prune, and every step stays slow.
    """
    if dirs.shape[0] == 0 or steps <= 0:
        return float("nan")
    opt = torch.optim.Adam(env.parameters(), lr=lr, betas=(0.9, 0.99), eps=1e-15, fused=True)
    uv = directions_to_uv(dirs.float())  # once: the trigonometry costs as much as the lookups
    mse = torch.tensor(float("nan"))
    for _ in range(int(steps)):
        idx = torch.randint(0, dirs.shape[0], (min(batch, dirs.shape[0]),), generator=generator)
        mse = ((env.at_uv(uv[idx]) - rgb[idx]) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        mse.backward()
        opt.step()
    return float(mse.detach())


PREFIT_RAYS = 400_000  # train rays tested against the box before an environment run (those that miss fit the world)
PREFIT_STEPS = 200  # Adam steps of that fit (8192 texture lookups each: ~15 ms on an idle 2-core CPU)


def prefit_from_split(
    model,
    split,
    near: float | None,
    far: float | None,
    generator: torch.Generator,
    device: torch.device,
    max_rays: int = PREFIT_RAYS,
    steps: int = PREFIT_STEPS,
) -> tuple[str, float]:
    """``prefit`` ``model.environment`` to the pixels of ``split`` (a ``data.Split``) whose rays miss
    the model's scene box (``model.ray_interval`` empty).

    Up to ``max_rays`` random pixels are tested, drawn from ``generator``. Returns (a one-line note
    for the user: share of rays that miss, time, PSNR of the fit; that share in [0, 1]).
    """

    started = time.perf_counter()

    hw = split.height * split.width
    n = min(max_rays, len(split) * hw)
    flat = torch.randint(0, len(split) * hw, (n,), generator=generator)
    view, pix = flat // hw, flat % hw
    j, i = pix // split.width, pix % split.width
    rays_o, rays_d, _ = rays_for_pixels(split.cameras, view, i, j)
    t0, t1 = model.ray_interval(rays_o.to(device), rays_d.to(device), near, far)
    miss = (t1 <= t0).cpu()
    rgb, _ = split.pixels(view[miss], j[miss], i[miss], torch.ones(3))
    dirs_t, cols_t = rays_d[miss].to(device), rgb.to(device)
    mse = prefit(model.environment, dirs_t, cols_t, steps=steps if len(dirs_t) else 0, generator=generator)
    share, took = len(dirs_t) / max(1, n), time.perf_counter() - started
    msg = (f"environment: {100 * share:.0f} % of the train rays miss the scene box; fitted the world to them "
           f"in {took:.1f} s" + (f" (psnr {psnr_from_mse(mse):.1f})" if mse == mse else ""))
    return msg, share
