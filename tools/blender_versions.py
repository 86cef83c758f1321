"""Run the Blender-side tests against several Blender releases, each in its own virtual environment.

    python tools/blender_versions.py                        # 4.2 LTS, 4.5 LTS and 5.0 (the defaults)
    python tools/blender_versions.py --versions 4.2.23 --groups register,capture
    python tools/blender_versions.py --cache /big/disk/venvs --markdown table.md

For each version it makes (or reuses) ``CACHE/bpy-VERSION`` with a Python 3.11 interpreter (bpy from
PyPI exists for CPython 3.11 only up to 5.0), installs ``bpy==VERSION`` plus what the Blender-side tests
need (torch for the trainer child, numpy below 2 as the bpy 4.5+ wheels require, Pillow, OpenEXR,
pytest, plyfile), then runs each test group from ``blender_tests/`` against this checkout and prints a
table of version x group. CI runs only the newest (the normal suite, in .venv); this runs on demand.

bpy wheels are 300-800 MB each and the first install of a version takes minutes; later runs reuse the
environment unless the requirements below change. Exit code: 0 when every group passed, 1 otherwise.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import time

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_VERSIONS = ("4.2.23", "4.5.15", "5.0.1")  # 4.2 LTS and 4.5 LTS (latest patch on PyPI), 5.0
# The Blender-side tests by what they exercise (issue: register, capture, import, render engine).
GROUPS = {
    "register": ["blender_tests/test_register.py", "blender_tests/test_addon_layers.py"],
    "capture": ["blender_tests/test_capture.py", "blender_tests/test_capture_layout.py",
                "blender_tests/test_capture_points.py", "blender_tests/test_capture_world.py",
                "blender_tests/test_capture_ui.py"],
    "import": ["blender_tests/test_import_views.py", "blender_tests/test_planes.py"],
    "render_engine": ["blender_tests/test_render_engine.py"],
    "train_loop": ["blender_tests/test_full_loop.py"],
    "torch_setup": ["blender_tests/test_torch_setup.py"],
}
# What the tests need besides bpy. torch: the CPU build the development environment pins (override
# with NERF_TORCH_SPEC / NERF_TORCH_INDEX); numpy < 2: the bpy 4.5+ wheels require it.
TORCH_SPEC = os.environ.get("NERF_TORCH_SPEC", "torch==2.13.0")
TORCH_INDEX = os.environ.get("NERF_TORCH_INDEX", "https://download.pytorch.org/whl/cpu")
TEST_DEPS = ["numpy>=1.26,<2", "pillow>=10", "openexr>=3.2,<4", "pytest>=8", "plyfile==1.1.2"]
GROUP_TIMEOUT = float(os.environ.get("NERF_GROUP_TIMEOUT", "1200"))  # seconds per test group
SUMMARY = re.compile(r"(\d+) (passed|failed|skipped|error|errors|xfailed|xpassed)")


def pick_python() -> str:
    """A CPython 3.11 to build the environments with ($NERF_PYTHON, else python3.11 on PATH)."""
    for cand in (os.environ.get("NERF_PYTHON", ""), "python3.11", sys.executable):
        path = shutil.which(cand) if cand else None
        if path and subprocess.run([path, "-c",
                                    "import sys; sys.exit(sys.version_info[:2] != (3, 11))"]).returncode == 0:
            return path
    sys.exit("blender_versions: a Python 3.11 is needed (bpy wheels exist for 3.11 only); set NERF_PYTHON")


def requirements(version: str) -> list:
    return [f"bpy=={version}", TORCH_SPEC, *TEST_DEPS]


def ensure_env(cache: str, version: str, base_python: str, log) -> str:
    """``CACHE/bpy-VERSION/bin/python`` with the requirements installed (reused when unchanged)."""
    venv = os.path.join(cache, f"bpy-{version}")
    python = os.path.join(venv, "bin", "python")
    stamp = os.path.join(venv, ".nerf_requirements")
    want = hashlib.sha256(f"{requirements(version)} {TORCH_INDEX}".encode()).hexdigest()
    if os.path.isfile(stamp) and open(stamp).read().strip() == want:
        return python
    if not os.path.isfile(python):
        subprocess.run([base_python, "-m", "venv", venv], check=True, stdout=log, stderr=log)
    pip = [python, "-m", "pip", "install", "--disable-pip-version-check", "-q"]
    # torch from its CPU index first (PyPI's Linux torch pulls GBs of CUDA), then the rest from PyPI.
    subprocess.run(pip + ["--index-url", TORCH_INDEX, "--extra-index-url", "https://pypi.org/simple", TORCH_SPEC],
                   check=True, stdout=log, stderr=log)
    subprocess.run(pip + requirements(version), check=True, stdout=log, stderr=log)
    with open(stamp, "w") as fh:
        fh.write(want)
    return python


def run_group(python: str, files: list, log) -> dict:
    """pytest on ``files`` with this checkout's add-on; counts of passed/failed/skipped and seconds."""
    present = [f for f in files if os.path.isfile(os.path.join(REPO_ROOT, f))]
    if not present:
        return {"status": "no tests", "seconds": 0.0}
    env = dict(os.environ, PYTHONPATH=REPO_ROOT)
    t0 = time.monotonic()
    cmd = [python, "-m", "pytest", "-q", "-p", "no:cacheprovider", *present]
    try:
        proc = subprocess.run(cmd, cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              timeout=GROUP_TIMEOUT)
    except subprocess.TimeoutExpired as exc:
        # bpy 4.5's module can hang at interpreter exit after the tests have reported: keep what they said.
        out = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        proc = subprocess.CompletedProcess(cmd, -9, out + f"\n[blender_versions: killed after {GROUP_TIMEOUT} s]\n")
    log.write(proc.stdout)
    log.flush()
    counts = {}
    for line in reversed(proc.stdout.splitlines()):
        found = SUMMARY.findall(line)
        if found and (" in " in line):
            counts = {kind.rstrip("s") if kind == "errors" else kind: int(n) for n, kind in found}
            break
    bad = counts.get("failed", 0) + counts.get("error", 0)
    status = "PASS" if proc.returncode == 0 else ("FAIL" if bad or counts else f"exit {proc.returncode}")
    if proc.returncode < 0 and counts and not bad:  # every test passed, then the interpreter died at exit
        status = f"PASS, then killed by signal {-proc.returncode} at exit"
    return {"status": status, "seconds": time.monotonic() - t0, **counts}


def cell(result: dict) -> str:
    if result["status"] in ("no tests",) or result["status"].startswith("exit") or result["status"] == "install failed":
        return result["status"]
    parts = [f"{result.get('passed', 0)} passed"]
    parts += [f"{result[k]} {k}" for k in ("failed", "error", "skipped") if result.get(k)]
    return f"{result['status']}: {', '.join(parts)} ({result['seconds']:.0f} s)"


def table(results: dict, groups: list) -> str:
    lines = ["| Blender (bpy) | " + " | ".join(groups) + " |", "|---" * (len(groups) + 1) + "|"]
    for version, row in results.items():
        lines.append(f"| {version} | " + " | ".join(cell(row[g]) for g in groups) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--versions", default=",".join(DEFAULT_VERSIONS), help="comma-separated bpy versions")
    ap.add_argument("--groups", default=",".join(GROUPS), help=f"comma-separated, of {', '.join(GROUPS)}")
    ap.add_argument("--cache", default=os.path.join(REPO_ROOT, ".venvs"), help="where the environments live")
    ap.add_argument("--markdown", help="also write the table to this file")
    args = ap.parse_args(argv)
    groups = [g for g in args.groups.split(",") if g]
    unknown = [g for g in groups if g not in GROUPS]
    if unknown:
        ap.error(f"--groups: unknown {', '.join(unknown)} (known: {', '.join(GROUPS)})")
    os.makedirs(args.cache, exist_ok=True)
    base = pick_python()
    results = {}
    for version in [v for v in args.versions.split(",") if v]:
        log_path = os.path.join(args.cache, f"bpy-{version}.log")
        with open(log_path, "w") as log:
            print(f"== bpy {version}: environment (log: {log_path})", flush=True)
            try:
                python = ensure_env(args.cache, version, base, log)
            except subprocess.CalledProcessError as exc:
                print(f"   install failed: {exc}; see {log_path}", flush=True)
                results[version] = {g: {"status": "install failed", "seconds": 0.0} for g in groups}
                continue
            results[version] = {}
            for group in groups:
                print(f"   {group} ...", end=" ", flush=True)
                results[version][group] = run_group(python, GROUPS[group], log)
                print(cell(results[version][group]), flush=True)
    text = table(results, groups)
    print(text)
    if args.markdown:
        with open(args.markdown, "w") as fh:
            fh.write(text + "\n")
    ok = all(r["status"].startswith("PASS") or r["status"] == "no tests"
             for row in results.values() for r in row.values())
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
