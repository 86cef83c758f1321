"""The CPU plane lookup of a VM grid, forward and backward: F.grid_sample against fused alternatives.

    python benchmarks/bench_plane_lookup.py [--res 160] [--rank 16] [--points 32768] [--repeats 15]
                                         [--threads 2] [--compile] [--json OUT.json]

One training step of ``vmgrid`` after growth reads each of the three planes and lines at every
sample (``TensorVMField._vm``: ``grid_sample`` on (3, R, N, N) planes and (3, R, N, 1) lines) and
scatters the gradient back (``grid_sampler_2d_backward``). This times that lookup, its product and
a backward of a sum-of-products loss, at realistic shapes, for:

- ``grid_sample``: today's ``_vm``;
- ``gather``: the four corners gathered by hand from a (3 N N, R) row-major copy of the planes
  (``index_select``), bilinear weights, and the two line taps likewise; the backward is index_add;
- ``embedding_bag``: the same corner rows and weights through ``F.embedding_bag(mode="sum")``
  (one fused weighted gather; its backward is one scatter);
- ``rowmajor``: ``embedding_bag`` on planes *stored* row-major (no per-step copies), as a field
  that kept its parameters in that layout would run;
- ``compiled`` (``--compile``): ``torch.compile`` (inductor, C++ on a CPU) of today's ``_vm``;
- ``vm_products_native`` (or ``_grid_sample`` where it does not build): the library's
  ``nerf_core.fields.vm_products`` on channels-last planes, as ``TensorVMField`` stores them.

The variants are run interleaved (A, B, C, A, B, C, ...) so a machine shared with other jobs slows
them alike; the median of ``--repeats`` rounds is reported, with each variant's ratio to grid_sample.
It checks first that every variant equals grid_sample's output and plane gradient within 1e-5.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import torch
import torch.nn.functional as F

PLANE_AXES = ((0, 1), (0, 2), (1, 2))
LINE_AXIS = (2, 1, 0)


def grid_sample_vm(planes, lines, u):
    """Today's lookup: (3, R, N, N), (3, R, N, 1), points u (m, 3) in [-1, 1] -> (3, R, m)."""
    pc = torch.stack([u[:, list(a)] for a in PLANE_AXES]).unsqueeze(2)
    lc_ = torch.stack([u[:, a] for a in LINE_AXIS])
    lc = torch.stack([torch.zeros_like(lc_), lc_], dim=-1).unsqueeze(2)
    p = F.grid_sample(planes, pc, mode="bilinear", align_corners=True).squeeze(-1)
    line = F.grid_sample(lines, lc, mode="bilinear", align_corners=True).squeeze(-1)
    return p * line


def _taps(u, n):
    """Corner rows and bilinear weights: plane rows (3, m, 4) into (3 N N) rows, weights (3, m, 4);
    line rows (3, m, 2) into (3 N) rows, weights (3, m, 2). align_corners=True: -1 -> 0, 1 -> N-1."""
    g = (u.clamp(-1, 1) + 1) * (0.5 * (n - 1))  # (m, 3) in cell units
    i0 = g.floor().clamp(0, n - 2)
    f = g - i0
    i0 = i0.long()
    base = torch.arange(3, device=u.device).view(3, 1) * (n * n)
    xs = torch.stack([i0[:, a[0]] for a in PLANE_AXES])  # grid_sample's x = first coordinate = width
    ys = torch.stack([i0[:, a[1]] for a in PLANE_AXES])
    fx = torch.stack([f[:, a[0]] for a in PLANE_AXES])
    fy = torch.stack([f[:, a[1]] for a in PLANE_AXES])
    r00 = base + ys * n + xs
    rows = torch.stack([r00, r00 + 1, r00 + n, r00 + n + 1], dim=-1)
    w = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=-1)
    ly = torch.stack([i0[:, a] for a in LINE_AXIS]) + torch.arange(3, device=u.device).view(3, 1) * n
    lf = torch.stack([f[:, a] for a in LINE_AXIS])
    return rows, w, torch.stack([ly, ly + 1], dim=-1), torch.stack([1 - lf, lf], dim=-1)


def gather_vm(planes, lines, u):
    """The same (3, R, m) by hand: gather corner rows of row-major copies, weight, sum."""
    n, r, m = planes.shape[-1], planes.shape[1], u.shape[0]
    table = planes.permute(0, 2, 3, 1).reshape(-1, r)  # (3 N N, R): one row per cell corner
    ltable = lines.permute(0, 2, 3, 1).reshape(-1, r)  # (3 N, R)
    rows, w, lrows, lw = _taps(u, n)
    p = (table.index_select(0, rows.reshape(-1)).view(3, m, 4, r) * w.unsqueeze(-1)).sum(2)
    line = (ltable.index_select(0, lrows.reshape(-1)).view(3, m, 2, r) * lw.unsqueeze(-1)).sum(2)
    return (p * line).permute(0, 2, 1)  # (3, R, m)


def embedding_bag_vm(planes, lines, u):
    """The same (3, R, m) through ``F.embedding_bag(mode="sum", per_sample_weights)``."""
    n, r, m = planes.shape[-1], planes.shape[1], u.shape[0]
    table = planes.permute(0, 2, 3, 1).reshape(-1, r)
    ltable = lines.permute(0, 2, 3, 1).reshape(-1, r)
    rows, w, lrows, lw = _taps(u, n)
    p = F.embedding_bag(rows.reshape(-1, 4), table, per_sample_weights=w.reshape(-1, 4), mode="sum")
    line = F.embedding_bag(lrows.reshape(-1, 2), ltable, per_sample_weights=lw.reshape(-1, 2), mode="sum")
    return (p * line).view(3, m, r).permute(0, 2, 1)


def rowmajor_vm(tables, u, n, r):
    """``embedding_bag_vm`` on planes and lines *stored* row-major ((3 N N, R), (3 N, R) leaves): what a
    field keeping that layout as its parameters would pay (no per-step permute copies)."""
    table, ltable = tables
    m = u.shape[0]
    rows, w, lrows, lw = _taps(u, n)
    p = F.embedding_bag(rows.reshape(-1, 4), table, per_sample_weights=w.reshape(-1, 4), mode="sum")
    line = F.embedding_bag(lrows.reshape(-1, 2), ltable, per_sample_weights=lw.reshape(-1, 2), mode="sum")
    return (p * line).view(3, m, r).permute(0, 2, 1)


def step(fn, planes, lines, u, gout):
    """Forward and backward of ``fn``; the gradients are left in planes.grad / lines.grad."""
    planes.grad = lines.grad = None
    out = fn(planes, lines, u)
    out.backward(gout)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench_plane_lookup.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", type=int, default=160)
    ap.add_argument("--rank", type=int, default=16, help="components per plane (density 16, appearance 32)")
    ap.add_argument("--points", type=int, default=32768, help="samples looked up per call")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--compile", action="store_true", help="also time torch.compile of grid_sample_vm")
    ap.add_argument("--json", help="write the numbers here too")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    g = torch.Generator().manual_seed(0)
    planes = (0.1 * torch.randn(3, args.rank, args.res, args.res, generator=g)).requires_grad_()
    lines = (0.1 * torch.randn(3, args.rank, args.res, 1, generator=g)).requires_grad_()
    u = torch.rand(args.points, 3, generator=g) * 2 - 1
    gout = torch.randn(3, args.rank, args.points, generator=g)
    variants = {"grid_sample": grid_sample_vm, "gather": gather_vm, "embedding_bag": embedding_bag_vm}
    if args.compile:
        variants["compiled"] = torch.compile(grid_sample_vm)
    n, r = args.res, args.rank
    table = planes.detach().permute(0, 2, 3, 1).reshape(-1, r).clone().requires_grad_()
    ltable = lines.detach().permute(0, 2, 3, 1).reshape(-1, r).clone().requires_grad_()

    class RowMajor:  # holds the row-major leaves; .grad reads back in the planes' layout for the check
        def __call__(self, _planes, _lines, uu):
            return rowmajor_vm((table, ltable), uu, n, r)

    def rowmajor_step(_fn, _p, _l, uu, go):
        table.grad = ltable.grad = None
        out = rowmajor_vm((table, ltable), uu, n, r)
        out.backward(go)
        planes.grad = table.grad.view(3, n, n, r).permute(0, 3, 1, 2)
        lines.grad = ltable.grad.view(3, n, 1, r).permute(0, 3, 1, 2)
        return out

    variants["rowmajor"] = RowMajor()
    steppers = {"rowmajor": rowmajor_step}

    # The library's own path: nerf_core's vm_products on planes stored channels-last, as TensorVMField
    # keeps them (its native CPU kernel where that builds).
    from nerf_core.fields import vm_products

    pcl = vm_products.planes_to_stored(planes.detach()).requires_grad_()
    lcl = vm_products.lines_to_stored(lines.detach()).requires_grad_()

    def native_step(_fn, _p, _l, uu, go):
        pcl.grad = lcl.grad = None
        out = vm_products.vm_products(vm_products.planes_from_stored(pcl), vm_products.lines_from_stored(lcl), uu)
        out.backward(go.permute(2, 0, 1))
        planes.grad = vm_products.planes_from_stored(pcl.grad)
        lines.grad = vm_products.lines_from_stored(lcl.grad)
        return out.permute(1, 2, 0)  # (3, R, m) as the others

    name = "vm_products_" + vm_products.backend()[0]
    variants[name] = native_step  # never called directly: its stepper runs it
    steppers[name] = native_step
    ref = step(grid_sample_vm, planes, lines, u, gout).detach()
    ref_gp, ref_gl = planes.grad.clone(), lines.grad.clone()
    errors = {}
    for name, fn in variants.items():
        t0 = time.perf_counter()
        out = steppers.get(name, step)(fn, planes, lines, u, gout).detach()
        errors[name] = {"out": float((out - ref).abs().max()), "grad_planes": float((planes.grad - ref_gp).abs().max()),
                        "grad_lines": float((lines.grad - ref_gl).abs().max()),
                        "first_call_s": time.perf_counter() - t0}
        print(f"{name:14s} max |diff| out {errors[name]['out']:.2e} grad planes {errors[name]['grad_planes']:.2e} "
              f"lines {errors[name]['grad_lines']:.2e} (first call {errors[name]['first_call_s']:.2f} s)", flush=True)
    times = {name: [] for name in variants}
    for _ in range(args.repeats):
        for name, fn in variants.items():  # interleaved: each round runs every variant once
            t0 = time.perf_counter()
            steppers.get(name, step)(fn, planes, lines, u, gout)
            times[name].append(time.perf_counter() - t0)
    base = statistics.median(times["grid_sample"])
    report = {"shape": {"res": args.res, "rank": args.rank, "points": args.points, "threads": args.threads},
              "errors": errors, "median_ms": {}, "ratio_to_grid_sample": {}}
    for name, ts in times.items():
        med = statistics.median(ts)
        report["median_ms"][name] = round(1000 * med, 2)
        report["ratio_to_grid_sample"][name] = round(base / med, 3)
        print(f"{name:14s} {1000 * med:8.2f} ms median of {len(ts)} (min {1000 * min(ts):.2f}); "
              f"{base / med:.2f}x grid_sample's speed", flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
