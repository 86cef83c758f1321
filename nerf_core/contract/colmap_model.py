"""COLMAP's sparse model on disk: ``cameras``, ``images`` and ``points3D``, binary and text (stdlib + numpy).

The layout is COLMAP's own (``src/colmap/scene/reconstruction_io.cc``; its ``scripts/python/read_write_model.py``),
all little-endian:

- ``cameras.bin``: uint64 count; per camera int32 id, int32 model id, uint64 width, uint64 height,
  float64 params[n] (n fixed by the model, ``MODELS``);
- ``images.bin``: uint64 count; per image int32 id, float64 qvec[4] (w, x, y, z), float64 tvec[3],
  int32 camera id, the name as NUL-terminated UTF-8, uint64 n2d, then n2d x (float64 x, float64 y,
  int64 point3D id, -1 = none);
- ``points3D.bin``: uint64 count; per point uint64 id, float64 xyz[3], uint8 rgb[3], float64 error,
  uint64 track length, then track length x (int32 image id, int32 point2D index).

The text twins hold the same values, one camera / point per line and two lines per image.

Poses: ``contract.colmap_poses`` (re-exported here). Pixel coordinates agree with ours: the top-left
corner of the image is (0, 0) and pixel centres sit at +0.5, so ``cx``/``cy`` pass through unchanged.

Every problem raises ``ColmapError`` (a ``DatasetError``) naming the file and the camera or image.
"""
from __future__ import annotations

import io
import os
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Dict, List, Optional, Tuple

import numpy as np

from .colmap_poses import GL_TO_CV, pose_from_colmap, pose_to_colmap, qvec_to_rotmat, rotmat_to_qvec  # noqa: F401
from .errors import DatasetError
from .paths import why_not_a_file

# model id -> (name, parameter names), COLMAP's numbering (src/colmap/sensor/models.h)
MODELS: Dict[int, Tuple[str, Tuple[str, ...]]] = {
    0: ("SIMPLE_PINHOLE", ("f", "cx", "cy")),
    1: ("PINHOLE", ("fx", "fy", "cx", "cy")),
    2: ("SIMPLE_RADIAL", ("f", "cx", "cy", "k")),
    3: ("RADIAL", ("f", "cx", "cy", "k1", "k2")),
    4: ("OPENCV", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    5: ("OPENCV_FISHEYE", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
    6: ("FULL_OPENCV", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    7: ("FOV", ("fx", "fy", "cx", "cy", "omega")),
    8: ("SIMPLE_RADIAL_FISHEYE", ("f", "cx", "cy", "k")),
    9: ("RADIAL_FISHEYE", ("f", "cx", "cy", "k1", "k2")),
    10: ("THIN_PRISM_FISHEYE", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1")),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", tuple(f"p{i}" for i in range(16))),
}
MODEL_IDS = {name: mid for mid, (name, _) in MODELS.items()}
MODEL_FILES = ("cameras", "images", "points3D")


class ColmapError(DatasetError):
    """A sparse model that cannot be read or written; the message names the file and the camera or image."""


@dataclass
class Camera:
    """One COLMAP camera: ``model`` a name of ``MODELS``, ``params`` (n,) float64 in the model's order."""

    id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class Image:
    """One registered image: world-to-camera ``qvec`` (4,) (w, x, y, z) and ``tvec`` (3,), OpenCV axes;
    ``xys`` (n, 2) float64 pixel positions of its 2D points and ``point3D_ids`` (n,) int64 (-1 = none)."""

    id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3D_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass
class Points:
    """The sparse points: ``ids`` (n,) int64, ``xyz`` (n, 3) float64, ``rgb`` (n, 3) uint8, ``error`` (n,)
    float64 and ``tracks``: n arrays (k, 2) int64 of (image id, point2D index)."""

    ids: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    error: np.ndarray
    tracks: List[np.ndarray]

    @staticmethod
    def empty() -> "Points":
        return Points(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0), [])

    def __len__(self) -> int:
        return len(self.ids)


@dataclass
class Model:
    """A whole sparse model: cameras and images by id, and the points."""

    cameras: Dict[int, Camera]
    images: Dict[int, Image]
    points: Points


# -- finding a model --------------------------------------------------------------------------------
def model_files(folder: Path | str) -> Optional[Tuple[Dict[str, Path], str]]:
    """({cameras, images, points3D} -> file, ".bin" | ".txt") of a sparse model folder, or None when
    it has no ``cameras.bin``/``cameras.txt``. Binary wins when both are there (COLMAP's own choice)."""
    folder = Path(folder)
    for ext in (".bin", ".txt"):
        if os.path.lexists(folder / f"cameras{ext}"):
            return {n: folder / f"{n}{ext}" for n in MODEL_FILES}, ext
    return None


def find_sparse(root: Path | str) -> Optional[Path]:
    """The sparse model of a COLMAP folder (``sparse/0``, else ``sparse``, else the folder itself when
    it holds ``cameras.bin``/``.txt``), or None."""
    root = Path(root)
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if cand.is_dir() and model_files(cand) is not None:
            return cand
    return None


# -- binary -----------------------------------------------------------------------------------------
class _Reader:
    """Little-endian reads from a whole file's bytes; a short read is a truncated file, named."""

    def __init__(self, path: Path):
        self.path = path
        problem = why_not_a_file(path) if not path.is_file() else None
        if problem:
            raise ColmapError(f"{path}: {problem}")
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str, what: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise ColmapError(f"{self.path}: the file is truncated (it ends inside {what}, at byte {len(self.data)})")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def array(self, dtype, count: int, what: str) -> np.ndarray:
        dt = np.dtype(dtype).newbyteorder("<")
        size = dt.itemsize * count
        if count < 0 or self.pos + size > len(self.data):
            raise ColmapError(f"{self.path}: the file is truncated (it ends inside {what}, at byte {len(self.data)})")
        out = np.frombuffer(self.data, dt, count, self.pos)
        self.pos += size
        return out

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise ColmapError(f"{self.path}: the file is truncated (it ends inside the name of {what})")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ColmapError(f"{self.path}: the name of {what} is not UTF-8 ({raw[:40]!r})") from None

    def done(self) -> None:
        if self.pos != len(self.data):
            raise ColmapError(f"{self.path}: {len(self.data) - self.pos} bytes after the last entry; "
                              "the file is not a COLMAP model of this kind, or it is damaged")


def _model_of(mid: int, where: str) -> Tuple[str, Tuple[str, ...]]:
    if mid not in MODELS:
        raise ColmapError(f"{where}: unknown camera model id {mid} (COLMAP's ids are 0-{max(MODELS)})")
    return MODELS[mid]


def read_cameras_bin(path: Path) -> Dict[int, Camera]:
    r = _Reader(path)
    out = {}
    (n,) = r.take("Q", "the camera count")
    for k in range(n):
        cid, mid, w, h = r.take("iiQQ", f"camera {k + 1} of {n}")
        name, pnames = _model_of(mid, f"{path}: camera {cid}")
        params = r.array(np.float64, len(pnames), f"the parameters of camera {cid}").copy()
        out[cid] = Camera(cid, name, int(w), int(h), params)
    r.done()
    return out


def read_images_bin(path: Path) -> Dict[int, Image]:
    r = _Reader(path)
    out = {}
    (n,) = r.take("Q", "the image count")
    for k in range(n):
        vals = r.take("i4d3di", f"image {k + 1} of {n}")
        iid = vals[0]
        name = r.name(f"image {iid}")
        (n2d,) = r.take("Q", f"the point count of image {iid} ({name})")
        rec = r.array(np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]), n2d, f"the 2D points of image {iid}")
        out[iid] = Image(iid, np.array(vals[1:5]), np.array(vals[5:8]), vals[8], name,
                         np.stack([rec["x"], rec["y"]], axis=1).astype(np.float64), rec["id"].astype(np.int64))
    r.done()
    return out


def read_points_bin(path: Path) -> Points:
    r = _Reader(path)
    (n,) = r.take("Q", "the point count")
    ids, xyz, rgb, err, tracks = np.zeros(n, np.int64), np.zeros((n, 3)), np.zeros((n, 3), np.uint8), np.zeros(n), []
    head = np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("err", "<f8"), ("len", "<u8")])
    for k in range(n):
        rec = r.array(head, 1, f"point {k + 1} of {n}")[0]
        ids[k], xyz[k], rgb[k], err[k] = rec["id"], rec["xyz"], rec["rgb"], rec["err"]
        tracks.append(r.array(np.int32, 2 * int(rec["len"]), f"the track of point {int(rec['id'])}")
                      .reshape(-1, 2).astype(np.int64))
    r.done()
    return Points(ids, xyz, rgb, err, tracks)


# The writers take an open binary file: the caller's atomic home opens it (``model_files_bytes``).
def write_cameras_bin(fh: BinaryIO, cameras: Dict[int, Camera]) -> None:
    fh.write(struct.pack("<Q", len(cameras)))
    for c in cameras.values():
        fh.write(struct.pack("<iiQQ", c.id, MODEL_IDS[c.model], c.width, c.height))
        fh.write(np.asarray(c.params, "<f8").tobytes())


def write_images_bin(fh: BinaryIO, images: Dict[int, Image]) -> None:
    fh.write(struct.pack("<Q", len(images)))
    for im in images.values():
        fh.write(struct.pack("<i4d3di", im.id, *im.qvec, *im.tvec, im.camera_id))
        fh.write(im.name.encode("utf-8") + b"\0")
        rec = np.zeros(len(im.point3D_ids), np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]))
        rec["x"], rec["y"], rec["id"] = im.xys[:, 0], im.xys[:, 1], im.point3D_ids
        fh.write(struct.pack("<Q", len(rec)) + rec.tobytes())


def write_points_bin(fh: BinaryIO, pts: Points) -> None:
    head = np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("err", "<f8"), ("len", "<u8")])
    fh.write(struct.pack("<Q", len(pts)))
    rec = np.zeros(len(pts), head)
    rec["id"], rec["xyz"], rec["rgb"], rec["err"] = pts.ids, pts.xyz, pts.rgb, pts.error
    rec["len"] = [len(t) for t in pts.tracks]
    for k in range(len(pts)):
        fh.write(rec[k].tobytes() + np.asarray(pts.tracks[k], "<i4").tobytes())


# -- text -------------------------------------------------------------------------------------------
def _lines(path: Path) -> List[Tuple[int, List[str]]]:
    """(line number, words) of a text model file, comments and blank lines left out."""
    problem = why_not_a_file(path) if not path.is_file() else None
    if problem:
        raise ColmapError(f"{path}: {problem}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ColmapError(f"{path}: cannot read it as UTF-8 text ({exc})") from None
    return [(k + 1, ln.split()) for k, ln in enumerate(text.split("\n")) if ln.strip() and not ln.startswith("#")]


def _numbers(path: Path, line: int, words: List[str], kind, what: str) -> list:
    try:
        return [kind(w) for w in words]
    except ValueError:
        raise ColmapError(f"{path}: line {line} ({what}): not a number in {' '.join(words)[:80]!r}") from None


def _floats(path: Path, line: int, words: List[str], what: str) -> np.ndarray:
    """``words`` as float64 in one C-level parse (a model's text holds millions of numbers); a word that
    is not a number stops the parse short, which is how it is found."""
    text = " ".join(words)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy warns where the parse stops; the count below says it
        values = np.fromstring(text, dtype=np.float64, sep=" ")
    if len(values) != len(words):
        raise ColmapError(f"{path}: line {line} ({what}): not a number in {text[:80]!r}")
    return values


def read_cameras_txt(path: Path) -> Dict[int, Camera]:
    out = {}
    for line, w in _lines(path):
        if len(w) < 4:
            raise ColmapError(f"{path}: line {line}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        cid, width, height = _numbers(path, line, [w[0], w[2], w[3]], int, "camera")
        if w[1] not in MODEL_IDS:
            raise ColmapError(f"{path}: camera {cid}: unknown camera model {w[1]!r}")
        pnames = MODELS[MODEL_IDS[w[1]]][1]
        params = _numbers(path, line, w[4:], float, f"camera {cid}")
        if len(params) != len(pnames):
            raise ColmapError(f"{path}: camera {cid}: model {w[1]} has {len(pnames)} parameters "
                              f"({' '.join(pnames)}), the line gives {len(params)}")
        out[cid] = Camera(cid, w[1], width, height, np.array(params, np.float64))
    return out


def read_images_txt(path: Path) -> Dict[int, Image]:
    out = {}
    rows = _lines_keep_empty_points(path)
    for k in range(0, len(rows), 2):
        line, w = rows[k]
        if len(w) < 10:
            raise ColmapError(f"{path}: line {line}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        iid, cid = _numbers(path, line, [w[0], w[8]], int, "image")
        vals = _numbers(path, line, w[1:8], float, f"image {iid}")
        name = " ".join(w[9:])
        if k + 1 >= len(rows):
            raise ColmapError(f"{path}: image {iid} ({name}): the file ends before its line of 2D points")
        pline, pw = rows[k + 1]
        if len(pw) % 3:
            raise ColmapError(f"{path}: line {pline}: image {iid}'s 2D points are not triples X Y POINT3D_ID")
        pts = _floats(path, pline, pw, f"image {iid}'s 2D points").reshape(-1, 3)
        out[iid] = Image(iid, np.array(vals[:4]), np.array(vals[4:7]), cid, name, pts[:, :2].copy(),
                         pts[:, 2].astype(np.int64))
    return out


def _lines_keep_empty_points(path: Path) -> List[Tuple[int, List[str]]]:
    """images.txt's lines without comments, keeping the (possibly empty) 2D-point line of each image."""
    _lines(path)  # the file checks
    text = path.read_text(encoding="utf-8").split("\n")
    rows = [(k + 1, ln.split()) for k, ln in enumerate(text) if not ln.startswith("#")]
    while rows and not rows[-1][1]:
        rows.pop()
    if len(rows) % 2:  # the last image has no 2D points: its empty line went with the trailing blanks
        rows.append((rows[-1][0] + 1, []))
    return rows


def read_points_txt(path: Path) -> Points:
    ids, xyz, rgb, err, tracks = [], [], [], [], []
    for line, w in _lines(path):
        if len(w) < 8 or (len(w) - 8) % 2:
            raise ColmapError(f"{path}: line {line}: expected POINT3D_ID X Y Z R G B ERROR TRACK[]")
        v = _floats(path, line, w, "point")
        if not (v[:1] == np.round(v[:1])).all() or not (v[8:] == np.round(v[8:])).all():
            raise ColmapError(f"{path}: line {line}: point {w[0]}: its id and track must be integers")
        ids.append(int(v[0]))
        xyz.append(v[1:4])
        rgb.append(v[4:7])
        err.append(v[7])
        tracks.append(v[8:].astype(np.int64).reshape(-1, 2))
    if not ids:
        return Points.empty()
    return Points(np.array(ids, np.int64), np.array(xyz), np.clip(rgb, 0, 255).astype(np.uint8), np.array(err), tracks)


def _fmt(v: float) -> str:
    return repr(float(v))  # shortest text that reads back as the same float64


def write_cameras_txt(fh: BinaryIO, cameras: Dict[int, Camera]) -> None:
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(cameras)}"]
    lines += [" ".join([str(c.id), c.model, str(c.width), str(c.height)] + [_fmt(p) for p in c.params])
              for c in cameras.values()]
    fh.write(("\n".join(lines) + "\n").encode("utf-8"))


def write_images_txt(fh: BinaryIO, images: Dict[int, Image]) -> None:
    n2d = sum(len(im.point3D_ids) for im in images.values())
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(images)}, mean observations per image: {n2d / max(1, len(images)):g}"]
    for im in images.values():
        lines.append(" ".join([str(im.id)] + [_fmt(v) for v in (*im.qvec, *im.tvec)] + [str(im.camera_id), im.name]))
        # one C-level format for the whole line (%r: the shortest text that reads back as the same float64)
        xs, ys, ids = im.xys[:, 0].tolist(), im.xys[:, 1].tolist(), [int(v) for v in im.point3D_ids]
        lines.append(("%r %r %d " * len(ids) % tuple(v for t in zip(xs, ys, ids) for v in t)).rstrip())
    fh.write(("\n".join(lines) + "\n").encode("utf-8"))


def write_points_txt(fh: BinaryIO, pts: Points) -> None:
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {len(pts)}"]
    xyz, rgb, err = pts.xyz.tolist(), pts.rgb.tolist(), pts.error.tolist()
    for k, pid in enumerate(pts.ids.tolist()):
        track = np.asarray(pts.tracks[k]).ravel().tolist()
        lines.append(("%d %r %r %r %d %d %d %r" + " %d" * len(track))
                     % (pid, *map(float, xyz[k]), *rgb[k], float(err[k]), *track))
    fh.write(("\n".join(lines) + "\n").encode("utf-8"))


_READERS = {".bin": (read_cameras_bin, read_images_bin, read_points_bin),
            ".txt": (read_cameras_txt, read_images_txt, read_points_txt)}


def read_model(folder: Path | str) -> Model:
    """The sparse model in ``folder`` (binary, else text). A missing ``points3D`` file reads as no points.

    Checks what the files must agree on: every image's camera exists, every track names an existing
    image and one of its 2D points. Raises ColmapError naming the file and the camera or image.
    """
    folder = Path(folder)
    found = model_files(folder)
    if found is None:
        raise ColmapError(f"{folder}: no cameras.bin or cameras.txt: not a COLMAP sparse model folder")
    files, ext = found
    read_cams, read_ims, read_pts = _READERS[ext]
    cameras = read_cams(files["cameras"])
    images = read_ims(files["images"])
    points = read_pts(files["points3D"]) if os.path.lexists(files["points3D"]) else Points.empty()
    for im in images.values():
        if im.camera_id not in cameras:
            raise ColmapError(f"{files['images']}: image {im.id} ({im.name}) refers to camera {im.camera_id}, "
                              f"which {files['cameras'].name} lacks (it has {sorted(cameras)[:8]})")
    _check_tracks(points, images, files)
    return Model(cameras, images, points)


def _check_tracks(points: Points, images: Dict[int, Image], files: Dict[str, Path]) -> None:
    """ColmapError for the first track element naming an image or a 2D point ``images`` lacks (vectorised:
    a model holds millions of observations)."""
    if not len(points) or not any(len(t) for t in points.tracks):
        return
    elems = np.concatenate([np.asarray(t, np.int64).reshape(-1, 2) for t in points.tracks])
    owner = np.repeat(points.ids, [len(t) for t in points.tracks])
    ids = np.array(sorted(images), np.int64)
    n2d = np.array([len(images[int(i)].point3D_ids) for i in ids], np.int64)
    at = np.clip(np.searchsorted(ids, elems[:, 0]), 0, max(len(ids) - 1, 0))
    ok = (len(ids) > 0) & (ids[at] == elems[:, 0]) & (elems[:, 1] >= 0) & (elems[:, 1] < n2d[at])
    if not ok.all():
        k = int(np.argmin(ok))
        raise ColmapError(f"{files['points3D']}: point {int(owner[k])}'s track names image {int(elems[k, 0])}, "
                          f"2D point {int(elems[k, 1])}, which {files['images'].name} does not have")


_WRITERS = {".bin": (write_cameras_bin, write_images_bin, write_points_bin),
            ".txt": (write_cameras_txt, write_images_txt, write_points_txt)}


def model_files_bytes(model: Model, exts: Tuple[str, ...] = (".bin", ".txt")) -> Dict[str, bytes]:
    """{file name: content} of ``model`` in each format of ``exts`` (``cameras.bin``, ...): the caller
    writes them through its atomic home (this module writes no file: the add-on loads it too)."""
    out = {}
    for ext in exts:
        for name, write, part in zip(MODEL_FILES, _WRITERS[ext], (model.cameras, model.images, model.points)):
            buf = io.BytesIO()
            write(buf, part)
            out[f"{name}{ext}"] = buf.getvalue()
    return out
