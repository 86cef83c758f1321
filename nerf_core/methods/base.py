"""The interface every NeRF method implements (the registry that builds one by name is ``registry``).

A method is a ``RadianceModel``: an ``nn.Module`` that turns a batch of rays into colours. Everything
the trainer, the renderers and the loaders ask of a method is declared here, with its default: the
class attributes below, ``Options`` (its typed build options), ``render_batch`` and ``loss``. Nothing
outside ``nerf_core/methods`` probes a model for attributes, so a new method is one class in one file
that sets what differs from these defaults, implements ``render_rays`` and registers with
``@register("name")``.
"""
from __future__ import annotations

from typing import ClassVar, Dict, Mapping, Optional, Tuple

import torch
from torch import nn

from nerf_core.cameras.rays import ray_bounds
from nerf_core.data.batcher import Batcher, BatchOptions, RayBatcher
from nerf_core.data.scene_box import box_length_unit
from nerf_core.data.split import Split
from nerf_core.image.losses import masked_mse
from nerf_core.methods.environment_options import checked_environment
from nerf_core.methods.options import MAX_GRID_RES, MethodOptions, PluginOptions
from nerf_core.methods.registry import current_option_names
from nerf_core.optim import Adam, TrainingOptimizer
from nerf_core.volume.occupancy import OccupancyGrid

__all__ = ["RadianceModel", "MAX_GRID_RES", "density_length"]


def density_length(aabb: torch.Tensor, unit: str) -> float:
    """Scene units per unit of length that a field's density is measured against: the box unit
    (``scene_box.box_length_unit``) for "box", 1 for "scene" (checkpoints from before the option)."""
    return box_length_unit(aabb) if unit == "box" else 1.0


def ray_weights(out: Dict[str, torch.Tensor], weight: Optional[torch.Tensor]) -> Optional[torch.Tensor]:
    """Each ray's weight in every loss term: the batch's ``weight`` (n,) (masks, importance; None =
    uniform), times 0 for the rays a fixed-size step did not render whole (``out["fits"]`` (n,) bool,
    vmgrid's ``sample_budget``). The one home of that rule, for the colour loss and the terms of
    ``--depth`` and ``--alpha-weight`` alike."""
    fits = out.get("fits")
    if fits is None:
        return weight
    return fits.to(out["rgb"].dtype) if weight is None else weight * fits


class RadianceModel(nn.Module):
    """Base class of every method: an ``nn.Module`` that renders batches of rays.

    A subclass implements ``render_rays`` and may override the class attributes, ``Options`` and the
    hooks below; everything else has a working default.

    Args:
        aabb: (2, 3) scene box [min corner, max corner] (anything ``torch.as_tensor`` takes); kept as
            the float32 buffer ``self.aabb``.
        **options: the method's build options, checked by ``Options.parse`` and kept as ``self.opts``.

    Raises:
        ValueError: an option the method does not have, or a value out of its bounds.
    """

    method_name: ClassVar[str] = "base"
    # The typed build options (``methods.options``). A method that declares none keeps what it is given.
    Options: ClassVar[type] = PluginOptions
    # Options a variant fixes whatever it is given (``nerf-nope``: use_pe false).
    forced_options: ClassVar[Dict[str, object]] = {}
    # Options added after checkpoints existed -> the value that matches how those checkpoints were
    # trained (``registry.saved_options``). New runs get the defaults.
    options_before: ClassVar[Dict[str, object]] = {}

    # Training defaults, read by the trainer when the run does not set them.
    default_lr: ClassVar[float] = 5e-4  # base learning rate (``--lr``)
    default_batch_rays: ClassVar[int] = 1024  # rays per step on a CPU (``--batch-rays``; 4x on CUDA)
    warmup_steps: ClassVar[Optional[int]] = None  # LR warm-up; None: 5 % of the step budget, at most 100
    default_max_steps: ClassVar[int] = 5000  # the budget when neither --max-steps nor --max-seconds is given
    adam_eps: ClassVar[float] = 1e-15
    environment_lr: ClassVar[float] = 0.02  # Adam step for the environment's texture, at ``default_lr``
    # Rendering without grad on a CPU: at most this many rays a model call (``render.frame``).
    cpu_call_rays: ClassVar[int] = 512
    # Weights (state-dict names) that grow during training (coarse-to-fine grids), each with the
    # dimensions that grow: a checkpoint may hold them at another size than a fresh build along those
    # dimensions (``runs.checkpoint_checks.check_weights``); no other weight or dimension may.
    growing: ClassVar[Dict[str, Tuple[int, ...]]] = {}
    # True when rays run on past the box (scene contraction): no ray misses the scene then.
    contracted: bool = False

    def __init__(self, aabb: torch.Tensor, **options):
        super().__init__()
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).reshape(2, 3).clone())
        self.opts: MethodOptions = self.parse_options(options)
        self.environment: Optional[nn.Module] = None  # an EnvironmentMap when the run models a visible world

    # ------------------------------------------------------------------ options and state

    @classmethod
    def parse_options(cls, options: Mapping[str, object]) -> MethodOptions:
        """The typed options for ``options`` (old option names mapped to today's; the ``environment``
        entry excluded: ``build_model`` attaches it), with ``forced_options`` applied. Raises ValueError
        naming a bad option."""
        declared = cls.Options.declared()
        given = current_option_names(dict(options), declared or None)
        checked_environment(cls.method_name, given.pop("environment", None))  # ``build_model`` attaches it
        return cls.Options.parse(cls.method_name, {**given, **cls.forced_options})

    @property
    def options(self) -> Dict[str, object]:
        """The build options as the JSON-able dict that checkpoints save and ``build_model`` takes back,
        with ``environment`` (the learned world's options) when there is one."""
        out = self.opts.to_dict()
        if self.environment is not None:
            out["environment"] = dict(self.environment.options)
        return out

    def run_state(self) -> Dict[str, object]:
        """What training changed that the options do not say (vmgrid: its grid size), as JSON-able
        values; checkpoints save it as ``method_state`` and ``restore_run_state`` takes it back."""
        return {}

    def restore_run_state(self, state: Mapping[str, object]) -> None:
        """Take back a checkpoint's ``run_state`` before its weights are checked and loaded."""

    def upgrade_checkpoint(self, weights: dict, optimizer_state: Optional[dict] = None) -> tuple:
        """(weights, optimiser state) of a checkpoint saved by an older version, in this version's layout,
        as new dicts (the inputs are not changed). Called before the weights are checked and loaded.
        Methods whose stored layout changed override this; by default both come back as they are."""
        return weights, optimizer_state

    def kernels(self, device: torch.device) -> Dict[str, str]:
        """Which implementation each of the method's hot loops takes on ``device`` (for the ``start``
        event): name -> a short description, containing "fallback" when a slower path stands in."""
        return {}

    # ------------------------------------------------------------------ the world behind the scene

    def attach_environment(self, env: nn.Module) -> None:
        """Model the background as light from infinity (``nerf_core.fields.environment``); recorded in options."""
        self.environment = env

    @property
    def models_world(self) -> bool:
        """True when the run learned the world behind the scene: renders are then opaque, and the
        background colour a caller gives is replaced by the learned one."""
        return self.environment is not None

    def background(self, rays_d: torch.Tensor, default: torch.Tensor) -> torch.Tensor:
        """Colour (n_rays, 3) behind each ray: the learned environment when there is one, else ``default``
        ((3,) or (n_rays, 3), e.g. the white or random training background)."""
        if self.environment is not None:
            return self.environment(rays_d)
        return default.expand(rays_d.shape[0], 3)

    # ------------------------------------------------------------------ rendering and loss

    def render_batch(self, rays_o: torch.Tensor, rays_d: torch.Tensor, background: torch.Tensor,
                     near: Optional[float] = None, far: Optional[float] = None,
                     training: bool = False) -> Dict[str, torch.Tensor]:
        """Render a batch of camera rays: the method's ray interval, its background, then ``render_rays``.

        Args:
            rays_o: (n_rays, 3) origins in world space.
            rays_d: (n_rays, 3) unit directions.
            background: (3,) or (n_rays, 3) colour behind the scene (replaced by the learned world when
                the model has one).
            near, far: the dataset's ray bounds in scene units, or None.
            training: True inside the optimisation loop (jitter, noise, regularisers).

        Returns:
            what ``render_rays`` returns.
        """
        t0, t1 = self.ray_interval(rays_o, rays_d, near, far)
        bg = self.background(rays_d, background)
        return self.render_rays(rays_o, rays_d, t0, t1, bg, training)

    def render_rays(self, rays_o: torch.Tensor, rays_d: torch.Tensor, near: torch.Tensor, far: torch.Tensor,
                    background: torch.Tensor, training: bool) -> Dict[str, torch.Tensor]:
        """Render a batch of rays over a given interval (``render_batch`` computes it).

        Args:
            rays_o: (n_rays, 3) origins in world space.
            rays_d: (n_rays, 3) unit directions.
            near, far: (n_rays,) ray interval (``ray_interval``).
            background: (n_rays, 3) colour composited behind the accumulated opacity.
            training: True inside the optimisation loop (enables jitter and noise).

        Returns:
            dict with ``rgb`` (n_rays, 3), ``depth`` (n_rays,) distance along the ray, ``acc``
            (n_rays,) opacity, and optionally ``aux_loss`` (scalar, added by ``loss``), ``n_samples``
            (int, samples evaluated for this batch), ``fits`` ((n_rays,) bool: the rays that a fixed-size
            step rendered whole; ``loss`` leaves the others out) and what the method's own ``loss`` reads.
        """
        raise NotImplementedError

    def ray_interval(self, rays_o: torch.Tensor, rays_d: torch.Tensor, near: float | None = None,
                     far: float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The (n_rays,), (n_rays,) interval each ray is rendered over: the scene box clipped to the
        dataset's ``near``/``far``. Methods that model the world beyond the box override it."""
        return ray_bounds(rays_o, rays_d, self.aabb, near, far)

    def loss(self, out: Dict[str, torch.Tensor], target: torch.Tensor,
             weight: Optional[torch.Tensor]) -> Tuple[torch.Tensor, torch.Tensor]:
        """The training loss of a rendered batch.

        Args:
            out: what ``render_batch`` returned for the batch (``rgb`` (n, 3), optional ``aux_loss``).
            target: (n, 3) the pixels' colours.
            weight: (n,) per-ray weights of the colour error, or None.

        Returns:
            (loss, mse): scalar tensors; ``mse`` is the colour error that the PSNR is reported from.
            A method extends the loss by overriding this and adding to ``super().loss(...)``'s.
        """
        mse = masked_mse(out["rgb"], target, ray_weights(out, weight))
        loss = mse
        if out.get("aux_loss") is not None:
            loss = loss + out["aux_loss"]
        return loss, mse

    # ------------------------------------------------------------------ the field at points (export)

    def density_at(self, pts: torch.Tensor) -> torch.Tensor:
        """Density per scene unit (m,) at world points (m, 3), without grad: what the geometry export
        samples. A method whose field cannot be read at points raises NotImplementedError."""
        raise NotImplementedError(f"method {self.method_name!r} does not offer its density at points")

    def colour_at(self, pts: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """Colour (m, 3) in [0, 1] at world points (m, 3) seen along unit directions (m, 3), without grad."""
        raise NotImplementedError(f"method {self.method_name!r} does not offer its colour at points")

    def sampled_at(self, pts: torch.Tensor) -> torch.Tensor:
        """(m,) bool at world points (m, 3): False where the renderer skips space without sampling it
        (an occupancy grid's empty cells), so that the density there never reaches a render. An export
        gives those points zero density (``export.field.density``). True everywhere by default."""
        return torch.ones(pts.shape[0], dtype=torch.bool, device=pts.device)

    def detail_resolution(self) -> int:
        """Samples per axis of the scene box that match the model's own detail (the export's default
        grid): 256 unless the method knows better."""
        return 256

    # ------------------------------------------------------------------ optimisation

    def param_groups(self, lr: float) -> list[dict]:
        """Optimiser parameter groups of the method itself (the environment's group is added by
        ``optimizer_groups``); override to give grids and MLPs different learning rates."""
        return [{"params": [p for n, p in self.named_parameters() if p.requires_grad
                            and not n.startswith("environment.")], "lr": lr}]

    def optimizer_groups(self, lr: float) -> list[dict]:
        """Every parameter group the trainer optimises: the method's, then the environment's."""
        groups = self.param_groups(lr)
        if self.environment is not None:
            scale = lr / self.default_lr
            groups.append({"params": list(self.environment.parameters()), "lr": self.environment_lr * scale,
                           "name": "environment"})
        return groups

    # ------------------------------------------------------------------ the training step
    # The trainer's step is: budget, ``training_hook``, ``make_batcher``'s batch, ``render_batch``,
    # ``loss``, backward, checks, ``optimizer_step``. What differs between methods is theirs to say.

    def make_batcher(self, split: Split, background: str, gen: torch.Generator, device: torch.device,
                     options: BatchOptions = BatchOptions()) -> Batcher:
        """What the trainer draws each step's rays from: by default ``RayBatcher``, one ray through each
        of ``batch_rays`` random pixels, as the run's ``options`` say.

        Args:
            split: the train ``Split``.
            background: the training background mode (``data.backgrounds``; "auto" already decided).
            gen: the CPU generator every random draw must come from (checkpoints save its state).
            device: where the batches go.
            options: the run's ``BatchOptions``: each ray's sub-pixel footprint (``--train-rays``), the
                depth targets the batches carry (``--depth``), which pixels are drawn (``--ray-sampling``).
        """
        return RayBatcher(split, background, gen, device, options)

    def occupancy_grid(self) -> Optional[OccupancyGrid]:
        """The grid that skips empty space, over the scene box in world coordinates, for the trainer
        to mark what the capture shows empty (``train --depth``: ``OccupancyGrid.mark_known_free``);
        None when the method has none, or when its grid spans a contracted world."""
        return None

    def make_optimizer(self, lr: float) -> TrainingOptimizer:
        """The optimiser over ``optimizer_groups(lr)``: by default Adam (fused where it can be).
        Called at the start, after growth (``training_hook`` returned True) and after a rollback."""
        return Adam(self.optimizer_groups(lr), eps=self.adam_eps)

    def optimizer_step(self, opt: TrainingOptimizer, out: Dict[str, torch.Tensor]) -> None:
        """Apply one step's gradients.

        Args:
            opt: what ``make_optimizer`` returned (its learning rates already scheduled).
            out: what ``render_batch`` returned for the step's batch: a method that reports what the
                step touched there (the cells of a grid, say) can update only that.
        """
        opt.step()

    def rays_per_step(self, batch_rays: int) -> int:
        """Rays the next training step draws: ``batch_rays`` (``--batch-rays`` or the method's default),
        unless the method sizes its steps by samples (vmgrid's ``sample_budget``). Called before each
        step's batch; a method changes its answer on its periodic steps only, so shapes stay fixed."""
        return batch_rays

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

    def replica_masks(self) -> list[torch.Tensor]:
        """Bool tensors the method keeps from its own training batch (the cells a sparse optimiser will
        step), which under ``torchrun`` the trainer ORs over the ranks in place after the backward pass,
        so that every rank steps the same cells with the same averaged gradients."""
        return []

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

    # ------------------------------------------------------------------ reporting

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def num_bytes(self) -> int:
        return sum(p.numel() * p.element_size() for p in self.parameters()) + sum(
            b.numel() * b.element_size() for b in self.buffers()
        )

    def describe(self) -> dict:
        """What was built and why (reported by the trainer in the ``start`` event and config.json)."""
        out = {"method": self.method_name, "options": self.options, "n_params": self.num_parameters()}
        state = self.run_state()
        if state:
            out["state"] = state
        if self.environment is not None:
            out["environment_params"] = sum(p.numel() for p in self.environment.parameters())
        return out
