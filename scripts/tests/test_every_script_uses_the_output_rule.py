"""Every entry point in ``scripts/`` that writes a user's file calls the one output rule
(``nerf_core.contract.outputs`` through ``_bootstrap.check_output`` / ``check_outputs_in`` / ``out_blend``),
and every script honours Ctrl-C even when started with SIGINT ignored (issue 58, rules 1 and 7).

The first test parses each script (``ast``): one that declares an output flag (``--out``,
``--save-blend``) must call the rule; a script added without it fails here. A check below feeds it
a script that writes without the rule, to see it refused.
"""
from __future__ import annotations

import ast
import signal
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = REPO / "scripts"
OUTPUT_FLAGS = {"--out", "--save-blend", "--out-dir"}
RULE_CALLS = {"check_output", "check_outputs_in", "out_blend"}
# script: why it needs no call of the rule (each entry is a door: keep them few)
EXEMPT = {
    "build_addon.py": "writes only dist/<id>-<version>.zip through mkstemp; runs on a Python without numpy",
    "demo.py": "writes a new timestamped folder of its own (demo_out/<time>/); its steps are the other scripts",
}


def _declared_outputs(tree: ast.AST) -> set[str]:
    return {a.value for node in ast.walk(tree) if isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute) and node.func.attr == "add_argument"
            for a in node.args if isinstance(a, ast.Constant) and a.value in OUTPUT_FLAGS}


def _calls_the_rule(tree: ast.AST) -> bool:
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            if name in RULE_CALLS:
                return True
    return False


def scripts_missing_the_rule(sources: dict[str, str]) -> list[str]:
    """The names of scripts (``{name: source}``) that declare an output flag and never call the rule."""
    missing = []
    for name, text in sorted(sources.items()):
        tree = ast.parse(text)
        if _declared_outputs(tree) and not _calls_the_rule(tree) and name not in EXEMPT:
            missing.append(name)
    return missing


# script: why it need not import _bootstrap at module level (each entry is a door: keep them few)
NO_BOOTSTRAP = {"build_addon.py": "a build of seconds, on a Python without nerf_core or numpy",
                "demo.py": "calls honour_interrupts() itself at module level; its steps are the other scripts"}


def scripts_not_honouring_stops(sources: dict[str, str]) -> list[str]:
    """The names of scripts (``{name: source}``) that neither import ``_bootstrap`` nor call
    ``honour_interrupts()`` in a module-level statement: one that did so only inside a function could
    run its work first, with Ctrl-C still ignored."""
    missing = []
    for name, text in sorted(sources.items()):
        tree = ast.parse(text)
        top = tree.body + [n for node in tree.body if isinstance(node, ast.If) for n in node.body]
        imports = any(isinstance(n, ast.Import) and any(a.name == "_bootstrap" for a in n.names)
                      or isinstance(n, ast.ImportFrom) and n.module == "_bootstrap" for n in top)
        honours = any(isinstance(n, ast.Expr) and isinstance(n.value, ast.Call)
                      and getattr(n.value.func, "id", None) == "honour_interrupts" for n in top)
        if not (imports or honours) and name not in NO_BOOTSTRAP:
            missing.append(name)
    return missing


def _entry_points() -> dict[str, str]:
    return {p.name: p.read_text(encoding="utf-8") for p in sorted(SCRIPTS.glob("*.py")) if p.name != "_bootstrap.py"}


def test_every_script_with_an_output_calls_the_output_rule():
    sources = _entry_points()
    assert len(sources) >= 10  # the walk found the scripts
    missing = scripts_missing_the_rule(sources)
    assert not missing, (f"scripts that write an output without the output rule (_bootstrap.check_output, "
                         f"check_outputs_in or out_blend): {missing}")
    assert set(EXEMPT) <= set(sources), "EXEMPT names a script that no longer exists"


def test_the_entry_point_check_fails_on_a_script_without_the_rule():
    bad = 'ap.add_argument("--out")\nopen(args.out, "w")\n'
    good = 'ap.add_argument("--out")\nout = _bootstrap.check_output("x", "--out", args.out, False, {})\n'
    assert scripts_missing_the_rule({"new.py": bad, "ok.py": good}) == ["new.py"]


def test_every_script_restores_sigint_when_started_with_it_ignored():
    # As a farm manager starts jobs: SIGINT ignored, inherited across exec. Every script imports
    # _bootstrap first; after it, Ctrl-C raises KeyboardInterrupt again.
    code = ("import signal, sys; sys.path.insert(0, sys.argv[1]); "
            "assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN; import _bootstrap; "
            "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)")
    proc = subprocess.run([sys.executable, "-c", code, str(SCRIPTS)], capture_output=True, text=True, timeout=120,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    assert proc.returncode == 0 and proc.stdout.strip() == "True", proc.stderr[-2000:]
    sources = _entry_points()
    assert len(sources) >= 10 and set(NO_BOOTSTRAP) <= set(sources)
    missing = scripts_not_honouring_stops(sources)
    assert not missing, f"scripts that never restore Ctrl-C at start (import _bootstrap at module level): {missing}"


def test_the_stop_check_fails_on_a_script_that_imports_bootstrap_late():
    late = "import sys\n\ndef main():\n    import _bootstrap\n    work()\n"
    none = "import bpy\nbpy.ops.wm.save_as_mainfile()\n"
    good = "import sys\nsys.path.insert(0, '.')\nimport _bootstrap  # noqa: E402\n"
    also = "from _bootstrap import exit_code, fail\n"
    assert scripts_not_honouring_stops({"late.py": late, "none.py": none, "good.py": good,
                                        "also.py": also}) == ["late.py", "none.py"]
