"""Reading one frame's pixels: the image (PNG or EXR) checked and box-downscaled, its intrinsics at that
scale, a distorting lens folded into a pinhole, and its extras (depth, normals, mask).
"""
from __future__ import annotations

import functools

import numpy as np

from nerf_core.cameras.distortion import fold_pixel
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.intrinsics import resolve_intrinsics
from nerf_core.contract.lens import DISTORTION_KEYS
from nerf_core.contract.paths import why_not_a_file
from nerf_core.contract.transforms import FrameInfo
from nerf_core.errors import ImageReadError
from nerf_core.image.io import (
    read_depth,
    read_exr_rgba,
    read_mask,
    read_normals,
    read_png,
)

# Per-frame extra channels: Split attribute -> (FrameInfo attribute, JSON field named in errors, reader,
# value where a frame has none). Depth 0 = unknown; normals 0 = none; a missing mask keeps every pixel.
EXTRAS = {
    "depth": ("depth", "depth_file_path", None, lambda h, w: np.zeros((h, w), np.float32)),
    "normals": ("normal", "normal_file_path", read_normals, lambda h, w: np.zeros((h, w, 3), np.float32)),
    "masks": ("mask", "mask_path", read_mask, lambda h, w: np.ones((h, w), bool)),
}


def checked_float_pixels(fr: FrameInfo, img: np.ndarray) -> np.ndarray:
    """Float (EXR) pixels (h, w, 3|4) that training can use: NaN or infinite values (a failed render or
    a broken writer) and alpha outside [0, 1] are refused, naming the image and the first pixel;
    colours may exceed 1 (HDR), but light is never negative: those values are clipped to 0."""
    bad = ~np.isfinite(img).all(axis=-1)
    if bad.any():
        y, x = (int(v) for v in np.argwhere(bad)[0])
        raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} has {int(bad.sum())} pixel(s) with NaN or "
                           f"infinite values (the first at x={x}, y={y}); re-render or repair the image")
    if img.shape[-1] == 4:
        a = img[..., 3]
        out = (a < -1e-3) | (a > 1 + 1e-3)
        if out.any():
            y, x = (int(v) for v in np.argwhere(out)[0])
            raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} has alpha {float(a[y, x]):.4g} at x={x}, "
                               f"y={y}; alpha is a coverage in [0, 1]")
        img = img.copy()
        img[..., 3] = np.clip(a, 0.0, 1.0)
    return np.maximum(img, 0.0) if (img[..., :3] < 0).any() else img


def load_pixels(fr: FrameInfo, downscale: int) -> tuple[np.ndarray, tuple[int, int]]:
    """(image as loaded, downscaled by ``downscale``; (width, height) of the file itself)."""
    if not fr.image.is_file():
        raise DatasetError(f"{fr.where}: field 'file_path': image {fr.image} {why_not_a_file(fr.image, fr.file_path)}")
    try:
        if fr.image.suffix.lower() == ".exr":
            img = checked_float_pixels(fr, read_exr_rgba(fr.image))
        else:
            img = read_png(fr.image)
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=-1)
            if fr.alpha is not None:
                img = restore_film(fr, img)
            if img.dtype == np.uint16:  # 16-bit PNG: keep the precision as float
                img = img.astype(np.float32) / 65535.0
            elif img.dtype != np.uint8:
                raise DatasetError(f"{fr.where}: field 'file_path': unsupported pixel type {img.dtype} in {fr.image}")
    except ImageReadError as exc:
        raise DatasetError(f"{fr.where}: field 'file_path': {exc}") from exc
    if img.shape[-1] not in (3, 4):
        raise DatasetError(
            f"{fr.where}: field 'file_path': {fr.image} has {img.shape[-1]} channels, expected RGB or RGBA"
        )
    if downscale > 1:
        if img.shape[0] < downscale or img.shape[1] < downscale:
            raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} is {img.shape[1]}x{img.shape[0]} px; "
                               f"downscaled by {downscale} it would have no pixels (--downscale must be at most "
                               f"{min(img.shape[:2])})")
    full = (int(img.shape[1]), int(img.shape[0]))
    if downscale > 1:
        img = downscale_image(img, downscale)
    return img, full


def restore_film(fr: FrameInfo, rgb: np.ndarray) -> np.ndarray:
    """The RGBA film (h, w, 4) uint8 of an RGB image composited onto white with the 8-bit alpha in
    ``fr.alpha`` (our COLMAP export): colour = (composite - (1 - a)) / a, 0 where a = 0."""
    a = read_png(fr.alpha)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3 or a.dtype != np.uint8 or a.shape != rgb.shape[:2]:
        raise DatasetError(f"{fr.where}: {fr.alpha} is not the 8-bit alpha of {fr.image} (another size or kind)")
    af = a.astype(np.float32)[..., None]
    colour = (rgb.astype(np.float32) - (255.0 - af)) * 255.0 / np.maximum(af, 1.0)
    colour = np.where(af > 0, np.clip(colour + 0.5, 0, 255), 0).astype(np.uint8)
    return np.concatenate([colour, a[..., None]], axis=-1)


def downscale_image(img: np.ndarray, f: int) -> np.ndarray:
    """Box-filter by an integer factor, averaging colours premultiplied by alpha so edges do not darken."""
    h, w = img.shape[0] // f, img.shape[1] // f
    x = img[: h * f, : w * f].astype(np.float32)
    if img.dtype == np.uint8:
        x = x / 255.0
    if x.shape[-1] == 4:
        x = np.concatenate([x[..., :3] * x[..., 3:], x[..., 3:]], -1)
    x = x.reshape(h, f, w, f, -1).mean(axis=(1, 3))
    if x.shape[-1] == 4:
        a = x[..., 3:]
        x = np.concatenate([np.where(a > 0, x[..., :3] / np.maximum(a, 1e-8), 0.0), a], -1)
    if img.dtype == np.uint8:
        return (np.clip(x, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    return x.astype(np.float32)


def resize_map(m: np.ndarray, f: int, mode: str) -> np.ndarray:
    h, w = m.shape[0] // f, m.shape[1] // f
    m = m[: h * f, : w * f]
    if mode == "nearest":
        return m[f // 2 :: f, f // 2 :: f][:h, :w]
    return m.reshape(h, f, w, f, *m.shape[2:]).mean(axis=(1, 3))


def camera_params(fr: FrameInfo, full_w: int, full_h: int, downscale: int) -> tuple:
    """(fx, fy, cx, cy) of ``fr`` for its image as loaded: ``full_w`` x ``full_h`` px in the file,
    downscaled by ``downscale`` = F (``downscale_image``: cropped to a multiple of F at the right and bottom,
    then box-filtered). Pixel (u, v) of the loaded image averages file pixels [F u, F u + F), so every
    intrinsic divides by F exactly; scaling by the size ratio instead ((W // F) / W) moved the cameras
    of an image whose size F does not divide (35 px at F = 4: 0.44 px at the centre)."""
    w_decl, h_decl = fr.intrinsics.get("w"), fr.intrinsics.get("h")
    # The declared size is checked against the file's: a wrong w/h would silently rescale the focal.
    # Either one alone is checked too: a lone 'w' of twice the image width halved the focal length.
    if ((w_decl is not None and int(w_decl) != full_w) or (h_decl is not None and int(h_decl) != full_h)):
        said = "x".join(str(int(v)) if v is not None else "?" for v in (w_decl, h_decl))
        raise DatasetError(f"{fr.where}: fields 'w'/'h' say {said} but {fr.image} is {full_w}x{full_h}")
    fx, fy, cx, cy, W, H = resolve_intrinsics(fr.intrinsics, None, (full_w, full_h), fr.where)
    if fr.lens is not None:
        at = lens_fold(fx, fy, cx, cy, int(W), int(H), fr.lens.coeffs, fr.lens.fisheye)
        if at is not None:
            named = [repr(k) for k, c in zip(DISTORTION_KEYS, fr.lens.coeffs) if c != 0.0] or ["'camera_model'"]
            raise DatasetError(
                f"{fr.where}: field{'s' * (len(named) > 1)} {', '.join(named)}: this {fr.lens.model} distortion "
                "cannot be undone over the whole "
                f"{int(W)}x{int(H)} image: near pixel ({at[0]:.0f}, {at[1]:.0f}) it turns back, so two pixels would "
                "see one ray. Check the coefficients and the image size they were calibrated for"
            )
    f = float(downscale)
    return fx / f, fy / f, cx / f, cy / f


@functools.lru_cache(maxsize=256)
def lens_fold(fx, fy, cx, cy, w, h, coeffs, fisheye):
    """``lens.fold_pixel``, once per distinct camera (a dataset repeats one lens in every frame)."""
    return fold_pixel(fx, fy, cx, cy, w, h, coeffs, fisheye)


def load_extra(attr: str, fr: FrameInfo, h: int, w: int, downscale: int, depth_scale: float) -> np.ndarray:
    """One frame's depth (h, w) float32, normals (h, w, 3) float32 or mask (h, w) bool (``EXTRAS``),
    resized like its image (nearest: averaging depths or normals across an edge would invent surfaces)."""
    fr_attr, json_field, reader, missing = EXTRAS[attr]
    path = getattr(fr, fr_attr)
    if path is None:
        return missing(h, w)
    if not path.is_file():
        raise DatasetError(f"{fr.where}: field {json_field!r}: {path} {why_not_a_file(path)}")
    try:
        m = read_depth(path, png_scale=depth_scale) if attr == "depth" else reader(path)
    except ImageReadError as exc:
        raise DatasetError(f"{fr.where}: field {json_field!r}: {exc}") from exc
    if downscale > 1:
        m = resize_map(m, downscale, "nearest")
    if m.shape[:2] != (h, w):
        raise DatasetError(f"{fr.where}: field {json_field!r}: {path} is {m.shape[1]}x{m.shape[0]}, image is {w}x{h}")
    return m
