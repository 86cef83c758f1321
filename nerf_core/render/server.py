"""``python -m nerf_core serve RUN``: load a run once, then render one camera per JSON line on stdin.

The Blender render engine (``addon/render_engine.py``) keeps this process alive across the frames of
an animation and the redraws of a viewport, so the model loads once and torch never loads in
Blender. The protocol is in docs/CONTRACTS.md ("Render server"); in short:

stdin, one JSON object per line::

    {"id": 7, "c2w": [[...4 rows...]] or 16 numbers row-major, "fx": .., "fy": .., "cx": .., "cy": ..,
     "w": W, "h": H, "out": "/abs/path/frame.npy", "depth": true, "near": 0.1, "far": 20.0,
     "group": "viewport"}
    {"cmd": "quit"}                                 (or end of input)

stdout, one JSON object per line (nothing else is ever printed there):
``ready`` once the model is loaded; ``progress`` during a frame (at most every ``PROGRESS_EVERY_S``);
``result`` with the written paths; ``skipped`` when a newer request of the same ``group`` replaced
a queued or running one; ``error`` for a bad request (the server goes on) or, with ``"fatal": true``,
when the run cannot be loaded (exit code 2).

Outputs: ``out`` is ``(H, W, 4)`` float32 RGBA (row 0 at the top, straight colour in the same
display-referred values as ``render``'s PNGs, alpha = accumulated opacity, 1 for a run with a learned
world); with ``depth``, ``<out without .npy>_depth.npy`` is ``(H, W)`` float32 planar z-depth
(distance along the camera's -Z, scene units, 0 where nothing was hit). Both are written to a
temporary name and renamed, so a reader never sees half a file; an existing file is refused.
"""
from __future__ import annotations

import json
import math
import os
import queue
import sys
import threading
import time
from typing import Any, Dict, Optional, TextIO

import numpy as np
import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.contract.errors import PoseError
from nerf_core.contract.numbers import is_number, is_whole
from nerf_core.contract.poses import MAX_COORDINATE, coordinate_problem, parse_pose
from nerf_core.contract.transforms import MAX_FOCAL_PX, MIN_FOCAL_PX
from nerf_core.errors import RunError
from nerf_core.image.pixel_filter import of_run
from nerf_core.render.frame import render_view, straight_rgba
from nerf_core.render.memory import DEFAULT_CHUNK, check_view_memory
from nerf_core.runs.checkpoints import load_trained
from nerf_core.utils.atomic import LinkRefused, atomic_file
from nerf_core.utils.device import pick_device
from nerf_core.utils.memory import OutOfMemory, named_out_of_memory

PROGRESS_EVERY_S = 0.5
MAX_SIDE = 16384  # a larger request is a mistake (wrong units), not a render


class RequestError(ValueError):
    """A request that cannot be rendered; the message names the request and the field."""


class _Superseded(Exception):
    """A newer request of the same group arrived while this one was rendering."""


def _number(req: dict, key: str, where: str, positive: bool = False, default=None) -> Optional[float]:
    value = req.get(key, default)
    if value is None and default is None and not positive:
        return None
    if not is_number(value):
        raise RequestError(f"{where}: field {key!r} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise RequestError(f"{where}: field {key!r} must be positive, got {value!r}")
    return float(value)


def valid_id(value) -> bool:
    """Whether a request ``id`` can be echoed in a JSON answer: None, a string, a bool, an int or a finite float."""
    if isinstance(value, float):
        return math.isfinite(value)
    return value is None or isinstance(value, (str, int))


def parse_request(req: Any) -> Dict[str, Any]:
    """Validate one request object; returns a dict with c2w (4, 4) float64 and plain numbers.

    Raises RequestError naming the request id and field.
    """

    if not isinstance(req, dict):
        raise RequestError(f"request must be a JSON object, got {type(req).__name__}")
    where = f"request {req.get('id')!r}" if "id" in req else "request"
    try:
        c2w = parse_pose(req.get("c2w"), f"{where}: field 'c2w'")
    except PoseError as exc:
        raise RequestError(str(exc)) from None
    out: Dict[str, Any] = {"id": req.get("id"), "c2w": c2w, "group": req.get("group")}
    for key in ("fx", "fy"):
        out[key] = _number(req, key, where, positive=True)
        if not MIN_FOCAL_PX <= out[key] <= MAX_FOCAL_PX:  # beyond, float32 rays turn NaN or parallel
            raise RequestError(f"{where}: field {key!r} is a focal length in pixels and must lie in "
                               f"[{MIN_FOCAL_PX:g}, {MAX_FOCAL_PX:g}], got {out[key]:.4g}")
    for key in ("cx", "cy"):  # optional: the image centre
        out[key] = _number(req, key, where) if req.get(key) is not None else None
        if out[key] is not None and abs(out[key]) > MAX_COORDINATE:
            raise RequestError(f"{where}: field {key!r} is {out[key]:.4g} pixels, beyond {MAX_COORDINATE:.0e}")
    for key in ("w", "h"):
        v = req.get(key)
        if not is_whole(v) or not 1 <= v <= MAX_SIDE:
            raise RequestError(f"{where}: field {key!r} must be a whole number of pixels in 1..{MAX_SIDE}, got {v!r}")
        out[key] = v
    for key in ("near", "far"):
        out[key] = _number(req, key, where) if req.get(key) is not None else None
        if out[key] is not None and out[key] < 0:
            raise RequestError(f"{where}: field {key!r} must be >= 0, got {out[key]}")
        far_out = coordinate_problem([out[key]], f"field {key!r}") if out[key] is not None else None
        if far_out:
            raise RequestError(f"{where}: {far_out}")
    if out["near"] is not None and out["far"] is not None and out["far"] <= out["near"]:
        raise RequestError(f"{where}: 'far' ({out['far']}) must be greater than 'near' ({out['near']})")
    path = req.get("out")
    if not isinstance(path, str) or not path.endswith(".npy") or not os.path.isabs(path):
        raise RequestError(f"{where}: field 'out' must be an absolute path ending in .npy, got {path!r}")
    out["out"] = path
    if not isinstance(req.get("depth", False), bool):  # "no" would be truthy
        raise RequestError(f"{where}: field 'depth' must be true or false, got {req.get('depth')!r}")
    if "\0" in path:
        raise RequestError(f"{where}: field 'out' holds a NUL character")
    out["depth_out"] = path[:-4] + "_depth.npy" if req.get("depth") else None
    if not isinstance(req.get("pixel_filter", False), bool):
        raise RequestError(f"{where}: field 'pixel_filter' must be true or false, got {req.get('pixel_filter')!r}")
    out["pixel_filter"] = bool(req.get("pixel_filter", False))
    for p in filter(None, (out["out"], out["depth_out"])):
        if os.path.lexists(p):  # also a dangling link: writing would follow it to wherever it points
            what = "is a link to a file that does not exist" if not os.path.exists(p) else "already exists"
            raise RequestError(f"{where}: {p} {what}; the server never overwrites a file or writes through a link")
        if not os.path.isdir(os.path.dirname(p)):
            raise RequestError(f"{where}: folder {os.path.dirname(p)} does not exist")
    return out


def _save_npy(path: str, array: np.ndarray) -> None:
    """np.save through a temporary name in the same folder, then into place (readers never see half a
    file) without replacing a file: ``parse_request`` refused existing outputs, but one created while
    the view rendered was replaced by the rename. A hard link fails where the name exists; where the
    file system has no hard links, the check is repeated just before the rename."""
    try:
        with atomic_file(path, replace=False) as fh:
            np.save(fh, np.ascontiguousarray(array, dtype=np.float32))
    except FileExistsError:
        raise RequestError(f"{path} appeared while the view rendered; the server never overwrites a file") from None
    except LinkRefused as exc:
        raise RequestError(str(exc)) from None


class NotUtf8(str):
    """An input line that could not be decoded: its text is the error message to send back."""


class RenderServer:
    """A loaded run answering render requests (see the module docstring for the protocol)."""

    def __init__(self, run: str, checkpoint: Optional[str] = None, device: Optional[str] = None,
                 chunk: int = DEFAULT_CHUNK, out: TextIO = sys.stdout):

        self.out = out
        self.chunk = chunk
        self.device = pick_device(device)
        self.model, self.record, ckpt = load_trained(run, self.device, checkpoint)
        self.opaque = self.model.models_world

        self.film_filter = of_run(self.record.raw)  # for requests with "pixel_filter": true (final renders)
        self.info = {"run": os.path.abspath(run), "method": ckpt.get("method"), "step": ckpt.get("step"),
                     "device": str(self.device), "background": "environment" if self.opaque else "transparent",
                     "near": self.record.near, "far": self.record.far}
        self._inbox: "queue.Queue[Optional[str]]" = queue.Queue()
        self._pending: list = []  # lines read from the inbox but not handled yet, oldest first

    def emit(self, event: str, **fields) -> None:
        self.out.write(json.dumps({"event": event, "time": time.time(), **fields}) + "\n")
        self.out.flush()

    # -- input ----------------------------------------------------------------------------------
    def _read_stdin(self, stream) -> None:
        """Queue each input line, decoded as UTF-8 here: a text stream would raise on the first invalid
        byte and end this thread, after which no request was answered and EOF no longer stopped the
        server. A line that is not UTF-8 is answered with an error event, like any bad line."""
        raw = getattr(stream, "buffer", stream)
        try:
            for line in raw:
                if isinstance(line, bytes):
                    try:
                        line = line.decode("utf-8")
                    except UnicodeDecodeError as exc:
                        line = NotUtf8(
                            f"input line is not UTF-8 (byte {exc.start}: {line[exc.start : exc.start + 1]!r}): "
                            f"{line[:80]!r}"
                        )
                self._inbox.put(line)
        finally:
            self._inbox.put(None)  # end of input, also when reading failed

    def _drain(self) -> None:
        while True:
            try:
                self._pending.append(self._inbox.get_nowait())
            except queue.Empty:
                return

    def _newer_in_group(self, group) -> bool:
        """Is a request of ``group`` waiting? (Lines are parsed cheaply here; bad ones are left for later.)"""
        if group is None:
            return False
        self._drain()
        for line in self._pending:
            if line is None:
                continue
            try:
                obj = json.loads(line)
            except (ValueError, RecursionError):
                continue
            if isinstance(obj, dict) and obj.get("group") == group and "cmd" not in obj:
                try:
                    parse_request(obj)
                except (RequestError, TypeError):
                    continue  # a bad newer request gets its error; it does not cancel a good one
                return True
        return False

    # -- rendering ------------------------------------------------------------------------------
    def render(self, req: Dict[str, Any]) -> Dict[str, Any]:
        """Render one parsed request and write its files; returns the ``result`` fields."""

        w, h = req["w"], req["h"]
        check_view_memory(w, h, f"request {req['id']!r}")
        cx = req["cx"] if req["cx"] is not None else w / 2
        cy = req["cy"] if req["cy"] is not None else h / 2
        cams = Cameras.create(req["c2w"][None], req["fx"], req["fy"], cx, cy, w, h)
        near = req["near"] if req["near"] is not None else self.record.near
        far = req["far"] if req["far"] is not None else self.record.far
        t0 = time.monotonic()
        last = [t0]

        def on_chunk(done: int, total: int) -> None:
            now = time.monotonic()
            if now - last[0] >= PROGRESS_EVERY_S:
                last[0] = now
                if self._newer_in_group(req["group"]):
                    raise _Superseded()
                self.emit("progress", id=req["id"], done=done, total=total, fraction=round(done / total, 4))

        # an allocation that fails is one request's error naming the flag, not the end of the server
        with torch.no_grad(), named_out_of_memory(f"serve --chunk {self.chunk}", "lower serve's --chunk, or "
                                                  "ask for a smaller view"):
            res = render_view(self.model, cams, 0, background=(0.0, 0.0, 0.0), near=near, far=far,
                              chunk=self.chunk, on_chunk=on_chunk,
                              pixel_filter=self.film_filter if req["pixel_filter"] else None)
        _save_npy(req["out"], straight_rgba(res, self.opaque))
        if req["depth_out"]:
            _save_npy(req["depth_out"], res["z_depth"].numpy())
        return {"id": req["id"], "path": req["out"], "depth_path": req["depth_out"], "w": w, "h": h,
                "seconds": round(time.monotonic() - t0, 4)}

    def handle(self, line: str) -> bool:
        """Answer one input line; False when the server should stop."""

        if isinstance(line, NotUtf8):
            self.emit("error", id=None, message=str(line))
            return True
        if not line.strip():
            return True
        try:
            obj = json.loads(line)
        except ValueError as exc:
            self.emit("error", id=None, message=f"input line is not JSON ({exc}): {line.strip()[:80]!r}")
            return True
        except RecursionError:  # json recurses once per level: 100 000 '[' stopped the server
            self.emit("error", id=None, message=f"input line is JSON nested too deeply to read: {line.strip()[:80]!r}")
            return True
        if not isinstance(obj, dict):
            self.emit("error", id=None, message=f"a request must be a JSON object, got {type(obj).__name__}: "
                                                f"{line.strip()[:80]!r}")
            return True
        if not valid_id(obj.get("id")):  # echoed back in every answer: NaN there would not be JSON
            self.emit("error", id=None, message=f"request id must be a string, an integer or a finite number, got "
                                                f"{obj.get('id')!r:.80}")
            return True
        if "cmd" in obj:
            if obj["cmd"] == "quit":
                return False
            self.emit("error", id=obj.get("id"), message=f"unknown cmd {obj['cmd']!r} (known: quit)")
            return True
        try:
            req = parse_request(obj)
            if self._newer_in_group(req["group"]):
                self.emit("skipped", id=req["id"], reason="a newer request of the same group is waiting")
                return True
            self.emit("result", **self.render(req))
        except _Superseded:
            self.emit("skipped", id=obj.get("id"), reason="a newer request of the same group arrived")
        except (RequestError, RunError, OutOfMemory) as exc:
            self.emit("error", id=obj.get("id"), message=f"request {obj.get('id')!r}: {exc}"
                      if isinstance(exc, OutOfMemory) else str(exc))
        except OSError as exc:
            self.emit(
                "error",
                id=obj.get("id"),
                message=f"request {obj.get('id')!r}: cannot write {exc.filename or ''}: {exc.strerror or exc}",
            )
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            # e.g. out of memory inside torch, or a value the checks above missed: one request fails, the
            # server goes on (a client waits for an answer to every request).
            first = (str(exc).splitlines() or [type(exc).__name__])[0]
            self.emit("error", id=obj.get("id"), message=f"request {obj.get('id')!r}: rendering failed: {first}")
        return True

    def serve(self, stream: TextIO = sys.stdin) -> int:
        threading.Thread(target=self._read_stdin, args=(stream,), daemon=True, name="serve-stdin").start()
        self.emit("ready", **self.info)
        while True:
            if not self._pending:
                self._pending.append(self._inbox.get())
            line = self._pending.pop(0)
            if line is None or not self.handle(line):
                return 0
