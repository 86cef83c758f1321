"""Build the installable NeRF Bridge extension zip into dist/.

    python scripts/build_addon.py                         # see "Which builder" below
    python scripts/build_addon.py --blender /path/to/blender   # `blender --command extension build`

Which builder: ``--blender`` runs Blender's ``--command extension validate/build``; otherwise the
same command-line tool shipped inside the ``bpy`` module (``bl_pkg/cli/blender_ext.py``) when it is
installed; otherwise Python's zipfile with the manifest checks and exclusion rules below.

The add-on is staged in a temporary folder together with a copy of nerf_core (without tests) in
``vendor/nerf_core``: the training process the add-on starts puts that folder on its PYTHONPATH, so
an installed extension needs no checkout. The manifest is validated first (by Blender when given,
else by the checks below); the zip is ``dist/<id>-<version>.zip``.
"""
from __future__ import annotations

import argparse
import fnmatch
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile

try:
    import tomllib
except ImportError:  # Python < 3.11
    tomllib = None

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ADDON_DIR = os.path.join(REPO_ROOT, "addon")
VENDOR = "vendor"
REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type", "blender_version_min",
            "license")
# Blender skips these whatever the manifest says (dot files, caches, compiled files).
DEFAULT_EXCLUDES = (".*", "__pycache__/", "*.pyc", "*.pyo", "*.zip")


class BuildError(Exception):
    pass


def read_manifest(addon_dir: str) -> dict:
    path = os.path.join(addon_dir, "blender_manifest.toml")
    if not os.path.isfile(path):
        raise BuildError(f"{path}: missing")
    if tomllib is None:
        raise BuildError("reading the manifest needs Python 3.11+ (tomllib), or pass --blender")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise BuildError(f"{path}: invalid TOML: {exc}") from None


def validate_manifest(manifest: dict) -> list:
    """Problems Blender's validator would report for the fields we use (empty list when valid)."""
    problems = [f"missing field '{key}'" for key in REQUIRED if key not in manifest]
    ident = manifest.get("id", "")
    if ident and not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", str(ident)):
        problems.append(f"id {ident!r}: must be a Python identifier (letters, digits, underscore)")
    version = str(manifest.get("version", ""))
    if version and not re.fullmatch(r"\d+\.\d+\.\d+([-+][0-9A-Za-z.-]+)?", version):
        problems.append(f"version {version!r}: must be semantic (MAJOR.MINOR.PATCH)")
    tagline = str(manifest.get("tagline", ""))
    if len(tagline) > 64:
        problems.append(f"tagline is {len(tagline)} characters; at most 64")
    if tagline and tagline[-1] in ".!?,;:":
        problems.append("tagline must not end with punctuation")
    if manifest.get("type") not in (None, "add-on", "theme"):
        problems.append(f"type {manifest.get('type')!r}: must be 'add-on' or 'theme'")
    bmin = str(manifest.get("blender_version_min", ""))
    if bmin and not re.fullmatch(r"\d+\.\d+\.\d+", bmin):
        problems.append(f"blender_version_min {bmin!r}: must be X.Y.Z")
    licenses = manifest.get("license")
    if licenses is not None and (not isinstance(licenses, list) or not all(
            isinstance(x, str) and x.startswith("SPDX:") for x in licenses)):
        problems.append("license must be a list of 'SPDX:...' strings")
    return problems


def _excluded(rel: str, is_dir: bool, patterns) -> bool:
    """gitignore-like: 'name/' matches directories, '/x' is anchored at the root, else any component."""
    name = os.path.basename(rel)
    for pat in patterns:
        dir_only = pat.endswith("/")
        p = pat.rstrip("/")
        if dir_only and not is_dir:
            continue
        if p.startswith("/"):
            if fnmatch.fnmatch(rel, p[1:]):
                return True
        elif fnmatch.fnmatch(name, p) or fnmatch.fnmatch(rel, p):
            return True
    return False


def stage(addon_dir: str, dest: str) -> None:
    """Copy the add-on and a test-free nerf_core into ``dest``."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "tests", VENDOR)
    shutil.copytree(addon_dir, dest, ignore=ignore)
    core = os.path.join(REPO_ROOT, "nerf_core")
    if not os.path.isfile(os.path.join(core, "__init__.py")):
        raise BuildError(f"{core}: nerf_core not found; the add-on could not train without it")
    shutil.copytree(core, os.path.join(dest, VENDOR, "nerf_core"), ignore=ignore)


def zip_with_python(stage_dir: str, manifest: dict, out_path: str) -> list:
    patterns = list(DEFAULT_EXCLUDES) + list(manifest.get("build", {}).get("paths_exclude_pattern", []))
    names = []
    # A new temporary (mkstemp: exclusive, never through a link) beside the zip; this script runs on
    # any Python without packages, so nerf_core.utils.atomic (numpy) is out of reach.
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(out_path)}.", suffix=".part",
                               dir=os.path.dirname(os.path.abspath(out_path)))
    with os.fdopen(fd, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED) as zf:
        for root, dirs, files in os.walk(stage_dir):
            rel_root = os.path.relpath(root, stage_dir).replace(os.sep, "/")
            rel_root = "" if rel_root == "." else rel_root + "/"
            dirs[:] = sorted(d for d in dirs if not _excluded(rel_root + d, True, patterns))
            for f in sorted(files):
                rel = rel_root + f
                if not _excluded(rel, False, patterns):
                    zf.write(os.path.join(root, f), rel)
                    names.append(rel)
    os.chmod(tmp, 0o644)  # mkstemp's file is private (0600); an add-on zip is for everyone
    os.replace(tmp, out_path)
    return names


def bundled_blender_ext() -> str:
    """Path of Blender's extension CLI inside the installed ``bpy`` module, or '' (found without
    importing bpy, which takes seconds)."""
    import importlib.util

    try:
        spec = importlib.util.find_spec("bpy")
    except (ImportError, ValueError):
        return ""
    for root in (spec.submodule_search_locations or []) if spec else []:
        for version in sorted(os.listdir(root), reverse=True):
            path = os.path.join(root, version, "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")
            if os.path.isfile(path):
                return path
    return ""


def _run_checked(cmd: list, what: str) -> None:
    """Run a Blender tool step; BuildError saying what ran, its exit status and its output (or that it
    printed nothing: a --blender that is not Blender, such as /bin/false)."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, errors="replace")
    except OSError as exc:
        raise BuildError(f"{what}: cannot run {cmd[0]} ({exc.strerror or exc})") from None
    if proc.returncode != 0:
        output = (proc.stdout + proc.stderr).strip()
        raise BuildError(f"{what} failed: {cmd[0]} exited with status {proc.returncode}"
                         + (f":\n{output}" if output else " and printed nothing; is it a Blender 4.2+ executable?"))


def build(blender: str = "", out_dir: str = "", use_bundled: bool = True, addon_dir: str = ADDON_DIR) -> str:
    out_dir = out_dir or os.path.join(REPO_ROOT, "dist")
    manifest = read_manifest(addon_dir)
    problems = validate_manifest(manifest)
    if problems:
        raise BuildError("blender_manifest.toml: " + "; ".join(problems))
    os.makedirs(out_dir, exist_ok=True)
    out_path = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
    with tempfile.TemporaryDirectory(prefix="nerf_bridge_build_") as tmp:
        stage_dir = os.path.join(tmp, manifest["id"])
        stage(addon_dir, stage_dir)
        tool = [blender, "--factory-startup", "--command", "extension"] if blender else []
        if not tool and use_bundled and bundled_blender_ext():
            tool = [sys.executable, bundled_blender_ext()]
        if tool:
            _run_checked(tool + ["validate", stage_dir], "extension validate")
            _run_checked(tool + ["build", "--source-dir", stage_dir, "--output-filepath", out_path],
                         "extension build")
        else:
            zip_with_python(stage_dir, manifest, out_path)
    return out_path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--blender", default="", help="Blender executable: build and validate with Blender itself")
    ap.add_argument("--out-dir", default="", help="output folder (default dist/)")
    ap.add_argument("--no-bundled", action="store_true",
                    help="without --blender, use Python's zipfile even when bpy's extension tool is installed")
    args = ap.parse_args(argv)
    if args.out_dir and os.path.exists(args.out_dir) and not os.path.isdir(args.out_dir):
        print(f"build_addon: error: --out-dir {args.out_dir}: is a file, and a folder is needed there",
              file=sys.stderr)
        return 2
    if args.blender and not shutil.which(args.blender):
        print(f"build_addon: error: --blender {args.blender}: not an executable", file=sys.stderr)
        return 2
    try:
        path = build(args.blender, args.out_dir, use_bundled=not args.no_bundled)
    except BuildError as exc:
        print(f"build_addon: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"build_addon: error: could not write the zip: {exc}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
