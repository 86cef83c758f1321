"""``RowSparseAdam``: Adam that updates a grid only at the rows a step touched (a lazy Adam).

A dense Adam passes over every parameter every step: on vmgrid's grids that is most of a step's cost
at fine resolutions, although a batch of rays reads a small part of them (issue 55). Here a parameter
group marked ``row_sparse`` is a set of tables of rows (a parameter viewed as (-1, its last dim): the
R components of one grid cell), and ``step(rows)`` updates, for each such parameter, only the rows
given (``fields.vm_touched``). The rows not given keep their moments frozen, as if the step had
not happened for them (the lazy Adam of TensorFlow and of Taming 3DGS's sparse Adam), so a cell's
moments are those of the steps that saw it. Every other group is torch's (fused) Adam.

Bias correction, ``bias``:
  * ``"per_row"``: each row counts its own steps (``row_step``) and is corrected by them, as
    instant-ngp keeps a step count per parameter: a cell seen for the first time moves by the
    learning rate, as a dense Adam's first step does;
  * ``"none"``: no correction (Taming 3DGS): early steps of a cell are damped by 1 - beta1.
"""
from __future__ import annotations

from typing import Mapping, Optional, Sequence

import torch

from nerf_core.optim.adam import BETAS, fused_adam_kwargs
from nerf_core.optim.base import TrainingOptimizer

BIAS_MODES = ("per_row", "none")


def _rows(p: torch.Tensor) -> torch.Tensor:
    """``p`` as a (rows, last dim) view (its own storage: updates write the parameter)."""
    return p.view(-1, p.shape[-1])


class RowSparseAdam(TrainingOptimizer, torch.optim.Adam):
    """Adam over ``groups``; those with ``"row_sparse": True`` update only the rows ``step`` is given.

    Args:
        groups: parameter groups (dicts with ``params`` and ``lr``); a row-sparse group's parameters
            must be contiguous (their rows are views).
        eps: Adam's epsilon.
        bias: ``"per_row"`` or ``"none"`` (module docstring).
    """

    def __init__(self, groups: Sequence[dict], eps: float, bias: str = "per_row"):
        if bias not in BIAS_MODES:
            raise ValueError(f"RowSparseAdam: bias must be one of {BIAS_MODES}, got {bias!r}")
        groups = [dict(g) for g in groups]
        for g in groups:
            g.setdefault("row_sparse", False)
            g["bias"] = bias
        super().__init__(groups, betas=BETAS, eps=eps, **fused_adam_kwargs(groups))

    def state_shape(self, key: str, param: torch.Tensor) -> tuple:
        if key == "row_step":
            return (_rows(param).shape[0],) if param.is_contiguous() else (param.numel() // param.shape[-1],)
        return super().state_shape(key, param)

    @torch.no_grad()
    def step(self, rows: Optional[Mapping[torch.Tensor, Optional[torch.Tensor]]] = None,
             l1: Optional[Mapping[torch.Tensor, float]] = None, closure=None):
        """One update.

        Args:
            rows: parameter -> the rows (k,) long it touched, for the row-sparse parameters; a parameter
                missing here (or ``rows`` None) is updated at every row (a dense step, still per row).
            l1: parameter -> c: add the gradient of an L1 prior, ``c * sign(p)``, at the rows stepped
                (a prior that acts on the touched cells, at no extra pass).
            closure: not supported (None).
        """
        if closure is not None:
            raise ValueError("RowSparseAdam does not take a closure")
        sparse = [p for g in self.param_groups if g["row_sparse"] for p in g["params"] if p.grad is not None]
        held = [p.grad for p in sparse]
        for p in sparse:  # the dense groups go through torch's (fused) Adam
            p.grad = None
        try:
            super().step()
        finally:
            for p, grad in zip(sparse, held):
                p.grad = grad
        for g in self.param_groups:
            if g["row_sparse"]:
                for p in g["params"]:
                    if p.grad is not None:
                        self._update_rows(p, g, None if rows is None else rows.get(p), (l1 or {}).get(p, 0.0))

    def _update_rows(self, p: torch.Tensor, group: dict, idx: Optional[torch.Tensor], l1: float) -> None:
        st = self.state[p]
        table = _rows(p)
        if not st:
            st["exp_avg"] = torch.zeros_like(p, memory_format=torch.contiguous_format)
            st["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.contiguous_format)
            st["row_step"] = torch.zeros(table.shape[0], dtype=torch.float32, device=p.device)
        if idx is None:
            idx = torch.arange(table.shape[0], device=p.device)
        if idx.numel() == 0:
            return
        b1, b2 = group["betas"]
        m_all, v_all = _rows(st["exp_avg"]), _rows(st["exp_avg_sq"])
        g = p.grad.reshape(table.shape).index_select(0, idx)
        values = table.index_select(0, idx)
        if l1:
            g = g.add_(values.sign(), alpha=l1)
        m = m_all.index_select(0, idx).mul_(b1).add_(g, alpha=1 - b1)
        v = v_all.index_select(0, idx).mul_(b2).addcmul_(g, g, value=1 - b2)
        m_all.index_copy_(0, idx, m)
        v_all.index_copy_(0, idx, v)
        if group["bias"] == "per_row":
            s = st["row_step"].index_select(0, idx).add_(1.0)
            st["row_step"].index_copy_(0, idx, s)
            m = m.div_((1.0 - torch.pow(b1, s)).unsqueeze(-1))
            v = v.div_((1.0 - torch.pow(b2, s)).unsqueeze(-1))
        # index_copy, not index_add: the rows are distinct, and a copy needs no accumulation
        table.index_copy_(0, idx, values.sub_(m.div_(v.sqrt_().add_(group["eps"])), alpha=group["lr"]))
