"""Rule 1 of issue 58 as a mechanism: nothing is written to a user-visible path outside the atomic homes.

Every write to a file goes through ``nerf_core.utils.atomic`` (the library, the scripts) or
``addon/file_writes.py`` (the add-on, without nerf_core): a new temporary created exclusively and
never through a link, renamed over a target that is no link. So this test parses every module of
``nerf_core/``, ``scripts/`` and ``addon/`` (``ast``) and refuses a write in any other form: a bare
``open(..., "w" | "a" | "x" | "+")``, ``os.open``, ``torch.save``, ``np.save*``, any ``.save(...)``
(PIL, Blender images), ``save_as_mainfile``, ``save_render``, ``write_text``, ``write_bytes``,
``zipfile.ZipFile(..., "w")``, ``os.replace``/``os.rename``, ``shutil.copy*``/``move``; unless it sits
inside a ``with`` block of one of the homes' context managers (``HOME_CONTEXTS``: the file or path
they yield is the new temporary), or is listed in ``ALLOWED`` with the reason it is safe.

A test beside it feeds the checker the forbidden forms on purpose and sees each refused.
"""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ROOTS = ("nerf_core", "scripts", "addon")
HOMES = {"nerf_core/utils/atomic.py", "addon/file_writes.py"}  # the mechanism itself
HOME_CONTEXTS = {"atomic_file", "atomic_path", "partial_file", "partial_path", "open_exclusive"}
WRITE_METHODS = {"save", "savez", "savez_compressed", "save_as_mainfile", "save_render", "write_text",
                 "write_bytes"}
OS_CALLS = {"open", "replace", "rename"}
SHUTIL_CALLS = {"copy", "copy2", "copyfile", "move", "copytree"}

# (module, what the call looks like): why it is safe. Keep it short: each entry is a door in the rule.
ALLOWED = {
    ("nerf_core/runs/folder.py", "os.open"):
        "the run lock: opened with O_NOFOLLOW, refused when a link, hard link or no lock file (_open_lock_file)",
    ("nerf_core/runs/folder.py", "open:a"):
        "check_progress_file's probe appends nothing; --progress may be /dev/stdout (a link by design)",
    ("nerf_core/runs/events.py", "open:a"):
        "append-only progress logs: RUN/progress.jsonl is no link (check_run_layout), --progress is checked "
        "by check_progress_file",
    ("nerf_core/engine/report.py", "os.replace"):
        "moves an old metrics.json aside inside the checked run folder: a rename writes no content",
    ("nerf_core/utils/native.py", "os.replace"):
        "the native kernel's cache: a mkstemp file (exclusive, no link) renamed into the private cache folder",
    ("scripts/build_addon.py", "os.replace"):
        "runs on any Python without numpy: its zip is a mkstemp file (exclusive, no link) renamed into dist/",
    ("scripts/build_addon.py", "ZipFile:w"):
        "the zip is written into the open mkstemp file (exclusive, no link), then renamed into dist/",
    ("nerf_core/utils/stdout.py", "os.open"):
        "opens os.devnull to silence a broken stdout: no file of the user's",
    ("scripts/build_addon.py", "shutil.copytree"):
        "copies the add-on into its own new staging folder (tempfile.mkdtemp)",
    ("nerf_core/export/colmap.py", "os.rename"):
        "renames the export's own new mkdtemp folder (every file in it written by the atomic homes) onto --out, "
        "checked as no link just before: a rename writes no content",
    ("addon/capture/files/frame_files.py", "save_render"):
        "the render passes' scratch EXR, in the capture's private scratch folder, read and removed at once",
    ("addon/compare/display_colours.py", "save"):
        "a scratch EXR of colours in its own new tempfile.TemporaryDirectory, read back and removed at once",
}


def _call_form(call: ast.Call) -> str | None:
    """What kind of write ``call`` is ("open:w", "os.replace", "save", ...), or None for no write."""
    f = call.func
    if isinstance(f, ast.Name) and f.id == "open":
        mode = call.args[1] if len(call.args) > 1 else next((k.value for k in call.keywords if k.arg == "mode"), None)
        if isinstance(mode, ast.Constant) and isinstance(mode.value, str):
            kinds = [c for c in "wax+" if c in mode.value]
            return f"open:{kinds[0]}" if kinds else None
        return "open:?" if mode is not None else None  # a computed mode: assume the worst
    if not isinstance(f, ast.Attribute):
        return None
    owner = f.value.id if isinstance(f.value, ast.Name) else None
    if owner == "os" and f.attr in OS_CALLS:
        return f"os.{f.attr}"
    if owner == "shutil" and f.attr in SHUTIL_CALLS:
        return f"shutil.{f.attr}"
    if f.attr == "ZipFile":
        mode = call.args[1] if len(call.args) > 1 else next((k.value for k in call.keywords if k.arg == "mode"), None)
        if isinstance(mode, ast.Constant) and mode.value in ("w", "a", "x"):
            return "ZipFile:w"
        return None
    if f.attr in WRITE_METHODS:
        root = f.value
        while isinstance(root, (ast.Attribute, ast.Call)):
            root = root.value if isinstance(root, ast.Attribute) else root.func
        if f.attr == "save" and isinstance(root, ast.Name) and root.id == "self":
            return None  # an object's own save method (a checkpoint schedule), which writes through the homes
        return f.attr
    return None


def _context_name(item: ast.withitem) -> str | None:
    expr = item.context_expr
    if isinstance(expr, ast.Call):
        f = expr.func
        return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
    return None


def bare_writes(source: str, rel: str) -> list[str]:
    """``"rel:line: form"`` for every write in ``source`` outside a home context and not ``ALLOWED``."""
    found: list[str] = []

    def visit(node: ast.AST, inside_home: bool) -> None:
        if isinstance(node, (ast.With, ast.AsyncWith)):
            inside_home = inside_home or any(_context_name(i) in HOME_CONTEXTS for i in node.items)
        if isinstance(node, ast.Call) and not inside_home:
            form = _call_form(node)
            if form is not None and (rel, form) not in ALLOWED:
                found.append(f"{rel}:{node.lineno}: {form}")
        for child in ast.iter_child_nodes(node):
            visit(child, inside_home)

    visit(ast.parse(source), False)
    return found


def _modules():
    for root in ROOTS:
        for path in sorted((REPO / root).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if "/tests/" in f"/{rel}" or "__pycache__" in rel or rel in HOMES:
                continue
            yield rel, path


def test_every_write_goes_through_the_atomic_homes():
    found = [w for rel, path in _modules() for w in bare_writes(path.read_text(encoding="utf-8"), rel)]
    assert not found, ("writes outside nerf_core.utils.atomic / addon/file_writes.py (a fixed temporary name or "
                       "a write in place follows a planted link onto a user's file; write through atomic_file, "
                       "atomic_path, write_*_atomic, or the add-on's partial_file / partial_path / write_atomic):\n"
                       + "\n".join(found))


def test_every_allowed_entry_is_still_needed():
    used = set()
    for rel, path in _modules():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        used |= {(rel, form) for node in ast.walk(tree) if isinstance(node, ast.Call)
                 and (form := _call_form(node)) is not None}
    assert not set(ALLOWED) - used, f"ALLOWED entries that match nothing any more: {sorted(set(ALLOWED) - used)}"


def test_the_rule_fails_on_each_forbidden_form():
    forms = {
        'open(p, "w")': "open:w", 'open(p, mode="ab")': "open:a", 'open(p, "x")': "open:x", "open(p, m)": "open:?",
        "torch.save(obj, p)": "save", "np.savez(p, a=a)": "savez", "np.savez_compressed(p)": "savez_compressed",
        "Image.fromarray(a).save(p)": "save", "bpy.ops.wm.save_as_mainfile(filepath=p)": "save_as_mainfile",
        "img.save_render(p)": "save_render", "Path(p).write_text(t)": "write_text",
        "Path(p).write_bytes(b)": "write_bytes", 'zipfile.ZipFile(p, "w")': "ZipFile:w",
        "os.replace(a, b)": "os.replace", "os.open(p, flags)": "os.open", "shutil.copy(a, b)": "shutil.copy",
    }
    for code, form in forms.items():
        assert bare_writes(code, "nerf_core/new.py") == [f"nerf_core/new.py:1: {form}"], code
    # reads, an object's own save method, and writes inside a home's with block, pass
    assert bare_writes('open(p)\nopen(p, "rb")\nself.checkpoints.save(self)\n'
                       "with atomic_file(p) as fh:\n    torch.save(obj, fh)\n"
                       "with atomic.atomic_path(p) as t:\n    img.save(t)\n", "nerf_core/new.py") == []
