"""Reading and writing the image files of datasets and renders (PNG through Pillow, EXR through OpenEXR).

Every reader raises ``ImageReadError`` naming the file, so callers can turn it into a dataset error
without a deep traceback. Writers go through a temporary file and a rename so that an interrupted
render never leaves a truncated image behind.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Dict, Optional, Sequence

import numpy as np
from PIL import Image

from nerf_core.contract.eight_bit import to_8bit
from nerf_core.errors import ImageReadError
from nerf_core.utils.atomic import atomic_file, atomic_path


def _openexr(path: Path | str, doing: str):
    """The OpenEXR module, imported on first use (PNG-only work never needs it). A Python without it
    (a broken install: it is a declared dependency) gets an ImageReadError naming the file, which the
    CLI prints as one line, rather than a traceback."""
    try:
        import OpenEXR
    except ImportError as exc:
        raise ImageReadError(f"{path}: {doing} an EXR needs the OpenEXR package, which this Python lacks "
                             f"({exc}); install it with: pip install 'openexr>=3.2,<4'") from exc
    return OpenEXR


def read_png(path: Path | str) -> np.ndarray:
    """An 8- or 16-bit PNG/JPEG as an array (h, w) or (h, w, c), keeping its dtype (uint8 or uint16)."""

    path = Path(path)
    if not path.is_file():
        raise ImageReadError(f"{path}: file not found")
    try:
        with warnings.catch_warnings():
            # Pillow warns (as a raw two-line Python warning) past 89 MP and refuses past twice that;
            # the refusal is reported below with the file's name, and a large real photo just loads.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                im.load()
                if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                    arr = np.asarray(im).astype(np.uint16 if im.mode != "I" else np.int32)
                elif im.mode in ("P", "PA", "LA", "CMYK", "YCbCr", "1") or (
                        im.mode in ("RGB", "L") and "transparency" in im.info):
                    # A tRNS chunk (one colour that is transparent) is alpha too, in RGB and grey PNGs
                    # as in palette ones: a cut-out saved that way is not an opaque image.
                    arr = np.asarray(im.convert("RGBA" if "A" in im.mode or "transparency" in im.info else "RGB"))
                else:
                    arr = np.asarray(im)
    except ImageReadError:
        raise
    except Exception as exc:  # Pillow raises many types for corrupt files
        raise ImageReadError(f"{path}: cannot read image ({exc})") from exc
    return arr


def png_info(path: Path | str) -> tuple[int, int, str, int]:
    """(width, height, mode, bits per channel) of an image without decoding its pixels.

    ``mode`` is Pillow's, prefixed with the format when the content is not what the suffix says
    ("JPEG RGB" for a JPEG named .png). ``bits`` is the file's own depth: Pillow opens a 16-bit RGB(A)
    PNG as 8-bit "RGBA", so the depth is read from the PNG header (IHDR) itself; loaders that divide
    by 255 (the original NeRF's imageio) read such a file as values up to 257.
    """

    path = Path(path)
    try:
        with Image.open(path) as im:
            bits = 16 if im.mode.startswith("I;16") or im.mode == "I" else 8
            if im.format == "PNG":
                with open(path, "rb") as fh:
                    head = fh.read(26)  # signature (8), IHDR length and type (8), w, h (8), depth, colour type
                if len(head) == 26 and head[12:16] == b"IHDR":
                    bits = head[24]
            mode = im.mode
            named = Image.registered_extensions().get(path.suffix.lower())  # ".tif" -> "TIFF", ".jpg" -> "JPEG"
            if im.format and named and im.format != named:
                mode = f"{im.format} {mode}"
            return im.width, im.height, mode, bits
    except FileNotFoundError as exc:
        raise ImageReadError(f"{path}: file not found") from exc
    except Exception as exc:
        raise ImageReadError(f"{path}: cannot read image ({exc})") from exc


def read_exr(path: Path | str) -> Dict[str, np.ndarray]:
    """All channels of an EXR as float32 arrays (h, w), keyed by channel name (``R``, ``Z``,
    ``ViewLayer.Combined.R`` ...), from every part: Blender 5 writes a multilayer EXR as one part
    per pass, and reading the first part alone would see only one pass."""
    OpenEXR = _openexr(path, "reading")

    path = Path(path)
    if not path.is_file():
        raise ImageReadError(f"{path}: file not found")
    try:
        with OpenEXR.File(str(path), header_only=True) as f:
            claimed = sum(
                _window_pixels(part.header) * max(1, len(part.header.get("channels") or ())) for part in f.parts
            )
    except Exception as exc:
        raise ImageReadError(f"{path}: cannot read EXR ({exc})") from exc
    if claimed > MAX_EXR_VALUES:
        raise ImageReadError(
            f"{path}: the EXR header claims {claimed / 1e6:.0f} million values "
            f"(more than {MAX_EXR_VALUES / 1e6:.0f} million, {4 * claimed / 2**30:.1f} GiB as float32); "
            "damaged, or far larger than a dataset image"
        )
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            out: Dict[str, np.ndarray] = {}
            for part in f.parts:
                for name, ch in part.channels.items():
                    out.setdefault(name, np.asarray(ch.pixels, dtype=np.float32))
            return out
    except Exception as exc:
        raise ImageReadError(f"{path}: cannot read EXR ({exc})") from exc


# Values (pixels x channels, over all parts) an EXR may hold: 8k x 8k RGBA with depth and normals
# (about 550 million). A damaged header that claims more would otherwise make OpenEXR allocate it
# (13 GiB for 60000 x 60000) before failing.
MAX_EXR_VALUES = 8192 * 8192 * 8


def _window_pixels(header: dict) -> int:
    """Pixels in an EXR part's ``dataWindow`` (0 when the header has none)."""
    window = header.get("dataWindow")
    if window is None:
        return 0
    lo, hi = (np.asarray(v, dtype=np.int64) for v in window)
    w, h = (hi - lo + 1).tolist()
    return max(0, w) * max(0, h)


def _layers(channels: Dict[str, np.ndarray]) -> Dict[str, Dict[str, np.ndarray]]:
    """Channels grouped by layer: ``ViewLayer.Combined.R`` -> ``{"ViewLayer.Combined": {"R": ...}}``;
    the channels of a plain EXR (``R``, ``Z``) form the layer ``""``."""
    layers: Dict[str, Dict[str, np.ndarray]] = {}
    for key, value in channels.items():
        layer, _, name = key.rpartition(".")
        layers.setdefault(layer, {})[name] = value
    return layers


def _first(chans: Dict[str, np.ndarray], names: Sequence[str]) -> Optional[np.ndarray]:
    return next((chans[n] for n in names if n in chans), None)


def _pick_layer(path: Path, channels: Dict[str, np.ndarray], needs: Sequence[Sequence[str]],
                passes: Sequence[str], what: str) -> Optional[Dict[str, np.ndarray]]:
    """The channels ({name: array}) of the EXR layer that holds ``what``: one with a channel of each
    group in ``needs`` (``[("X", "R"), ...]``: X, else R); None when no layer has them.

    A plain EXR's own channels come first. In a multilayer EXR (Blender's, with a layer per pass
    and view layer: ``ViewLayer.Combined``, ``ViewLayer.Ambient Occlusion`` ...) the layer whose
    pass is named in ``passes`` (``Combined`` for colour) is taken, so that another pass never
    stands in for the image because its name sorts first. When several view layers hold that pass,
    or several layers qualify and none is such a pass, ImageReadError names them.
    """
    layers = {name: chans for name, chans in _layers(channels).items()
              if all(_first(chans, group) is not None for group in needs)}
    if "" in layers:
        return layers[""]
    if not layers:
        return None
    named = [name for name in layers if name.rpartition(".")[2] in passes]
    if len(named) == 1:
        return layers[named[0]]
    if len(named) > 1:
        raise ImageReadError(f"{path}: multilayer EXR holds {what} in several layers ({', '.join(sorted(named))}); "
                             "save one view layer per file")
    if len(layers) == 1:
        return next(iter(layers.values()))
    raise ImageReadError(f"{path}: multilayer EXR has several layers that could be {what} "
                         f"({', '.join(sorted(layers))}) and none is the {' or '.join(passes)} pass; "
                         "save that pass alone")


# Names of the colour pass in multilayer EXRs: Blender's render result, its compositor output, and
# the names other tools give the beauty layer.
COLOUR_PASSES = ("Combined", "Composite", "Image", "rgba")


def read_exr_rgba(path: Path | str) -> np.ndarray:
    """A colour EXR as float32 (h, w, 3) or (h, w, 4) when it has alpha. In a multilayer EXR the
    ``Combined`` pass is the colour, with its own alpha."""
    path = Path(path)
    ch = read_exr(path)
    layer = _pick_layer(path, ch, [("R",), ("G",), ("B",)], COLOUR_PASSES, "colour")
    if layer is None:
        if len(ch) == 1:  # greyscale EXR
            (only,) = ch.values()
            return np.stack([only, only, only], axis=-1)
        raise ImageReadError(f"{path}: EXR has no R, G, B channels (found {sorted(ch)})")
    return np.stack([layer[c] for c in "RGBA" if c in layer], axis=-1)


def read_depth(path: Path | str, png_scale: float = 1e-3, refuse_invalid: bool = False) -> np.ndarray:
    """Depth map as float32 (h, w) in scene units; 0 where there is no value.

    NaN and negative values read as 0 (no value), unless ``refuse_invalid`` (training with depth):
    then the first such pixel raises ImageReadError, naming it. Infinity is no surface either way.

    EXR: channel ``Z`` (else ``R``/``Y``/``V``/``D``/the only channel), already in scene units; in a
    multilayer EXR, the ``Depth`` pass (Blender's name for Z).
    PNG: 16-bit integers multiplied by ``png_scale`` (nerfstudio's millimetres -> metres is 1e-3).
    NPY: a (h, w) or (h, w, 1) array multiplied by ``png_scale`` too, as nerfstudio's loader does
    (``get_depth_image_from_path`` scales both by ``depth_unit_scale_factor``).
    """
    path = Path(path)
    if path.suffix.lower() == ".npy":
        depth = _read_npy_depth(path) * np.float32(png_scale)
    elif path.suffix.lower() == ".exr":
        ch = read_exr(path)
        names = ("Z", "R", "Y", "V", "D")
        layer = _pick_layer(path, ch, [names], ("Depth", "Z"), "depth")
        if layer is None:
            if len(ch) != 1:
                raise ImageReadError(f"{path}: depth EXR has no Z channel (found {sorted(ch)})")
            (depth,) = ch.values()
        else:
            depth = _first(layer, names)
    else:
        raw = read_png(path)
        if raw.dtype == np.uint8:
            # 8 bits hold 0-255 mm: a picture of depth (normalised for viewing), not a measurement.
            raise ImageReadError(f"{path}: an 8-bit depth PNG holds 256 levels, so it is a visualisation of depth, "
                                 "not a depth map; depth must be a 16-bit PNG (millimetres, or the dataset's depth "
                                 "scale) or a float EXR")
        if raw.ndim == 3:
            raw = raw[..., 0]
        depth = raw.astype(np.float32) * np.float32(png_scale)
    if refuse_invalid:
        bad = np.isnan(depth) | (depth < 0)
        if bad.any():
            y, x = (int(v) for v in np.argwhere(bad)[0])
            raise ImageReadError(f"{path}: depth at pixel (x {x}, y {y}) is {float(depth[y, x])!r} "
                                 f"({int(bad.sum())} pixels are NaN or negative); a depth map holds distances "
                                 "(0 or inf where there is no surface)")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    return depth


def _read_npy_depth(path: Path) -> np.ndarray:
    """A NumPy ``.npy`` depth map as float32 (h, w), unscaled. Never unpickles (a ``.npy`` of objects
    would run code on load), and checks the shape in the header before reading the values."""
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
    except OSError as exc:
        raise ImageReadError(f"{path}: cannot read depth .npy ({exc.strerror or exc})") from exc
    if magic != b"\x93NUMPY":
        kind = "a .npz archive" if magic.startswith(b"PK") else "no NumPy header"
        raise ImageReadError(f"{path}: not a .npy array ({kind})")
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as exc:  # a damaged header; object arrays cannot be mapped (nor unpickled here)
        reason = "it holds Python objects, not numbers" if "object" in str(exc).lower() else exc
        raise ImageReadError(f"{path}: cannot read depth .npy ({reason})") from exc
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2 or arr.dtype.kind not in "fiub":
        raise ImageReadError(f"{path}: a depth .npy must be a (height, width) array of numbers, got shape "
                             f"{tuple(arr.shape)} of {arr.dtype}")
    if arr.size > MAX_EXR_VALUES:
        raise ImageReadError(f"{path}: the .npy header claims {arr.shape[1]}x{arr.shape[0]} values, more than "
                             f"{MAX_EXR_VALUES / 1e6:.0f} million")
    return np.array(arr, dtype=np.float32)


def read_normals(path: Path | str) -> np.ndarray:
    """Normal map as float32 (h, w, 3). EXR holds world-space vectors; 8-bit PNGs map [0, 255] to [-1, 1]."""
    path = Path(path)
    if path.suffix.lower() == ".exr":
        ch = read_exr(path)
        axes = (("X", "R"), ("Y", "G"), ("Z", "B"))
        layer = _pick_layer(path, ch, axes, ("Normal",), "normals")
        if layer is None:
            raise ImageReadError(f"{path}: normal EXR needs X/Y/Z or R/G/B channels (found {sorted(ch)})")
        return np.stack([_first(layer, a) for a in axes], axis=-1).astype(np.float32)
    raw = read_png(path)
    if raw.ndim != 3 or raw.shape[2] < 3:
        raise ImageReadError(f"{path}: normal PNG must have 3 channels")
    scale = 65535.0 if raw.dtype == np.uint16 else 255.0
    return (raw[..., :3].astype(np.float32) / scale) * 2.0 - 1.0


def read_mask(path: Path | str) -> np.ndarray:
    """Mask as bool (h, w): True where the pixel is used (nerfstudio: black means ignore)."""
    raw = read_png(path)
    if raw.ndim == 3:
        raw = raw[..., 0]  # grey masks saved as RGB(A) repeat the value in every colour channel
    return raw > 0


def write_png(path: Path | str, image: np.ndarray) -> None:
    """Write float [0, 1] or uint8 (h, w, 3|4) / (h, w) as an 8-bit PNG, atomically (float values
    become levels by ``contract.eight_bit.to_8bit``, the render engine's rule too)."""

    path = Path(path)
    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        arr = to_8bit(arr)
    with atomic_file(path) as fh:
        Image.fromarray(arr).save(fh, format="PNG")


def write_exr(path: Path | str, channels: Dict[str, np.ndarray]) -> None:
    """Write float32 (h, w) channels, e.g. ``{"Z": depth}``, as a ZIP-compressed EXR, atomically."""
    OpenEXR = _openexr(path, "writing")

    path = Path(path)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    with atomic_path(path) as tmp, OpenEXR.File(header, data) as f:
        f.write(str(tmp))

