"""Radiance fields: functions from position (and view direction) to density and colour.

- :mod:`.mlp`: coordinate MLPs (the classic NeRF network).
- :mod:`.tensorf`: a TensoRF-style vector-matrix (VM) factorised grid with a tiny colour MLP.
"""
from nerf_core.fields.mlp import NeRFMLP
from nerf_core.fields.tensorf import TensorVMField

__all__ = ["NeRFMLP", "TensorVMField"]
