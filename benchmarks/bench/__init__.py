"""The benchmark and stability studies' shared machinery (``benchmarks/benchmark.py``, ``benchmarks/stability.py``,
``benchmarks/bench_render.py``).

Imported as ``bench`` with ``benchmarks/`` and ``scripts/`` on sys.path (the entry scripts put them there):

- ``runner``: running the command-line tools, their JSON-line events, parallel jobs, the machine;
- ``datasets``: capturing demo scenes once and reusing them; derived datasets (subsets, noisy poses);
- ``analysis``: training summaries, floaters, mean/spread, Pareto fronts, the benchmark's tables;
- ``report``: CSV/JSON/markdown writers and the charts;
- ``plan``: what a benchmark run trains (scenes, series, checkpoints, size presets);
- ``profiler``: the in-process per-stage profile of a training step;
- ``render_speed``: training against rendering rays/s (``benchmarks/bench_render.py``).

Only ``profiler`` (when called) and ``plan.default_fast_method`` import torch.
"""
