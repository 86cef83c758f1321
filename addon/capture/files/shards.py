"""Per-shard state files of a sharded capture: ``nerf_capture/shards/shard-K-of-N.json``.

Shards may run at once on machines that share the dataset folder, so no two of them write the same
file: each shard writes only its own state file (atomically: a temporary name unique to the host
and process, then a rename) and the frames of its share. The manifest, the transforms files and
the point cloud are written by the merge alone. A state holds the plan, its hash, the shard's
place (K, N) and {frame key: {file key: sha256}} of the frames it finished.
"""
from __future__ import annotations

import json
import os
import re
import socket
import time

from ...file_writes import write_atomic
from ..plan.frame_plan import CaptureError, shard_settings_error

SHARD_DIR = "shards"  # inside the dataset's manifest folder
_STATE_RE = re.compile(r"shard-(\d+)-of-(\d+)\.json")


def state_dir(out: str, manifest_dir: str) -> str:
    return os.path.join(out, manifest_dir, SHARD_DIR)


def state_path(out: str, manifest_dir: str, k: int, n: int) -> str:
    return os.path.join(state_dir(out, manifest_dir), f"shard-{k}-of-{n}.json")


def unique_suffix() -> str:
    """A name part no other shard uses at the same time (host + process id)."""
    host = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())[:40] or "host"
    return f"{host}-{os.getpid()}"


def write_state(path: str, state: dict) -> None:
    """Write a shard's state atomically (readers see the old file or the new one, whole)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    state = dict(state, updated=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
    write_atomic(path, lambda fh: json.dump(state, fh), tmp=f"{path}.{unique_suffix()}.partial")


def read_states(out: str, manifest_dir: str) -> list[tuple[str, dict]]:
    """(file name, state) of every shard state in ``out``, sorted by (N, K); CaptureError if unreadable."""
    folder = state_dir(out, manifest_dir)
    if not os.path.isdir(folder):
        return []
    found = []
    for name in os.listdir(folder):
        m = _STATE_RE.fullmatch(name)
        if not m:
            continue
        path = os.path.join(folder, name)
        try:
            with open(path) as fh:
                state = json.load(fh)
        except (OSError, ValueError) as exc:
            raise CaptureError(f"{path}: unreadable shard state ({exc}); run that shard again or delete the file")
        if not isinstance(state, dict) or not isinstance(state.get("done"), dict):
            raise CaptureError(f"{path}: not a shard state (no 'done' map); run that shard again or delete the file")
        found.append(((int(m.group(2)), int(m.group(1))), name, state))
    return [(name, state) for _, name, state in sorted(found)]


def describe(name: str, manifest_dir: str) -> str:
    return f"{manifest_dir}/{SHARD_DIR}/{name}"


def conflict(out: str, manifest_dir: str, plan: dict, plan_hash: str, shard, manifest, states) -> str | None:
    """Why a job with ``plan`` may not write into ``out``, or None: shards of one folder share one
    plan and one shard count. ``shard``: (K, N) or None (one machine); ``states``: ``read_states``."""
    records = [(describe(name, manifest_dir), st) for name, st in states]
    if shard and manifest is not None and manifest.get("plan_hash"):
        records.append((f"the capture in {os.path.join(out, manifest_dir)}",
                        {"hash": manifest["plan_hash"], "plan": manifest.get("plan")}))
    for source, rec in records:
        err = shard_settings_error(plan, plan_hash, {"hash": rec.get("hash"), "plan": rec.get("plan")}, source)
        if err:
            return f"output folder {out}: {err}"
    if shard:
        for name, st in states:
            if st.get("shards") != shard[1]:
                return (f"output folder {out} is being captured in {st.get('shards')} shards "
                        f"({describe(name, manifest_dir)}), not {shard[1]}; run every shard with the same N")
    return None


def done_records(out: str, manifest_dir: str, frames: list[dict], plan_hash: str, manifest) -> dict:
    """{frame key: {"hash", "sha256"}} of frames already written: the manifest's, then every shard's
    (of the same plan). ``sha256`` is None for manifests from before per-file hashes."""
    records = {}
    for key, entry in ((manifest or {}).get("frames") or {}).items():
        if isinstance(entry, dict) and entry.get("done"):
            records[key] = {"hash": entry.get("hash"),
                            "sha256": entry["sha256"] if isinstance(entry.get("sha256"), dict) else None}
    by_key = {fr["key"]: fr for fr in frames}
    for _name, st in read_states(out, manifest_dir):
        if st.get("hash") != plan_hash:
            continue
        for key, sha in st["done"].items():
            if key in by_key and isinstance(sha, dict):
                records[key] = {"hash": by_key[key]["hash"], "sha256": sha}
    return records
