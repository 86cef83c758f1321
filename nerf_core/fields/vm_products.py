"""The plane-times-line products of a VM grid at m points, with their gradient: the hot loop of vmgrid.

    vm_products(planes (3, R, N, N), lines (3, R, N, 1), u (m, 3) in [-1, 1]) -> (m, 3, R)

``out[i, k, r] = P_kr(u_i) * L_kr(u_i)``: plane k (axes (x, y), (x, z), (y, z)) read bilinearly and
its line (along z, y, x) linearly, as ``F.grid_sample(..., align_corners=True)`` reads them, with zero
padding outside the grid. Two implementations give the same numbers (to float rounding, tested):

* :func:`reference`: two ``grid_sample`` calls and a product. Used on GPUs, for float64, when a
  gradient with respect to the points is needed, and wherever the native kernel is not available.
* the native CPU kernel (``native/vm_products.c``), built at first use by ``utils.native``. It
  reads the planes channels-last (as ``tensorf`` stores them), so one tap of all R components is
  one contiguous run, and its backward scatters in parallel over the 3 R (plane, component) pairs;
  grid_sample's CPU backward is parallel over the 3 planes only, and was the largest single cost of
  a CPU step (``docs/benchmarks/plane_lookup.md``).

:func:`backend` says which one a call would take (``"native"`` or ``"grid_sample"``) and why.
"""
from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Optional

import torch
import torch.nn.functional as F

from nerf_core.utils import native

Tensor = torch.Tensor

# Plane k spans axes PLANE_AXES[k] (its columns, its rows) and its line runs along LINE_AXIS[k]; the one
# home of this order (``vm_lookup`` and ``native/vm_products.c`` follow it).
PLANE_AXES = ((0, 1), (0, 2), (1, 2))
LINE_AXIS = (2, 1, 0)
_SOURCE = Path(__file__).with_name("native") / "vm_products.c"


# The channels-last layout the kernel reads, and ``tensorf`` stores its grids in: the one home of the
# conversions both ways. ``*_to_stored`` copy only when the input is not already that layout in memory;
# ``*_from_stored`` are views.
def planes_to_stored(planes: Tensor) -> Tensor:
    """(3, R, N, N) planes -> (3, N, N, R) contiguous."""
    return planes.permute(0, 2, 3, 1).contiguous()


def lines_to_stored(lines: Tensor) -> Tensor:
    """(3, R, N, 1) lines -> (3, N, R) contiguous."""
    return lines[..., 0].permute(0, 2, 1).contiguous()


def planes_from_stored(stored: Tensor) -> Tensor:
    """(3, N, N, R) -> a (3, R, N, N) view."""
    return stored.permute(0, 3, 1, 2)


def lines_from_stored(stored: Tensor) -> Tensor:
    """(3, N, R) -> a (3, R, N, 1) view."""
    return stored.permute(0, 2, 1).unsqueeze(-1)
_lib: ctypes.CDLL | None = None
_why_not = ""
_tried = False


def reference(planes: Tensor, lines: Tensor, u: Tensor) -> Tensor:
    """(3, R, N, N), (3, R, N, 1), (m, 3) -> (m, 3, R) with ``F.grid_sample`` (any device and dtype)."""
    pc = torch.stack([u[:, list(a)] for a in PLANE_AXES]).unsqueeze(2)  # (3, m, 1, 2)
    line_c = torch.stack([u[:, a] for a in LINE_AXIS])  # (3, m)
    lc = torch.stack([torch.zeros_like(line_c), line_c], dim=-1).unsqueeze(2)  # x = 0 (width 1), y = coordinate
    p = F.grid_sample(planes, pc, mode="bilinear", align_corners=True).squeeze(-1)  # (3, R, m)
    l_ = F.grid_sample(lines, lc, mode="bilinear", align_corners=True).squeeze(-1)
    return (p * l_).permute(2, 0, 1)


def _library() -> tuple[ctypes.CDLL | None, str]:
    global _lib, _why_not, _tried
    if not native.enabled():
        return None, "turned off by NERF_CORE_NATIVE"
    if not _tried:
        _tried = True
        lib, _why_not = native.load(_SOURCE)
        if lib is not None:
            f, b = lib.vm_products_forward, lib.vm_products_backward
            p, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
            f.argtypes = [p, p, p, i64, i32, i32, p, p, i32]
            b.argtypes = [p, p, p, i64, i32, i32, p, p, p, i32]
            f.restype = b.restype = i32
            lib.vm_products_taps_bytes.restype = i32
            _lib = lib
    return _lib, _why_not


def _kernel_shapes_ok(planes: Tensor, lines: Tensor, u: Tensor) -> bool:
    """The shapes the kernel assumes (it indexes raw memory, so anything else goes to grid_sample):
    planes (3, R, N, N), lines (3, R, N, 1), points (m, 3)."""
    return (planes.dim() == 4 and planes.shape[0] == 3 and planes.shape[2] == planes.shape[3] >= 1
            and tuple(lines.shape) == (3, planes.shape[1], planes.shape[2], 1)
            and u.dim() == 2 and u.shape[1] == 3)


def backend(planes: Tensor | None = None, u: Tensor | None = None) -> tuple[str, str]:
    """("native" | "grid_sample", reason) for these tensors (or for float32 CPU tensors when omitted)."""
    lib, why = _library()
    if lib is None:
        return "grid_sample", why
    if planes is not None and (planes.device.type != "cpu" or planes.dtype != torch.float32):
        return "grid_sample", f"the native kernel is for float32 CPU tensors ({planes.dtype} on {planes.device})"
    if u is not None and u.requires_grad:
        return "grid_sample", "a gradient with respect to the points is needed"
    return "native", ""


def _threads() -> int:
    return max(1, torch.get_num_threads())


class _NativeVMProducts(torch.autograd.Function):
    """The native kernel reads channels-last planes and lines, (3, N, N, R) and (3, N, R) in memory.
    ``tensorf`` stores its parameters that way (shapes unchanged, strides channels-last), so the
    permutes below are views; any other layout is copied here, per call."""

    @staticmethod
    def forward(ctx, planes: Tensor, lines: Tensor, u: Tensor, sink: Optional[tuple] = None) -> Tensor:
        lib = _library()[0]
        r, n, m = planes.shape[1], planes.shape[-1], u.shape[0]
        planes_cl, lines_cl = planes_to_stored(planes.detach()), lines_to_stored(lines.detach())
        u_c = u.detach().contiguous()
        out = planes.new_empty(m, 3, r)
        taps = torch.empty(3 * m * lib.vm_products_taps_bytes(), dtype=torch.uint8)
        lib.vm_products_forward(planes_cl.data_ptr(), lines_cl.data_ptr(), u_c.data_ptr(), m, r, n,
                                out.data_ptr(), taps.data_ptr(), _threads())
        ctx.save_for_backward(planes_cl, lines_cl, taps)
        ctx.shape = (m, r, n)
        ctx.sink = sink
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        planes_cl, lines_cl, taps = ctx.saved_tensors
        m, r, n = ctx.shape
        need_p, need_l = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if ctx.sink is not None:  # buffers kept zero between steps by their owner (``vm_touched``): no fill
            gp, gl = (ctx.sink[0] if need_p else None), (ctx.sink[1] if need_l else None)
        else:
            gp = torch.zeros_like(planes_cl) if need_p else None
            gl = torch.zeros_like(lines_cl) if need_l else None
        if m and (need_p or need_l):
            g = grad_out.contiguous()
            _library()[0].vm_products_backward(planes_cl.data_ptr(), lines_cl.data_ptr(), taps.data_ptr(), m, r, n,
                                               g.data_ptr(), gp.data_ptr() if gp is not None else None,
                                               gl.data_ptr() if gl is not None else None, _threads())
        # Views with channels-last strides: the same strides as the parameters that ``tensorf`` keeps
        # channels-last, so autograd stores them as they are (any other layout gets copied there).
        return (planes_from_stored(gp) if gp is not None else None,
                lines_from_stored(gl) if gl is not None else None, None, None)


NO_GRAD_CHUNK = 1 << 16  # points per kernel call without autograd: bounds the scratch taps to 9 MiB


def _native_no_grad(planes: Tensor, lines: Tensor, u: Tensor) -> Tensor:
    """The forward alone, in chunks of NO_GRAD_CHUNK points, so that a query of millions of points
    (occupancy probes, mesh export) does not hold 144 bytes of taps per point."""
    lib = _library()[0]
    r, n, m = planes.shape[1], planes.shape[-1], u.shape[0]
    planes_cl, lines_cl = planes_to_stored(planes.detach()), lines_to_stored(lines.detach())
    u_c = u.detach().contiguous()
    out = planes.new_empty(m, 3, r)
    taps = torch.empty(3 * min(m, NO_GRAD_CHUNK) * lib.vm_products_taps_bytes(), dtype=torch.uint8)
    for a in range(0, m, NO_GRAD_CHUNK):
        b = min(m, a + NO_GRAD_CHUNK)
        uc, oc = u_c[a:b], out[a:b]  # contiguous row ranges
        lib.vm_products_forward(planes_cl.data_ptr(), lines_cl.data_ptr(), uc.data_ptr(), b - a, r, n,
                                oc.data_ptr(), taps.data_ptr(), _threads())
    return out


def vm_products(planes: Tensor, lines: Tensor, u: Tensor, sink: Optional[tuple] = None) -> Tensor:
    """(3, R, N, N) planes, (3, R, N, 1) lines, (m, 3) points in [-1, 1] -> (m, 3, R) products.

    Differentiable in ``planes`` and ``lines``; takes the native CPU kernel when :func:`backend` allows,
    else :func:`reference`. ``sink``: (planes (3, N, N, R), lines (3, N, R)) stored-layout buffers, zero
    everywhere, that the native kernel's backward adds the gradients into (and returns as them) instead
    of filling a fresh zero grid each step; their owner zeroes what was written (``vm_touched``).
    """
    if (backend(planes, u)[0] != "native" or lines.dtype != torch.float32 or u.dtype != torch.float32
            or lines.device.type != "cpu" or u.device.type != "cpu" or not _kernel_shapes_ok(planes, lines, u)):
        return reference(planes, lines, u)
    if torch.is_grad_enabled() and (planes.requires_grad or lines.requires_grad):
        return _NativeVMProducts.apply(planes, lines, u, sink)
    return _native_no_grad(planes, lines, u)
