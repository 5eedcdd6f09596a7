"""The command line's option types and the one mapping of options to sampler settings."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.inference.settings import SamplerSettings

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERNAL", "EXIT_OK", "effect_list", "initial_condition",
           "int_at_least",
           "non_negative_float", "non_negative_int", "positive_int", "probability",
           "sampler_settings", "unit_mapping", "working_rate"]

#: exit status: success, internal error, bad input
EXIT_OK, EXIT_INTERNAL, EXIT_BAD_INPUT = 0, 1, 2


def int_at_least(minimum: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum`` (``what`` names it in the message)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value

    return parse


positive_int = int_at_least(1, "a positive integer")
non_negative_int = int_at_least(0, "an integer >= 0")

#: The options every sampling command maps onto its :class:`SamplerSettings`, and the
#: field each one sets (``--quiet`` sets ``progress`` to its negation).
_SAMPLER_FLAGS = {"seed": "seed", "walkers": "n_walkers", "steps": "max_steps",
                  "moves": "moves"}


def sampler_settings(args: argparse.Namespace, **overrides: Any) -> SamplerSettings:
    """The one :class:`SamplerSettings` of a command, from its command-line options.

    ``--seed``, ``--walkers`` (``n_walkers``), ``--steps`` (``max_steps``), ``--moves``
    and ``--quiet`` (``progress = not quiet``) are mapped here and nowhere else; an
    option the command does not have (``bayeshyst demo`` has no ``--steps``), or left
    at None, keeps the record's default. ``overrides`` (``checkpoint=...``, a demo's
    budget) replace what the options give. ``first_chunk`` stays at its default unless
    the step budget is below it.

    Raises
    ------
    ParameterError
        For values the record rejects (``--steps 5``: fewer steps than a convergence
        check needs).
    """
    values: dict[str, Any] = {}
    for flag, name in _SAMPLER_FLAGS.items():
        value = getattr(args, flag, None)
        if value is not None:
            values[name] = value
    if getattr(args, "quiet", None) is not None:
        values["progress"] = not args.quiet
    values.update(overrides)
    if "first_chunk" not in values and "max_steps" in values:
        values["first_chunk"] = min(SamplerSettings.first_chunk, values["max_steps"])
    return SamplerSettings(**values)



def probability(text: str) -> float:
    """An argparse type: a number strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {value:g}")
    return value


def closed_probability(text: str) -> float:
    """An argparse type: a number in [0, 1] (0 and 1 allowed)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {value:g}")
    return value


def initial_condition(text: str) -> Any:
    """An argparse type: ``relaxed``, ``rest``, ``warmup:SECONDS`` or ``periodic[:K]``.

    Returns the :class:`~bayeshyst.inference.predict.InitialCondition` it names.
    """
    from bayeshyst.inference.predict import InitialCondition

    try:
        return InitialCondition.parse(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def column_mapping(text: str) -> dict[str, str]:
    """An argparse type: ``t=Time [s],u=Voltage [V],y=Displacement`` -> role -> column.

    Roles are those of the readers (``t``, ``u``, ``y``, ``segment``, ``frequency_hz``,
    ``record``); a column may be named with or without its unit.
    """
    from bayeshyst.data.parsing import OPTIONAL_ROLES, REQUIRED_ROLES

    roles = REQUIRED_ROLES + OPTIONAL_ROLES
    out: dict[str, str] = {}
    for part in text.split(","):
        if not part.strip():
            continue
        role, sep, name = part.partition("=")
        role, name = role.strip(), name.strip()
        if not sep or not name:
            raise argparse.ArgumentTypeError(f"expected ROLE=COLUMN pairs separated by ',' "
                                             f"(e.g. t=Time [s],u=Voltage,y=Disp), got "
                                             f"{part.strip()!r}")
        if role not in roles:
            raise argparse.ArgumentTypeError(f"unknown role {role!r} in {part.strip()!r}; "
                                             f"roles: {', '.join(roles)}")
        if role in out:
            raise argparse.ArgumentTypeError(f"role {role!r} given twice")
        out[role] = name
    if not out:
        raise argparse.ArgumentTypeError(f"no ROLE=COLUMN pair in {text!r}")
    return out


def unit_mapping(text: str) -> dict[str, str]:
    """An argparse type: ``u=mT,y=um`` -> role -> unit of the data file's columns.

    Roles ``t``, ``u``, ``y``; every unit must parse (pint, or a dimensionless label
    such as ``%`` or ``counts``; ``unknown`` declares no unit). The reader converts the
    columns as it does units written in the header
    (:func:`bayeshyst.data.units.apply_units`).
    """
    from bayeshyst.data.units import UNKNOWN, known_unit

    out: dict[str, str] = {}
    for part in text.split(","):
        if not part.strip():
            continue
        role, sep, unit = part.partition("=")
        role, unit = role.strip(), unit.strip()
        if not sep or not unit:
            raise argparse.ArgumentTypeError(f"expected ROLE=UNIT pairs separated by ',' "
                                             f"(e.g. t=ms,u=mT,y=um), got {part.strip()!r}")
        if role not in ("t", "u", "y"):
            raise argparse.ArgumentTypeError(f"unknown role {role!r} in {part.strip()!r}; "
                                             f"roles: t, u, y")
        if role in out:
            raise argparse.ArgumentTypeError(f"role {role!r} given twice")
        if unit.lower() != UNKNOWN and not known_unit(unit):
            raise argparse.ArgumentTypeError(f"role {role!r}: unknown unit {unit!r}; expected "
                                             f"a unit such as s, ms, V, mV, um, mm, N, A, T, "
                                             f"mT, A/m, Oe, or a label (%, counts)")
        out[role] = unit
    if not out:
        raise argparse.ArgumentTypeError(f"no ROLE=UNIT pair in {text!r}")
    return out


def effect_list(text: str) -> tuple[str, ...]:
    """``creep,delay`` -> ``("creep", "delay")``; ModelError naming an unknown effect."""
    from bayeshyst.diagnosis import get_effect

    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ParameterError(f"--effects: no effect named in {text!r}")
    for n in names:
        get_effect(n)  # raises, listing the valid names
    return tuple(dict.fromkeys(names))


def non_negative_float(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value



def working_rate(text: str) -> str | float:
    """An argparse type: ``auto``, ``full`` or a working rate in Hz (a finite number > 0).

    Returns ``"auto"``, ``"full"`` or the rate [Hz] as a float, what
    :func:`bayeshyst.data.working_rate.to_working_rate` takes as ``rate``.
    """
    word = text.strip().lower()
    if word in ("auto", "full"):
        return word
    try:
        value = float(word)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, full or a rate in Hz > 0, got "
                                         f"{text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected auto, full or a rate in Hz > 0, got "
                                         f"{text!r}")
    return value
