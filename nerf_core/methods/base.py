"""The interface every NeRF method implements (the registry that builds one by name is ``registry``).

A method is a ``RadianceModel``: an ``nn.Module`` that turns a batch of rays into colours. The
trainer (``nerf_core/engine/trainer.py``) knows nothing else about it, so a new method only has to
implement ``render_rays`` and register itself with ``@register("name")``.
"""
from __future__ import annotations

import math
from typing import Dict, Optional

import torch
from torch import nn

from nerf_core.cameras.rays import ray_bounds
from nerf_core.data.scene_box import box_length_unit

MAX_GRID_RES = 2048  # resolution options above this would ask for terabytes, not train


def check_options(name: str, defaults: dict, options: dict, positive=(), fractions=(), shares=(), grids=()) -> None:
    """Refuse (ValueError naming the option) unknown ``--set`` names and values of the wrong kind.

    The kind comes from the default: a bool option takes true/false, an int option a whole number
    >= 0, a float option a finite number >= 0, a list of numbers a list of finite numbers. Options in
    ``positive`` must be > 0, in ``fractions`` lie in (0, 1), in ``shares`` in [0, 1], and in ``grids`` (resolutions, cells
    per axis) lie in 2..MAX_GRID_RES. String options are checked by their methods.
    """
    unknown = set(options) - set(defaults)
    if unknown:
        raise ValueError(f"{name}: unknown options {sorted(unknown)}; known: {sorted(defaults)}")

    def bad(key, want):
        return ValueError(f"{name}: option {key!r} must be {want}, got {options[key]!r}")

    for key, value in options.items():
        default = defaults[key]
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise bad(key, "true or false")
            continue
        if isinstance(default, int) or (default is None and key in grids):
            if value is None and default is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise bad(key, "a whole number >= 0")
        elif isinstance(default, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise bad(key, "a finite number >= 0")
        elif isinstance(default, list):
            if (not isinstance(value, list) or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                                   or not math.isfinite(v) for v in value)):
                raise bad(key, "a list of numbers, e.g. [0.1,0.2]")
            continue
        else:
            continue
        if key in positive and value <= 0:
            raise bad(key, "greater than 0")
        if key in fractions and not 0 < value < 1:
            raise bad(key, "between 0 and 1 (exclusive)")
        if key in shares and not 0 <= value <= 1:
            raise bad(key, "between 0 and 1")
        if key in grids and not 2 <= value <= MAX_GRID_RES:
            raise bad(key, f"between 2 and {MAX_GRID_RES} cells per axis")


DENSITY_UNITS = ("box", "scene")


def check_density_unit(name: str, options: dict) -> None:
    """Refuse a ``density_unit`` option other than "box" or "scene" (ValueError naming it)."""
    unit = options.get("density_unit", "box")
    if unit not in DENSITY_UNITS:
        raise ValueError(f"{name}: option 'density_unit' must be one of {', '.join(DENSITY_UNITS)}, got {unit!r}")


def density_length(aabb: torch.Tensor, unit: str) -> float:
    """Scene units per unit of length that a field's density is measured against: the box unit
    (``scene_box.box_length_unit``) for "box", 1 for "scene" (checkpoints from before the option)."""
    return box_length_unit(aabb) if unit == "box" else 1.0


class RadianceModel(nn.Module):
    """Base class of every method: an ``nn.Module`` that renders batches of rays (``render_rays``).

    Subclasses store what they need to be rebuilt in ``self.options`` (a JSON-able dict): the trainer
    saves ``method_name`` and ``options`` in checkpoints and calls ``build_model`` to restore. A new
    method implements ``render_rays`` (rays_o, rays_d (n_rays, 3), near, far (n_rays,), background
    (n_rays, 3) -> dict with ``rgb`` (n_rays, 3), ``depth`` (n_rays,), ``acc`` (n_rays,)) and registers
    itself with ``@register("name")``; the other methods have working defaults.

    Args:
        aabb: (2, 3) scene box [min corner, max corner] (anything ``torch.as_tensor`` takes); kept as
            the float32 buffer ``self.aabb``.
        **options: the method's build options, kept in ``self.options``.
    """

    method_name = "base"
    # Options added after checkpoints existed -> the value that matches how those checkpoints were
    # trained (``saved_options``). New runs get ``defaults``.
    options_before: dict = {}
    environment_lr = 0.02  # Adam step for the environment's texture logits, at the method's default_lr
    # Weights (state-dict names) that grow during training (coarse-to-fine grids), each with the
    # dimensions that grow: a checkpoint may hold them at another size than a fresh build along those
    # dimensions (``runs.checkpoint_checks.check_weights``); no other weight or dimension may.
    growing: dict = {}

    def __init__(self, aabb: torch.Tensor, **options):
        super().__init__()
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3).clone())
        self.options = dict(options)
        self.environment = None  # an EnvironmentMap when the run models a visible world

    def kernels(self, device: torch.device) -> Dict[str, str]:
        """Which implementation each of the method's hot loops takes on ``device`` (for the ``start``
        event): name -> a short description, containing "fallback" when a slower path stands in."""
        return {}

    def upgrade_checkpoint(self, weights: dict, optimizer_state: Optional[dict] = None) -> tuple:
        """(weights, optimiser state) of a checkpoint saved by an older version, in this version's layout,
        as new dicts (the inputs are not changed). Called before the weights are checked and loaded.
        Methods whose stored layout changed override this; by default both come back as they are."""
        return weights, optimizer_state

    def attach_environment(self, env: nn.Module) -> None:
        """Model the background as light from infinity (``nerf_core.fields.environment``); recorded in options."""
        self.environment = env
        self.options["environment"] = dict(env.options)

    def background(self, rays_d: torch.Tensor, default: torch.Tensor) -> torch.Tensor:
        """Colour (n_rays, 3) behind each ray: the learned environment when there is one, else ``default``
        ((3,) or (n_rays, 3), e.g. the white or random training background)."""
        if self.environment is not None:
            return self.environment(rays_d)
        return default.expand(rays_d.shape[0], 3)

    def render_rays(
        self,
        rays_o: torch.Tensor,
        rays_d: torch.Tensor,
        near: torch.Tensor,
        far: torch.Tensor,
        background: torch.Tensor,
        training: bool,
    ) -> Dict[str, torch.Tensor]:
        """Render a batch of rays.

        Args:
            rays_o: (n_rays, 3) origins in world space.
            rays_d: (n_rays, 3) unit directions.
            near, far: (n_rays,) ray interval, already clipped to the scene box by the caller.
            background: (n_rays, 3) colour composited behind the accumulated opacity.
            training: True inside the optimisation loop (enables jitter and noise).

        Returns:
            dict with ``rgb`` (n_rays, 3), ``depth`` (n_rays,) distance along the ray, ``acc``
            (n_rays,) opacity, and optionally ``rgb_coarse`` (n_rays, 3), ``aux_loss`` (scalar) and
            ``n_samples`` (int, samples evaluated for this batch).
        """
        raise NotImplementedError

    def ray_interval(self, rays_o: torch.Tensor, rays_d: torch.Tensor, near: float | None = None,
                     far: float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The (n_rays,), (n_rays,) interval each ray is rendered over, handed back to ``render_rays``:
        the scene box clipped to the dataset's ``near``/``far``. Methods that model the world beyond the
        box (scene contraction) override it."""

        return ray_bounds(rays_o, rays_d, self.aabb, near, far)

    def param_groups(self, lr: float) -> list[dict]:
        """Optimiser parameter groups of the method itself (the environment's group is added by
        ``optimizer_groups``); override to give grids and MLPs different learning rates."""
        return [{"params": [p for n, p in self.named_parameters() if p.requires_grad and not n.startswith("environment.")],
                 "lr": lr}]

    def optimizer_groups(self, lr: float) -> list[dict]:
        """Every parameter group the trainer optimises: the method's, then the environment's."""
        groups = self.param_groups(lr)
        if self.environment is not None:
            scale = lr / float(getattr(self, "default_lr", lr) or lr)
            groups.append({"params": list(self.environment.parameters()), "lr": self.environment_lr * scale,
                           "name": "environment"})
        return groups

    def training_hook(self, step: int, frac: float | None) -> bool:
        """Called by the trainer before each step (occupancy updates, coarse-to-fine growth).

        Args:
            step: optimisation steps done so far.
            frac: share of the training budget spent, in [0, 1]: the step or the time budget,
                whichever runs out first (``contract.budget_fraction``); None when the caller has no
                budget (a method then assumes one of its own).

        Returns True when the set or shape of parameters changed, so the trainer rebuilds its optimiser.
        """
        return False

    def replica_stats(self) -> dict[str, float]:
        """Running statistics the method keeps from its own training batches (name -> float). Under
        ``torchrun`` each rank sees other rays, so the trainer averages these over the ranks after
        every step (``set_replica_stats``) to keep decisions that depend on them equal on every rank.
        Only running means belong here: their average over the ranks is the mean over all rays."""
        return {}

    def set_replica_stats(self, stats: dict[str, float]) -> None:
        """Take the rank-averaged values of ``replica_stats``."""

    @classmethod
    def size_options(cls, fine_res: float, texture: float, fine_share: float) -> tuple[dict, list[str]]:
        """``--size auto`` for this method (``nerf_core.methods.sizing.auto_size`` answers the questions,
        the method turns the answers into its build options).

        Args:
            fine_res: cells per axis the images can supervise: the pixel footprint's resolution for
                pixel-fine texture, half of it for coarse texture or none.
            texture: amount of texture in [0, 1] (1: the full appearance budget).
            fine_share: how much of that texture is at the pixel scale, in [0, 1].

        Returns (build options, one human-readable reason per decision).
        """
        return {}, [f"no sizing rule for method {cls.method_name!r}: using its defaults"]

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def num_bytes(self) -> int:
        return sum(p.numel() * p.element_size() for p in self.parameters()) + sum(
            b.numel() * b.element_size() for b in self.buffers()
        )

    def describe(self) -> dict:
        """What was built and why (reported by the trainer in the ``start`` event and config.json)."""
        out = {"method": self.method_name, "options": self.options, "n_params": self.num_parameters()}
        if self.environment is not None:
            out["environment_params"] = sum(p.numel() for p in self.environment.parameters())
        return out
