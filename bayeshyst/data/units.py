"""Units of measured columns (pint), working units, and plausibility from the data.

An instrument exports ``Time [s],Voltage [V],Displacement [um]``, ``t/ms;U/V;x (nm)`` or
``H [A/m],BL [T]`` rather than ``t,u,y``. This module reads such a header cell as a
base name and a unit (:func:`split_header`: ``name [unit]``, ``name (unit)``,
``name / unit``), recognises the roles ``t``, ``u``, ``y`` from the base names
(:data:`ROLE_NAMES`; only where exactly one column fits, otherwise the reader asks for
``columns``), and parses every unit a header, a sidecar or a ``units=`` argument gives
with pint (one registry, :func:`registry`).

Working units
-------------
:func:`apply_units` is the one place where a file's units become a Record's: every
reader goes through it (via :func:`bayeshyst.data.io._assemble`).

* ``t`` must have the dimension of time and is converted to s; without a unit, s is
  assumed (and said so in the conversion notes).
* ``u`` and ``y`` are converted to the working unit of their dimension where
  :data:`WORKING_UNITS` has one (a displacement in cm to um, a field in mT to T, a
  force in kN to N) and otherwise kept as written, in pint's spelling (``kV/mm``).
  Dimensionless labels (:data:`LABEL_UNITS`: ``%``, ``-``, ``1``, ``counts``,
  ``a.u.``) are kept as written.
* Without a unit anywhere, ``u`` and ``y`` are labelled :data:`UNKNOWN` -- never a
  unit the data may not be in.

:func:`convert_units` brings a Record or Dataset into other units (e.g. those a fit was
made in). :func:`plausibility` names what the data themselves show to be inconsistent
(too few samples per cycle, irregular time steps, a frequency the time stamps
contradict); the CLI prints it.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError

__all__ = ["LABEL_UNITS", "ROLE_NAMES", "UNKNOWN", "WORKING_UNITS", "apply_units",
           "conversion", "convert_units", "known_unit", "plausibility", "recognise_roles",
           "registry", "split_header", "unit_dimension"]

#: The unit string of a column whose unit nobody gave.
UNKNOWN = "unknown"

#: Working unit per physical dimension: ``u`` and ``y`` of these dimensions are
#: converted to them when read, ``t`` always to s. A constant (not a setting):
#: the models' priors and the reports' labels are in these units.
WORKING_UNITS: Mapping[str, str] = MappingProxyType({
    "time": "s",
    "voltage": "V",
    "length": "um",
    "force": "N",
    "current": "A",
    "magnetic flux density": "T",
    "magnetic field strength": "A/m",
    "magnetic flux": "Wb",
    "pressure": "Pa",
    "charge": "C",
})

#: Dimensionless labels, kept as written and never converted (compared as text).
LABEL_UNITS = frozenset({"-", "1", "%", "count", "counts", "a.u.", "au", "arb. u.",
                         "arb.u.", "arb", "arb. units", "digits", "dimensionless"})

#: base names (lower case) that name a role in instrument exports
ROLE_NAMES = {
    "t": ("t", "time", "times", "zeit", "timestamp", "time_s"),
    "u": ("u", "v", "voltage", "volt", "volts", "input", "drive", "command", "excitation",
          "vin", "u_in", "spannung", "input voltage", "drive voltage", "applied voltage"),
    "y": ("y", "x", "displacement", "disp", "position", "pos", "output", "stroke",
          "extension", "elongation", "weg", "sensor"),
}
# "name [unit]", "name (unit)", "name / unit", "name/unit" (the last only for a unit)
_BRACKETED = re.compile(r"^(.*?)\s*[\[(]\s*([^\[\]()]+?)\s*[\])]\s*$")
_SLASHED = re.compile(r"^(.*?)\s*/\s*([^/]+?)\s*$")
# CGS magnetic units: pint gives oersted and gauss one Gaussian dimension; which SI
# quantity they are is a matter of their name
_CGS = {"oersted": ("magnetic field strength", 1000.0 / (4.0 * math.pi)),
        "gauss": ("magnetic flux density", 1e-4)}


@functools.cache
def registry() -> Any:
    """The pint ``UnitRegistry`` every unit of bayeshyst is parsed with (built once)."""
    import pint  # 0.4 s to import: only readers of units pay

    return pint.UnitRegistry()


@functools.cache
def _dimensions() -> tuple[tuple[str, Any], ...]:
    reg = registry()
    return tuple((name, reg.Unit(unit).dimensionality) for name, unit in WORKING_UNITS.items())


@dataclass(frozen=True)
class _Unit:
    """A parsed unit: its spelling, pint unit (None for a label) and dimension name."""

    text: str
    unit: Any = None
    dimension: str | None = None
    cgs: tuple[str, float] | None = None


def _is_label(text: str) -> bool:
    return text.strip().lower() in LABEL_UNITS


@functools.cache
def _parse(text: str) -> _Unit:
    """Parse ``text``; ValueError (saying why) when pint does not know it."""
    stripped = text.strip()
    if _is_label(stripped):
        return _Unit(stripped)
    if not stripped or stripped.lower() == UNKNOWN:
        raise ValueError("no unit")
    reg = registry()
    try:
        unit = reg.Unit(stripped)
    except Exception as exc:  # pint raises UndefinedUnitError, AssertionError, ...
        raise ValueError(f"not a unit ({type(exc).__name__}: {exc})") from None
    if unit.dimensionless and str(unit) not in ("radian", "degree", "milliradian"):
        # "ppm", "percent" spelled out: dimensionless labels too
        return _Unit(stripped)
    name = str(unit)
    for base, (dim, _) in _CGS.items():
        if name.endswith(base) and unit.dimensionality == reg.Unit(base).dimensionality:
            return _Unit(_spell(unit), unit, dim, (base, float(reg.Quantity(1.0, unit).to(
                base).magnitude) * _CGS[base][1]))
    dimension = next((d for d, dims in _dimensions() if unit.dimensionality == dims), None)
    return _Unit(_spell(unit), unit, dimension)


def _spell(unit: Any) -> str:
    """Pint's short spelling with micro as ``u`` (``um``, ``kV/mm``, ``m/s**2``)."""
    return format(unit, "~C").replace("µ", "u").replace("μ", "u")


def known_unit(unit: str) -> bool:
    """Whether ``unit`` is a unit pint parses or a dimensionless label (``%``, ``-``)."""
    try:
        _parse(unit)
    except ValueError:
        return False
    return True


def unit_dimension(unit: str) -> str | None:
    """The :data:`WORKING_UNITS` dimension of ``unit`` (``"length"`` for ``"cm"``), or None.

    None for a label, an unparsable unit or a dimension without a working unit.
    """
    try:
        return _parse(unit).dimension
    except ValueError:
        return None


def _factor(src: _Unit, dst: str) -> float:
    """Multiplicative factor from ``src`` to the unit ``dst`` of the same dimension."""
    if src.cgs is not None:
        target = registry().Unit(dst)
        base = registry().Unit(WORKING_UNITS[src.dimension])  # type: ignore[index]
        return src.cgs[1] * float(registry().Quantity(1.0, base).to(target).magnitude)
    return float(registry().Quantity(1.0, src.unit).to(dst).magnitude)


def conversion(role: str, unit: str | None) -> tuple[float, str] | None:
    """Factor and working unit that convert ``unit`` for ``role``; None to keep it.

    None when there is no unit, pint does not parse it, it is a label, its dimension
    has no working unit (:data:`WORKING_UNITS`), or (for ``t``) it is not a time.

    Examples
    --------
    >>> conversion("y", "cm")
    (10000.0, 'um')
    """
    if unit is None or role not in ("t", "u", "y"):
        return None
    try:
        parsed = _parse(unit)
    except ValueError:
        return None
    if parsed.dimension is None or (role == "t" and parsed.dimension != "time"):
        return None
    working = WORKING_UNITS[parsed.dimension]
    return _factor(parsed, working), working


def split_header(name: str) -> tuple[str, str | None]:
    """A header cell as its base name and unit (None without one).

    ``"Time [ms]"`` -> ``("Time", "ms")``, ``"U/V"`` -> ``("U", "V")``, ``"t"`` ->
    ``("t", None)``. Brackets and parentheses take any unit text; a slash only a unit
    pint parses (``"in/out"`` stays a name).
    """
    text = name.strip()
    m = _BRACKETED.match(text)
    if m and m.group(1):
        return m.group(1).strip(), m.group(2).strip()
    m = _SLASHED.match(text)
    if m and m.group(1) and known_unit(m.group(2)):
        return m.group(1).strip(), m.group(2).strip()
    return text, None


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


# ------------------------------------------------------------------- working units
def _same(a: _Unit, b: _Unit) -> bool:
    """Whether two parsed units are one unit (pint equality; labels by text)."""
    if a.unit is None or b.unit is None:
        return a.unit is None and b.unit is None and a.text.lower() == b.text.lower()
    return bool(a.unit == b.unit)


def _parse_or_refuse(unit: str, where: str) -> _Unit:
    try:
        return _parse(unit)
    except ValueError as exc:
        raise DataError(f"{where}: unknown unit {unit!r}: {exc}; expected a unit pint "
                        "parses (s, ms; V, mV; um, mm, cm; N, kN; A, mA; T, mT; A/m, Oe; "
                        "...) or a dimensionless label (%, -, 1, counts, a.u.)") from None


def apply_units(cols: Mapping[str, np.ndarray], written: Mapping[str, str | None],
                declared: Mapping[str, tuple[str, str]], where: Mapping[str, str]
                ) -> tuple[dict[str, np.ndarray], dict[str, str], list[str]]:
    """Bring the ``t``, ``u``, ``y`` columns of a file into working units.

    The one function every reader's units go through (header, sidecar and ``units=``
    argument alike).

    Parameters
    ----------
    cols : mapping of str to ndarray
        Role -> values as read; other roles are passed through untouched.
    written : mapping of str to str or None
        Role -> the unit written in the column's name (the header), None without one.
    declared : mapping of str to (str, str)
        Role -> (unit, where it was declared, e.g. ``"sidecar data.json, key 'units'"``)
        from the sidecar or the ``units`` argument, the winning one per role.
    where : mapping of str to str
        Role -> how the column is named in messages (file, header line, column).

    Returns
    -------
    cols : dict
        The columns, ``t``, ``u``, ``y`` converted (new arrays where converted).
    units : dict
        Role -> the unit of the returned values: s for ``t``, the working unit of the
        dimension, the unit as written (pint's spelling), a label, or :data:`UNKNOWN`.
    notes : list of str
        One line per conversion or assumption, e.g.
        ``"column 'Time [ms]' (t): ms -> s, x 0.001"``.

    Raises
    ------
    DataError
        A unit pint does not parse, a header unit that disagrees with a declared one, or
        a ``t`` whose unit is not a time; the message names file, column and unit.
    """
    out = dict(cols)
    units: dict[str, str] = {}
    notes: list[str] = []
    for role in ("t", "u", "y"):
        header = written.get(role)
        given = declared.get(role)
        if given is not None and given[0].strip().lower() == UNKNOWN:
            given = None
        parsed = None
        if header is not None:
            parsed = _parse_or_refuse(header, where[role])
            if given is not None:
                other = _parse_or_refuse(given[0], f"{where[role]}, unit declared in "
                                                   f"{given[1]}")
                if not _same(parsed, other):
                    raise DataError(f"{where[role]}: the header says {header!r}, the declared "
                                    f"unit of {role!r} is {given[0]!r} ({given[1]}); "
                                    "expected the same unit")
            origin = ""
            text = header
        elif given is not None:
            parsed = _parse_or_refuse(given[0], f"{where[role]}, unit declared in {given[1]}")
            origin = f" ({given[1]})"
            text = given[0]
        if parsed is None:
            if role == "t":
                units[role] = "s"
                notes.append(f"{where[role]}: no unit given, s assumed")
            else:
                units[role] = UNKNOWN
            continue
        if role == "t" and parsed.dimension != "time":
            found = "a dimensionless label" if parsed.unit is None else (
                f"dimension {parsed.dimension or parsed.unit.dimensionality}")
            raise DataError(f"{where[role]}: the time must have a unit of time (s, ms, us, "
                            f"min, ...), got {text!r}{origin}, {found}")
        if parsed.dimension is None:
            units[role] = parsed.text
            continue
        working = WORKING_UNITS[parsed.dimension]
        factor = _factor(parsed, working)
        if factor != 1.0:
            out[role] = np.asarray(cols[role], dtype=float) * factor
            notes.append(f"{where[role]}: {text.strip()}{origin} -> {working}, x {factor:g}")
        units[role] = working
    return out, units, notes


# -------------------------------------------------------------------- conversions
def convert_units(data: Any, units: Mapping[str, str]) -> Any:
    """``data`` with ``t``, ``u``, ``y`` converted to ``units`` (e.g. a fit's units).

    Parameters
    ----------
    data : Record or Dataset
        The data to convert.
    units : mapping of str to str
        Role (``t``, ``u``, ``y``) -> target unit; roles not given are kept.

    Returns
    -------
    Record or Dataset
        Of the type given, the values multiplied by pint's factors (offset units such as
        degC converted by pint) and ``units`` updated; the same object when nothing
        changes.

    Raises
    ------
    DataError
        An unknown role, a unit pint does not parse, units of different dimensions, or
        ``"unknown"`` on one side only; the message names the record, the role and both
        units.
    """
    bad = [r for r in units if r not in ("t", "u", "y")]
    if bad:
        raise DataError(f"convert_units: unknown role {bad[0]!r}; expected t, u or y")
    if isinstance(data, Record):
        return _convert_record(data, units)
    if isinstance(data, Dataset):
        records = [_convert_record(r, units) for r in data]
        if all(a is b for a, b in zip(records, data, strict=True)):
            return data
        return Dataset(records, name=data.name)
    raise DataError(f"convert_units: expected a Record or a Dataset, got "
                    f"{type(data).__name__}")


def _convert_record(rec: Any, units: Mapping[str, str]) -> Any:
    changes: dict[str, Any] = {}
    new_units = dict(rec.units)
    for role, target in units.items():
        source = str(rec.units.get(role, UNKNOWN))
        what = f"record {rec.name!r}, role {role!r}"
        if source.strip() == str(target).strip():
            continue
        src_unknown = source.strip().lower() == UNKNOWN
        dst_unknown = str(target).strip().lower() == UNKNOWN
        if src_unknown or dst_unknown:
            if src_unknown and dst_unknown:
                continue
            raise DataError(f"{what}: cannot convert {source!r} to {target!r}: one of them is "
                            "unknown; give the record's unit (in the header, a sidecar, "
                            "units= or the command line's --units u=...,y=...)")
        src = _parse_or_refuse(source, f"{what}, unit of the record")
        dst = _parse_or_refuse(str(target), f"{what}, target unit")
        if _same(src, dst):
            new_units[role] = str(target)
            continue
        if src.unit is None or dst.unit is None:
            raise DataError(f"{what}: cannot convert {source!r} to {target!r}: a "
                            "dimensionless label converts only to itself")
        values = np.asarray(getattr(rec, role), dtype=float)
        if src.cgs is not None or dst.cgs is not None:
            if src.dimension is None or src.dimension != dst.dimension:
                raise _dimension_error(what, source, target, src, dst)
            converted = values * (_factor(src, WORKING_UNITS[src.dimension])
                                  / _factor(dst, WORKING_UNITS[dst.dimension]))
        else:
            if src.unit.dimensionality != dst.unit.dimensionality:
                raise _dimension_error(what, source, target, src, dst)
            try:
                converted = np.asarray(registry().Quantity(values, src.unit).to(
                    dst.unit).magnitude, dtype=float)
            except Exception as exc:  # an offset unit pint will not convert
                raise DataError(f"{what}: cannot convert {source!r} to {target!r}: "
                                f"{exc}") from None
        changes[role] = converted
        new_units[role] = str(target)
    if not changes and new_units == dict(rec.units):
        return rec
    return rec.with_(**changes, units=new_units)


def _dimension_error(what: str, source: str, target: str, src: _Unit, dst: _Unit
                     ) -> DataError:
    def dim(p: _Unit) -> str:
        return p.dimension or str(p.unit.dimensionality)

    return DataError(f"{what}: cannot convert {source!r} ({dim(src)}) to {target!r} "
                     f"({dim(dst)}): not the same dimension")


# ------------------------------------------------------------------------ plausibility
#: Fewest samples per cycle of the excitation frequency without a caution.
MIN_SAMPLES_PER_CYCLE = 10
#: Largest spread of the time steps (sd / median) without a caution.
MAX_STEP_SPREAD = 0.05
#: Ratio between the declared frequency and the input's own at which the two contradict.
FREQUENCY_CONTRADICTION = 20.0
#: Share of the Nyquist frequency that a broadband input's band may reach without a
#: caution: the passband of the anti-aliasing filters of acquisition systems ends near
#: 0.4 fs; content above it is attenuated, folded, or both
MAX_BAND_SHARE = 0.8


def _input_frequency(rec: Any) -> float | None:
    """The input's dominant frequency by its own time stamps [1/unit of t], or None."""
    u = np.asarray(rec.u, dtype=float)
    if u.size < 16:
        return None
    spectrum = np.abs(np.fft.rfft(u - u.mean()))
    if spectrum.size < 3 or not spectrum[1:].max() > 0:
        return None
    k = int(np.argmax(spectrum[1:])) + 1
    duration = float(rec.t[-1] - rec.t[0]) * u.size / (u.size - 1)
    return k / duration if duration > 0 else None


def plausibility(data: Any) -> list[str]:
    """Cautions about what a Dataset's records themselves show to be inconsistent.

    No range of sampling rates or spans is assumed (a magnet sampled at 0.3 Hz, a creep
    hold over twenty minutes and a damper at 750 Hz are all plausible). Cautioned are:

    * fewer than :data:`MIN_SAMPLES_PER_CYCLE` samples per cycle of the record's
      excitation frequency (``frequency_hz``, when known);
    * irregular sampling: time steps whose sd exceeds :data:`MAX_STEP_SPREAD` of the
      median step (jitter or gaps), with their range;
    * a ``frequency_hz`` that the input's own cycles contradict by a factor of
      :data:`FREQUENCY_CONTRADICTION` or more (time in ms read as s, or the reverse);
    * a broadband or multisine input (``metadata["band_hz"]``, from
      :func:`~bayeshyst.data.label_frequencies`) whose band reaches past
      :data:`MAX_BAND_SHARE` of the Nyquist frequency (content that an acquisition
      system's anti-aliasing filter attenuates or folds).

    Parameters
    ----------
    data : Dataset or iterable of Record

    Returns
    -------
    list of str
        One sentence per caution, naming the record.
    """
    out = []
    for rec in data:
        steps = np.diff(np.asarray(rec.t, dtype=float))
        median = float(np.median(steps))
        spread = float(np.std(steps)) / median if median > 0 else 0.0
        if spread > MAX_STEP_SPREAD:
            out.append(f"{rec.name}: irregular sampling: time steps from {steps.min():.4g} to "
                       f"{steps.max():.4g} {rec.units['t']} (median {median:.4g}, sd "
                       f"{100 * spread:.3g} % of it); expected uniform steps -- gaps or "
                       "time-stamp jitter?")
        f = rec.frequency_hz
        band = rec.metadata.get("band_hz")
        if f is None and isinstance(band, tuple | list) and len(band) == 2 and median > 0:
            nyquist = 0.5 / median
            if float(band[1]) > MAX_BAND_SHARE * nyquist:
                out.append(f"{rec.name}: the input's band reaches {float(band[1]):.4g} Hz, "
                           f"{100 * float(band[1]) / nyquist:.0f} % of the Nyquist "
                           f"frequency {nyquist:.4g} Hz ({1 / (float(band[1]) * median):.3g} "
                           f"samples per period at its top); expected at most "
                           f"{100 * MAX_BAND_SHARE:.0f} % -- content may be aliased and "
                           "fast dynamics unresolved")
        if f is None:
            continue
        per_cycle = 1.0 / (f * median) if median > 0 else math.inf
        found = _input_frequency(rec)
        hint = ""
        # judged where the record holds two cycles by either frequency
        if found is not None and max(f, found) * float(rec.t[-1] - rec.t[0]) >= 2:
            ratio = f / found
            if ratio >= FREQUENCY_CONTRADICTION or ratio <= 1 / FREQUENCY_CONTRADICTION:
                hint = (f"; its input cycles at {found:.4g} Hz by the time stamps, "
                        f"{ratio:.3g} x less than frequency_hz {f:g} Hz says -- "
                        + ("time in ms read as s?" if ratio > 1 else "time in s read as "
                           "ms?") + " Give the time unit in the header (e.g. 'Time [ms]') "
                        "or the sidecar")
                if per_cycle >= MIN_SAMPLES_PER_CYCLE:
                    out.append(f"{rec.name}: frequency_hz {f:g} Hz contradicts the sampling "
                               f"({median:.4g} {rec.units['t']} steps){hint}")
                    continue
        if per_cycle < MIN_SAMPLES_PER_CYCLE:
            out.append(f"{rec.name}: {per_cycle:.3g} samples per cycle of the "
                       f"{f:g} Hz excitation (step {median:.4g} {rec.units['t']}); "
                       f"expected at least {MIN_SAMPLES_PER_CYCLE} to resolve a loop"
                       + (hint or " -- the sampling too slow, or frequency_hz wrong?"))
    return out
