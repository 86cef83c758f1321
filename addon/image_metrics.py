"""Image comparison in plain numpy (Blender's Python has numpy but not torch): PSNR, SSIM, error heat-map.

Images are float arrays (height, width, 3) in [0, 1]; RGBA inputs are composited onto a background
first (``composite``), exactly as NeRF loaders do with transparent PNGs. ``write_png`` needs only
the standard library, so heat-maps can be written from inside Blender.
"""
from __future__ import annotations

import errno
import os
import struct
import zlib

import numpy as np

# A perceptually ordered dark-to-bright map (stops sampled from matplotlib's "inferno"), so that
# larger errors read as brighter in any viewer, including for colour-blind users.
_INFERNO = np.array([
    [0.001, 0.000, 0.014], [0.133, 0.047, 0.329], [0.341, 0.062, 0.429], [0.550, 0.161, 0.506],
    [0.735, 0.216, 0.330], [0.894, 0.366, 0.176], [0.978, 0.557, 0.035], [0.973, 0.804, 0.188],
    [0.988, 0.998, 0.645],
], dtype=np.float32)


def composite(image: np.ndarray, background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(h, w, 3|4) -> (h, w, 3): RGBA composited over ``background`` (straight alpha); RGB unchanged."""
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"expected an (h, w, 3) or (h, w, 4) image, got shape {image.shape}")
    if image.shape[2] == 3:
        return image
    alpha = image[..., 3:4]
    return image[..., :3] * alpha + np.asarray(background, dtype=np.float32)[:3] * (1.0 - alpha)


def _check_pair(a: np.ndarray, b: np.ndarray) -> tuple:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape} vs {b.shape}")
    return a, b


def psnr(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB over all pixels and channels; inf for identical images."""
    a, b = _check_pair(a, b)
    mse = float(np.mean((a - b) ** 2))
    if mse == 0.0:
        return float("inf")
    return 10.0 * np.log10(data_range ** 2 / mse)


def _gaussian_kernel(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def _filter_valid(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Separable 'valid' correlation of (h, w, c) with a 1D kernel along both image axes."""
    n = len(kernel)
    h, w = img.shape[:2]
    rows = sum(kernel[i] * img[i : h - n + 1 + i] for i in range(n))
    return sum(kernel[i] * rows[:, i : w - n + 1 + i] for i in range(n))


def ssim(a: np.ndarray, b: np.ndarray, data_range: float = 1.0, win_size: int = 11, sigma: float = 1.5) -> float:
    """Structural similarity (Wang et al. 2004): Gaussian 11x11 window, sigma 1.5, K1 0.01, K2 0.03,
    averaged over valid windows and channels, the setting NeRF papers report."""
    a, b = _check_pair(a, b)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    if min(a.shape[:2]) < win_size:
        raise ValueError(f"images of {a.shape[1]}x{a.shape[0]} are smaller than the {win_size}px SSIM window")
    k = _gaussian_kernel(win_size, sigma)
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    mu_a = _filter_valid(a, k)
    mu_b = _filter_valid(b, k)
    var_a = _filter_valid(a * a, k) - mu_a ** 2
    var_b = _filter_valid(b * b, k) - mu_b ** 2
    cov = _filter_valid(a * b, k) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2)
    return float(np.mean(num / den))


def error_heatmap(a: np.ndarray, b: np.ndarray, vmax: float = 0.25) -> np.ndarray:
    """(h, w, 3) colour image of the per-pixel mean absolute error, ``vmax`` and above at full scale.

    A fixed scale (not the image's own maximum) keeps heat-maps of different views comparable.
    """
    a, b = _check_pair(a, b)
    err = np.mean(np.abs(a - b), axis=-1) if a.ndim == 3 else np.abs(a - b)
    t = np.clip(err / vmax, 0.0, 1.0) * (len(_INFERNO) - 1)
    lo = np.floor(t).astype(np.int64)
    hi = np.minimum(lo + 1, len(_INFERNO) - 1)
    frac = (t - lo)[..., None].astype(np.float32)
    return _INFERNO[lo] * (1.0 - frac) + _INFERNO[hi] * frac


def write_png(path: str, image: np.ndarray) -> None:
    """Write (h, w, 3|4) floats in [0, 1] (row 0 at the top) as an 8-bit PNG, standard library only.

    Written to a temporary file first, so a full disk never leaves a truncated PNG (OSError with
    errno ENOSPC names the file).
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"{path}: expected an (h, w, 3) or (h, w, 4) image, got shape {image.shape}")
    h, w, c = image.shape
    data = np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), data.reshape(h, w * c)], axis=1).tobytes()

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload))

    colour_type = 6 if c == 4 else 2
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, "wb") as fh:
            fh.write(png)
        os.replace(tmp, path)
    except OSError as exc:
        if os.path.exists(tmp):
            os.remove(tmp)
        if exc.errno == errno.ENOSPC:
            raise OSError(errno.ENOSPC, f"Disk full while writing {path}") from exc
        raise
