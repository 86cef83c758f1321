"""Optimisers a method trains with (``RadianceModel.make_optimizer``), each one a ``TrainingOptimizer``:
a ``torch.optim.Optimizer`` that also checks a checkpoint's saved state against itself and carries
state over when the model's parameters change (coarse-to-fine growth).

- ``base``: ``TrainingOptimizer``, the declared type, and its generic state check;
- ``adam``: ``Adam``, the default: torch's Adam (fused where the parameters allow it);
- ``row_adam``: ``RowSparseAdam``, which updates a grid only at the rows a step touched.
"""
from nerf_core.optim.adam import Adam, fused_adam_kwargs
from nerf_core.optim.base import TrainingOptimizer
from nerf_core.optim.row_adam import RowSparseAdam

__all__ = ["Adam", "RowSparseAdam", "TrainingOptimizer", "fused_adam_kwargs"]
