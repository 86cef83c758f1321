"""``scripts/capture.py --out DATASET --merge``: join the shards of a farm capture into one dataset.

Needs no scene: the plan travels in every shard's state file. Every planned frame must have been
recorded by a shard (or by an earlier manifest of the same plan) and pass the resume check
(``files.verify``: each file's sha256 as recorded, images decode at the capture's size). Then the
merge writes what no shard may: the transforms files, the point cloud and the manifest. With a
frame missing it writes nothing and names every missing frame.
"""
from __future__ import annotations

import os

from ...dataset import capture_manifest
from ..files import shards, verify, write
from ..plan.frame_plan import CaptureError, plan_hash, shard_frames


def _plans(out: str, states: list, manifest: dict | None) -> tuple[dict, str, int | None]:
    """(plan, its hash, shard count) the states agree on; CaptureError naming the files when not."""
    hashes = {}
    for name, st in states:
        hashes.setdefault(st.get("hash"), []).append(shards.describe(name, capture_manifest.MANIFEST_DIR))
    if len(hashes) > 1:
        listed = "; ".join(f"{h[:12] if h else None}: {', '.join(files)}" for h, files in hashes.items())
        raise CaptureError(f"{out}: the shards were planned with different settings ({listed}); run them again "
                           "with one command line (only --shard differing)")
    counts = {st.get("shards") for _, st in states}
    if len(counts) > 1:
        raise CaptureError(f"{out}: shard states disagree on the number of shards ({sorted(map(str, counts))}); "
                           f"delete {capture_manifest.MANIFEST_DIR}/{shards.SHARD_DIR} of the wrong ones")
    name, st = states[0]
    plan = st.get("plan")
    if not isinstance(plan, dict) or plan_hash(plan) != st.get("hash"):
        raise CaptureError(f"{shards.describe(name, capture_manifest.MANIFEST_DIR)}: its plan does not match its "
                           "hash (edited or damaged); run that shard again")
    return plan, st["hash"], counts.pop()


def missing_frames(out: str, plan: dict, records: dict, n_shards: int | None) -> list[str]:
    """One line per planned frame that is absent or invalid: split, name, shard, why."""
    w, h = plan["resolution"]
    owner = {}
    if n_shards:
        for k in range(1, n_shards + 1):
            owner.update({fr["key"]: k for fr in shard_frames(plan["frames"], k, n_shards)})
    lines = []
    for fr in plan["frames"]:
        rec = records.get(fr["key"])
        shard = f", shard {owner[fr['key']]}/{n_shards}" if fr["key"] in owner else ""
        if rec is None or rec["hash"] != fr["hash"]:
            why = "not rendered (no shard recorded it)"
        else:
            why = verify.frame_problem(out, fr, rec["sha256"], w, h)
            if why is None:
                continue
        lines.append(f"{fr['split']} {fr['name']} ({fr['image']}{shard}): {why}")
    return lines


def merge(out_dir: str) -> dict:
    """Verify every planned frame of the capture in ``out_dir``, then write its dataset files.

    Returns a summary dict; raises CaptureError (listing each missing frame) and writes nothing
    when a frame is missing or invalid.
    """
    out = os.path.abspath(out_dir)
    if not os.path.isdir(out):
        raise CaptureError(f"--merge: {out} is not a folder")
    manifest = capture_manifest.read_manifest(out)
    states = shards.read_states(out, capture_manifest.MANIFEST_DIR)
    if not states:
        raise CaptureError(f"--merge: {out} holds no shard states "
                           f"({capture_manifest.MANIFEST_DIR}/{shards.SHARD_DIR}/); "
                           "run the shards (--shard K/N) first")
    plan, phash, n_shards = _plans(out, states, manifest)
    if manifest is not None and manifest.get("plan_hash") not in (None, phash):
        raise CaptureError(f"--merge: {capture_manifest.manifest_path(out)} records another capture (plan hash "
                           f"{str(manifest.get('plan_hash'))[:12]}, the shards' {phash[:12]}); "
                           f"merge into a clean folder")
    records = shards.done_records(out, capture_manifest.MANIFEST_DIR, plan["frames"], phash,
                                          manifest if manifest and manifest.get("plan_hash") == phash else None)
    missing = missing_frames(out, plan, records, n_shards)
    if missing:
        raise CaptureError(f"--merge: {len(missing)} of {len(plan['frames'])} planned frames are missing or invalid "
                           "in " + out + "; run their shards again (they resume), then merge:\n  "
                           + "\n  ".join(missing))
    info = dict(states[0][1].get("manifest_info") or {})
    created = sorted(str(st.get("manifest_info", {}).get("created")) for _, st in states
                     if st.get("manifest_info", {}).get("created"))
    info.update(created=created[0] if created else None, plan_hash=phash, shards=n_shards,
                file_sha256={key: rec["sha256"] for key, rec in records.items() if rec["sha256"]})
    done = {fr["key"] for fr in plan["frames"]}
    near, far = write.write_dataset(out, plan, done, True, info)
    return {"out": out, "status": "complete", "frames": len(done), "shards": n_shards, "plan_hash": phash,
            "near": near, "far": far}
