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
import os
import sys

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO_ROOT not in sys.path:
    # Makes ``import addon`` and ``import nerf_core`` work from a checkout without installing.
    sys.path.insert(0, REPO_ROOT)

from nerf_core.contract import outputs  # noqa: E402  (standard library + numpy: fine in Blender)
from nerf_core.contract.paths import file_problem  # noqa: E402
from nerf_core.utils.atomic import atomic_path  # noqa: E402  (standard library: fine in Blender)
from nerf_core.utils.interrupts import honour_interrupts  # noqa: E402  (standard library)

# Every stop is honoured: a script started with SIGINT ignored (as a farm manager or Blender starts
# jobs) would ignore Ctrl-C and go on to save its output. The CLI does the same (cli/main.py).
honour_interrupts()


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


def whole_number(low: int, high: int, why: str = ""):
    """An argparse ``type``: an integer in ``low..high``; otherwise one line naming the flag (argparse
    adds it) and the range, ``why`` saying what the range is."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must lie in {low}..{high}{' (' + why + ')' if why else ''}, "
                                             f"got {value}")
        return value
    return parse


def share(text: str) -> float:
    """An argparse ``type``: a finite number in [0, 1] (a colour channel); otherwise one line naming the
    flag (argparse adds it). ``float`` alone takes nan, inf and -3."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:  # False for nan too
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1], got {text}")
    return value


def fail(prog: str, message: str) -> None:
    """A script's expected failure: one ``prog: error: message`` line on stderr, exit code 2."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    exit_code(2)


def _inputs(inputs: dict | None) -> dict:
    """``inputs`` ({flag: path or None}), and under Blender the open .blend ("the open scene")."""
    found = {k: v for k, v in (inputs or {}).items() if v}
    if inside_blender():
        import bpy

        if bpy.data.filepath:
            found.setdefault("the open scene", bpy.data.filepath)
    return found


def check_output(prog: str, flag: str, path: str, overwrite: bool, inputs: dict, suffix: str = "",
                 need_folder: bool = False) -> str:
    """The one output rule (``nerf_core.contract.outputs.check_output``) for a script's output file:
    no link written through, no input replaced (compared by identity; under Blender the open .blend
    counts as one), no dataset's own file, an existing file only with ``overwrite``; ``need_folder``:
    its folder must exist (else the script makes it). Returns the
    absolute path; ``fail``s with one line naming the flag otherwise."""
    try:
        return str(outputs.check_output(path, overwrite, _inputs(inputs), flag=flag, suffix=suffix,
                                        need_folder=need_folder))
    except outputs.OutputError as exc:
        fail(prog, str(exc))


def check_outputs_in(prog: str, flag: str, folder: str, names: list, overwrite: bool, inputs: dict) -> list:
    """The output rule for the files ``names`` a script writes into ``folder`` (``check_output`` for each)."""
    try:
        return [str(p) for p in outputs.check_outputs_in(folder, names, overwrite, _inputs(inputs), flag=flag)]
    except outputs.OutputError as exc:
        fail(prog, str(exc))


def out_blend(prog: str, path: str, overwrite: bool, inputs: dict | None = None) -> str:
    """``--out OUT.blend`` as an absolute path, by the output rule (``check_output``): it must end in
    .blend, sit in an existing folder, and be none of ``inputs`` (the open scene included)."""
    return check_output(prog, "--out", path, overwrite, inputs or {}, suffix=".blend", need_folder=True)


def save_blend(prog: str, out: str) -> None:
    """Save the open scene as a copy at ``out`` (checked by ``out_blend``), atomically: Blender writes a
    fresh private name (``utils.atomic.atomic_path``), never through a link, and a failed save leaves
    ``out`` as it was. ``fail``s naming the file."""
    import bpy

    try:
        with atomic_path(out, flag="--out", beside=True) as tmp:  # beside: relative paths stay right
            bpy.ops.wm.save_as_mainfile(filepath=str(tmp), copy=True, relative_remap=True)
    except (OSError, RuntimeError) as exc:
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        hint = " (is the disk full?)" if "space" in text.lower() else ""
        fail(prog, f"--out {out}: could not save the scene{hint}: {text}")


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
