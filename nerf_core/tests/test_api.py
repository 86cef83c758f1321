"""The public API: ``nerf_core.__all__`` and ``nerf_core.volume.__all__`` against docs/API.md, lazy
loading and docstrings. The page's example runs end to end from an installed wheel
(test_wheel_install.py)."""
from __future__ import annotations

import ast
import inspect
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import nerf_core
import nerf_core.volume

REPO_ROOT = Path(__file__).resolve().parents[2]
API_MD = REPO_ROOT / "docs" / "API.md"


def _public() -> list[str]:
    return [n for n in nerf_core.__all__ if n != "__version__"]


def _all_public_objects():
    """(qualified name, object) of every public name of both ``__all__``s."""
    out = [(f"nerf_core.{n}", getattr(nerf_core, n)) for n in _public()]
    out += [(f"nerf_core.volume.{n}", getattr(nerf_core.volume, n)) for n in nerf_core.volume.__all__]
    return out


def _page() -> str:
    return API_MD.read_text(encoding="utf-8")


def test_api_page_lists_exactly_the_public_names():
    text = _page()
    top = re.findall(r"^### `([^`]+)`\s*$", text, flags=re.M)
    vol = re.findall(r"^#### `volume\.([^`]+)`\s*$", text, flags=re.M)
    twice = sorted({n for n in top if top.count(n) > 1} | {f"volume.{n}" for n in vol if vol.count(n) > 1})
    assert not twice, f"docs/API.md has a heading twice: {twice}"
    public, volume = set(_public()), set(nerf_core.volume.__all__)
    problems = []
    for names, headings, heading in ((public, set(top), "'### `name`'"), (volume, set(vol), "'#### `volume.name`'")):
        where = "nerf_core.volume.__all__" if names is volume else "nerf_core.__all__"
        if names - headings:
            problems.append(f"in {where} but without a {heading} heading in docs/API.md: {sorted(names - headings)}")
        if headings - names:
            problems.append(f"{heading} headings in docs/API.md that are not in {where}: {sorted(headings - names)}")
    assert not problems, "; ".join(problems)


def test_import_is_lazy_and_every_name_resolves():
    code = textwrap.dedent("""
        import sys
        import nerf_core
        assert "torch" not in sys.modules, "import nerf_core imported torch"
        for name in nerf_core.__all__:
            assert getattr(nerf_core, name) is not None, name
        try:
            nerf_core.no_such_name
        except AttributeError:
            pass
        else:
            raise SystemExit("an unknown name did not raise AttributeError")
        print("ok", len(nerf_core.__all__))
    """)
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.startswith("ok")


def _takes_arguments(obj) -> bool:
    """Whether a public function or class is called with arguments (an exception's message does not count)."""
    if inspect.ismodule(obj) or (isinstance(obj, type) and issubclass(obj, BaseException)):
        return False
    try:
        params = inspect.signature(obj).parameters
    except (TypeError, ValueError):
        return False
    return any(p.name != "self" for p in params.values())


def _returns_a_value(func) -> bool:
    """A function returns a value when its return annotation is not None, or (without one) when its
    body has a ``return <value>`` (nested functions and classes not counted)."""
    ann = inspect.signature(func).return_annotation
    if ann is not inspect.Signature.empty:
        return ann not in (None, "None")
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(inspect.unwrap(func))))
    except (OSError, TypeError):
        return False  # no source to read (a builtin): only the annotation could tell
    fn = tree.body[0]

    def walk(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
                continue
            if isinstance(child, ast.Return) and child.value is not None and not (
                    isinstance(child.value, ast.Constant) and child.value.value is None):
                return True
            if walk(child):
                return True
        return False

    return walk(fn)


def test_public_names_have_structured_docstrings():
    problems = []
    for qual, obj in _all_public_objects():
        doc = inspect.getdoc(obj) if not inspect.ismodule(obj) else obj.__doc__
        if not doc or not doc.strip():
            problems.append(f"{qual}: no docstring")
            continue
        if isinstance(obj, type) and obj.__doc__ is None:
            problems.append(f"{qual}: no docstring of its own")
            continue
        if _takes_arguments(obj) and "Args:" not in doc and "Attributes:" not in doc:
            problems.append(f"{qual}: docstring has no 'Args:' (or 'Attributes:') section")
        if inspect.isfunction(obj) and _returns_a_value(obj) and "Returns:" not in doc:
            problems.append(f"{qual}: returns a value but its docstring has no 'Returns:' section")
    assert not problems, "\n".join(problems)


def test_example_is_short_and_uses_the_public_api(api_example_code):
    code = api_example_code("scene_dataset", "runs/scene")
    assert len(code.strip().splitlines()) <= 30, "the example must stay within 30 lines"
    imported = re.findall(r"^\s*(?:from\s+(\S+)\s+import|import\s+(\S+))", code, flags=re.M)
    modules = {a or b for a, b in imported}
    assert modules <= {"torch", "nerf_core", "pathlib"}, f"the example imports more than the public API: {modules}"
