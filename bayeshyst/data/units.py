"""Instrument headers: column names with units, roles recognised by name, unit conversion.

An instrument exports ``Time [s],Voltage [V],Displacement [um]`` or ``t/ms;U/V;x (nm)``
rather than ``t,u,y``. This module reads such a header cell as a base name and a unit
(:func:`split_header`: ``name [unit]``, ``name (unit)``, ``name / unit``), recognises the
roles ``t``, ``u``, ``y`` from the base names (:data:`ROLE_NAMES`; only where exactly one
column fits, otherwise the reader asks for ``columns``), and converts a header's unit to
the working units of bayeshyst — s, V, µm — with the factor stated
(:func:`conversion`). A unit of another dimension (an input in mA, a force in N) stays
a label: the numbers are used as they are.

:func:`plausibility` names what looks wrong for a piezo stage once the data are read (a
sampling rate or a stroke that says "time in ms read as s"); the CLI prints it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.errors import DataError

__all__ = ["OTHER_UNITS", "ROLE_NAMES", "WORKING_UNITS", "conversion", "header_units",
           "known_unit", "plausibility", "recognise_roles", "split_header"]

#: the units bayeshyst works in, per role
WORKING_UNITS = {"t": "s", "u": "V", "y": "um"}
#: unit -> (dimension, factor to the working unit of that dimension); micro as u, µ or μ
_UNITS: dict[str, tuple[str, float]] = {
    "s": ("time", 1.0), "sec": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6),
    "ns": ("time", 1e-9), "min": ("time", 60.0),
    "v": ("voltage", 1.0), "mv": ("voltage", 1e-3), "kv": ("voltage", 1e3),
    "uv": ("voltage", 1e-6),
    "m": ("length", 1e6), "mm": ("length", 1e3), "um": ("length", 1.0),
    "micron": ("length", 1.0), "microns": ("length", 1.0), "nm": ("length", 1e-3),
    "pm": ("length", 1e-6),
}
_DIMENSION = {"t": "time", "u": "voltage", "y": "length"}
#: units of other quantities an actuator's file may hold in the t, u, y roles (a force
#: output, a current input): kept as labels, the numbers used as they are
OTHER_UNITS = frozenset(
    _k for _k in ("N", "kN", "mN", "A", "mA", "uA", "µA", "μA", "C", "nC", "uC", "µC",
                  "Pa", "kPa", "MPa", "bar", "deg", "rad", "mrad", "urad", "%", "-", "1",
                  "counts", "a.u.", "au", "um/V", "mm/s", "m/s", "g", "m/s^2", "m/s2",
                  "N/m", "W", "mW", "Hz"))
#: base names (lower case) that name a role in instrument exports
ROLE_NAMES = {
    "t": ("t", "time", "times", "zeit", "timestamp", "time_s"),
    "u": ("u", "v", "voltage", "volt", "volts", "input", "drive", "command", "excitation",
          "vin", "u_in", "spannung", "input voltage", "drive voltage", "applied voltage"),
    "y": ("y", "x", "displacement", "disp", "position", "pos", "output", "stroke",
          "extension", "elongation", "weg", "sensor"),
}
# "name [unit]", "name (unit)", "name / unit", "name/unit" (the last only for a known unit)
_BRACKETED = re.compile(r"^(.*?)\s*[\[(]\s*([^\[\]()]+?)\s*[\])]\s*$")
_SLASHED = re.compile(r"^(.*?)\s*/\s*([^/]+?)\s*$")


def _key(unit: str) -> str:
    return unit.strip().replace("µ", "u").replace("μ", "u").lower()


def split_header(name: str) -> tuple[str, str | None]:
    """A header cell as its base name and unit (None without one).

    ``"Time [ms]"`` -> ``("Time", "ms")``, ``"U/V"`` -> ``("U", "V")``, ``"t"`` ->
    ``("t", None)``. Brackets and parentheses take any unit text; a slash only a unit
    bayeshyst knows (``"in/out"`` stays a name).
    """
    text = name.strip()
    m = _BRACKETED.match(text)
    if m and m.group(1):
        return m.group(1).strip(), m.group(2).strip()
    m = _SLASHED.match(text)
    if m and m.group(1) and _key(m.group(2)) in _UNITS:
        return m.group(1).strip(), m.group(2).strip()
    return text, None


def known_unit(unit: str) -> bool:
    """Whether ``unit`` is one bayeshyst converts or knows to keep as a label."""
    return _key(unit) in _UNITS or unit.strip() in OTHER_UNITS or _key(unit) in {
        _key(u) for u in OTHER_UNITS}


def conversion(role: str, unit: str | None) -> tuple[float, str] | None:
    """Factor and working unit that convert ``unit`` for ``role``; None to keep it a label.

    None when there is no unit, the unit is unknown, or it is not of the role's
    dimension (time for ``t``, voltage for ``u``, length for ``y``).
    """
    if unit is None or role not in _DIMENSION:
        return None
    found = _UNITS.get(_key(unit))
    if found is None or found[0] != _DIMENSION[role]:
        return None
    return found[1], WORKING_UNITS[role]


def recognise_roles(available: Sequence[str], taken: dict[str, str]
                    ) -> tuple[dict[str, str], dict[str, list[str]]]:
    """Roles found by name among ``available`` columns, for the roles not in ``taken``.

    Returns
    -------
    found : dict
        Role -> column, where exactly one free column's base name is one of the role's
        names (:data:`ROLE_NAMES`).
    ambiguous : dict
        Role -> the columns that fit, where several do.
    """
    used = set(taken.values())
    found: dict[str, str] = {}
    ambiguous: dict[str, list[str]] = {}
    for role, names in ROLE_NAMES.items():
        if role in taken:
            continue
        fits = [c for c in available if c not in used
                and split_header(c)[0].strip().lower() in names]
        if len(fits) == 1:
            found[role] = fits[0]
            used.add(fits[0])
        elif len(fits) > 1:
            ambiguous[role] = fits
    return found, ambiguous


# ------------------------------------------------------------------------ plausibility
#: what a piezo stage's data plausibly span (working units): sampling rate, input and
#: output peak-to-peak. Outside, a unit was most likely misread.
FS_RANGE_HZ = (10.0, 1e7)
U_SPAN_V = (1e-3, 5e3)
Y_SPAN_UM = (1e-3, 1e4)


def plausibility(data: Any) -> list[str]:
    """Cautions about a Dataset that do not look like a piezo stage in s, V and µm.

    Only quantities in the working units are judged (a force in N is not).
    """
    out = []
    for rec in data:
        units = dict(rec.units)
        checks = []
        if units.get("t") == "s":
            checks.append(("sampling rate", float(rec.fs), "Hz", FS_RANGE_HZ,
                           "time in ms or µs read as s?"))
        if units.get("u") == "V":
            checks.append(("input span", float(np.ptp(rec.u)), "V", U_SPAN_V,
                           "input in mV or kV labelled V?"))
        if units.get("y") == "um":
            checks.append(("output span", float(np.ptp(rec.y)), "µm", Y_SPAN_UM,
                           "displacement in m, mm or nm labelled µm?"))
        for what, value, unit, (lo, hi), hint in checks:
            if math.isfinite(value) and not lo <= value <= hi:
                out.append(f"{rec.name}: {what} {value:.4g} {unit} is outside what a piezo "
                           f"stage gives ({lo:g}-{hi:g} {unit}): {hint} Give the units in "
                           "the header (e.g. 'Time [ms]') or the sidecar")
    return out


def header_units(path: Path, header: str, resolved: Mapping[str, str],
                  cols: dict[str, np.ndarray], units: Mapping[str, str] | None,
                  side: tuple[Path, dict[str, Any]] | None
                  ) -> tuple[dict[str, str] | None, list[str]]:
    """Units written in the header: convert ``cols`` in place to s, V, µm where known.

    Used by :func:`bayeshyst.data.io.read_csv` once the columns' roles are resolved.

    The header describes the file's numbers, so it wins; a unit declared for the same
    role in the sidecar or the ``units`` argument must agree with it (else DataError).

    Returns
    -------
    units : dict or None
        ``units`` with the header's (converted) units over it.
    notes : list of str
        One line per conversion, e.g. ``"column 'Time [ms]' (t): ms -> s, x 0.001"``.
    """
    declared = {**((side[1].get("units") or {}) if side else {}), **(units or {})}
    out = dict(units or {})
    notes = []
    for role in ("t", "u", "y"):
        unit = split_header(resolved[role])[1]
        if unit is None:
            continue
        if not known_unit(unit):
            raise DataError(f"{path}: {header}, column {resolved[role]!r} ({role}): unknown "
                            f"unit {unit!r}; expected s/ms/us/ns for t, V/mV/kV for u, "
                            f"m/mm/um/nm for y (converted), or a unit of another quantity "
                            f"(N, A, ...; kept as a label)")
        conv = conversion(role, unit)
        given = declared.get(role)
        if given is not None and given.strip() not in (unit, conv[1] if conv else unit):
            raise DataError(f"{path}: {header}, column {resolved[role]!r}: the header says "
                            f"{unit!r}, the declared unit of {role!r} is {given!r}")
        if conv is None:
            out[role] = unit
            continue
        factor, working = conv
        if factor != 1.0:
            cols[role] = cols[role] * factor
            notes.append(f"column {resolved[role]!r} ({role}): {unit} -> {working}, "
                         f"x {factor:g}")
        out[role] = working
    return (out or None), notes
