"""Low-level parsing: delimited UTF-8 text tables, JSON sidecars, column roles.

Kept apart from :mod:`bayeshyst.data.io` (which turns parsed columns into Records) so
that the measured-data loaders can reuse the line-aware text parser on headerless
files. The parser is written on the ``csv`` module rather than ``numpy.genfromtxt``
precisely so that it knows the file line of every cell. Every failure is a
:class:`~bayeshyst.errors.DataError` naming the file, the 1-based line (header = line 1),
the column, and what was expected vs found.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.record import MIN_SAMPLES, Record
from bayeshyst.data.units import ROLE_NAMES, recognise_roles, split_header
from bayeshyst.errors import DataError

__all__ = [
    "OPTIONAL_ROLES",
    "REQUIRED_ROLES",
    "SIDECAR_FORMAT",
    "Table",
    "check_file",
    "encode_sidecar",
    "is_number",
    "read_sidecar",
    "read_table",
    "resolve_roles",
    "role_labels",
    "sidecar_path",
]

#: Column roles: required, and optional (``record`` = integer block index).
REQUIRED_ROLES = ("t", "u", "y")
OPTIONAL_ROLES = ("segment", "frequency_hz", "record")
_ROLES = REQUIRED_ROLES + OPTIONAL_ROLES

#: Value of the ``format`` key written into every sidecar.
SIDECAR_FORMAT = "bayeshyst-sidecar"
_SIDECAR_KEYS = ("format", "version", "name", "columns", "warmup", "metadata", "units", "records")
_ENTRY_KEYS = ("name", "warmup", "metadata", "units", "segment")
_WHITESPACE = " "  # internal marker: split on runs of blanks/tabs


# ------------------------------------------------------------------------------ text
def check_file(path: str | os.PathLike[str]) -> Path:
    """Return ``Path(path)`` after checking it is an existing non-directory, else DataError."""
    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    if p.is_dir():
        raise DataError(f"{p}: is a directory; expected a data file")
    return p


def _decode(path: Path, data: bytes, what: str = "text file") -> str:
    """Strict UTF-8 decoding whose errors name the byte offset and line."""
    bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # tolerate Excel's UTF-8 BOM
    try:
        text = data[bom:].decode("utf-8")
    except UnicodeDecodeError as exc:
        pos = exc.start + bom
        line = data.count(b"\n", 0, pos) + 1
        raise DataError(
            f"{path}: line {line}, byte offset {pos}: expected a UTF-8 {what}, got "
            f"undecodable byte 0x{data[pos]:02x} (binary file, or another encoding?)"
        ) from exc
    nul = text.find("\x00")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        raise DataError(
            f"{path}: line {line}: expected a {what}, got a NUL character (binary file?)"
        )
    return text


def _detect(line: str) -> str | None:
    """Delimiter of ``line``: ',' ';' tab or whitespace, in that order; None if one field."""
    for d in (",", ";", "\t"):
        if d in line:
            return d
    return _WHITESPACE if len(line.split()) > 1 else None


def is_number(text: str) -> bool:
    """Whether ``text`` parses as a float (a data cell rather than a name or a note)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _delim_name(d: str) -> str:
    return {"\t": "tab", _WHITESPACE: "whitespace"}.get(d, repr(d))


@dataclass(frozen=True, eq=False)
class Table:
    """Raw cells of a delimited text file, column by column, with their file lines.

    Attributes
    ----------
    path : Path
        The file.
    names : tuple of str
        Column names from the header, or ``"col0", "col1", ...`` (0-based) without one.
    cells : tuple of tuple of str
        ``cells[j][i]``: the text of column ``j`` in data row ``i``.
    lines : numpy.ndarray of int, shape (n_rows,)
        1-based file line of each data row (the header, if any, is line 1 or later).
    delimiter : str
        The delimiter used (``" "`` means runs of whitespace).
    header_line : int or None
        1-based file line of the header, None for headerless tables.
    """

    path: Path
    names: tuple[str, ...]
    cells: tuple[tuple[str, ...], ...]
    lines: np.ndarray
    delimiter: str
    header_line: int | None = None

    @property
    def n_rows(self) -> int:
        """Number of data rows."""
        return int(self.lines.size)

    def floats(self, name: str, *, label: str | None = None, integer: bool = False) -> np.ndarray:
        """Column ``name`` as finite float64 values, shape (n_rows,).

        Parameters
        ----------
        name : str
            Column name in the file.
        label : str, optional
            How to name the column in error messages (default ``"column '<name>'"``).
        integer : bool, default False
            Require integer values (segment labels, record indices).

        Raises
        ------
        DataError
            On an empty, non-numeric, non-finite (or non-integer) cell, naming the file,
            line and column.
        """
        label = f"column {name!r}" if label is None else label
        cells = self.cells[self.names.index(name)]
        try:
            values = np.fromiter(map(float, cells), dtype=np.float64, count=len(cells))
        except ValueError:
            # slow path only on failure: find the first offending cell for the message
            for i, cell in enumerate(cells):
                try:
                    float(cell)
                except ValueError:
                    self._fail(i, label, "a number", cell)
            raise  # pragma: no cover - the loop above always finds the cell
        finite = np.isfinite(values)
        if not finite.all():
            i = int(np.argmax(~finite))
            self._fail(i, label, "a finite number", cells[i])
        if integer:
            ok = values == np.round(values)
            if not ok.all():
                i = int(np.argmax(~ok))
                self._fail(i, label, "an integer label", cells[i])
        return values

    def _fail(self, i: int, label: str, expected: str, cell: str) -> None:
        got = "an empty cell" if not cell.strip() else repr(cell.strip())
        hint = ""
        if "," in cell and self.delimiter != ",":
            hint = " (decimal comma? use '.' as decimal separator)"
        raise DataError(
            f"{self.path}: line {self.lines[i]}, {label}: expected {expected}, "
            f"got {got}{hint}"
        )


def read_table(
    path: str | os.PathLike[str], *, delimiter: str | None = None, header: bool = True
) -> Table:
    r"""Split a delimited UTF-8 text file into cells, keeping every row's file line.

    Blank lines and lines starting with ``#`` are skipped (they still count for line
    numbers). Every data row must have as many fields as the header (or, without a
    header, as the first data row).

    Parameters
    ----------
    path : path-like
        The file.
    delimiter : str, optional
        ``","``, ``";"``, ``"\t"``, or ``" "`` (runs of whitespace). Detected from the
        first line when None, in the order ``,`` ``;`` tab whitespace.
    header : bool, default True
        Whether the first non-comment line holds column names.

    Returns
    -------
    Table

    Raises
    ------
    DataError
        Empty file, header only, one-column header (wrong delimiter), ragged row,
        duplicate column name, undecodable bytes.
    """
    p = check_file(path)
    text = _decode(p, p.read_bytes())
    kept: list[tuple[int, str]] = []
    for number, line in enumerate(text.split("\n"), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            kept.append((number, line.rstrip("\r")))
    if not kept:
        raise DataError(f"{p}: file is empty; expected a header line 't,u,y' and data rows")
    first_no, first = kept[0]
    d = delimiter if delimiter is not None else _detect(first)
    if delimiter is not None and delimiter not in (",", ";", "\t", _WHITESPACE):
        raise DataError(f"{p}: delimiter: expected ',', ';', tab or ' ', got {delimiter!r}")
    rows = _split([ln for _, ln in kept], d or ",", p, [n for n, _ in kept])
    if header:
        names = tuple(c.strip().strip('"').strip() for c in rows[0])
        if d is None or len(names) < 2:
            how = "any of ',' ';' tab or whitespace" if d is None else _delim_name(d)
            found = [c for c in (",", ";", "\t", "|") if c in first]
            hint = f" (the line contains {found[0]!r}: wrong delimiter?)" if found else ""
            raise DataError(
                f"{p}: line {first_no}: header {first.strip()!r} splits into one column "
                f"with {how}; expected at least 3 columns t,u,y{hint}"
            )
        if all(is_number(name) for name in names):
            # the commonest mistake with instrument exports: no header line at all
            raise DataError(
                f"{p}: line {first_no} (header), column {names[0]!r}: expected a header naming "
                f"the columns (t,u,y), got numbers (headerless file? add a header line, or "
                f"use read_table(path, header=False))"
            )
        for j, name in enumerate(names):
            if not name:
                raise DataError(f"{p}: line {first_no}, column {j + 1}: empty column name")
            if name in names[:j]:
                raise DataError(
                    f"{p}: line {first_no}, column {name!r}: expected unique column names, "
                    f"got {name!r} twice (fields {names.index(name) + 1} and {j + 1})"
                )
        body, lines = rows[1:], [n for n, _ in kept[1:]]
        if not body:
            raise DataError(
                f"{p}: line {first_no}: header only, no data rows; expected at least "
                f"{MIN_SAMPLES} samples"
            )
    else:
        names = tuple(f"col{j}" for j in range(len(rows[0])))
        body, lines = rows, [n for n, _ in kept]
    width = len(names)
    if any(len(r) != width for r in body):
        i = next(i for i, r in enumerate(body) if len(r) != width)
        got = len(body[i])
        ref = f"the header (line {first_no})" if header else f"line {first_no}"
        col = f"{names[got]!r} (missing)" if got < width else f"{width + 1} (extra field)"
        raise DataError(
            f"{p}: line {lines[i]}, column {col}: ragged row, expected {width} fields like "
            f"{ref}, got {got} (delimiter {_delim_name(d or ',')})"
        )
    cells = tuple(zip(*body, strict=True))
    return Table(p, names, cells, np.asarray(lines, dtype=np.int64), d or ",",
                 first_no if header else None)


def _split(lines: list[str], d: str, path: Path, numbers: list[int]) -> list[list[str]]:
    if d == _WHITESPACE:
        return [ln.split() for ln in lines]
    reader = csv.reader(lines, delimiter=d, strict=True)
    rows: list[list[str]] = []
    try:
        rows.extend(reader)
    except csv.Error as exc:
        line = numbers[min(reader.line_num, len(numbers)) - 1]
        raise DataError(f"{path}: line {line}: malformed field ({exc})") from exc
    if len(rows) != len(lines):
        # a quoted field spanning lines would shift every later line number
        raise DataError(f"{path}: a quoted field spans several lines; expected one row per line")
    return rows


# --------------------------------------------------------------------------- sidecar
def sidecar_path(path: str | os.PathLike[str]) -> Path:
    """The JSON sidecar of a data file: same directory and stem, suffix ``.json``."""
    return Path(path).with_suffix(".json")


def _type_error(sp: Path, key: str, expected: str, value: Any) -> DataError:
    return DataError(
        f"{sp}: key {key!r}: expected {expected}, got {value!r} ({type(value).__name__})"
    )


def _check_entry(sp: Path, obj: Mapping[str, Any], allowed: Sequence[str], prefix: str) -> None:
    for key, value in obj.items():
        full = prefix + key
        if key not in allowed:
            raise DataError(f"{sp}: key {full!r}: unknown key; expected one of {list(allowed)}")
        if key == "name" and (not isinstance(value, str) or not value):
            raise _type_error(sp, full, "a non-empty string", value)
        if key == "warmup" and (
            isinstance(value, bool) or not isinstance(value, int) or value < 0
        ):
            raise _type_error(sp, full, "a non-negative integer", value)
        if key == "metadata":
            if not isinstance(value, dict):
                raise _type_error(sp, full, "an object", value)
            freq = value.get("frequency_hz")
            # json.loads accepts Infinity and NaN, which no frequency can be
            if freq is not None and (
                isinstance(freq, bool) or not isinstance(freq, int | float)
                or not 0 < freq < math.inf
            ):
                raise _type_error(sp, f"{full}.frequency_hz", "a positive number or null", freq)
        if key in ("units", "columns"):
            if not isinstance(value, dict):
                raise _type_error(sp, full, "an object of strings", value)
            for k, v in value.items():
                if not isinstance(v, str):
                    raise _type_error(sp, f"{full}.{k}", "a string", v)
        if key == "segment" and not isinstance(value, bool):
            raise _type_error(sp, full, "true or false", value)


def read_sidecar(path: Path) -> tuple[Path, dict[str, Any]] | None:
    """Load and type-check the JSON sidecar of data file ``path``.

    Returns
    -------
    tuple of (Path, dict) or None
        The sidecar path and its parsed content, or None when there is no sidecar.

    Raises
    ------
    DataError
        Undecodable or invalid JSON, unknown keys, or wrongly typed values; the message
        names the sidecar file and the key (e.g. ``'records[1].warmup'``).
    """
    sp = sidecar_path(path)
    if sp == path or not sp.exists():
        return None
    if sp.is_dir():
        raise DataError(f"{sp}: sidecar is a directory; expected a JSON file")
    text = _decode(sp, sp.read_bytes(), "JSON sidecar")
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(
            f"{sp}: line {exc.lineno}, column {exc.colno}: invalid JSON sidecar: {exc.msg}"
        ) from exc
    if not isinstance(obj, dict):
        raise DataError(f"{sp}: expected a JSON object at top level, got {type(obj).__name__}")
    _check_entry(sp, obj, _SIDECAR_KEYS, "")
    if obj.get("format", SIDECAR_FORMAT) != SIDECAR_FORMAT:
        raise _type_error(sp, "format", repr(SIDECAR_FORMAT), obj["format"])
    if obj.get("version", 1) != 1:
        raise _type_error(sp, "version", "1", obj["version"])
    entries = obj.get("records")
    if entries is not None:
        if not isinstance(entries, list):
            raise _type_error(sp, "records", "a list of objects", entries)
        for i, entry in enumerate(entries):
            if not isinstance(entry, dict):
                raise _type_error(sp, f"records[{i}]", "an object", entry)
            _check_entry(sp, entry, _ENTRY_KEYS, f"records[{i}].")
    return sp, obj


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def encode_sidecar(name: str, records: Sequence[Record], path: Path) -> bytes:
    """The sidecar that lets :mod:`bayeshyst.data.io` restore ``records`` exactly.

    Parameters
    ----------
    name : str
        Dataset name.
    records : sequence of Record
        One ``records`` entry each (name, warmup, units, metadata, has-segment flag).
    path : Path
        The data file, named in the error message.

    Raises
    ------
    DataError
        If some metadata value is not JSON-serialisable.
    """
    side = {
        "format": SIDECAR_FORMAT,
        "version": 1,
        "name": name,
        "records": [
            {
                "name": r.name,
                "warmup": r.warmup,
                "segment": r.segment is not None,
                "units": dict(r.units),
                "metadata": _jsonable(r.metadata),
            }
            for r in records
        ],
    }
    try:
        return (json.dumps(side, indent=2, allow_nan=True) + "\n").encode("utf-8")
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: metadata is not JSON-serialisable ({exc})") from exc


# ----------------------------------------------------------------------------- roles
def explicit_roles(columns: Mapping[str, str] | None,
                   side: tuple[Path, dict[str, Any]] | None, path: Path) -> dict[str, str]:
    """Role -> name as the sidecar's ``columns`` and the ``columns`` argument give them.

    The argument wins over the sidecar. Every reader starts from this mapping.

    Raises
    ------
    DataError
        An unknown role or a name that is not a string, naming where it was given.
    """
    mapping: dict[str, str] = {}
    for origin, given in (
        (f"{side[0]}: key 'columns'" if side else "", side[1].get("columns") if side else None),
        (f"{path}: columns argument", columns),
    ):
        if not given:
            continue
        for role, name in given.items():
            if role not in _ROLES:
                raise DataError(
                    f"{origin}: unknown column role {role!r} (mapped to {name!r}); "
                    f"expected one of {list(_ROLES)}"
                )
            if not isinstance(name, str):
                raise DataError(f"{origin}: role {role!r}: expected a string, got {name!r}")
            mapping[role] = name
    return mapping


def resolve_roles(
    columns: Mapping[str, str] | None,
    side: tuple[Path, dict[str, Any]] | None,
    available: Sequence[str],
    path: Path,
    kind: str,
    header: str,
    notes: list[str] | None = None,
    required: Sequence[str] = REQUIRED_ROLES,
) -> dict[str, str]:
    """Map each role present to the name used in the file (explicit > sidecar > role).

    Roles not mapped are recognised by name (:func:`~bayeshyst.data.units.recognise_roles`).
    A text file of exactly three columns whose names say too little (``H [A/m]``,
    ``BL [T]``; or a displacement that drives a damper whose force is measured) and
    with no mapping given is read in its column order as t, u, y -- the order
    :func:`~bayeshyst.data.writers.write_csv` writes -- and ``notes`` says so.

    Parameters
    ----------
    columns : mapping of str to str or None
        Explicit role -> file name mapping (the reader's ``columns`` argument).
    side : (Path, dict) or None
        The sidecar from :func:`read_sidecar`; its ``columns`` key is a mapping too.
    available : sequence of str
        Names present in the file (header columns, archive arrays, .mat variables).
    path : Path
        The data file, for messages.
    kind : str
        ``"column"``, ``"array"`` or ``"variable"``, for messages.
    header : str
        Where the names come from, for messages, e.g. ``"line 1 (header)"``.
    notes : list of str, optional
        Receives one line when the roles were taken from the column order; without it
        (archives, HDF5) the order is never used.
    required : sequence of str
        The roles that must be found: t, u, y, or t and u for a file that may hold no
        measured output (a command to predict the output of).

    Returns
    -------
    dict of str to str
        Role -> file name, for ``t``, ``u``, ``y`` and the optional roles present.

    Raises
    ------
    DataError
        Unknown role, missing required (or explicitly mapped) name, a name used twice.
    """
    mapping = explicit_roles(columns, side, path)
    resolved: dict[str, str] = {}
    for role in _ROLES:
        name = mapping.get(role, role)
        if name in available:
            resolved[role] = name
        elif role in mapping:
            # a mapping may name a column without its unit: "Displacement" for
            # "Displacement [um]"
            fits = [c for c in available if split_header(c)[0] == name]
            if len(fits) != 1:
                raise DataError(
                    f"{path}: {header}, {kind} {name!r} (role {role!r}): "
                    + ("missing" if not fits else f"matches several {kind}s {fits}")
                    + f"; found {list(available)}")
            resolved[role] = fits[0]
    missing = [r for r in REQUIRED_ROLES if r not in resolved]
    if missing:
        # an instrument's header: roles recognised by name where exactly one column fits
        found, ambiguous = recognise_roles(available, resolved)
        resolved.update({r: c for r, c in found.items() if r in missing})
        still = [r for r in required if r not in resolved]
        order = REQUIRED_ROLES[:len(available)]
        if still and notes is not None and not mapping and 2 <= len(available) <= 3 \
                and set(required) <= set(order):
            resolved = dict(zip(order, available, strict=True))
            notes.append(f"columns taken in their order as {', '.join(order)}: "
                         + ", ".join(f"{r} = {c!r}" for r, c in resolved.items())
                         + " (name them with --columns t=...,u=...,y=... otherwise)")
            still = []
        if still:
            role = still[0]
            if role in ambiguous:
                raise DataError(
                    f"{path}: {header}: several {kind}s could be {role!r}: "
                    f"{ambiguous[role]}; name one (columns={{'{role}': ...}}, CLI "
                    f"--columns {role}=NAME)")
            raise DataError(
                f"{path}: {header}, {kind} {role!r}: missing; expected {kind}s t,u,y (or "
                f"names such as {', '.join(repr(n) for n in ROLE_NAMES[role][1:4])}, or "
                f"mapped names: --columns t=...,u=...,y=...), found {list(available)}")
    for name in set(resolved.values()):
        roles = [r for r, c in resolved.items() if c == name]
        if len(roles) > 1:
            raise DataError(f"{path}: {header}, {kind} {name!r}: mapped to several roles {roles}")
    return resolved


def role_labels(resolved: Mapping[str, str], kind: str) -> dict[str, str]:
    """How each role's column is named in messages, e.g. "column 'volt' (u)"."""
    return {r: f"{kind} {c!r}" + ("" if c == r else f" ({r})") for r, c in resolved.items()}
