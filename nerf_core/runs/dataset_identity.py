"""The dataset a run belongs to: how ``--resume``, ``eval`` and ``render`` tell it from another one, or
from the same folder changed since the run trained on it.

Two records, both in ``RUN/config.json`` (and every checkpoint's config):

* ``dataset_hash``: sha256 over the transforms files (names and contents); it survives a move or a copy;
* ``dataset_images``: {image path relative to the dataset folder: [size in bytes, mtime in ns]} of every
  image, depth and mask file the frames name. Statting files is cheap (no pixel is read), and an image
  replaced in place almost always changes one of the two. A copied dataset keeps the sizes but not
  always the times, so a dataset at another path is compared by the sizes alone.
"""
from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path
from typing import Dict, List, Optional

from nerf_core.contract.colmap_dataset import MANIFEST
from nerf_core.contract.colmap_model import find_sparse
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.transforms import detect_layout, frame_infos
from nerf_core.errors import TrainError

SHOWN = 3  # changed files named in a message


def dataset_images(path) -> Optional[Dict[str, List[int]]]:
    """{relative path: [size, mtime_ns]} of the image, depth and mask files the dataset's frames name
    (those that exist); None when the transforms cannot be read (loading the dataset says why)."""
    try:
        _, root, splits, _ = frame_infos(Path(path))
    except (DatasetError, OSError, ValueError):
        return None
    out: Dict[str, List[int]] = {}
    for frames in splits.values():
        for fr in frames:
            for f in (fr.image, fr.depth, fr.mask, fr.alpha):
                if f is None:
                    continue
                try:
                    st = os.stat(f)
                except OSError:
                    continue
                rel = os.path.relpath(f, root).replace(os.sep, "/")
                out[rel] = [int(st.st_size), int(st.st_mtime_ns)]
    return out


def images_changed(want, have, same_place: bool) -> Optional[str]:
    """What differs between two ``dataset_images`` records, in words naming the files, or None.

    ``same_place``: the dataset is at the path the run recorded, so modification times count too
    (a dataset at another path may be a copy with new times)."""
    if not isinstance(want, dict) or not isinstance(have, dict):
        return None  # a run from before the record: nothing to compare
    changed, gone, new = [], [], sorted(set(have) - set(want))
    for rel, old in want.items():
        now = have.get(rel)
        if now is None:
            gone.append(rel)
        elif not isinstance(old, list) or len(old) != 2:
            continue
        elif now[0] != old[0] or (same_place and now[1] != old[1]):
            what = "size" if now[0] != old[0] else "modification time"
            changed.append(f"{rel} ({what})")
    parts = []
    for label, items in (("changed", sorted(changed)), ("missing", sorted(gone)), ("new", new)):
        if items:
            parts.append(f"{len(items)} {label}: " + ", ".join(items[:SHOWN]) + (", ..." if len(items) > SHOWN else ""))
    return "; ".join(parts) or None


def dataset_hash(path) -> str:
    """sha256 over the transforms files (a COLMAP folder: its sparse model files and our manifest) of a
    dataset (names and contents): what ``--resume`` compares
    to tell the dataset a run was trained on from another one at the same or a different path."""
    layout, root = detect_layout(Path(path))
    if layout == "synthetic":
        files = [root / f"transforms_{s}.json" for s in ("train", "val", "test")]
    elif layout == "colmap":  # the sparse model's files and our export's manifest (its split lists)
        files = sorted(find_sparse(root).glob("*.*")) + [root / MANIFEST]
    else:
        files = [Path(path) if Path(path).is_file() else root / "transforms.json"]
    h = hashlib.sha256()
    for f in files:
        if f.is_file():
            h.update(f.name.encode() + b"\0")
            try:
                h.update(f.read_bytes())
            except OSError as exc:
                raise DatasetError(f"{f}: cannot read ({exc.strerror})") from None
            h.update(b"\0")
    return h.hexdigest()


SCORES = "the scores compare the model with the data there now"


def dataset_changed_note(config: dict, consequence: str = SCORES) -> Optional[str]:
    """A note when the dataset a run's config.json names no longer holds the data it trained on (its
    transforms files' hash differs, or images were replaced, removed or added), else None: ``eval``,
    ``render``, ``export`` and ``open_run(...).dataset`` still work on it, but what they make of it then
    compares the model with other data (``consequence`` says what: the scores, the culling) and
    ``--resume`` refuses it outright. The one test of "the dataset changed": every loader of a run's
    dataset calls it (nerf_core/tests/test_dataset_identity_everywhere.py)."""
    path, want = config.get("dataset"), config.get("dataset_hash")
    if not (isinstance(path, str) and isinstance(want, str) and Path(path).exists()):
        return None
    try:
        have = dataset_hash(path)
    except (DatasetError, OSError):
        return None  # loading the dataset reports it, naming the file
    if have != want:
        return (f"{path} changed since the run trained on it (transforms hash {have[:12]}, trained on {want[:12]}); "
                + consequence)
    images = images_changed(config.get("dataset_images"), dataset_images(path), same_place=True)
    if images:
        return f"{path}: images changed since the run trained on it ({images}); " + consequence
    return None


def _refuse_changed_images(saved: dict, path: str, same_place: bool) -> None:
    """TrainError naming the images that differ from those the run recorded (``dataset_images``)."""
    images = images_changed(saved.get("dataset_images"), dataset_images(path), same_place)
    if images:
        raise TrainError(f"{path}: the dataset's images changed since the run started ({images}); resuming "
                         "would train on other data. Start a new run (another --out, or --overwrite)")


def resume_dataset(saved: dict, dataset: str, dataset_moved: bool) -> str:
    """The dataset to resume on: the recorded one (``saved``: the run's config), or ``dataset`` (the
    DATASET argument) when it holds the same dataset.

    A run continued on other data would silently mix two scenes, so a DATASET other than the one the
    run was trained on is refused unless the content hash of its transforms files (recorded in
    config.json when the run started) matches: then the dataset was moved or copied, and the new
    path is used. Runs from before the hash was recorded need ``dataset_moved`` to accept another path.
    """
    recorded = saved.get("dataset")
    if not recorded:
        return dataset
    new = str(Path(dataset).resolve())
    want = saved.get("dataset_hash")
    if new == str(Path(recorded).resolve()):
        if want and Path(new).exists():
            have = dataset_hash(new)
            if have != want:
                raise TrainError(
                    f"{new}: the dataset changed since the run started (transforms hash {have[:12]} "
                    f"instead of {want[:12]}); resuming would train on other data. Start a new run "
                    "(another --out, or --overwrite)")
        if Path(new).exists():
            _refuse_changed_images(saved, new, same_place=True)
        return new
    if want:
        try:
            have = dataset_hash(new)
        except DatasetError as exc:
            raise TrainError(f"--resume: the run was trained on {recorded}, and {exc}") from None
        if have == want:
            _refuse_changed_images(saved, new, same_place=False)
            print(f"train: {new} holds the dataset the run was trained on (moved from {recorded}); using it",
                  file=sys.stderr)
            return new
        raise TrainError(
            f"--resume: the run was trained on {recorded} (transforms hash {want[:12]}), but {new} holds "
            f"another dataset (hash {have[:12]}); resume with the original DATASET, or start a new run")
    if dataset_moved:
        print(f"train: --dataset-moved: resuming on {new} instead of {recorded} (this run recorded no dataset "
              "hash to check it against)", file=sys.stderr)
        return new
    raise TrainError(
        f"--resume: the run was trained on {recorded}, not {new}, and recorded no dataset hash to check that "
        f"they hold the same data; resume with the original DATASET, or pass --dataset-moved if you moved it")
