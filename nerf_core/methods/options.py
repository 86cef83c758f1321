"""A method's build options as one declared type: a dataclass per method (``VMGridOptions``,
``NeRFOptions``) whose fields carry their default, a one-line doc and their bounds.

Every rule about an option's value lives in its field (``option(...)``), and ``MethodOptions.parse``
is the one place that applies them: ``train`` refuses bad ``--set`` values before a run folder is
made, and ``build_model`` refuses them from the Python API, with the same message.

What a run changes as it trains (vmgrid's grid resolution) is not an option: a method keeps it apart
(``RadianceModel.run_state``) and checkpoints save it explicitly. Checkpoints written before that kept
it among the options; ``RUN_STATE_KEYS`` names those keys so that loading moves them out again.
"""
from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, Dict, Mapping, Optional, Sequence, Tuple

from nerf_core.contract.numbers import is_bool, is_number, is_whole

MAX_GRID_RES = 2048  # resolution options above this would ask for terabytes, not train
MAX_SEED = 2 ** 63 - 1  # torch's generators take a signed 64-bit seed (as ``--seed``)
MAX_STEPS = 10 ** 9  # step counts beyond this are no schedule a run reaches (a CPU makes ~10^4 steps an hour)
MAX_WEIGHT = 100.0  # a loss weight beyond this drowns the photometric loss; the defaults are 1e-4 or 0
MAX_REACH = 10.0  # shares of the box diagonal: beyond, every sample of every ray is "near a camera"


def option(default: Any, doc: str, *, low: Optional[float] = None, high: Optional[float] = None,
           open_low: bool = False, open_high: bool = False, choices: Optional[Sequence[Any]] = None) -> Any:
    """A dataclass field of a ``MethodOptions`` subclass: its default, its one-line doc and its bounds.

    Args:
        default: the value a new run takes (a list is copied per instance). Its type is the option's
            kind: bool takes true/false, int a whole number, float any finite number, list a list of
            finite numbers, str one of ``choices``.
        doc: one line that says what the option does (``python -m nerf_core methods`` prints it).
        low, high: the value (each entry of a list) must lie in [low, high]; ``open_low``/``open_high``
            exclude the end. A number option with no ``low`` must be >= 0.
        choices: the values allowed for a string option (may include ``True``/``False`` for an option
            that is a string or a bool, such as ``train_ert``).
    """
    meta = {"doc": doc, "low": 0 if low is None and choices is None else low, "high": high, "open_low": open_low,
            "open_high": open_high, "choices": tuple(choices) if choices is not None else None}
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def grid_option(default: int, doc: str) -> Any:
    """An option counting cells per axis: a whole number in 2..MAX_GRID_RES."""
    return option(default, doc, low=2, high=MAX_GRID_RES)


@dataclasses.dataclass
class MethodOptions:
    """Base of every method's options. A method with no declared fields (a plugin that takes its
    options as keyword arguments) keeps whatever it is given, unchecked, in ``extra``."""

    # Keys that older checkpoints stored among the options but that are run state (``run_state``).
    RUN_STATE_KEYS: ClassVar[Tuple[str, ...]] = ()

    @classmethod
    def declared(cls) -> Dict[str, dataclasses.Field]:
        """name -> field of the options the class declares."""
        return {f.name: f for f in dataclasses.fields(cls) if f.name != "extra"}

    @classmethod
    def docs(cls) -> Dict[str, str]:
        """name -> one-line doc of each declared option."""
        return {name: f.metadata.get("doc", "") for name, f in cls.declared().items()}

    @classmethod
    def allowed(cls) -> Dict[str, str]:
        """name -> what each declared option may be, in the words of its error ("in [0.05, 64]", "one of
        ...", "true or false"), for ``python -m nerf_core methods``."""
        out = {}
        for name, f in cls.declared().items():
            meta, default = f.metadata, _default_of(f)
            if meta.get("choices") is not None:
                out[name] = "one of " + ", ".join(_shown(c) for c in meta["choices"])
            elif isinstance(default, bool):
                out[name] = "true or false"
            else:
                out[name] = ("a list of numbers " if isinstance(default, list) else "") + _range_text(meta)
        return out

    @classmethod
    def defaults(cls) -> Dict[str, Any]:
        """name -> default of each declared option."""
        return cls().to_dict()

    @classmethod
    def parse(cls, method: str, values: Mapping[str, Any]) -> "MethodOptions":
        """The options ``values`` asks for, over the defaults, every value checked.

        Raises:
            OptionError (a ValueError): an option the method does not have, a value of the wrong kind or
                out of its bounds, or options that break a rule together (``check_together``); the message
                names the method, the option and what it must be, and ``.option`` holds the option's name.
        """
        if not isinstance(values, Mapping):
            raise TypeError(f"{method}: options must be a dict of option name -> value, got {type(values).__name__}")
        declared = cls.declared()
        if not declared:
            return cls(extra=dict(values)) if "extra" in {f.name for f in dataclasses.fields(cls)} else cls()
        unknown = sorted(set(values) - set(declared), key=str)
        if unknown:
            raise OptionError(str(unknown[0]), f"{method}: unknown options {unknown}; known: {sorted(declared)}")
        opts = cls(**{name: _check_value(method, name, value, declared[name]) for name, value in values.items()})
        opts.check_together(method)
        return opts

    def check_together(self, method: str) -> None:
        """Rules between options (override; raise ``OptionError`` naming the option the user would change)."""

    def to_dict(self) -> Dict[str, Any]:
        """The options as the JSON-able dict that checkpoints and config.json hold."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "extra"}
        out.update(getattr(self, "extra", {}) or {})
        return {k: list(v) if isinstance(v, list) else v for k, v in out.items()}


@dataclasses.dataclass
class PluginOptions(MethodOptions):
    """The options of a method that declares none: kept as given (its own ``__init__`` checks them)."""

    extra: Dict[str, Any] = dataclasses.field(default_factory=dict)


class OptionError(ValueError):
    """A method option refused: ``option`` is its name (``train`` says ``--set NAME`` with it)."""

    def __init__(self, option: str, message: str):
        super().__init__(message)
        self.option = option


def _check_value(method: str, name: str, value: Any, field: dataclasses.Field) -> Any:
    """``value`` for option ``name`` as the option's own kind (a numpy number becomes a Python one);
    OptionError when it is not of the default's kind or out of bounds."""
    meta, default = field.metadata, _default_of(field)

    def bad(want: str) -> OptionError:
        return OptionError(name, f"{method}: option {name!r} must be {want}, got {_shown_value(value)}")

    choices = meta.get("choices")
    if choices is not None:
        if is_bool(value):
            value = bool(value)
        if not any(value is c or (type(value) is type(c) and value == c) for c in choices):
            raise bad("one of " + ", ".join(_shown(c) for c in choices))
        return value
    if isinstance(default, bool):
        if not is_bool(value):
            raise bad("true or false")
        return bool(value)
    if isinstance(default, list):
        if not isinstance(value, (list, tuple)) or any(not is_number(v) for v in value):
            raise bad("a list of numbers, e.g. [0.1,0.2]")
        for v in value:
            _check_bounds(v, meta, lambda want: bad(f"a list of numbers {want}"))
        return [float(v) for v in value]
    if isinstance(default, int):
        if not is_whole(value):
            raise bad("a whole number")
        value = int(value)
    elif isinstance(default, float):
        if not is_number(value):
            raise bad("a finite number")
        value = float(value)
    _check_bounds(value, meta, bad)
    return value


def _check_bounds(value: float, meta: Mapping[str, Any], bad) -> None:
    low, high = meta.get("low"), meta.get("high")
    if low is not None and (value < low or (meta.get("open_low") and value == low)):
        raise bad(_range_text(meta))
    if high is not None and (value > high or (meta.get("open_high") and value == high)):
        raise bad(_range_text(meta))


def _range_text(meta: Mapping[str, Any]) -> str:
    low, high = _bound(meta.get("low")), _bound(meta.get("high"))
    if high is None:
        return f"greater than {low}" if meta.get("open_low") else f">= {low}"
    left, right = "(" if meta.get("open_low") else "[", ")" if meta.get("open_high") else "]"
    return f"in {left}{low}, {high}{right}"


def _bound(v: Any) -> Optional[str]:
    """A bound as the user would type it: a whole number in full (2^63 - 1, not 9.22337e+18)."""
    return None if v is None else str(v) if isinstance(v, int) else f"{v:g}"


def _shown_value(value: Any, limit: int = 80) -> str:
    text = repr(value.item() if hasattr(value, "item") and not isinstance(value, (list, tuple, dict)) else value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _default_of(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    return field.default_factory()  # type: ignore[misc]


def _shown(c: Any) -> str:
    return ("true" if c else "false") if isinstance(c, bool) else f'"{c}"' if isinstance(c, str) else str(c)
