"""Shared start-up for the headless scripts.

Every script in ``scripts/`` runs two ways with the same flags:

    blender -b scene.blend --python scripts/X.py -- ARGS       (Blender's own Python)
    python scripts/X.py [--blend scene.blend] ARGS              (the ``bpy`` module from PyPI)

``script_args()`` returns ARGS in both cases; ``open_blend()`` loads ``--blend`` when the script runs
as plain Python (under Blender the file on the command line is already open). The preamble the
scripts share is here too: ``scene_parser`` (a parser with ``--blend``), ``add_python_option`` and
``torch_python`` (the interpreter that runs nerf_core), and ``fail`` (one error line, exit code 2).
"""
from __future__ import annotations

import argparse
import errno
import os
import sys

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    # Makes ``import addon`` and ``import nerf_core`` work from a checkout without installing.
    sys.path.insert(0, REPO_ROOT)

from nerf_core.contract.paths import file_problem  # noqa: E402  (standard library + numpy: fine in Blender)


def inside_blender() -> bool:
    """True when running inside a Blender executable rather than the PyPI ``bpy`` module."""
    try:
        import bpy
    except ImportError:
        return False
    module = getattr(bpy.app, "module", None)  # Blender 4.4+
    if module is None:  # older: the bpy module has no Blender binary
        module = not bpy.app.binary_path
    return not module


def script_args() -> list[str]:
    """The script's own arguments: what follows ``--`` under Blender, else ``sys.argv[1:]``."""
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1 :]
    if inside_blender():
        return []
    return sys.argv[1:]


def scene_parser(prog: str, description: str, blend_help: str) -> argparse.ArgumentParser:
    """The parser of a script that works on a scene, its ``--blend`` option already added."""
    ap = argparse.ArgumentParser(prog=prog, description=description,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--blend", help=f"{blend_help} (plain Python; under Blender the open file is used)")
    return ap


def add_python_option(ap: argparse.ArgumentParser, used_by: str) -> None:
    """``--python``: the interpreter with torch for ``used_by`` (default $NERF_PYTHON, else this Python)."""
    ap.add_argument("--python", default=os.environ.get("NERF_PYTHON", ""),
                    help=f"interpreter with torch for {used_by} (default: $NERF_PYTHON, else this Python)")


def fail(prog: str, message: str) -> None:
    """A script's expected failure: one ``prog: error: message`` line on stderr, exit code 2."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    exit_code(2)


def same_file(a: str, b: str) -> bool:
    """Whether two paths name one file: by identity (device and inode), through links and relative
    paths; two paths of which one does not exist are not the same file."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def check_output(prog: str, flag: str, path: str, overwrite: bool, inputs: dict) -> str:
    """The one rule for every script's output file: an absolute path that is not a link loop, that
    exists only with ``overwrite``, and that is none of the ``inputs`` ({flag: path or None}; under
    Blender the open .blend counts as one). ``fail``s naming the flags otherwise."""
    out = os.path.abspath(path)
    try:
        os.stat(out)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            fail(prog, f"{flag} {path}: a symbolic link loop (a link that points back to itself); remove it "
                       "or choose another name")
    except ValueError:
        fail(prog, f"{flag} {path!r}: not a usable file name")
    found = {k: v for k, v in inputs.items() if v}
    if inside_blender():
        import bpy

        if bpy.data.filepath:
            found.setdefault("the open scene", bpy.data.filepath)
    for name, src in found.items():
        if same_file(out, src):
            fail(prog, f"{flag} {path} is the same file as {name} {src}; an output never replaces an input. "
                       "Choose another name")
    if os.path.lexists(out) and not overwrite:
        fail(prog, f"{flag} {out} already exists; pass --overwrite or choose another file")
    return out


def out_blend(prog: str, path: str, overwrite: bool, inputs: dict | None = None) -> str:
    """``--out OUT.blend`` as an absolute path; ``fail``s naming the flag when it does not end in .blend,
    exists without ``overwrite``, is one of ``inputs`` (``check_output``) or its folder is missing."""
    if not os.path.abspath(path).endswith(".blend"):
        fail(prog, f"--out {path!r}: must name a .blend file")
    out = check_output(prog, "--out", path, overwrite, inputs or {})
    if not os.path.isdir(os.path.dirname(out)):
        fail(prog, f"--out {out}: folder {os.path.dirname(out)} does not exist")
    return out


def torch_python(prog: str, requested: str) -> str:
    """The interpreter that runs nerf_core for a script: ``requested`` (``--python``), else
    $NERF_PYTHON, else this Python; when it cannot import torch, ``fail`` says what to pass."""
    from addon.bridge import child_process

    try:
        return child_process.resolve_interpreter(requested, addon_dir=os.path.join(REPO_ROOT, "addon"))
    except child_process.SetupError as exc:
        fail(prog, f"{exc} (or pass --python / set NERF_PYTHON)")


def open_blend(path: str | None) -> None:
    """Open ``path`` when given; errors name the file. Under Blender without --blend, keep the open file."""
    if not path:
        return
    problem = file_problem(path)
    if problem:
        raise SystemExit(f"error: --blend {path!r}: {problem}")
    import bpy

    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path))
    except RuntimeError as exc:
        raise SystemExit(f"error: --blend {path!r}: Blender could not open it: {exc}")


MAX_FRAME = 1048574  # Blender's MAXFRAME: a larger range was a MemoryError


def frame_range(prog: str, text, scene) -> list:
    """``--frames A:B``: frames A..B inclusive (step 1), else the scene's start..end by its frame step.
    A malformed or out-of-range value ``fail``s naming the flag."""
    if not text:
        return list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        fail(prog, f"--frames {text!r}: expected A:B, two whole frame numbers, e.g. 1:48")
    if b < a:
        fail(prog, f"--frames {text!r}: the last frame comes before the first")
    if max(abs(a), abs(b)) > MAX_FRAME:
        fail(prog, f"--frames {text!r}: Blender's frames run from -{MAX_FRAME} to {MAX_FRAME}")
    return list(range(a, b + 1))


def exit_code(code: int, skip_finalization: bool = False) -> None:
    """Exit with ``code`` in both modes (under Blender, sys.exit inside --python is honoured in -b).

    ``skip_finalization``: leave without Python's shutdown also as the bpy module. The bpy modules of
    Blender 4.2 and 4.5 crash (4.2: SIGSEGV) or hang (4.5) at interpreter exit once a Python render
    engine has rendered (scripts/render_nerf.py); the work is done and written by then."""
    sys.stdout.flush()
    sys.stderr.flush()
    if inside_blender() or skip_finalization:
        os._exit(code)
    sys.exit(code)
