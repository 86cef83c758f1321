"""Volume rendering as flat functions, in the style of nerfacc: samples along rays, their weights and
what they add up to. Shapes are in each function's docstring; "packed" functions take samples of
many rays in one flat (n_samples,) array with ``ray_indices``.

- ``volrend``: transmittance, weights, accumulation, background compositing (dense and packed);
- ``sampling``: box intersection, stratified, importance and occupancy-guided samples;
- ``occupancy``: ``OccupancyGrid``, to skip empty space; ``ray_termination``: early termination;
- ``contraction``: mip-NeRF 360 scene contraction; ``grad_scaling``: near-camera gradient scaling.
"""
from nerf_core.volume.contraction import squeeze_into_outer_box
from nerf_core.volume.occupancy import OccupancyGrid
from nerf_core.volume.ray_termination import visible_samples
from nerf_core.volume.sampling import importance_samples, ray_aabb_intersect, stratified_samples
from nerf_core.volume.volrend import (
    accumulate_along_rays,
    accumulate_along_rays_packed,
    composite_background,
    distortion_loss_packed,
    packed_info_from_ray_indices,
    render_transmittance_from_density,
    render_transmittance_from_density_packed,
    render_weight_from_density,
    render_weight_from_density_packed,
)

__all__ = [
    "accumulate_along_rays", "accumulate_along_rays_packed", "composite_background",
    "distortion_loss_packed", "importance_samples", "OccupancyGrid", "packed_info_from_ray_indices",
    "ray_aabb_intersect", "render_transmittance_from_density", "render_transmittance_from_density_packed",
    "render_weight_from_density", "render_weight_from_density_packed", "squeeze_into_outer_box", "stratified_samples",
    "visible_samples",
]
