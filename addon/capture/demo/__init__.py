"""The procedural demo scenes (``scenes``) and how each wants to be captured (``capture_flags``, plain
Python: the benchmarks and ``scripts/demo.py`` load it by path)."""
