"""The catalogue of candidate effects the diagnosis tests, in reporting order.

The classic six (:mod:`bayeshyst.diagnosis.effects`) and the effects that follow a
driver other than the input (:mod:`bayeshyst.diagnosis.driven`).
"""

from __future__ import annotations

from collections.abc import Mapping

from bayeshyst.diagnosis.driven import AuxEffect, ChangePointEffect
from bayeshyst.diagnosis.effects import (
    Asymmetry,
    ColoredNoise,
    CreepEffect,
    DelayEffect,
    DriftEffect,
    Effect,
    RateDependence,
)
from bayeshyst.errors import ModelError

__all__ = ["EFFECTS", "get_effect"]

#: The candidate effects in reporting order.
EFFECTS: Mapping[str, Effect] = {e.name: e for e in (
    CreepEffect(), RateDependence(), Asymmetry(), DriftEffect(), DelayEffect(), AuxEffect(),
    ChangePointEffect(), ColoredNoise())}


def get_effect(name: str) -> Effect:
    """The effect called ``name``; ModelError listing the valid names."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise ModelError(f"unknown effect {name!r}; valid: {', '.join(EFFECTS)}") from None
