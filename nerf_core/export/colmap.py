"""``export colmap``: a capture folder as a COLMAP sparse model that splatting trainers read (no torch).

``export_colmap(dataset, out)`` writes, for the frames of ``splits`` (default train):

- ``OUT/sparse/0/{cameras,images,points3D}.{bin,txt}``: one camera per distinct intrinsics (PINHOLE, or
  OPENCV/OPENCV_FISHEYE/FULL_OPENCV for a lens, ``contract.colmap_dataset.colmap_camera``), each frame's
  pose as COLMAP's world-to-camera (``contract.colmap_model.pose_to_colmap``), the capture's
  ``points3d.ply`` as points whose tracks name the train images that see them (``tracks``);
- ``OUT/images/NAME.png``: opaque RGB, the film composited onto the background (white), and, where
  the film was transparent, ``OUT/masks/NAME.png``: the film's 8-bit alpha (0 = transparent; nerfstudio's
  ``--masks-path`` convention, the mask named as the image with ``.png``, keeps every non-zero pixel);
- ``OUT/nerf_bridge_colmap.json`` (``contract.colmap_dataset.MANIFEST``): the source, splits, each
  split's image names, the scene box, and that no normalisation was applied (scene units and frame).

Everything goes into a new hidden folder beside OUT (``mkdtemp``), renamed to OUT at the end: a failure leaves nothing
half-written. Importable without torch, so a capture in Blender runs the same code.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from nerf_core.contract.camera_files import image_size
from nerf_core.contract.colmap_dataset import MANIFEST, MANIFEST_FORMAT, colmap_camera
from nerf_core.contract.colmap_model import Camera, Image, Model, Points, model_files_bytes, pose_to_colmap
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.intrinsics import resolve_intrinsics
from nerf_core.contract.transforms import SPLITS, FrameInfo, frame_infos
from nerf_core.errors import ImageReadError
from nerf_core.export.ply import GeometryFileError, read_geometry
from nerf_core.image.io import read_depth, read_png, write_png
from nerf_core.utils.atomic import TEMP_DIR_SUFFIX, write_bytes_atomic, write_json_atomic

POINTS_FILE = "points3d.ply"
OWN_ENTRIES = ("images", "masks", "sparse", MANIFEST)  # what an export writes: all --overwrite replaces
CAPTURE_SUBDIR = "colmap"  # capture.py --colmap writes DATASET/colmap: the one place inside a dataset
DEFAULT_BACKGROUND = (1.0, 1.0, 1.0)  # captures on a transparent film are read composited onto white
NO_POINTS_NOTE = ("{ply}: no point cloud; points3D is empty. 3D Gaussian Splatting and gsplat start from the "
                  "sparse points: capture with --points")


def parse_splits(text: str) -> List[str]:
    """``"train,test"`` -> ["train", "test"]; ValueError naming an unknown split."""
    names = [s.strip() for s in str(text).split(",") if s.strip()]
    bad = [s for s in names if s not in SPLITS]
    if bad or not names:
        raise ValueError(f"--splits {text!r}: choose among {', '.join(SPLITS)} (comma-separated)")
    return list(dict.fromkeys(names))


def check_out(out: Path | str, dataset: Path, overwrite: bool, in_capture: bool = False) -> Path:
    """The output folder after refusing (ValueError) a link, a file, the dataset or a folder inside or
    around it (``in_capture``: except ``DATASET/colmap``, where the capture puts it), and an existing
    non-empty folder without ``overwrite``."""
    out = Path(os.path.abspath(out))
    if os.path.islink(out):
        raise ValueError(f"--out {out}: is a symbolic link; name a real folder (nothing is written through links)")
    ds = Path(os.path.realpath(dataset))
    real = Path(os.path.realpath(out))
    own = in_capture and real == ds / CAPTURE_SUBDIR
    if not own and (real == ds or ds in real.parents or real in ds.parents):
        raise ValueError(f"--out {out}: is the dataset {ds}, inside it or around it; the export never writes there")
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"--out {out}: exists and is not empty; pass --overwrite to replace it")
    foreign = sorted(p.name for p in out.iterdir() if p.name not in OWN_ENTRIES) if out.is_dir() else []
    if foreign:
        # --overwrite replaces a COLMAP export, never a folder of the user's other files
        raise ValueError(f"--out {out}: holds files an export does not write ({', '.join(foreign[:5])}); "
                         "choose another folder")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: folder {out.parent} does not exist")
    return out


def _intrinsics(fr: FrameInfo) -> tuple:
    """(fx, fy, cx, cy, w, h) of a frame at its image's own size, the size checked against ``w``/``h``."""
    size = image_size(fr.image)
    if size is None:
        raise DatasetError(f"{fr.where}: field 'file_path': image {fr.image} is missing or not a PNG/JPEG")
    fx, fy, cx, cy, w, h = resolve_intrinsics(fr.intrinsics, None, size, fr.where)
    if (int(w), int(h)) != tuple(size):
        raise DatasetError(f"{fr.where}: fields 'w'/'h' say {int(w)}x{int(h)} but {fr.image} is {size[0]}x{size[1]}")
    return fx, fy, cx, cy, int(w), int(h)


def _distort(x: np.ndarray, y: np.ndarray, lens) -> tuple:
    """Normalised (x, y) (OpenCV axes, z = 1) through the lens (``contract.lens``'s formulas)."""
    k1, k2, k3, k4, p1, p2 = lens.coeffs
    if lens.fisheye:
        r = np.hypot(x, y)
        th = np.arctan(r)
        th_d = th * (1 + k1 * th ** 2 + k2 * th ** 4 + k3 * th ** 6 + k4 * th ** 8)
        s = np.where(r > 1e-12, th_d / np.maximum(r, 1e-12), 1.0)
        return x * s, y * s
    rr = x * x + y * y
    radial = 1 + k1 * rr + k2 * rr ** 2 + k3 * rr ** 3 + k4 * rr ** 4
    return (x * radial + 2 * p1 * x * y + p2 * (rr + 2 * x * x),
            y * radial + p1 * (rr + 2 * y * y) + 2 * p2 * x * y)


def project(xyz: np.ndarray, c2w: np.ndarray, intr: tuple, lens) -> tuple:
    """Pixels of world points (n, 3) in one view: (u (n,), v (n,), z (n,) planar depth, OpenCV z forward)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    cam = (xyz - c2w[:3, 3]) @ c2w[:3, :3]  # OpenGL camera coordinates
    x, y, z = cam[:, 0], -cam[:, 1], -cam[:, 2]  # OpenCV: y down, z forward
    zs = np.where(z > 0, z, 1.0)
    xn, yn = x / zs, y / zs
    if lens is not None:
        xn, yn = _distort(xn, yn, lens)
    fx, fy, cx, cy = intr[:4]
    return cx + fx * xn, cy + fy * yn, z


def visible(u, v, z, w: int, h: int, depth: Optional[np.ndarray], fx: float) -> np.ndarray:
    """(n,) bool: in front, inside the frame and, with a depth map (h, w) of planar depth, not hidden:
    some pixel of the 3x3 around it has a depth within 2 % (or 3 pixels' footprint) of the point's."""
    ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    if depth is None or not ok.any():
        return ok
    idx = np.nonzero(ok)[0]
    col, row = np.floor(u[idx]).astype(int), np.floor(v[idx]).astype(int)
    zz = z[idx]
    tol = np.maximum(0.02 * zz, 3.0 * zz / fx)
    hit = np.zeros(len(idx), bool)
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            d = depth[np.clip(row + dj, 0, h - 1), np.clip(col + di, 0, w - 1)]
            hit |= (d > 0) & (np.abs(d - zz) <= tol)
    ok[idx] = hit
    return ok


def _composite(fr: FrameInfo, background) -> tuple:
    """(rgb (h, w, 3) uint8 composited onto ``background``, mask (h, w) uint8 or None when opaque)."""
    try:
        img = read_png(fr.image)
    except ImageReadError as exc:
        raise DatasetError(f"{fr.where}: field 'file_path': {exc}") from None
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise DatasetError(f"{fr.where}: field 'file_path': {fr.image} is not an 8-bit RGB or RGBA image")
    if img.shape[2] == 3 or (img[..., 3] == 255).all():
        return np.ascontiguousarray(img[..., :3]), None
    a = img[..., 3:].astype(np.float32) / 255.0
    rgb = img[..., :3].astype(np.float32) / 255.0 * a + np.asarray(background, np.float32) * (1.0 - a)
    # the mask is the film's alpha itself: 0 where transparent, which every mask reader drops (nerfstudio keeps
    # each non-zero pixel), and the levels let our loader restore the RGBA film exactly (colmap_dataset)
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8), np.ascontiguousarray(img[..., 3])


def _depth(fr: FrameInfo, notes: list) -> Optional[np.ndarray]:
    if fr.depth is None:
        return None
    try:
        return read_depth(fr.depth)
    except ImageReadError as exc:
        notes.append(f"{fr.where}: depth not used for occlusion ({exc}); points count as seen when in the frame")
        return None


def tracks(xyz: np.ndarray, views: List[dict], notes: list) -> tuple:
    """Which views see each point: (keep (n,) bool, per view a list of kept-point indices and pixels).

    ``views``: dicts with ``id``, ``c2w``, ``intr``, ``lens``, ``frame`` (for its depth map). A point no
    view sees is dropped (``keep`` False)."""
    seen = []
    for view in views:
        u, v, z = project(xyz, view["c2w"], view["intr"], view["lens"])
        ok = visible(u, v, z, view["intr"][4], view["intr"][5], _depth(view["frame"], notes), view["intr"][0])
        idx = np.nonzero(ok)[0]
        seen.append((idx, np.stack([u[idx], v[idx]], axis=1)))
    keep = np.zeros(len(xyz), bool)
    for idx, _ in seen:
        keep[idx] = True
    return keep, seen


def _points_model(root: Path, images: Dict[int, Image], track_views: List[dict], notes: list) -> tuple:
    """(the points of the capture's ``points3d.ply`` seen by ``track_views``, how many were dropped);
    fills each image's 2D points to match the tracks."""
    ply = root / POINTS_FILE
    if not ply.is_file():
        notes.append(NO_POINTS_NOTE.format(ply=ply))
        return Points.empty(), 0
    try:
        geo = read_geometry(ply)
    except GeometryFileError as exc:
        raise DatasetError(str(exc)) from None
    colors = geo.colors if geo.colors is not None else np.full((len(geo.points), 3), 128, np.uint8)
    keep, seen = tracks(geo.points, track_views, notes)
    if not keep.all():
        notes.append(f"{ply}: {int((~keep).sum())} of {len(keep)} point(s) are seen by no train image "
                     "(outside every frame, behind every camera, or hidden): dropped")
    new_id = np.cumsum(keep) * keep  # point k -> COLMAP id 1..m, 0 when dropped
    for view, (idx, uv) in zip(track_views, seen):
        im = images[view["id"]]
        im.xys, im.point3D_ids = uv, new_id[idx].astype(np.int64)
    # every observation (point, image id, index of the point among the image's 2D points), grouped by point
    obs_p = np.concatenate([idx for idx, _ in seen] + [np.zeros(0, np.int64)]).astype(np.int64)
    obs = np.concatenate([np.stack([np.full(len(idx), v["id"]), np.arange(len(idx))], 1)
                          for v, (idx, _) in zip(track_views, seen)] + [np.zeros((0, 2), np.int64)]).astype(np.int64)
    order = np.argsort(obs_p, kind="stable")
    per_point = np.split(obs[order], np.cumsum(np.bincount(obs_p, minlength=len(keep)))[:-1])
    kept = np.nonzero(keep)[0]
    return Points(new_id[kept].astype(np.int64), geo.points[kept], colors[kept], np.zeros(len(kept)),
                  [per_point[p] for p in kept]), int((~keep).sum())


def export_colmap(dataset: Path | str, out: Path | str, splits: Sequence[str] = ("train",), overwrite: bool = False,
                  background=DEFAULT_BACKGROUND, on_note: Optional[Callable[[str], None]] = None,
                  in_capture: bool = False) -> dict:
    """Write a COLMAP folder of ``dataset``'s ``splits`` into ``out`` (layout in the module doc).

    Args:
        dataset: a dataset folder (any layout ``contract.frame_infos`` reads).
        out: the folder to write; it must not exist, or be empty, unless ``overwrite``.
        splits: names among "train", "val", "test"; the tracks name the train images when "train" is there.
        background: (3,) colour in [0, 1] behind a transparent film.
        in_capture: allow ``out`` = ``DATASET/colmap`` (``capture.py --colmap``); any other path inside the
            dataset, or the dataset itself, is refused.
    Returns:
        the summary: ``out``, ``cameras``, ``images`` ({split: count}), ``points``, ``dropped_points``,
        ``masks``, ``notes``, ``seconds``.
    Raises:
        DatasetError naming the file and frame (an unreadable dataset, image or point cloud, a lens
        COLMAP cannot hold), ValueError for the output path; nothing is left in ``out`` then.
    """
    started = time.perf_counter()
    say = on_note or (lambda s: None)
    layout, root, infos, scene = frame_infos(dataset, SPLITS)
    out = check_out(out, root, overwrite, in_capture)
    frames = [(s, fr) for s in splits for fr in infos.get(s, [])]
    if not frames:
        raise DatasetError(f"{root}: no frames in split(s) {', '.join(splits)} to export")
    notes: List[str] = []
    cameras: Dict[tuple, Camera] = {}
    images: Dict[int, Image] = {}
    names: Dict[str, List[str]] = {s: [] for s in splits}
    views, used = [], {}
    # a new private folder beside OUT (mkdtemp: exclusive, never a link), renamed to OUT when complete
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=TEMP_DIR_SUFFIX, dir=out.parent))
    try:
        for sub in ("sparse/0", "images"):
            (tmp / sub).mkdir(parents=True)
        masks = 0
        for k, (split, fr) in enumerate(frames):
            intr = _intrinsics(fr)
            try:
                model, params = colmap_camera(*intr, fr.lens)
            except ValueError as exc:
                raise DatasetError(f"{fr.where}: {exc}") from None
            key = (model, intr[4], intr[5], tuple(params))
            if key not in cameras:
                cameras[key] = Camera(len(cameras) + 1, model, intr[4], intr[5], np.asarray(params, np.float64))
            name = f"{fr.stem}.png" if len(splits) == 1 else f"{split}_{fr.stem}.png"
            if name.lower() in used:
                raise DatasetError(f"{fr.where}: its image name {name} is also that of {used[name.lower()]}; "
                                   "COLMAP names every image once")
            used[name.lower()] = fr.where
            qvec, tvec = pose_to_colmap(fr.c2w)
            images[k + 1] = Image(k + 1, qvec, tvec, cameras[key].id, name)
            names[split].append(name)
            rgb, mask = _composite(fr, background)
            write_png(tmp / "images" / name, rgb)
            if mask is not None:
                (tmp / "masks").mkdir(exist_ok=True)
                write_png(tmp / "masks" / name, mask)
                masks += 1
            if split == "train" or "train" not in splits:
                views.append({"id": k + 1, "c2w": fr.c2w, "intr": intr, "lens": fr.lens, "frame": fr})
        points, dropped = _points_model(root, images, views, notes)
        model = Model({c.id: c for c in cameras.values()}, images, points)
        for name, data in model_files_bytes(model).items():
            write_bytes_atomic(tmp / "sparse" / "0" / name, data)
        manifest = {"format": MANIFEST_FORMAT, "version": 1, "source": str(root), "source_layout": layout,
                    "splits": list(splits), "images": names, "normalization": None,
                    "note": "no normalisation: poses and points are in the capture's own units and frame",
                    "background": [float(c) for c in background],
                    "masks": "masks/NAME.png: the film's alpha (0 = transparent); images/ are composited onto "
                             "background" if masks else None,
                    "aabb": scene.get("aabb"), "near": scene.get("near"), "far": scene.get("far")}
        write_json_atomic(tmp / MANIFEST, manifest)
        if os.path.islink(out):  # again: OUT may have changed while we worked
            raise ValueError(f"--out {out}: became a symbolic link while the export ran; nothing was written")
        if out.is_dir():
            shutil.rmtree(out)
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for n in notes:
        say(n)
    return {"out": str(out), "kind": "colmap", "dataset": str(root), "cameras": len(cameras),
            "images": {s: len(v) for s, v in names.items()}, "points": len(points), "dropped_points": dropped,
            "masks": masks, "notes": notes, "seconds": round(time.perf_counter() - started, 3)}

