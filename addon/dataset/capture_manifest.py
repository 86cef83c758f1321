"""The capture manifest, ``nerf_capture/manifest.json``: what a capture planned, rendered and checked."""
from __future__ import annotations

import json
import os

from ..file_writes import write_atomic
from .errors import ExportError

MANIFEST_DIR = "nerf_capture"
MANIFEST_NAME = "manifest.json"


def manifest_path(out_dir: str) -> str:
    return os.path.join(out_dir, MANIFEST_DIR, MANIFEST_NAME)


def read_manifest(out_dir: str) -> dict | None:
    """The capture manifest of ``out_dir``, None when there is none; ExportError if unreadable."""
    path = manifest_path(out_dir)
    if not os.path.exists(path):
        return None
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError) as exc:
        raise ExportError(f"{path}: unreadable capture manifest ({exc}); move the folder aside or pass --overwrite")


def _json_lines(obj, levels: int, indent: str = "") -> str:
    """JSON with one line per entry for the outer ``levels`` of dicts/lists, compact below.

    ``json.dump(indent=...)`` runs Python's pure-Python encoder; the manifest is rewritten after every
    frame and holds the whole plan, so its inner values go through the C encoder instead.
    """
    if levels <= 0 or not isinstance(obj, (dict, list)) or not obj:
        return json.dumps(obj)
    inner = indent + " "
    if isinstance(obj, dict):
        items = [f"{inner}{json.dumps(str(k))}: {_json_lines(v, levels - 1, inner)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    return "[\n" + ",\n".join(inner + _json_lines(v, levels - 1, inner) for v in obj) + "\n" + indent + "]"


_PLAN_TEXT: dict = {}  # (plan_hash, id(plan)) -> its JSON: a capture's plan is fixed while it rewrites the manifest


def write_manifest(out_dir: str, manifest: dict) -> None:
    """Write the capture manifest atomically (one line per frame entry: quick to rewrite, easy to read).

    The capture rewrites it after every frame; its ``plan`` (fixed for the capture, identified by
    ``plan_hash``) is encoded once, so the per-frame cost does not grow with it.
    """
    os.makedirs(os.path.join(out_dir, MANIFEST_DIR), exist_ok=True)
    plan, key = manifest.get("plan"), (manifest.get("plan_hash"), id(manifest.get("plan")))
    lines = []
    for k, v in manifest.items():
        if k == "plan" and plan is not None and key[0]:
            if key not in _PLAN_TEXT:
                _PLAN_TEXT.clear()
                _PLAN_TEXT[key] = _json_lines(plan, 1, " ")
            text = _PLAN_TEXT[key]
        else:
            text = _json_lines(v, 1, " ")
        lines.append(f" {json.dumps(str(k))}: {text}")
    path = manifest_path(out_dir)
    write_atomic(path, "{\n" + ",\n".join(lines) + "\n}\n")
