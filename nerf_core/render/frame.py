"""Rendering one view: rays in chunks sized for the device, the pixel filter's extra rays where the
image has an edge, and straight (not premultiplied) RGBA.
"""
from __future__ import annotations

from typing import Callable, Dict, List, Optional

import numpy as np
import torch

from nerf_core.cameras.rays import Cameras, rays_for_pixels, rays_for_view
from nerf_core.image.pixel_filter import DEFAULT_SAMPLES, PixelFilter, edge_pixels
from nerf_core.methods.base import RadianceModel
from nerf_core.render.memory import DEFAULT_CHUNK, check_view_memory
from nerf_core.utils import arguments

# On the CPU a model call is fastest when its samples' intermediate tensors stay in cache: measured
# at one thread on trained runs, vmgrid renders 1.28x faster in calls of 1024 rays than of 8192 and
# no faster below 512; nerf (128 samples per ray) 1.21x faster at 1024 rays than at 4096, 1.44x again
# at 512, 1.27x at 256, 1.11x at 128: ~16k samples per call. Calls are at most the model's
# ``cpu_call_rays`` rays (``RadianceModel``: 512; vmgrid, whose samples are cheaper: 2048), fewer when
# the previous call reported more than CPU_SAMPLES_PER_CALL samples.
CPU_SAMPLES_PER_CALL = 1 << 14


CPU_MIN_CALL_RAYS = 64  # below this the per-call Python overhead dominates


@torch.no_grad()
def render_rays_chunked(
    model: RadianceModel,
    rays_o,
    rays_d,
    background,
    near=None,
    far=None,
    chunk: int = DEFAULT_CHUNK,
    on_chunk: Optional[Callable[[int, int], None]] = None,
) -> Dict[str, torch.Tensor]:
    """Evaluation rendering of (m, 3) camera rays (``model.render_batch``) in model calls of at most
    ``chunk`` rays to bound memory.

    On the CPU calls are smaller: at most the model's ``cpu_call_rays`` rays and about
    ``CPU_SAMPLES_PER_CALL`` samples, from the ``n_samples`` the model returned for the previous call
    (per-ray results do not depend on the call size).

    Args:
        model: the ``RadianceModel``; rays_o, rays_d: (m, 3) on its device.
        background: (3,) or (m, 3) colour behind the scene (the learned world replaces it).
        near, far: the dataset's ray bounds in scene units, or None.
        chunk: most rays per call; on_chunk: called as ``on_chunk(done, m)`` after each call
            (progress; it may raise to stop early).

    Returns:
        rgb (m, 3), depth (m,) (distance along the ray) and acc (m,) on the rays' device.
    """
    out: Dict[str, List[torch.Tensor]] = {"rgb": [], "depth": [], "acc": []}
    m = rays_o.shape[0]
    bg = background.expand(m, 3) if background.dim() == 1 else background
    cpu = rays_o.device.type == "cpu"
    cap = min(chunk, int(model.cpu_call_rays)) if cpu else chunk
    step = cap
    s = 0
    while s < m:
        e = min(s + step, m)
        res = model.render_batch(rays_o[s:e], rays_d[s:e], bg[s:e], near, far, training=False)
        for k in out:
            out[k].append(
                res[k].detach().float().reshape(res[k].shape[0], -1).squeeze(-1)
                if k != "rgb"
                else res[k].detach().float()
            )
        if cpu and "n_samples" in res:
            per_ray = max(1.0, float(res["n_samples"]) / (e - s))
            step = int(min(cap, max(CPU_MIN_CALL_RAYS, CPU_SAMPLES_PER_CALL / per_ray)))
        s = e
        if on_chunk is not None:
            on_chunk(e, m)
    return {k: torch.cat(v) for k, v in out.items()}


@torch.no_grad()
def render_view(
    model,
    cameras: Cameras,
    view: int,
    background=(1.0, 1.0, 1.0),
    near: Optional[float] = None,
    far: Optional[float] = None,
    chunk: int = DEFAULT_CHUNK,
    on_chunk: Optional[Callable[[int, int], None]] = None,
    pixel_filter: Optional[PixelFilter] = None,
    filter_samples: int = DEFAULT_SAMPLES,
) -> Dict[str, torch.Tensor]:
    """Render a whole camera on the model's device (``on_chunk``: see ``render_rays_chunked``).

    Runs without gradients, over the model's own ray interval (the scene box clipped to ``near``/``far``).

    Args:
        model: a ``RadianceModel`` (eval mode; its device is ``model.aabb.device``).
        cameras: the ``Cameras``; view ``view`` is (h, w) = (``height[view]``, ``width[view]``).
        view: index of the camera.
        background: (3,) colour in [0, 1] behind the scene (a tuple or tensor).
        near, far: the dataset's ray bounds in scene units (``Dataset.near``/``far`` or the run config's),
            or None.
        chunk: most rays per model call (fewer on the CPU, where small calls are faster).
        on_chunk: called as ``on_chunk(done, h * w)`` after each call (progress; it may raise to stop).
        pixel_filter: the film's filter (``nerf_core.image.pixel_filter``, e.g. ``Dataset.pixel_filter``):
            pixels at an edge of the centre-ray image become the mean of ``filter_samples`` rays drawn
            from it, as Cycles renders them; None (or the filter "NONE"): one ray through each pixel centre.
        filter_samples: rays per edge pixel with a ``pixel_filter``.

    Returns:
        dict of CPU tensors: ``rgb`` (h, w, 3) float32 in [0, 1] composited onto ``background`` (onto
        the model's learned environment instead when it has one), ``acc`` (h, w) float32 opacity in
        [0, 1], ``depth`` (h, w) float32 distance along the ray (as the method reports it; the built-in
        methods normalise it by acc) and ``z_depth`` (h, w) float32 planar depth along the camera's -Z
        (0 where acc < 0.5);
        plus ``n_rays``, an int (not a tensor): rays rendered, one a pixel and the filter's at edges.

    Raises:
        RunError: the view is too large to render in the memory available (``render.memory``).
    """
    if view is None:
        raise TypeError("render_view: view must be an integer index of cameras, got None")
    check_render_arguments("render_view", model, cameras, view, background, near, far, chunk)
    filter_samples = arguments.integer("render_view", "filter_samples", filter_samples, low=1)
    h, w = int(cameras.height[view]), int(cameras.width[view])
    check_view_memory(w, h, f"view {view}")
    rays_o, rays_d, z_per_t = rays_for_view(cameras, view)
    res = render_rays_of(model, rays_o, rays_d, background, near, far, chunk, on_chunk)
    rgb, acc = res["rgb"].cpu().clamp(0, 1).reshape(h, w, 3), res["acc"].clamp(0, 1).cpu().reshape(h, w)
    # Whether a model's depth is already divided by acc is method-specific; dividing again would be
    # wrong, so only use acc to mark empty pixels.
    dist = res["depth"].cpu().reshape(h, w)
    z = dist * z_per_t.reshape(h, w)
    n_rays = h * w
    if pixel_filter is not None and not pixel_filter.is_point and filter_samples > 1:
        rgb, acc, dist, z, n_rays = filter_edges(model, cameras, view, rgb, acc, dist, z, pixel_filter, filter_samples,
                                                  background, near, far, chunk, on_chunk)
    return {
        "rgb": rgb,
        "acc": acc,
        "depth": dist,
        "z_depth": torch.where(acc >= 0.5, z, torch.zeros_like(z)),
        "n_rays": n_rays,  # rays rendered: one a pixel, and the filter's at edges
    }


def check_render_arguments(func: str, model, cameras, view, background, near, far, chunk) -> None:
    """The public boundary of ``render_view`` (ValueError/TypeError naming the argument); ``view`` None: not given."""
    if not isinstance(model, RadianceModel):
        raise TypeError(f"{func}: model must be a RadianceModel (from build_model or open_run), got {model!r:.60}")
    if view is not None:  # render_view's camera (evaluate_split passes None for both)
        arguments.instance(func, "cameras", cameras, Cameras, "a nerf_core.Cameras")
        arguments.integer(func, "view", view, low=0, high=len(cameras) - 1)
    arguments.colour(func, "background", background)
    near = None if near is None else arguments.number(func, "near", near, low=0.0)
    far = None if far is None else arguments.number(func, "far", far, above=0.0)
    if near is not None and far is not None and far <= near:
        raise ValueError(f"{func}: far ({far}) must be greater than near ({near})")
    arguments.integer(func, "chunk", chunk, low=1)


def render_rays_of(model, rays_o, rays_d, background, near, far, chunk, on_chunk) -> Dict[str, torch.Tensor]:
    """``render_rays_chunked`` of camera rays (origins (m, 3) or (1, 3), unit directions (m, 3)) on the
    model's device."""
    device = model.aabb.device
    rays_o = rays_o.expand_as(rays_d).to(device)
    rays_d = rays_d.to(device)
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    return render_rays_chunked(model, rays_o, rays_d, bg, near, far, chunk, on_chunk)


def filter_edges(model, cameras: Cameras, view: int, rgb: torch.Tensor, acc: torch.Tensor, dist: torch.Tensor,
                  z: torch.Tensor, pixel_filter: PixelFilter, samples: int, background, near, far, chunk,
                  on_chunk) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """rgb (h, w, 3) and acc (h, w) with every pixel at an edge of the centre-ray image (colour or
    opacity, ``pixel_filter.edge_pixels``) replaced by the mean of ``samples`` rays drawn from the
    filter; its distance ``dist`` and z-depth ``z`` (h, w) by those rays' opacity-weighted mean (the
    depth of what covers the pixel, so a pixel the filter makes opaque has one); and the number of
    rays rendered in all.

    A render of part of a frame (a Blender Render Region: the same camera, its principal point moved
    into the crop) gives its pixels what the whole frame gives them: edges are found with the pixels
    one beyond the image rendered too, and each pixel's draws are a hash of its place relative to the
    principal point (``PixelFilter.offsets``), not of its place in the request."""
    h, w = rgb.shape[:2]
    total = h * w
    # the one-pixel ring around the image, through offsets from the nearest pixel inside (a lens
    # camera's per-pixel tables cover only the image)
    ring_i = torch.cat([torch.arange(-1, w + 1), torch.arange(-1, w + 1), torch.full((h,), -1), torch.full((h,), w)])
    ring_j = torch.cat([torch.full((w + 2,), -1), torch.full((w + 2,), h), torch.arange(h), torch.arange(h)])
    inside_i, inside_j = ring_i.clamp(0, w - 1), ring_j.clamp(0, h - 1)
    step = torch.stack([ring_i - inside_i, ring_j - inside_j], dim=-1).float()
    views = torch.full((ring_i.shape[0],), int(view), dtype=torch.long)
    o, d, _ = rays_for_pixels(cameras, views, inside_i, inside_j, step)
    ring = render_rays_of(model, o, d, background, near, far, chunk, None)
    # Edges of the scene itself, premultiplied, whatever fixed colour lies behind it: render (on black)
    # and eval (on white) refine the same pixels. A learned world is part of the picture.
    behind = None if model.models_world else torch.as_tensor(background, dtype=torch.float32)

    def scene_layer(c: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        c = c if behind is None else c - (1 - a).unsqueeze(-1) * behind
        return torch.cat([c, a.unsqueeze(-1)], dim=-1)

    padded = torch.zeros(h + 2, w + 2, 4)
    padded[1:-1, 1:-1] = scene_layer(rgb, acc)
    padded[ring_j + 1, ring_i + 1] = scene_layer(ring["rgb"].cpu().clamp(0, 1), ring["acc"].cpu().clamp(0, 1))
    jj, ii = edge_pixels(padded)[1:-1, 1:-1].nonzero(as_tuple=True)
    q = int(jj.shape[0])
    if q == 0:
        return rgb, acc, dist, z, total + ring_i.shape[0]
    keys = torch.stack([torch.round(ii.double() + 0.5 - float(cameras.cx[view])),
                        torch.round(jj.double() + 0.5 - float(cameras.cy[view]))], dim=-1).long()
    off = pixel_filter.offsets(q, samples, keys=keys).reshape(-1, 2)
    views = torch.full((q * samples,), int(view), dtype=torch.long)
    rays_o, rays_d, z_per_t = rays_for_pixels(
        cameras, views, ii.repeat_interleave(samples), jj.repeat_interleave(samples), off
    )
    # The centre pass has reported the whole view; these calls only let ``on_chunk`` stop the render.
    res = render_rays_of(model, rays_o, rays_d, background, near, far, chunk,
                          None if on_chunk is None else (lambda done, m: on_chunk(total, total)))
    rgb, acc, dist, z = rgb.clone(), acc.clone(), dist.clone(), z.clone()
    rgb[jj, ii] = res["rgb"].cpu().clamp(0, 1).reshape(q, samples, 3).mean(dim=1)
    a = res["acc"].cpu().clamp(0, 1).reshape(q, samples)
    acc[jj, ii] = a.mean(dim=1)
    d = res["depth"].cpu().reshape(q, samples)
    hit = a.sum(dim=1) > 1e-6  # where no filter ray hits anything the centre ray's depth stays
    wsum = a.sum(dim=1).clamp_min(1e-6)
    dist[jj[hit], ii[hit]] = ((a * d).sum(dim=1) / wsum)[hit]
    z[jj[hit], ii[hit]] = ((a * d * z_per_t.cpu().reshape(q, samples)).sum(dim=1) / wsum)[hit]
    return rgb, acc, dist, z, total + ring_i.shape[0] + q * samples


def straight_rgba(res: Dict[str, torch.Tensor], opaque: bool) -> np.ndarray:
    """(h, w, 4) float32 RGBA with straight colour from ``render_view(..., background=(0, 0, 0))``.

    ``opaque`` (a run with a learned world): what the camera sees, background included, alpha 1,
    like the opaque capture it was trained on. Otherwise alpha = accumulated opacity.
    """
    acc = res["acc"]
    if opaque:
        return torch.cat([res["rgb"].clamp(0, 1), torch.ones_like(acc)[..., None]], -1).numpy()
    # Rendered onto black, the result is premultiplied: dividing by acc gives straight colour for RGBA.
    rgb = torch.where(acc[..., None] > 1e-6, res["rgb"] / acc[..., None].clamp_min(1e-6), torch.zeros_like(res["rgb"]))
    return torch.cat([rgb.clamp(0, 1), acc[..., None]], -1).numpy()
