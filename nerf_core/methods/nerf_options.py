"""``NeRFOptions``: the build options of ``nerf`` (and ``nerf-nope``, ``nerf-noview``), one field each.

Why each default is what it is, with the measurements behind it, is in docs/METHODS.md.
"""
from __future__ import annotations

import dataclasses
from typing import Union

from nerf_core.methods.options import MAX_REACH, MAX_STEPS, MethodOptions, OptionError, grid_option, option
from nerf_core.volume import grad_scaling

SAMPLERS = ("occupancy", "hierarchical")
# Positional-encoding frequencies go up to 2^(L-1): beyond ~20 the encoding's sines no longer resolve
# in float32 (and 2^200 overflows to inf), so a larger L cannot train.
MAX_FREQS = 20


@dataclasses.dataclass
class NeRFOptions(MethodOptions):
    """The options of ``nerf``; ``python -m nerf_core methods`` lists them with these docs."""

    width: int = option(128, "width of the MLP", low=1, high=4096)
    depth: int = option(4, "layers of the MLP's trunk", low=1, high=64)
    skip: int = option(2, "trunk layer that takes the encoded input again", high=64)
    pos_freqs: int = option(10, "frequencies of the positional encoding", high=MAX_FREQS)
    dir_freqs: int = option(4, "frequencies of the view direction's encoding", high=MAX_FREQS)
    use_pe: bool = option(True, "encode positions (false: raw coordinates, as nerf-nope)")
    density_activation: str = option("exp", "the density's activation", choices=("exp", "softplus"))
    sampler: str = option("occupancy", "how rays are sampled: an occupancy grid, or coarse and fine networks",
                          choices=SAMPLERS)
    march_steps: int = option(128, "marching steps per box diagonal once the occupancy grid prunes", low=1,
                              high=1 << 16)
    # Coarser means >= 1 (1e-9 asked for a billion samples a ray); beyond 64 the warm-up step crosses the box.
    warmup_step_scale: float = option(4.0, "the step is this many times coarser until the grid first prunes",
                                      low=1, high=64)
    occ_res: int = grid_option(48, "occupancy grid cells per axis")
    occ_every: int = option(16, "training steps between occupancy updates", low=1, high=MAX_STEPS)
    occ_decay: float = option(0.8, "share of a cell's remembered density kept per update", low=0, high=1)
    occ_alpha: float = option(0.01, "a cell is occupied when one fine step there is more opaque than this",
                              low=0, high=1, open_low=True, open_high=True)
    train_ert: Union[bool, str] = option("auto", "early ray termination while training: measured, or always/never",
                                         choices=("auto", True, False))
    ert_probe_every: int = option(25, "steps between measurements of what early termination would keep", low=1,
                                  high=MAX_STEPS)
    n_coarse: int = option(32, "samples per ray of the hierarchical sampler's coarse network", low=1, high=4096)
    n_fine: int = option(64, "samples per ray of the hierarchical sampler's fine network (0: none)", high=4096)
    grad_reach: float = option(grad_scaling.DEFAULT_REACH_SHARE,
                               "share of the box diagonal within which samples near a camera learn damped",
                               high=MAX_REACH)
    density_unit: str = option("box", "the density's length unit: the box rescaled to [-1, 1]^3, or the scene's",
                               choices=("box", "scene"))
    view_dependent: bool = option(True, "the colour depends on the view direction")

    def check_together(self, method: str) -> None:
        if self.skip > self.depth:
            raise OptionError("skip", f"{method}: option 'skip' ({self.skip}) must be at most 'depth' ({self.depth})")
