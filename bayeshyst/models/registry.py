"""Model registry: names -> model classes, and construction from a name or spec string."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from bayeshyst.errors import ModelError
from bayeshyst.models.base import HysteresisModel

__all__ = ["build", "get", "model_class", "names", "register", "register_spec_parser"]

_REGISTRY: dict[str, type[HysteresisModel]] = {}
_SPEC_PARSER: list[Callable[[str], HysteresisModel]] = []


def register(cls: type[HysteresisModel]) -> type[HysteresisModel]:
    """Class decorator adding a model under its ``name``."""
    if not cls.name:
        raise ModelError(f"{cls.__name__} has no registry name")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise ModelError(f"model name {cls.name!r} is already taken by "
                         f"{_REGISTRY[cls.name].__name__}")
    _REGISTRY[cls.name] = cls
    return cls


def register_spec_parser(parser: Callable[[str], HysteresisModel]) -> None:
    """Install the parser of composed spec strings (``"bouc_wen+creep"``)."""
    _SPEC_PARSER[:] = [parser]


def names() -> list[str]:
    """Registered model names, sorted."""
    return sorted(_REGISTRY)


def model_class(name: str) -> type[HysteresisModel]:
    """The class registered under ``name``."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ModelError(f"unknown model {name!r}; available: {', '.join(names())}") from None


def get(spec: str, **settings: Any) -> HysteresisModel:
    """Build a model from a registry name (or a ``+``-composed spec string).

    Parameters
    ----------
    spec : str
        A model name such as ``"pi_play"``; with effect blocks, ``"pi_play+arx"``;
        with settings in the string, ``"pi_play(n_operators=6)+second_order"``.
    **settings
        Structural settings of the model (e.g. ``n_operators=12``); unknown names are
        an error, not ignored.
    """
    spec = spec.strip()
    if "+" in spec or "(" in spec:
        if settings:
            raise ModelError("settings cannot be combined with a composed spec string; "
                             "build the blocks in Python instead")
        if not _SPEC_PARSER:
            raise ModelError(f"composed spec {spec!r}: no effect blocks are installed")
        return _SPEC_PARSER[0](spec)
    return build(model_class(spec), settings, f"model {spec!r}")


def build(cls: type, settings: dict[str, Any], label: str) -> Any:
    """``cls(**settings)`` after checking every setting is a field of the dataclass.

    ``label`` names the thing in the message (``"model 'pi_play'"``); unknown settings
    are an error that lists the valid ones, never silently dropped.
    """
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(settings) - fields)
    if unknown:
        raise ModelError(f"{label} has no setting(s) {unknown}; "
                         f"settings: {sorted(fields) or 'none'}")
    return cls(**settings)
