"""benchmarks/vmgrid200/error_breakdown.py: the pixel kinds it splits a view into."""
from __future__ import annotations

import importlib.util
import os

import torch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_spec = importlib.util.spec_from_file_location(
    "error_breakdown", os.path.join(ROOT, "benchmarks", "vmgrid200", "error_breakdown.py"))
eb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(eb)


def test_kinds_split_a_view_into_background_silhouette_texture_edges_and_flat():
    # A 16x16 view on white: an opaque square at columns/rows 3..12, its left half black, right half grey.
    alpha = torch.zeros(16, 16)
    alpha[3:13, 3:13] = 1.0
    gt = torch.ones(16, 16, 3)
    gt[3:13, 3:8] = 0.0
    gt[3:13, 8:13] = 0.5
    k = eb.kinds(gt, alpha)
    stack = torch.stack([k[n] for n in eb.KINDS])
    assert (stack.sum(0) == 1).all()  # disjoint and covering
    # Silhouette: within one pixel of the alpha step, on both sides of it.
    assert k["silhouette"][2, 5] and k["silhouette"][3, 5] and k["silhouette"][13, 5] and k["silhouette"][7, 4]
    assert k["background"][0, 0] and not k["background"][2, 5]
    # The black/grey step inside the square (between columns 7 and 8) is a texture edge there.
    assert k["texture edge"][7, 7] and k["texture edge"][7, 8] and k["texture edge"][7, 9]
    assert k["flat"][7, 5] and k["flat"][7, 10] and not k["flat"][7, 7]
    assert int(k["texture edge"].sum()) == 3 * 7  # rows 5..11; rows 2-4 and 12-14 are silhouette
    # The run's name: the scene folder when the run folder is named for its method.
    assert eb.run_name("/x/multi/vmgrid") == "multi" and eb.run_name("/x/my_run") == "my_run"
