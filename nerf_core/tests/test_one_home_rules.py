"""Round five's rules as mechanisms (docs/RELIABILITY.md, "Round five", rules 3, 4 and "one home"):
each test fails when new code bypasses the rule's home, and each is also fed a bypass on purpose.

- What a number is: ``nerf_core/contract/numbers.py`` alone spells "a number, not a bool" (and
  "finite"); a copy elsewhere drifts (numpy integers were refused by one copy, accepted by another).
- Every built-in method option is declared with both bounds (``methods.options.option``): an option
  without an upper bound is how ``step_ratio=1e-9`` and ``seed=2**64`` reached training.
- RUN/config.json is read by ``runs.record`` (the transforms files' JSON reader and one declaration of
  its fields); a second reader with ``json.loads`` skips both.
"""
from __future__ import annotations

import ast
import dataclasses
import textwrap
from pathlib import Path

import pytest

from nerf_core.methods.environment_options import EnvironmentOptions
from nerf_core.methods.options import MethodOptions, option
from nerf_core.methods.registry import available_methods, method_class

REPO = Path(__file__).resolve().parents[2]
NUMBERS_HOME = Path("nerf_core/contract/numbers.py")
NUMBER_TYPES = {"int", "float", "Real", "Integral", "Number", "integer", "floating", "number"}
# config.json's readers other than runs.record, each with its reason
CONFIG_READERS_ALLOWED = {
    # "is this folder a trainer's?" before --overwrite deletes: a damaged file must answer "no", not fail
    ("nerf_core/runs/folder.py", "_written_by_a_trainer"),
}


def _sources():
    for path in sorted((REPO / "nerf_core").rglob("*.py")):
        rel = path.relative_to(REPO)
        if "tests" not in rel.parts and "__pycache__" not in rel.parts:
            yield rel, path.read_text(encoding="utf-8")


def _isinstance_types(node) -> set:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        node = node.operand
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance"
            and len(node.args) == 2):
        kinds = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
        return {k.attr if isinstance(k, ast.Attribute) else getattr(k, "id", None) for k in kinds}
    return set()


def _is_isfinite(node) -> bool:
    if isinstance(node, ast.UnaryOp):
        node = node.operand
    return isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "isfinite" \
        and getattr(node.func.value, "id", None) == "math"


def number_test_copies(source: str) -> list:
    """Lines of ``source`` where one boolean expression spells the number test again: an isinstance of
    a number type together with an isinstance of bool, or with math.isfinite."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.BoolOp):
            kinds = [_isinstance_types(v) for v in node.values]
            number = any(k & NUMBER_TYPES for k in kinds)
            boolean = any(k & {"bool", "bool_"} for k in kinds)
            finite = any(_is_isfinite(v) for v in node.values)
            if number and (boolean or finite):
                found.append(node.lineno)
    return found


def test_the_number_test_has_one_home():
    copies = [f"{rel}:{line}" for rel, text in _sources() if rel != NUMBERS_HOME for line in number_test_copies(text)]
    assert not copies, ("these lines spell 'a number, not a bool' (or 'finite') again; use "
                        "nerf_core.contract.numbers (is_number, is_whole, is_real):\n" + "\n".join(copies))


def test_the_number_rule_fails_on_a_copy():
    bypass = textwrap.dedent("""
        def ok(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool)

        def finite(v):
            return isinstance(v, float) and math.isfinite(v)
    """)
    assert number_test_copies(bypass) == [3, 6]
    assert number_test_copies("def ok(v):\n    return is_number(v) and isinstance(v, (str, bool))\n") == []


def unbounded_options(cls) -> list:
    """Names of the declared number options of ``cls`` (a MethodOptions) without a lower or upper bound."""
    out = []
    for name, f in cls.declared().items():
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if f.metadata.get("choices") is not None or isinstance(default, bool):
            continue
        if f.metadata.get("low") is None or f.metadata.get("high") is None:
            out.append(name)
    return out


def test_every_built_in_option_is_bounded_on_both_sides():
    classes = {name: method_class(name).Options for name in available_methods()
               if method_class(name).__module__.startswith("nerf_core.methods.")}
    assert {"vmgrid", "nerf"} <= set(classes)
    classes["environment"] = EnvironmentOptions
    loose = {name: unbounded_options(cls) for name, cls in classes.items() if unbounded_options(cls)}
    assert not loose, f"options without a lower or upper bound (methods/options.option(low=, high=)): {loose}"


def test_the_bound_rule_fails_on_an_unbounded_option():
    @dataclasses.dataclass
    class Loose(MethodOptions):
        steps: int = option(10, "a count with no ceiling")
        share: float = option(0.5, "a share", high=1)
        mode: str = option("a", "a choice", choices=("a", "b"))

    assert unbounded_options(Loose) == ["steps"]


def config_json_readers(rel: Path, source: str) -> list:
    """Functions of ``source`` that read config.json themselves: they name it (``config_path``,
    ``CONFIG``, "config.json") and call ``json.load``/``json.loads``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        text = ast.unparse(node)
        names_it = "config_path(" in text or "contract.CONFIG" in text or "config.json" in text.replace(
            '"""', "").split("\n", 1)[-1]
        loads = any(isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in ("load", "loads")
                    and getattr(n.func.value, "id", None) == "json" for n in ast.walk(node))
        if names_it and loads and (str(rel), node.name) not in CONFIG_READERS_ALLOWED:
            found.append(f"{rel}:{node.lineno} {node.name}")
    return found


def test_config_json_is_read_only_by_the_record():
    readers = [r for rel, text in _sources() if rel != Path("nerf_core/runs/record.py")
               for r in config_json_readers(rel, text)]
    assert not readers, ("these functions read RUN/config.json with json.load(s), skipping the record's rules; "
                         "use nerf_core.runs.record.read_run_record (or contract.jsonfile.parse_json_file):\n"
                         + "\n".join(readers))


@pytest.mark.parametrize("body, found", [
    ("cfg = json.loads(Path(contract.config_path(run)).read_text())", True),
    ("cfg = parse_json_file(contract.config_path(run))", False),
])
def test_the_config_reader_rule_fails_on_a_second_reader(body, found):
    source = f"def read(run):\n    {body}\n    return cfg\n"
    assert bool(config_json_readers(Path("nerf_core/x.py"), source)) is found


def background_lists(source: str) -> list:
    """Lines of ``source`` with a tuple, list or set literal of two or more background names."""
    names = {"environment", "random", "white", "black", "white-then-random"}
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            words = {e.value for e in node.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
            if len(words & names) >= 2 and "white-then-random" in words:
                found.append(node.lineno)
    return found


def test_the_background_names_are_listed_once():
    home = Path("nerf_core/data/backgrounds.py")
    copies = [f"{rel}:{line}" for rel, text in _sources() if rel != home for line in background_lists(text)]
    assert not copies, "background names listed again; import them from nerf_core.data.backgrounds:\n" + "\n".join(
        copies)
    assert len(background_lists((REPO / home).read_text(encoding="utf-8"))) == 1  # FIXED_BACKGROUNDS, the rest built


def test_the_background_rule_fails_on_a_second_list():
    assert background_lists('MODES = ("environment", "random", "white", "black", "white-then-random")\n') == [1]
    assert background_lists('PAIR = ("white", "black")\n') == []
