"""``VMGridOptions``: the build options of ``vmgrid`` (and ``vmgrid-noview``), one field each.

Why each default is what it is, with the measurements behind it, is in docs/METHODS.md.
"""
from __future__ import annotations

import dataclasses
from typing import List

from nerf_core.methods import growth
from nerf_core.methods.options import (
    MAX_REACH,
    MAX_SEED,
    MAX_STEPS,
    MAX_WEIGHT,
    MethodOptions,
    OptionError,
    grid_option,
    option,
)
from nerf_core.optim.row_adam import BIAS_MODES
from nerf_core.volume import grad_scaling

BIG = 4096  # ranks and widths above this would need gigabytes per sample batch, not train


@dataclasses.dataclass
class VMGridOptions(MethodOptions):
    """The options of ``vmgrid``; ``python -m nerf_core methods`` lists them with these docs."""

    RUN_STATE_KEYS = ("resolution", "res_final_budget")

    res_init: int = grid_option(48, "plane cells per axis at the start of growth")
    res_final: int = grid_option(160, "plane cells per axis at the end of the scheduled growth")
    upsample_at: List[float] = option([0.06, 0.14, 0.24, 0.36],
                                      "fractions of the budget at which the grid grows (log-spaced sizes)",
                                      low=0, high=1, open_low=True, open_high=True)
    density_rank: int = option(16, "components of the density's VM factorisation", low=1, high=BIG)
    app_rank: int = option(32, "components of the appearance's VM factorisation", low=1, high=BIG)
    app_dim: int = option(27, "appearance features handed to the colour MLP", low=1, high=BIG)
    mlp_width: int = option(64, "width of the colour MLP", low=1, high=BIG)
    view_freqs: int = option(2, "frequencies of the view direction's encoding", high=16)
    occ_res: int = grid_option(64, "occupancy grid cells per axis")
    occ_every: int = option(16, "training steps between occupancy updates", low=1, high=MAX_STEPS)
    occ_alpha: float = option(1e-2, "a cell stays occupied while one marching step there is more opaque than this",
                              low=0, high=1, open_low=True, open_high=True)
    occ_decay: float = option(0.5, "share of a cell's remembered density kept per occupancy update", low=0, high=1)
    occ_dilate_formed: bool = option(False, "keep the one-cell dilation of the occupancy grid after geometry forms")
    occ_probe: str = option("max", "how an occupancy update reads a cell: the bound over the cell, or one random point",
                            choices=("max", "random"))
    # Below 0.05 voxels a ray of the largest grid takes ~70000 samples (step_ratio=1e-9 overflowed the
    # sample count); above 64 a step skips whole cells of the occupancy grid.
    step_ratio: float = option(0.5, "marching step in voxels", low=0.05, high=64)
    l1_weight: float = option(2e-4, "weight of the L1 prior on the density planes (once geometry has formed)",
                              high=MAX_WEIGHT)
    tv_weight: float = option(0.0, "weight of total variation on the density planes", high=MAX_WEIGHT)
    grid_lr_scale: float = option(20.0, "grids learn at lr times this", low=0, high=1e4, open_low=True)
    budget_steps: int = option(10000, "steps assumed by the schedule when the run has no budget", low=1,
                               high=MAX_STEPS)
    min_stage_steps: int = option(100, "steps each growth stage trains at least before the next", high=MAX_STEPS)
    # Coarser means >= 1 (1e-9 asked for a billion samples a ray); beyond 64 the warm-up step crosses the box.
    warmup_step_scale: float = option(3.0, "the marching step is this many times coarser until geometry forms",
                                      low=1, high=64)
    # Below 1e-8 the initial density's shift (about log(alpha)) leaves float32's softplus no gradient
    # (1e-300 trained a dead field); at 0.5 and above the box starts as fog every ray stops in.
    alpha_init: float = option(1e-4, "opacity of one marching step of the initial grid",
                               low=1e-8, high=0.5, open_high=True)
    seed: int = option(0, "seed of the grids' initialisation", high=MAX_SEED)
    unbounded: bool = option(False, "model the world beyond the box too (scene contraction; old name: contract)")
    dist_weight: float = option(0.0, "weight of the distortion loss (pulls each ray's weight together)",
                                high=MAX_WEIGHT)
    grad_reach: float = option(grad_scaling.DEFAULT_REACH_SHARE,
                               "share of the box diagonal within which samples near a camera learn damped",
                               high=MAX_REACH)
    color_weight: float = option(1e-4, "the colour path runs only at samples whose weight exceeds this", high=1)
    density_unit: str = option("box", "the density's length unit: the box rescaled to [-1, 1]^3, or the scene's",
                               choices=("box", "scene"))
    view_dependent: bool = option(True, "the colour depends on the view direction")
    budget_growth_steps: int = option(growth.BASE_STEPS,
                                      "a run predicted to make more steps than this grows past res_final (0: never)",
                                      high=MAX_STEPS)
    res_budget_max: int = grid_option(320, "the most cells per axis a long run grows to")
    grid_optimizer: str = option("adam", "how the grids are stepped: dense Adam over every cell, or a lazy Adam "
                                 "over the cells the step's rays touched", choices=("adam", "sparse"))
    sparse_bias: str = option("none", "the sparse Adam's bias correction: none, or a step count per cell",
                              choices=BIAS_MODES)
    sample_budget: int = option(0, "samples per training step, in buffers of fixed size, with the rays per step "
                                   "following (0: a fixed number of rays per step instead)", low=0, high=1 << 24)

    def check_together(self, method: str) -> None:
        # The grid grows from res_init to res_final: the other way round it would shrink, which growth
        # never does, so a run trained silently at res_init.
        if self.res_init > self.res_final:
            raise OptionError("res_init", f"{method}: option 'res_init' ({self.res_init}) must be at most "
                                          f"'res_final' ({self.res_final}): the grid grows from one to the other")
        # Each fraction is a later stage: out of order, a stage would be skipped without a word.
        if any(b <= a for a, b in zip(self.upsample_at, self.upsample_at[1:])):
            raise OptionError("upsample_at", f"{method}: option 'upsample_at' must be increasing, "
                                             f"got {self.upsample_at}")
