"""Helpers shared by ``scripts/benchmark.py`` and ``scripts/stability.py``.

Both scripts drive the same command lines users run (``scripts/make_demo_scene.py``,
``scripts/capture.py``, ``python -m nerf_core train/eval/render``) as subprocesses, so what they
measure is what users get. This module holds the pieces that do not depend on which study runs:

- running a CLI and reading its JSON-line progress events (``run_cli``, ``parse_events``);
- capturing a demo scene once and reusing it while the capture settings match (``ensure_dataset``);
- deriving datasets for stress tests (``subset_views``, ``perturb_poses``);
- table output (``write_csv``, ``write_json``, ``markdown_table``);
- the speed/accuracy analysis (``pareto_front``, ``auto_size_verdict``) and the charts.

Only the standard library and numpy/matplotlib/pillow at module level: importing this module must
not start torch, so the scripts stay cheap to import and to test.
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Iterable, Optional, Sequence

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    sys.path.insert(0, REPO_ROOT)

PYTHON = sys.executable


class BenchError(RuntimeError):
    """A step of a study failed; the message names the command, scene or file."""


# --------------------------------------------------------------------------------------------
# Running the command-line tools
# --------------------------------------------------------------------------------------------


def parse_event(line: str) -> Optional[dict]:
    """One progress line -> event dict, or None for lines that are not JSON events (library warnings)."""
    line = line.strip()
    if not line.startswith("{"):
        return None
    try:
        obj = json.loads(line)
    except ValueError:
        return None
    return obj if isinstance(obj, dict) else None


def parse_events(lines: Iterable[str]) -> list[dict]:
    return [ev for ev in (parse_event(line) for line in lines) if ev is not None]


@dataclass
class CliResult:
    """What a finished subprocess left behind."""

    args: list[str]
    returncode: int
    events: list[dict] = field(default_factory=list)
    stdout_tail: list[str] = field(default_factory=list)
    stderr_tail: list[str] = field(default_factory=list)
    wall: float = 0.0

    @property
    def ok(self) -> bool:
        return self.returncode == 0

    def last_json(self) -> Optional[dict]:
        """The last JSON object printed (``eval`` prints its metrics as the last line)."""
        return self.events[-1] if self.events else None

    def error_message(self) -> str:
        """The best one-line explanation of a failure: the ``error`` event, else stderr's last line."""
        for ev in reversed(self.events):
            if ev.get("event") == "error":
                return str(ev.get("message", "error"))
        for line in reversed(self.stderr_tail + self.stdout_tail):
            if line.strip():
                return line.strip()
        return f"exit code {self.returncode}"


def nerf_core_cmd(*args: str) -> list[str]:
    return [PYTHON, "-m", "nerf_core", *[str(a) for a in args]]


def thread_env(jobs: int) -> dict:
    """Environment that gives each of ``jobs`` parallel children an equal share of the CPU cores.

    torch (and numpy's BLAS) start one thread per core by default; ``jobs`` runs that each start
    ``cpu_count`` threads would fight over the cores and every timing would measure the contention.
    With ``jobs`` <= 1 nothing is set, so a single run uses the machine as a user's run does.
    """
    if jobs <= 1:
        return {}
    threads = str(max(1, (os.cpu_count() or 1) // jobs))
    return {"OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads, "OPENBLAS_NUM_THREADS": threads}


def run_parallel(tasks: Sequence[Callable[[], object]], jobs: int) -> list:
    """Run the zero-argument callables ``tasks``, ``jobs`` at a time; results in the order given.

    The tasks start subprocesses and wait on them, so threads are enough. A task that raises
    re-raises here after the others have finished: a study never loses the runs that worked.
    """
    if jobs <= 1 or len(tasks) <= 1:
        return [t() for t in tasks]
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(t) for t in tasks]
        return [f.result() for f in futures]


class SharedProgress:
    """One progress bar fed by several parallel runs: the bar shows finished work plus each live run's.

    ``advance(key, seconds)`` records how far run ``key`` is; ``finish(key, cost, info)`` books its
    full planned cost. Thread-safe, so parallel runs' event callbacks can call it directly.
    """

    def __init__(self, bar):
        self.bar = bar
        self.finished = bar.done
        self.live: dict = {}
        self.lock = threading.Lock()

    def _draw(self, info: str) -> None:
        self.bar.set(self.finished + sum(self.live.values()), info=info)

    def advance(self, key, seconds: float, info: str = "") -> None:
        with self.lock:
            self.live[key] = seconds
            self._draw(info)

    def finish(self, key, cost: float, info: str = "") -> None:
        with self.lock:
            self.live.pop(key, None)
            self.finished += cost
            self._draw(info)


def script_cmd(script: str, *args: str) -> list[str]:
    return [PYTHON, os.path.join(REPO_ROOT, "scripts", script), *[str(a) for a in args]]


def run_cli(
    cmd: Sequence[str],
    on_event: Optional[Callable[[dict], None]] = None,
    log_path: Optional[str] = None,
    timeout: Optional[float] = None,
    tail: int = 40,
    env_extra: Optional[dict] = None,
) -> CliResult:
    """Run ``cmd``, streaming stdout so ``on_event`` sees progress events as they happen.

    stderr goes to a temporary file (not a pipe) so a chatty child can never block on a full pipe.
    ``log_path`` receives both streams for post-mortems. A timeout kills the child and is reported as
    return code 124, like coreutils' ``timeout``. ``env_extra`` is merged into the child's
    environment (``thread_env`` for parallel jobs).
    """
    start = time.monotonic()
    env = dict(os.environ)
    env.update(env_extra or {})
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONPATH"] = REPO_ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    log = open(log_path, "a", encoding="utf-8") if log_path else None
    err_path = (log_path or os.path.join(_tmpdir(), f"bench_{os.getpid()}")) + ".stderr"
    result = CliResult(args=list(cmd), returncode=-1)
    try:
        if log:
            log.write("$ " + " ".join(cmd) + "\n")
            log.flush()
        with open(err_path, "w+", encoding="utf-8", errors="replace") as err:
            proc = subprocess.Popen(
                list(cmd), stdout=subprocess.PIPE, stderr=err, text=True, errors="replace",
                cwd=REPO_ROOT, env=env, bufsize=1,
            )
            try:
                assert proc.stdout is not None
                for line in proc.stdout:
                    if log:
                        log.write(line)
                        log.flush()  # the log is what one reads while a long run is still going
                    ev = parse_event(line)
                    if ev is not None:
                        result.events.append(ev)
                        if on_event:
                            on_event(ev)
                    else:
                        result.stdout_tail.append(line.rstrip("\n"))
                        del result.stdout_tail[:-tail]
                    if timeout is not None and time.monotonic() - start > timeout:
                        proc.kill()
                        break
                proc.wait(timeout=None if timeout is None else max(1.0, timeout - (time.monotonic() - start)))
                result.returncode = proc.returncode
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                result.returncode = 124
            if timeout is not None and time.monotonic() - start > timeout and result.returncode != 0:
                result.returncode = 124
            err.seek(0)
            err_text = err.read()
        result.stderr_tail = err_text.splitlines()[-tail:]
        if log:
            log.write(err_text)
    finally:
        if log:
            log.close()
        try:
            os.remove(err_path)
        except OSError:
            pass
    result.wall = time.monotonic() - start
    return result


def _tmpdir() -> str:
    import tempfile

    return tempfile.gettempdir()


def cli_help(*args: str) -> str:
    """``--help`` text of a CLI (empty when it cannot run), used to detect optional trainer flags."""
    try:
        out = subprocess.run(
            [*args, "--help"], capture_output=True, text=True, cwd=REPO_ROOT, timeout=120,
            env={**os.environ, "PYTHONPATH": REPO_ROOT},
        )
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return out.stdout + out.stderr


# --------------------------------------------------------------------------------------------
# Training summaries
# --------------------------------------------------------------------------------------------


def summarize_training(events: Sequence[dict]) -> dict:
    """Numbers a study needs from one training run's events.

    Returns n_params, steps, elapsed, samples_per_s (median of step events, robust to the slow first
    steps), rollbacks, nan (a NaN/inf loss was seen or a rollback gave NaN as its reason), error
    (message of the ``error`` event or None) and final train psnr.
    """
    out = {"n_params": None, "steps": 0, "elapsed": 0.0, "samples_per_s": None, "rollbacks": 0,
           "nan": False, "error": None, "train_psnr": None, "stage_times": None, "first_lr": None}
    rates = []
    for ev in events:
        kind = ev.get("event")
        if kind == "start":
            out["n_params"] = ev.get("n_params", out["n_params"])
        elif kind == "step":
            out["steps"] = max(out["steps"], int(ev.get("step", 0)))
            out["elapsed"] = float(ev.get("elapsed", out["elapsed"]) or 0.0)
            loss = ev.get("loss")
            if loss is None or (isinstance(loss, float) and not math.isfinite(loss)):
                out["nan"] = True
            if out["first_lr"] is None and ev.get("lr") is not None:
                out["first_lr"] = float(ev["lr"])
            if ev.get("samples_per_s"):
                rates.append(float(ev["samples_per_s"]))
            if ev.get("psnr") is not None:
                out["train_psnr"] = ev["psnr"]
            if isinstance(ev.get("stage_times"), dict):
                out["stage_times"] = ev["stage_times"]
        elif kind == "rollback":
            out["rollbacks"] += 1
            if "nan" in str(ev.get("reason", "")).lower() or "inf" in str(ev.get("reason", "")).lower():
                out["nan"] = True
        elif kind == "done":
            out["steps"] = max(out["steps"], int(ev.get("step", 0) or 0))
            out["elapsed"] = float(ev.get("elapsed", out["elapsed"]) or 0.0)
        elif kind == "error":
            out["error"] = str(ev.get("message", "error"))
    if rates:
        rates.sort()
        out["samples_per_s"] = rates[len(rates) // 2]
    return out


def checkpoint_size(path: str) -> Optional[int]:
    try:
        return os.path.getsize(path)
    except OSError:
        return None


# --------------------------------------------------------------------------------------------
# Datasets
# --------------------------------------------------------------------------------------------


def demo_capture_defaults(scene: str) -> dict:
    """Capture settings demo scene ``scene`` needs (``addon/demo_capture.py``: e.g. opaque, layout inside).

    That file is loaded by path: importing the ``addon`` package would import bpy.
    """
    import importlib.util

    path = os.path.join(REPO_ROOT, "addon", "demo_capture.py")
    if not os.path.isfile(path):
        return {}
    spec = importlib.util.spec_from_file_location("_nerf_bridge_demo_capture", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.capture_defaults(scene)


def settings_key(settings: dict) -> str:
    """Stable short hash of capture settings: the cache key of a captured dataset."""
    blob = json.dumps(settings, sort_keys=True, separators=(",", ":"))
    return hashlib.sha1(blob.encode()).hexdigest()[:10]


def dataset_is_complete(path: str) -> bool:
    return all(os.path.isfile(os.path.join(path, f"transforms_{s}.json")) for s in ("train", "test"))


def ensure_dataset(
    scene: str,
    root: str,
    settings: dict,
    log_path: Optional[str] = None,
    capture_args: Callable[[str, str, dict], list[str]] | None = None,
) -> tuple[str, bool]:
    """Capture demo scene ``scene`` into ``root/<scene>-<key>`` unless a matching capture is there.

    ``settings`` (resolution, view counts, ...) are written to ``<dataset>.settings.json`` beside the
    dataset folder (outside it, so instant-ngp-style loaders never read it). A cached dataset is reused only
    when that file matches exactly; a half-written one (no transforms) is captured again into a fresh
    folder, never over the user's data. Returns (dataset path, reused?).

    Scenes that need their own capture flags (``demo_capture_defaults``: hdri and interior are opaque,
    interior uses the inside layout) get them merged under ``settings`` (``settings`` wins), so they
    are part of the cache key and of the capture's flags; object scenes' keys are unchanged.
    """
    os.makedirs(root, exist_ok=True)
    settings = {**demo_capture_defaults(scene), **settings}
    key = settings_key({"scene": scene, **settings})
    ds = os.path.join(root, f"{scene}-{key}")
    stamp = ds + ".settings.json"
    if dataset_is_complete(ds) and os.path.isfile(stamp):
        with open(stamp, encoding="utf-8") as fh:
            if json.load(fh) == {"scene": scene, **settings}:
                return ds, True
    if os.path.exists(ds):
        # An interrupted capture: move it aside instead of deleting, then capture afresh.
        shutil.move(ds, ds + f".incomplete-{int(time.time())}")
    blend = os.path.join(root, f"{scene}.blend")
    res = run_cli(script_cmd("make_demo_scene.py", scene, "--out", blend, "--overwrite"), log_path=log_path)
    if not res.ok or not os.path.isfile(blend):
        # Older make_demo_scene.py without --overwrite: retry plainly into a fresh file name.
        blend = os.path.join(root, f"{scene}-{key}.blend")
        if os.path.exists(blend):
            os.remove(blend)
        res = run_cli(script_cmd("make_demo_scene.py", scene, "--out", blend), log_path=log_path)
        if not res.ok or not os.path.isfile(blend):
            raise BenchError(f"demo scene {scene!r}: make_demo_scene.py failed: {res.error_message()}")
    args = (capture_args or default_capture_args)(blend, ds, settings)
    res = run_cli(script_cmd("capture.py", *args), log_path=log_path)
    if not res.ok or not dataset_is_complete(ds):
        raise BenchError(f"demo scene {scene!r}: capture.py failed: {res.error_message()}")
    with open(stamp, "w", encoding="utf-8") as fh:
        json.dump({"scene": scene, **settings}, fh, indent=1, sort_keys=True)
    return ds, False


def default_capture_args(blend: str, out: str, settings: dict) -> list[str]:
    """Flags of scripts/capture.py for ``settings`` (keys are the flag names without dashes)."""
    args = ["--blend", blend, "--out", out]
    for key, value in settings.items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        args += [flag] if value is True else [flag, str(value)]
    return args


def _load_json(path: str) -> dict:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _write_json_file(path: str, obj) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=1)


def derive_dataset(src: str, dst: str, edit_train: Callable[[dict], dict], note: dict) -> str:
    """Copy dataset ``src`` to ``dst`` with the train split's JSON rewritten by ``edit_train``.

    Images are linked (copied where links are not allowed), so the original is never touched. The
    nerfstudio ``transforms.json`` (``nerfstudio/``, or the root in older captures) is not carried over: it
    would still list the unedited cameras.
    The edit is recorded in ``dst/nerf_capture/derived.json`` so a derived dataset is never mistaken
    for a capture.
    """
    if os.path.exists(dst):
        shutil.rmtree(dst)
    os.makedirs(dst)
    for name in os.listdir(src):
        s, d = os.path.join(src, name), os.path.join(dst, name)
        if name in ("transforms.json", "nerfstudio", "nerf_capture"):  # nerfstudio's file: root (old) or nerfstudio/
            continue
        if name.startswith("transforms_") and name.endswith(".json"):
            meta = _load_json(s)
            if name == "transforms_train.json":
                meta = edit_train(meta)
            _write_json_file(d, meta)
            continue
        try:
            os.symlink(os.path.abspath(s), d)
        except OSError:
            (shutil.copytree if os.path.isdir(s) else shutil.copy2)(s, d)
    os.makedirs(os.path.join(dst, "nerf_capture"), exist_ok=True)
    _write_json_file(os.path.join(dst, "nerf_capture", "derived.json"), {"source": os.path.abspath(src), **note})
    return dst


def evenly_spaced(n_total: int, n_keep: int) -> list[int]:
    """Indices of ``n_keep`` frames spread over ``n_total`` (cameras on an orbit stay well spread)."""
    if n_keep >= n_total:
        return list(range(n_total))
    if n_keep <= 0:
        return []
    return sorted({int(math.floor(i * n_total / n_keep)) for i in range(n_keep)})


def subset_views(src: str, dst: str, n_views: int) -> str:
    """A copy of ``src`` whose train split keeps ``n_views`` evenly spread frames."""

    def edit(meta: dict) -> dict:
        frames = meta["frames"]
        if n_views > len(frames):
            raise BenchError(f"{src}: asked for {n_views} train views but transforms_train.json has {len(frames)}")
        meta = dict(meta)
        meta["frames"] = [frames[i] for i in evenly_spaced(len(frames), n_views)]
        return meta

    return derive_dataset(src, dst, edit, {"train_views": n_views})


def rotation_matrix(axis: Sequence[float], angle: float):
    import numpy as np

    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    c, s, C = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return np.array(
        [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
         [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
         [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]
    )


def perturb_pose(c2w, rot_deg: float, trans: float, rng):
    """Rotate ``c2w`` (4, 4) by ``rot_deg`` degrees about a random axis (about the camera centre) and
    move its centre by a random vector of length ``trans`` (scene units)."""
    import numpy as np

    c2w = np.asarray(c2w, dtype=np.float64).copy()
    axis = rng.normal(size=3)
    R = rotation_matrix(axis, math.radians(rot_deg))
    c2w[:3, :3] = R @ c2w[:3, :3]
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    c2w[:3, 3] = c2w[:3, 3] + trans * direction
    return c2w


def perturb_poses(src: str, dst: str, rot_deg: float, trans_frac: float, seed: int = 0) -> str:
    """A copy of ``src`` whose train poses are noisy: each camera is rotated by ``rot_deg`` degrees
    and shifted by ``trans_frac`` times the mean camera distance from the scene-box centre.

    Test and val poses stay exact, so held-out PSNR measures what pose error costs.
    """
    import numpy as np

    rng = np.random.default_rng(seed)

    def edit(meta: dict) -> dict:
        meta = dict(meta)
        poses = [np.asarray(f["transform_matrix"], dtype=np.float64) for f in meta["frames"]]
        aabb = meta.get("aabb")
        centre = np.mean(np.asarray(aabb, dtype=np.float64), axis=0) if aabb else np.zeros(3)
        radius = float(np.mean([np.linalg.norm(p[:3, 3] - centre) for p in poses])) if poses else 1.0
        frames = []
        for f, p in zip(meta["frames"], poses):
            f = dict(f)
            f["transform_matrix"] = perturb_pose(p, rot_deg, trans_frac * radius, rng).tolist()
            frames.append(f)
        meta["frames"] = frames
        return meta

    return derive_dataset(src, dst, edit, {"pose_noise_deg": rot_deg, "pose_noise_trans_frac": trans_frac, "seed": seed})


def count_frames(dataset: str, split: str) -> int:
    path = os.path.join(dataset, f"transforms_{split}.json")
    return len(_load_json(path)["frames"]) if os.path.isfile(path) else 0


# --------------------------------------------------------------------------------------------
# Floaters: rendered opacity where the ground truth is empty
# --------------------------------------------------------------------------------------------


def _alpha(path: str):
    import numpy as np
    from PIL import Image

    with Image.open(path) as im:
        if im.mode not in ("RGBA", "LA"):
            return None
        return np.asarray(im.convert("RGBA"), dtype=np.float32)[..., 3] / 255.0


def floater_stats(render_dir: str, dataset: str, split: str = "test", empty_below: float = 0.02,
                  opaque_above: float = 0.5) -> dict:
    """Compare rendered alpha with ground-truth alpha on held-out views.

    Ground-truth background = pixels with dataset alpha below ``empty_below``. Returns
    ``floater_alpha`` (mean rendered alpha over background pixels) and ``floater_pixels`` (share of
    background pixels rendered more opaque than ``opaque_above``), averaged over views, and ``n_views``.
    """
    import numpy as np

    meta = _load_json(os.path.join(dataset, f"transforms_{split}.json"))
    means, shares = [], []
    for k, frame in enumerate(meta["frames"]):
        stem = os.path.basename(frame["file_path"]) if frame.get("file_path") else f"view_{k:03d}"
        gt_path = os.path.join(dataset, frame["file_path"])
        if not os.path.splitext(gt_path)[1]:
            gt_path += ".png"
        pred_path = os.path.join(render_dir, stem + ".png")
        if not os.path.isfile(pred_path):
            pred_path = os.path.join(render_dir, f"view_{k:03d}.png")
        if not (os.path.isfile(gt_path) and os.path.isfile(pred_path)):
            continue
        gt, pred = _alpha(gt_path), _alpha(pred_path)
        if gt is None or pred is None or gt.shape != pred.shape:
            continue
        bg = gt < empty_below
        if not bg.any():
            continue
        means.append(float(pred[bg].mean()))
        shares.append(float((pred[bg] > opaque_above).mean()))
    if not means:
        return {"floater_alpha": None, "floater_pixels": None, "n_views": 0}
    return {"floater_alpha": float(np.mean(means)), "floater_pixels": float(np.mean(shares)), "n_views": len(means)}


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def write_csv(path: str, rows: Sequence[dict], columns: Optional[Sequence[str]] = None) -> None:
    """Rows of dicts -> CSV; columns default to the union of keys in first-seen order."""
    if columns is None:
        columns = []
        for row in rows:
            for key in row:
                if key not in columns:
                    columns.append(key)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row.get(k)) for k in columns})


def _cell(value):
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return "" if value is None else value


def write_json(path: str, obj) -> None:
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    with open(path, "w", encoding="utf-8") as fh:
        json.dump(clean(obj), fh, indent=1)


def fmt(value, digits: int = 2) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "nan"
        return f"{value:.{digits}f}"
    return str(value)


def markdown_table(rows: Sequence[dict], columns: Sequence[str], headers: Optional[Sequence[str]] = None,
                   digits: int = 2) -> str:
    headers = list(headers or columns)
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for row in rows:
        out.append("| " + " | ".join(fmt(row.get(c), digits) for c in columns) + " |")
    return "\n".join(out)


def human_bytes(n: Optional[float]) -> str:
    if n is None:
        return "-"
    for unit in ("B", "KB", "MB", "GB"):
        if abs(n) < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} GB"


def mean_std(values: Sequence[Optional[float]]) -> tuple[Optional[float], Optional[float], int]:
    """Mean and sample standard deviation of the finite values; (None, None, 0) when there are none."""
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not xs:
        return None, None, 0
    m = sum(xs) / len(xs)
    sd = math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else 0.0
    return m, sd, len(xs)


# --------------------------------------------------------------------------------------------
# Speed against accuracy
# --------------------------------------------------------------------------------------------


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated when size (x) should be small and quality (y) high.

    A point is dominated when another is no larger and no worse and strictly better in one of the two.
    Points with a missing or non-finite coordinate never belong to the front. Returned sorted by size.
    """
    valid = [i for i, (x, y) in enumerate(points)
             if x is not None and y is not None and math.isfinite(x) and math.isfinite(y)]
    front = []
    for i in valid:
        xi, yi = points[i]
        dominated = any(
            (points[j][0] <= xi and points[j][1] >= yi) and (points[j][0] < xi or points[j][1] > yi)
            for j in valid if j != i
        )
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][0], -points[i][1]))


def auto_size_verdict(auto: tuple[float, float], fixed: Sequence[tuple[float, float]],
                      tol_db: float = 0.5, max_param_ratio: float = 0.5) -> dict:
    """Does ``--size auto`` (params, psnr) land on or near the front of the fixed sizes tried?

    ``ok``: auto is not dominated by any fixed size, or it is within ``tol_db`` of the best fixed size
    with no more parameters than it. ``within_half``: the stricter target, within ``tol_db`` of the
    best at no more than ``max_param_ratio`` of its parameters. ``gap_db`` = best PSNR - auto PSNR.
    """
    valid = [(x, y) for x, y in fixed if x is not None and y is not None and math.isfinite(y)]
    ax, ay = auto
    if not valid or ax is None or ay is None or not math.isfinite(ay):
        return {"ok": None, "within_half": None, "gap_db": None, "param_ratio": None, "best": None}
    best = max(valid, key=lambda p: (p[1], -p[0]))
    gap = best[1] - ay
    ratio = ax / best[0] if best[0] else None
    dominated = any((x <= ax and y >= ay) and (x < ax or y > ay) for x, y in valid)
    close = gap <= tol_db
    return {
        "ok": bool((close and ratio is not None and ratio <= 1.0) or not dominated),
        "within_half": bool(close and ratio is not None and ratio <= max_param_ratio),
        "on_front": not dominated,
        "gap_db": gap,
        "param_ratio": ratio,
        "best": {"params": best[0], "psnr": best[1]},
    }


# --------------------------------------------------------------------------------------------
# Charts (matplotlib, Agg backend: no display needed)
# --------------------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _panel_grid(plt, n_panels: int, width: float = 4.6):
    """(fig, axes, cols): up to 3 panels a row, one per scene or study."""
    n = max(1, n_panels)
    cols = min(3, n)
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(width * cols, 3.6 * rows), squeeze=False)
    return fig, axes, cols


def _finish_figure(plt, fig, axes, n_used: int, title: str, path: str, legend_space: float = 0.1) -> str:
    """Hide unused panels, add one legend shared by all panels (each label once), save and close."""
    for ax in list(axes.flat)[n_used:]:
        ax.axis("off")
    handles, labels = [], []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(4, len(labels)), fontsize=8)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, legend_space if handles else 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def chart_psnr_vs_time(curves: dict, path: str, title: str) -> str:
    """``curves``: {(scene, series): [(seconds, psnr), ...]} -> one line per series, one panel per scene."""
    plt = _plt()
    scenes = sorted({scene for scene, _ in curves})
    fig, axes, cols = _panel_grid(plt, len(scenes))
    series_names = sorted({s for _, s in curves})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(series_names)}
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        for (sc, series), pts in sorted(curves.items()):
            pts = [(t, p) for t, p in pts if t is not None and p is not None and math.isfinite(p)]
            if sc != scene or not pts:
                continue
            xs, ys = zip(*sorted(pts))
            ax.plot(xs, ys, marker="o", ms=3, label=series, color=colours[series])
        ax.set_title(scene)
        ax.set_xlabel("training time (s)")
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3)
    return _finish_figure(plt, fig, axes, len(scenes), title, path, legend_space=0.08)


def _draw_size_points(ax, pts: Sequence[dict], colours: dict, legend: bool) -> None:
    """Scatter (params, psnr) of ``pts`` on ``ax`` with the Pareto front as a dashed step line, members ringed."""
    for p in pts:
        star = "auto" in p["series"]
        ax.scatter([p["params"]], [p["psnr"]], color=colours[p["series"]], label=p["series"] if legend else None,
                   zorder=3, marker="*" if star else "o", s=90 if star else 30)
    front = pareto_front([(p["params"], p["psnr"]) for p in pts])
    if front:
        fx = [pts[i]["params"] for i in front]
        fy = [pts[i]["psnr"] for i in front]
        ax.step(fx, fy, where="post", ls="--", color="k", lw=1, label="Pareto front" if legend else None)
        ax.scatter(fx, fy, s=160, facecolors="none", edgecolors="k", zorder=4)
    ax.set_xscale("log")
    # Labels at 1, 2 and 5 per decade: decades alone leave a panel spanning less than one unlabelled,
    # and every minor tick overlaps into an unreadable row.
    from matplotlib.ticker import EngFormatter, LogLocator, NullFormatter
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(EngFormatter(sep=""))  # 200k, 1M
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(alpha=0.3, which="both")


def chart_psnr_vs_size(points: Sequence[dict], path: str, title: str, zoom_db: float = 2.0) -> str:
    """``points``: dicts with scene, series, params, psnr. Per scene, the Pareto front is drawn as a
    dashed step line and its members ringed. When the panel spans more than 2 ``zoom_db``, an inset
    repeats the points within ``zoom_db`` of the best: the sizes of the fast method usually differ by
    tenths of a dB, invisible beside a slow method 20 dB lower."""
    plt = _plt()
    scenes = sorted({p["scene"] for p in points})
    fig, axes, cols = _panel_grid(plt, len(scenes))
    series_names = sorted({p["series"] for p in points})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(series_names)}
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        pts = [p for p in points if p["scene"] == scene and p.get("params") is not None and p.get("psnr") is not None
               and math.isfinite(p["psnr"])]
        _draw_size_points(ax, pts, colours, legend=True)
        ax.set_title(scene)
        ax.set_xlabel("parameters")
        ax.set_ylabel("final test PSNR (dB)")
        if pts:
            best = max(p["psnr"] for p in pts)
            near = [p for p in pts if p["psnr"] >= best - zoom_db]
            if len(near) > 1 and best - min(p["psnr"] for p in pts) > 2 * zoom_db:
                inset = ax.inset_axes([0.5, 0.1, 0.47, 0.5])
                _draw_size_points(inset, near, colours, legend=False)
                # A fixed 2-dB window, so a 0.05 dB gap looks as small as it is.
                inset.set_ylim(best - zoom_db, best + 0.15 * zoom_db)
                xs = [p["params"] for p in near]
                inset.set_xlim(min(xs) / 1.5, max(xs) * 1.5)
                inset.tick_params(labelsize=6)
                inset.set_title(f"within {zoom_db:g} dB of the best", fontsize=7)
    return _finish_figure(plt, fig, axes, len(scenes), title, path)


def chart_bars(groups: dict, path: str, title: str, ylabel: str, threshold: Optional[float] = None) -> str:
    """``groups``: {panel: {series: [(x_label, mean, spread), ...]}} -> grouped bars with error bars."""
    plt = _plt()
    panels = list(groups)
    fig, axes, cols = _panel_grid(plt, len(panels), width=4.8)
    all_series = sorted({s for g in groups.values() for s in g})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(all_series)}
    for k, panel in enumerate(panels):
        ax = axes[k // cols][k % cols]
        series = groups[panel]
        labels = []
        for pts in series.values():
            for lab, _, _ in pts:
                if lab not in labels:
                    labels.append(lab)
        width = 0.8 / max(1, len(series))
        for j, (name, pts) in enumerate(sorted(series.items())):
            lookup = {lab: (m, s) for lab, m, s in pts}
            xs = [i + j * width for i in range(len(labels))]
            ms = [lookup.get(lab, (None, None))[0] for lab in labels]
            ss = [lookup.get(lab, (None, None))[1] or 0.0 for lab in labels]
            ax.bar(xs, [m if m is not None else 0.0 for m in ms], width, yerr=ss, label=name,
                   color=colours[name], capsize=2)
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(labels))])
        ax.set_xticklabels(labels, fontsize=8)
        if threshold is not None:
            ax.axhline(threshold, color="r", ls="--", lw=1, label="breakdown threshold")
        ax.set_title(panel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
    return _finish_figure(plt, fig, axes, len(panels), title, path)


# --------------------------------------------------------------------------------------------
# Machine description
# --------------------------------------------------------------------------------------------


def machine_info() -> dict:
    """Where the numbers came from: CPU model, cores, load, Python/torch versions."""
    info = {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        info["load_avg"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    try:
        import importlib.metadata as md

        info["torch"] = md.version("torch")
    except Exception:  # noqa: BLE001 (any metadata problem just leaves the field out)
        pass
    return info
