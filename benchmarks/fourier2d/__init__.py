"""The 2D kernel-width study: how a coordinate MLP's input encoding (positional encoding, Fourier
features and their scale) sets the width of the kernel it interpolates with, fitted on one image.

Research code behind ``benchmarks/kernel_width.py`` and ``benchmarks/kernel_width_report.py``, kept out of
the ``nerf_core`` library: it uses ``nerf_core.fields.encodings`` and nothing depends on it.
- ``photo2d``: a real photograph (a crop of one of Blender's studio-light HDRIs) as the target;
- ``fit2d``: fitting and sweeping encodings on it.
"""
