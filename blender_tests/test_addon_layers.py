"""The add-on's layers, read from its source (pure AST: nothing is imported, bpy not needed).

Layers, lowest first: ``file_writes`` (and the other root modules but ``__init__``), ``bridge`` (the child
process; never bpy), ``scene``, ``dataset`` and ``common``, then the features ``capture``, ``train``,
``compare`` and ``render_engine``. A module imports its own package and lower layers only; features do
not import each other, except compare -> train. Inside ``capture`` the subpackages are layers too
(``CAPTURE_RANK``). No module is over 500 lines, and none imports another module's ``_private`` names.
"""
from __future__ import annotations

import ast
import os
from typing import Iterator, List, Optional, Tuple

import pytest

ADDON = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon")
FEATURES = ("capture", "train", "compare", "render_engine")
ALLOWED_FEATURE_IMPORTS = {("compare", "train")}
# Rank of each lower layer; "" is the add-on root (file_writes). A lower module may import lower ranks.
LOWER_RANK = {"": 0, "bridge": 1, "scene": 2, "dataset": 3, "common": 3}
# The capture feature's subpackages, lowest first: where cameras go (layout), what a capture will render (plan),
# its files on disk (files), running it (run) and the panel (ui). The demo scenes stand beside layout.
CAPTURE_RANK = {"layout": 0, "demo": 0, "plan": 1, "files": 2, "run": 3, "ui": 4}
BLENDER_MODULES = ("bpy", "mathutils", "gpu", "gpu_extras", "bmesh", "bl_math", "blf", "aud")
MAX_LINES = 500


def _modules() -> List[Tuple[str, str]]:
    """(path, dotted name below ``addon``) of every module, e.g. ("addon/capture/layout/positions.py",
    "capture.layout.positions")."""
    found = []
    for root, dirs, files in os.walk(ADDON):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "vendor"))
        for f in sorted(files):
            if f.endswith(".py"):
                rel = os.path.relpath(os.path.join(root, f), ADDON)[:-3].replace(os.sep, ".")
                found.append((os.path.join(root, f), rel[: -len(".__init__")] if rel.endswith("__init__") else rel))
    return found


MODULES = _modules()
NAMES = {name for _, name in MODULES}


def _package(name: str) -> str:
    """The top package of a module below ``addon`` ("" for the root's own modules)."""
    return name.split(".")[0] if "." in name or name in {n.split(".")[0] for n in NAMES if "." in n} else ""


def _is_package(path: str) -> bool:
    return os.path.basename(path) == "__init__.py"


def _imports(path: str, name: str) -> Iterator[Tuple[int, str, Optional[str], str]]:
    """(line, imported add-on module or external module, imported name or None, source text) for every
    import in the file, function-local ones included. Add-on modules are dotted below ``addon``
    ("capture.layout.positions"); external ones are prefixed with "!" ("!bpy.props")."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    own = name if _is_package(path) else name.rpartition(".")[0]  # the package relative imports start from
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                mod = alias.name
                if mod == "addon" or mod.startswith("addon."):
                    yield node.lineno, mod[len("addon."):] if "." in mod else "", None, f"import {mod}"
                else:
                    yield node.lineno, "!" + mod, None, f"import {mod}"
        elif isinstance(node, ast.ImportFrom):
            text = f"from {'.' * node.level}{node.module or ''} import {', '.join(a.name for a in node.names)}"
            if node.level == 0:
                mod = node.module or ""
                if mod == "addon" or mod.startswith("addon."):
                    base = mod[len("addon."):] if "." in mod else ""
                else:
                    for alias in node.names:
                        yield node.lineno, "!" + mod, alias.name, text
                    continue
            else:
                parts = own.split(".") if own else []
                parts = parts[: len(parts) - (node.level - 1)] if node.level > 1 else parts
                base = ".".join(p for p in parts + ([node.module] if node.module else []) if p)
            for alias in node.names:
                sub = f"{base}.{alias.name}" if base else alias.name
                if sub in NAMES:  # ``from . import layouts``: the module itself
                    yield node.lineno, sub, None, text
                else:  # ``from .layouts import LayoutSpec``: a name of the module
                    yield node.lineno, base, alias.name, text


def _where(path: str, line: int) -> str:
    return f"{os.path.relpath(path, os.path.dirname(ADDON))}:{line}"


def test_every_module_is_found():
    assert len(MODULES) > 30 and "bridge.child_process" in NAMES and "capture.layout.positions" in NAMES


def test_bridge_never_imports_bpy():
    bad = [f"{_where(path, line)}: {text}" for path, name in MODULES if _package(name) == "bridge"
           for line, mod, _, text in _imports(path, name)
           if mod.startswith("!") and mod[1:].split(".")[0] in BLENDER_MODULES]
    assert not bad, "bridge/ must run without Blender's modules (the child process seam):\n" + "\n".join(bad)


def test_features_do_not_import_each_other():
    bad = []
    for path, name in MODULES:
        pkg = _package(name)
        if pkg not in FEATURES:
            continue
        for line, mod, _, text in _imports(path, name):
            target = "" if mod.startswith("!") else _package(mod)
            if target in FEATURES and target != pkg and (pkg, target) not in ALLOWED_FEATURE_IMPORTS:
                bad.append(f"{_where(path, line)}: {text}  ({pkg} -> {target})")
    assert not bad, "features import each other only compare -> train:\n" + "\n".join(bad)


def test_lower_layers_never_import_upward():
    bad = []
    for path, name in MODULES:
        pkg = _package(name)
        if name == "" or pkg not in LOWER_RANK:  # addon/__init__.py registers the features: it is the top
            continue
        for line, mod, _, text in _imports(path, name):
            if mod.startswith("!"):
                continue
            target = _package(mod)
            if target == pkg:
                continue
            if target in FEATURES or mod == "":
                bad.append(f"{_where(path, line)}: {text}  ({pkg or 'root'} -> feature {target or 'addon'})")
            elif LOWER_RANK[target] >= LOWER_RANK[pkg]:
                bad.append(f"{_where(path, line)}: {text}  ({pkg or 'root'} -> {target or 'root'}, not lower)")
    assert not bad, "lower layers import only lower layers:\n" + "\n".join(bad)


def test_no_module_over_500_lines():
    long = []
    for path, _ in MODULES:
        with open(path, encoding="utf-8") as fh:
            n = sum(1 for _ in fh)
        if n > MAX_LINES:
            long.append(f"{_where(path, 1)}: {n} lines")
    assert not long, f"modules over {MAX_LINES} lines:\n" + "\n".join(long)


def test_no_private_names_across_modules():
    bad = []
    for path, name in MODULES:
        for line, mod, imported, text in _imports(path, name):
            if imported and imported.startswith("_") and not imported.startswith("__"):
                bad.append(f"{_where(path, line)}: {text}  (private {imported!r})")
        # ``module._name`` on a module imported from the add-on
        tree = ast.parse(open(path, encoding="utf-8").read(), path)
        bound = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                for alias in node.names:
                    bound[alias.asname or alias.name] = alias.name
        add_on_modules = {local for local, real in bound.items()
                          if any(n == real or n.endswith("." + real) for n in NAMES)}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in add_on_modules
                    and node.attr.startswith("_") and not node.attr.startswith("__")):
                bad.append(f"{_where(path, node.lineno)}: {node.value.id}.{node.attr}  (private "
                           f"name of another module)")
    assert not bad, "no module uses another module's _private names:\n" + "\n".join(bad)


# Function-local imports the add-on needs, each with its reason in a comment where it is made.
LOCAL_IMPORTS_ALLOWED = {
    ("render_engine/engine.py", "gpu"),  # the gpu module does not exist in background mode
    ("render_engine/engine.py", "gpu_extras.presets"),
    ("compare/volume_files.py", "openvdb"),  # inside Blender's Python only; needed by a volume import alone
}


def test_imports_are_at_the_top_of_their_module():
    bad = []
    for path, _ in MODULES:
        rel = os.path.relpath(path, ADDON).replace(os.sep, "/")
        tree = ast.parse(open(path, encoding="utf-8").read(), path)
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    mods = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    mods = ["." * node.level + (node.module or "")]
                else:
                    continue
                bad += [f"{_where(path, node.lineno)}: {ast.unparse(node)}" for m in mods
                        if (rel, m) not in LOCAL_IMPORTS_ALLOWED]
    assert not bad, "function-local imports (move them to the top, or allow one with its reason):\n" + "\n".join(bad)


def test_capture_subpackages_import_only_lower_ones():
    bad = []
    for path, name in MODULES:
        parts = name.split(".")
        if parts[0] != "capture" or len(parts) < 3:
            continue
        for line, mod, _, text in _imports(path, name):
            target = mod.split(".")
            if mod.startswith("!") or target[0] != "capture" or len(target) < 2 or target[1] == parts[1]:
                continue
            if target[1] not in CAPTURE_RANK or CAPTURE_RANK[target[1]] >= CAPTURE_RANK[parts[1]]:
                bad.append(f"{_where(path, line)}: {text}  (capture.{parts[1]} -> capture.{target[1]}, not lower)")
    assert not bad, "capture's subpackages import only lower ones (CAPTURE_RANK):\n" + "\n".join(bad)


@pytest.mark.parametrize("rule", ["feature", "bpy", "upward", "private", "capture"])
def test_the_checks_catch_a_violation(tmp_path, monkeypatch, rule):
    """Each check fails on a module written to break it (a copy of the tree, not the real add-on)."""
    import shutil

    copy = tmp_path / "addon"
    shutil.copytree(ADDON, copy, ignore=shutil.ignore_patterns("__pycache__"))
    line = {"feature": ("train/train_ui.py", "from ..capture.layout import positions\n"),
            "bpy": ("bridge/progress.py", "def f():\n    import bpy\n"),
            "upward": ("scene/scene_bounds.py", "from ..compare import planes\n"),
            "private": ("compare/planes.py", "from ..capture.layout.cameras import _new_camera\n"),
            "capture": ("capture/layout/positions.py", "from ..run import job\n")}[rule]
    with open(copy / line[0], "a", encoding="utf-8") as fh:
        fh.write("\n" + line[1])
    monkeypatch.setitem(globals(), "ADDON", str(copy))
    monkeypatch.setitem(globals(), "MODULES", _modules())
    check = {"feature": test_features_do_not_import_each_other, "bpy": test_bridge_never_imports_bpy,
             "upward": test_lower_layers_never_import_upward, "private": test_no_private_names_across_modules,
             "capture": test_capture_subpackages_import_only_lower_ones}[rule]
    with pytest.raises(AssertionError, match=line[0].replace("/", "[/\\\\]").replace(".", r"\.")):
        check()
