"""The registry of methods: build one by name, and what a name offers.

The built-in methods (``catalog``) register when ``nerf_core.methods`` is imported, which any import
of this module does first; a plugin registers its own with ``@register("name")``.
"""
from __future__ import annotations

from typing import Callable, Dict, Optional

import torch

from nerf_core.data.validation import checked_box
from nerf_core.methods.environment_options import build_environment

_REGISTRY: Dict[str, Callable[..., "torch.nn.Module"]] = {}

# Options renamed after checkpoints were written with them: old name -> today's. Checkpoints, run
# configs and ``--set`` may still use an old name (``contract`` now names only the ``nerf_core.contract``
# package, so vmgrid's scene-contraction switch is ``unbounded``).
RENAMED_OPTIONS = {"contract": "unbounded"}


def register(name: str, replace: bool = False):
    """Class decorator: make a ``RadianceModel`` subclass buildable as ``build_model(name, ...)``.

    Also sets the class's ``method_name`` to ``name``. A second registration of a plugin's name
    replaces the first; a built-in method's name is refused unless ``replace=True`` (checkpoints of
    the built-in method would load into the replacement).

    Args:
        name: the method's name (``train --method NAME``, saved in checkpoints): a non-empty string.
        replace: allow replacing a built-in method.

    Returns:
        The decorator, which returns the class itself.
    """

    if not isinstance(name, str) or not name.strip() or name != name.strip():
        raise (TypeError if not isinstance(name, str) else ValueError)(
            f"register: name must be a non-empty string without surrounding spaces, got {name!r}")
    if not isinstance(replace, bool):
        raise TypeError(f"register: replace must be True or False, got {replace!r}")
    old = _REGISTRY.get(name)
    if old is not None and getattr(old, "__module__", "").startswith("nerf_core.methods.") and not replace:
        raise ValueError(f"register: {name!r} is a built-in method; pass replace=True to replace it, or register "
                         "your method under another name")

    def deco(cls):
        if not (isinstance(cls, type) and issubclass(cls, torch.nn.Module)):
            raise TypeError(f"register({name!r}): decorates a RadianceModel subclass, got {cls!r}")
        _REGISTRY[name] = cls
        cls.method_name = name
        return cls

    return deco


def available_methods() -> list[str]:
    """Names of the registered methods (built-in and plugins).

    Returns:
        The names, sorted.
    """
    return sorted(_REGISTRY)


def build_model(name: str, aabb: torch.Tensor, **options) -> torch.nn.Module:
    """Build method ``name`` for a scene inside ``aabb`` (2, 3) = [[xmin, ymin, zmin], [xmax, ymax, zmax]].

    ``options["environment"]`` (a dict of ``EnvironmentMap`` options, or None) is handled here for
    every method: the method is built without it and the environment is attached afterwards, so a
    method never needs to know about the world behind the scene.

    Args:
        name: a registered method (``available_methods()``).
        aabb: (2, 3) float scene box.
        **options: the method's build options (over its ``Options``' defaults), plus ``environment``.

    Returns:
        The new model (a ``RadianceModel``, in training mode, on the CPU).

    Raises:
        ValueError: an unknown method name, an ``environment`` that is not a dict, or (from the method)
            an option it refuses; a ``TypeError`` may come from an option the method does not take.
    """
    if not isinstance(name, str):
        raise TypeError(f"build_model: name must be a method name (str), got {name!r}")
    if name not in _REGISTRY:
        raise ValueError(f"build_model: unknown method {name!r}; choose one of {', '.join(sorted(_REGISTRY))}")
    aabb = checked_box("build_model", aabb)
    options = dict(options)
    environment = build_environment(name, options.pop("environment", None))  # checked before the build
    model = _REGISTRY[name](aabb=aabb, **options)
    if environment is not None:
        model.attach_environment(environment)
    return model


def saved_options(name: str, options: dict) -> dict:
    """The options a checkpoint of method ``name`` was trained with: ``options`` as saved, plus, for
    each option added after the checkpoint was written, the value that behaviour had before the
    option existed (the method's ``options_before``), less the run state that older checkpoints kept
    among the options (``Options.RUN_STATE_KEYS``; ``saved_run_state`` reads it). A checkpoint's
    model must be rebuilt as it was trained, not with today's defaults; ``train --resume`` and every
    loader go through here."""
    cls = method_class(name)
    if cls is None:
        return dict(options)
    state_keys = cls.Options.RUN_STATE_KEYS
    return {k: v for k, v in {**cls.options_before, **current_option_names(options)}.items()
            if k not in state_keys}


def saved_run_state(name: str, ckpt: dict) -> dict:
    """The run state (``RadianceModel.run_state``) a checkpoint of method ``name`` holds: its
    ``method_state``, or, in a checkpoint written before that entry, the state keys of its options."""
    state = ckpt.get("method_state")
    if isinstance(state, dict):
        return dict(state)
    cls, options = method_class(name), ckpt.get("options")
    if cls is None or not isinstance(options, dict):
        return {}
    return {k: options[k] for k in cls.Options.RUN_STATE_KEYS if k in options}


def current_option_names(options: dict, known=None) -> dict:
    """``options`` with each old option name (``RENAMED_OPTIONS``) replaced by today's name.

    Args:
        known: the option names the method declares, or None (any): an old name whose new name the
            method does not have stays as it is, so the method refuses it under the name the user wrote
            (``--set contract=true`` for nerf is "unknown option 'contract'", not 'unbounded').

    Raises:
        ValueError: an option given under its old and its new name with two different values.
    """
    out = dict(options)
    for old, new in RENAMED_OPTIONS.items():
        if old in out and (known is None or new in known):
            value = out.pop(old)
            if new in out and out[new] != value:
                raise ValueError(f"option {old!r} is the old name of {new!r}, and the two disagree "
                                 f"({old}={value!r}, {new}={out[new]!r}); give one of them")
            out.setdefault(new, value)
    return out


def method_class(name: str) -> Optional[type]:
    """The ``RadianceModel`` subclass registered as ``name`` (built-in or plugin), or None."""
    return _REGISTRY.get(name)


def has_option(name: str, key: str) -> bool:
    """Whether the method registered as ``name`` declares option ``key`` (a field of its ``Options``)."""
    cls = method_class(name)
    return cls is not None and key in cls.Options.declared()
