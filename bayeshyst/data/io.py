"""Reading measurement files (CSV/text, ``.npz``, ``.mat``) with JSON sidecars.

Every reader returns a :class:`~bayeshyst.data.dataset.Dataset` (one Record per contiguous
block; see :func:`read_csv`) and reports a malformed file with a
:class:`~bayeshyst.errors.DataError` naming the file, the column, the row (1-based file
line for text files, the header being line 1; 0-based index for arrays) and what was
expected vs found (the line-aware parsing lives in :mod:`bayeshyst.data.parsing`).

Sidecar
-------
``data.csv`` / ``data.npz`` / ``data.mat`` may have a JSON sidecar ``data.json`` (same
stem) with these optional keys::

    {"format": "bayeshyst-sidecar", "version": 1,
     "name": "dataset name",
     "columns": {"t": "time", "u": "volt", "y": "disp"},   # role -> name in the file
     "warmup": 100, "metadata": {...}, "units": {"y": "nm"},
     "records": [{"name": ..., "warmup": ..., "metadata": {...}, "units": {...},
                  "segment": true}, ...]}                   # one entry per block

Precedence, lowest first: sidecar top level, sidecar ``records`` entry, explicit
arguments. Unknown keys are errors (they are usually typos).

Units
-----
A unit in a column's name (``Time [ms]``), the sidecar's ``units`` and the ``units``
argument are parsed by pint and converted by :func:`bayeshyst.data.units.apply_units`
(time to s; input and output to the working unit of their dimension, else kept); a
role without any unit is ``"unknown"`` (time: s assumed), never a default unit.

Columns (roles)
---------------
``t``, ``u``, ``y`` are required; ``segment`` (integer labels), ``frequency_hz`` and
``record`` (integer block index, written by :func:`~bayeshyst.data.writers.write_csv`
for multi-record datasets) are optional. Rows are split into one Record per maximal run of constant
(``record``, ``frequency_hz``). Every other column that holds a finite number in every
row is kept as a covariate (:attr:`Record.covariates`, named as in the file: a
temperature, a load, a second sensor); the rest (text, gaps) are listed in
``metadata["ignored_columns"]``.

Fittable data
-------------
By default the readers also refuse what no model can be fitted to, once, here at the
file: an input or output that is constant over the whole file, or magnitudes outside
the range a fit handles (:func:`~bayeshyst.data.dataset.check_fittable`). ``fittable=False``
reads any finite data (to convert or plot it).
"""

from __future__ import annotations

import itertools
import logging
import os
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset, check_fittable
from bayeshyst.data.parsing import (
    OPTIONAL_ROLES,
    REQUIRED_ROLES,
    check_file,
    read_sidecar,
    read_table,
    resolve_roles,
    role_labels,
)
from bayeshyst.data.record import MIN_SAMPLES, Record
from bayeshyst.data.units import apply_units, split_header
from bayeshyst.errors import DataError

__all__ = [
    "OPTIONAL_ROLES",
    "REQUIRED_ROLES",
    "SUFFIXES",
    "load",
    "read_csv",
    "read_mat",
    "read_npz",
]

_log = logging.getLogger(__name__)

_INTEGER_ROLES = ("segment", "record")  # columns whose values must be integers
#: the name the output role has in messages when a file holds no output column
NO_OUTPUT = "(no output column)"


# -------------------------------------------------------------------------- assembly
def _blocks(cols: Mapping[str, np.ndarray]) -> list[tuple[int, int]]:
    """Maximal runs of constant (record, frequency_hz) as (start, stop) pairs."""
    n = cols["t"].size
    change = np.zeros(max(n - 1, 0), dtype=bool)
    for role in ("record", "frequency_hz"):
        if role in cols:
            change |= cols[role][1:] != cols[role][:-1]
    cuts = [0, *(np.flatnonzero(change) + 1).tolist(), n]
    return list(itertools.pairwise(cuts))


def _assemble(
    path: Path,
    cols: dict[str, np.ndarray],
    where: Callable[[int], str],
    resolved: Mapping[str, str],
    side: tuple[Path, dict[str, Any]] | None,
    *,
    warmup: int | None,
    metadata: Mapping[str, Any] | None,
    units: Mapping[str, str] | None,
    name: str | None,
    ignored: Sequence[str] = (),
    covariates: Mapping[str, np.ndarray] | None = None,
    kind: str = "column",
    fittable: bool = True,
    header: str = "",
) -> Dataset:
    """Split validated columns into Records, reporting problems at file positions.

    Every reader ends here, and so do the units: the unit written in a column's name
    (``"Time [ms]"``), the sidecar's (top level, then the block's ``records`` entry) and
    the ``units`` argument (winning) go through
    :func:`bayeshyst.data.units.apply_units`, which converts ``t`` to s and ``u``, ``y``
    to the working unit of their dimension, labels a role without any unit
    ``"unknown"`` (``t``: s assumed) and notes every conversion in
    ``metadata["unit_conversions"]``. ``header`` says where the column names are
    (``"line 1 (header)"``) for messages.
    """
    label = role_labels(resolved, kind)
    n = cols["t"].size
    covariates = {k: v for k, v in (covariates or {}).items() if v.size == n}
    for role in ("u", "y", *(r for r in OPTIONAL_ROLES if r in cols)):
        if cols[role].size != n:
            raise DataError(
                f"{path}: {label[role]}: expected {n} samples (the length of "
                f"{label['t']}), got {cols[role].size}"
            )
    if "frequency_hz" in cols and not (cols["frequency_hz"] > 0).all():
        i = int(np.argmax(~(cols["frequency_hz"] > 0)))
        raise DataError(
            f"{path}: {where(i)}, {label['frequency_hz']}: expected a positive "
            f"frequency, got {float(cols['frequency_hz'][i])!r}"
        )
    if metadata and "frequency_hz" in metadata and "frequency_hz" in cols:
        raise DataError(
            f"{path}: metadata argument 'frequency_hz' conflicts with the frequency column "
            f"{label['frequency_hz']}"
        )
    sp, sc = side if side else (None, {})
    blocks = _blocks(cols)
    entries = sc.get("records")
    if entries is not None and len(entries) != len(blocks):
        raise DataError(
            f"{sp}: key 'records': expected {len(blocks)} entries (one per block of rows in "
            f"{path.name}), got {len(entries)}"
        )
    stem = path.stem
    records = []
    for k, (a, b) in enumerate(blocks):
        span = f"{where(a)} to {where(b - 1)}"
        if b - a < MIN_SAMPLES:
            raise DataError(
                f"{path}: rows {span}, {label['t']}: too few samples, expected at "
                f"least {MIN_SAMPLES} (MIN_SAMPLES), got {b - a}"
            )
        entry = entries[k] if entries is not None else {}
        block, rec_units, notes = _units(path, sp, k if entries is not None else None,
                                         {r: cols[r][a:b] for r in ("t", "u", "y")},
                                         resolved, label, header, sc, entry, units)
        t = block["t"]
        steps = np.diff(t)
        if not (steps > 0).all():
            i = int(np.argmax(steps <= 0)) + 1
            problem = "duplicate time" if steps[i - 1] == 0 else "decreasing time"
            raise DataError(
                f"{path}: {where(a + i)}, {label['t']}: expected time greater than "
                f"{float(t[i - 1])!r} ({where(a + i - 1)}), got {float(t[i])!r} ({problem})"
            )
        meta: dict[str, Any] = {**sc.get("metadata", {}), **entry.get("metadata", {})}
        if notes:
            meta["unit_conversions"] = tuple(notes)
        if "frequency_hz" in cols:
            meta["frequency_hz"] = float(cols["frequency_hz"][a])
        meta.update(metadata or {})
        meta.setdefault("source", str(path))
        if ignored:
            meta.setdefault("ignored_columns", tuple(ignored))
        w = warmup if warmup is not None else entry.get("warmup", sc.get("warmup", 0))
        if isinstance(w, bool) or not isinstance(w, int | np.integer) or not 0 <= w <= b - a - 2:
            raise DataError(
                f"{path}: rows {span}: warmup: expected an integer in 0..{b - a - 2} "
                f"(at least 2 scored samples of {b - a}), got {w!r}"
            )
        if entry.get("name"):
            rec_name = entry["name"]
        elif len(blocks) == 1:
            rec_name = stem
        elif "frequency_hz" in cols and "record" not in cols:
            rec_name = f"{stem}@{cols['frequency_hz'][a]:g}Hz"
        else:
            rec_name = f"{stem}#{k}"
        if rec_name in (r.name for r in records):
            rec_name = f"{rec_name}#{k}"
        segment = cols.get("segment")
        if segment is not None and entry.get("segment", True):
            segment = segment[a:b]
        else:
            segment = None
        with _naming(path):
            records.append(
                Record(
                    t=t,
                    u=block["u"],
                    y=block["y"],
                    segment=segment,
                    warmup=int(w),
                    metadata=meta,
                    units=rec_units,
                    name=rec_name,
                    covariates={k: v[a:b] for k, v in covariates.items()},
                )
            )
    with _naming(path):
        data = Dataset(records, name=name or sc.get("name") or stem)
    if fittable:
        check_fittable(data, str(path), label)
    return data


def _units(
    path: Path,
    sidecar: Path | None,
    entry_index: int | None,
    cols: Mapping[str, np.ndarray],
    resolved: Mapping[str, str],
    label: Mapping[str, str],
    header: str,
    sc: Mapping[str, Any],
    entry: Mapping[str, Any],
    units: Mapping[str, str] | None,
) -> tuple[dict[str, np.ndarray], dict[str, str], list[str]]:
    """One block's ``t``, ``u``, ``y`` in working units, its units and conversion notes."""
    declared: dict[str, tuple[str, str]] = {}
    for origin, given in (
        (f"sidecar {sidecar}, key 'units'", sc.get("units") or {}),
        (f"sidecar {sidecar}, key 'records'[{entry_index}].units", entry.get("units") or {}),
        ("the units argument", units or {}),
    ):
        for role, unit in given.items():
            if not isinstance(unit, str):
                raise DataError(f"{path}: {origin}, role {role!r}: expected a unit string, "
                                f"got {unit!r}")
            declared[role] = (unit, origin)
    where = {r: f"{path}: " + (f"{header}, " if header else "") + label[r]
             for r in ("t", "u", "y")}
    written = {r: split_header(resolved[r])[1] for r in ("t", "u", "y")}
    block, rec_units, notes = apply_units(cols, written, declared, where)
    # roles other than t, u, y (a covariate's unit) are kept as declared
    extra = {r: u for r, (u, _) in declared.items() if r not in ("t", "u", "y")}
    notes = [n.removeprefix(f"{path}: ").removeprefix(f"{header}, ") for n in notes]
    return block, {**extra, **rec_units}, notes


@contextmanager
def _naming(path: Path) -> Iterator[None]:
    """Put ``path`` in front of a DataError that does not name it.

    Record and Dataset validation name the record and its ``metadata["source"]``, which
    a sidecar or the ``metadata`` argument may have set to something other than the
    file (the bundled data say "virtual actuator"); every reader error names the file.
    """
    try:
        yield
    except DataError as exc:
        if str(path) in str(exc):
            raise
        raise DataError(f"{path}: {exc}") from exc


# --------------------------------------------------------------------------- readers
def read_csv(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    delimiter: str | None = None,
    warmup: int | None = None,
    metadata: Mapping[str, Any] | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    fittable: bool = True,
    require_output: bool = True,
) -> Dataset:
    r"""Read a delimited text file with header ``t,u,y[,segment][,frequency_hz]``.

    Parameters
    ----------
    path : path-like
        ``.csv`` or ``.txt`` file, UTF-8.
    columns : mapping of str to str, optional
        Role -> column name in the file, e.g. ``{"t": "time", "u": "volt", "y": "disp"}``.
        Roles: ``t``, ``u``, ``y``, ``segment``, ``frequency_hz``, ``record``.
    delimiter : str, optional
        ``","``, ``";"``, ``"\t"`` or ``" "`` (whitespace); detected when None.
    warmup : int, optional
        Warm-up samples of every resulting Record. None: the sidecar's value, else 0.
    metadata : mapping, optional
        Merged over the sidecar metadata (explicit keys win). ``source`` defaults to
        the file path.
    units : mapping of str to str, optional
        Role -> unit of the file's columns, e.g. ``{"u": "A/m", "y": "mT"}``; wins over
        the sidecar's units, and a unit in the header must agree (pint equality). Every
        unit is converted as :func:`bayeshyst.data.units.apply_units` says: ``t`` to s
        (assumed s without a unit), ``u`` and ``y`` to the working unit of their
        dimension (V, um, N, A, T, A/m, Pa, C, ...) or kept as written; a role without a
        unit anywhere is ``"unknown"``. Conversions are listed in
        ``metadata["unit_conversions"]``.
    name : str, optional
        Dataset name (default: the sidecar's ``name``, else the file stem).
    fittable : bool, default True
        Refuse data no model can be fitted to (:func:`~bayeshyst.data.dataset.check_fittable`:
        a constant input or output, magnitudes outside the supported range). False
        reads any finite data, e.g. to convert or plot it.
    require_output : bool, default True
        False accepts a file without an output column (an input to predict the output
        of): its records get ``y`` zeros, ``metadata["output_measured"]`` False
        (:attr:`Record.measured_output`) and are not checked as fittable; two columns
        whose names say too little are then read in their order as t, u.

    Returns
    -------
    Dataset
        One Record per maximal run of constant ``record``/``frequency_hz`` values (one
        Record when those columns are absent), each with ``metadata["frequency_hz"]``
        taken from the column when present.

    Raises
    ------
    DataError
        Malformed file or sidecar, or (``fittable``) data no model can be fitted to; the
        message names file, 1-based line, column and the expected vs found value.
    """
    p = check_file(path)
    side = read_sidecar(p)
    table = read_table(p, delimiter=delimiter)
    header = f"line {table.header_line} (header)"
    order: list[str] = []
    resolved = resolve_roles(columns, side, table.names, p, "column", header, notes=order,
                             required=REQUIRED_ROLES if require_output else ("t", "u"))
    if order:
        metadata = {**(metadata or {}), "column_roles": tuple(order)}
    label = role_labels(resolved, "column")
    cols = {
        role: table.floats(col, label=label[role], integer=role in _INTEGER_ROLES)
        for role, col in resolved.items()
    }
    measured = "y" in resolved
    if not measured:
        # an input alone: the output is what a model is asked for; zeros hold its place
        resolved = {**resolved, "y": NO_OUTPUT}
        cols["y"] = np.zeros_like(cols["t"])
        metadata = {**(metadata or {}), "output_measured": False}
    covariates, ignored = {}, []
    for c in table.names:
        if c in resolved.values():
            continue
        try:  # a covariate must be a number in every row; anything else is left out
            values = table.floats(c, label=f"column {c!r}")
        except DataError:
            ignored.append(c)
            continue
        covariates[c] = values
    return _assemble(
        p, cols, lambda i: f"line {table.lines[i]}", resolved, side,
        warmup=warmup, metadata=metadata, units=units, name=name, ignored=ignored,
        covariates=covariates, fittable=fittable and measured, header=header,
    )


def _vector(path: Path, key: str, value: Any, kind: str) -> np.ndarray:
    """A numeric vector from an npz/mat variable; column/row vectors are flattened."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        raise DataError(
            f"{path}: {kind} {key!r}: expected a real numeric array, got dtype {arr.dtype}"
        )
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.ravel()
    if arr.ndim != 1:
        raise DataError(
            f"{path}: {kind} {key!r}: expected a vector (n,), (n, 1) or (1, n), got shape "
            f"{arr.shape}" + (" (a 2-D matrix)" if arr.ndim == 2 else "")
        )
    values = arr.astype(np.float64)
    finite = np.isfinite(values)
    if not finite.all():
        i = int(np.argmax(~finite))
        raise DataError(
            f"{path}: index {i} (0-based), {kind} {key!r}: expected a finite number, "
            f"got {float(values[i])!r}"
        )
    return values


def _read_arrays(
    path: Path,
    variables: Mapping[str, Any],
    kind: str,
    columns: Mapping[str, str] | None,
    options: dict[str, Any],
) -> Dataset:
    side = read_sidecar(path)
    resolved = resolve_roles(columns, side, list(variables), path, kind, f"{kind}s in file")
    cols = {}
    for role, key in resolved.items():
        cols[role] = _vector(path, key, variables[key], kind)
        if role in _INTEGER_ROLES and not (cols[role] == np.round(cols[role])).all():
            i = int(np.argmax(cols[role] != np.round(cols[role])))
            raise DataError(
                f"{path}: index {i} (0-based), {kind} {key!r}: expected an integer label, "
                f"got {float(cols[role][i])!r}"
            )
    covariates, ignored = {}, []
    for k in variables:
        if k in resolved.values():
            continue
        try:  # a numeric vector of the record's length is a covariate; the rest is left out
            values = _vector(path, k, variables[k], kind)
        except DataError:
            ignored.append(k)
            continue
        if values.size == cols["t"].size:
            covariates[k] = values
        else:
            ignored.append(k)
    return _assemble(
        path, cols, lambda i: f"index {i} (0-based)", resolved, side,
        ignored=ignored, covariates=covariates, kind=kind, header=f"{kind}s in file",
        **options,
    )


def read_npz(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    warmup: int | None = None,
    metadata: Mapping[str, Any] | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    fittable: bool = True,
) -> Dataset:
    """Read a NumPy ``.npz`` archive with arrays ``t, u, y[, segment][, frequency_hz]``.

    Loaded with ``allow_pickle=False``: object arrays are refused. Sidecar handling and
    the split into Records are those of :func:`read_csv`; positions in error messages
    are 0-based array indices.

    Parameters
    ----------
    path : path-like
        The ``.npz`` file; arrays of shape (n,), (n, 1) or (1, n).
    columns : mapping of str to str, optional
        Role -> array name in the archive.
    warmup : int, optional
        Warm-up samples of every Record (None: sidecar value, else 0).
    metadata : mapping, optional
        Merged over the sidecar metadata.
    units : mapping of str to str, optional
        As in :func:`read_csv` (wins over the sidecar's units, converted alike).
    name : str, optional
        Dataset name (default: sidecar ``name``, else the file stem).
    fittable : bool, default True
        As in :func:`read_csv`.

    Returns
    -------
    Dataset
    """
    p = check_file(path)
    try:
        archive = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise DataError(f"{p}: expected a NumPy .npz archive, could not read it ({exc})") from exc
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise DataError(f"{p}: expected a .npz archive of named arrays, got a single .npy array")
    variables: dict[str, Any] = {}
    with archive:
        for key in archive.files:
            try:
                variables[key] = archive[key]
            except ValueError as exc:  # object arrays need pickle, which we refuse
                raise DataError(
                    f"{p}: array {key!r}: expected a numeric array, got an object array "
                    f"(pickled data is not loaded)"
                ) from exc
            except (OSError, zipfile.BadZipFile, EOFError) as exc:
                raise DataError(f"{p}: array {key!r}: corrupt archive member ({exc})") from exc
    opts = {"warmup": warmup, "metadata": metadata, "units": units, "name": name,
            "fittable": fittable}
    return _read_arrays(p, variables, "array", columns, opts)


def read_mat(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    warmup: int | None = None,
    metadata: Mapping[str, Any] | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    fittable: bool = True,
) -> Dataset:
    """Read a MATLAB ``.mat`` file (v4-v7.2) with variables ``t, u, y[, ...]``.

    Column and row vectors are flattened; 2-D matrices, cells, structs and strings are
    refused. MATLAB v7.3 (HDF5) files are not supported.

    Parameters
    ----------
    path : path-like
        The ``.mat`` file; variables of shape (n,), (n, 1) or (1, n).
    columns, warmup, metadata, units, name, fittable
        As in :func:`read_npz` (``columns`` maps roles to variable names).

    Returns
    -------
    Dataset
    """
    from scipy.io import loadmat  # scipy.io is slow to import; only .mat users pay

    p = check_file(path)
    try:
        raw = loadmat(p)
    except NotImplementedError as exc:
        raise DataError(
            f"{p}: MATLAB v7.3 (HDF5) file; expected v7 or older (save with '-v7')"
        ) from exc
    except Exception as exc:
        # scipy's parser raises IndexError, struct.error, zlib.error, ... on corrupt
        # input; every one of them means "not a readable .mat file"
        raise DataError(
            f"{p}: expected a MATLAB .mat file, could not read it "
            f"({type(exc).__name__}: {exc})"
        ) from exc
    variables = {k: v for k, v in raw.items() if not k.startswith("__")}
    opts = {"warmup": warmup, "metadata": metadata, "units": units, "name": name,
            "fittable": fittable}
    return _read_arrays(p, variables, "variable", columns, opts)


def _read_hdf5(path: str | os.PathLike[str], **options: Any) -> Dataset:
    """:func:`bayeshyst.data.hdf5.read_hdf5`, imported when first called.

    The HDF5 reader builds on this module's assembly (``_assemble``), so this module
    cannot import it at the top without an import cycle.
    """
    from bayeshyst.data.hdf5 import read_hdf5

    return read_hdf5(path, **options)


#: Readers by lower-case file suffix, used by :func:`load`.
SUFFIXES: Mapping[str, Callable[..., Dataset]] = {
    ".csv": read_csv,
    ".txt": read_csv,
    ".npz": read_npz,
    ".mat": read_mat,
    ".h5": _read_hdf5,
    ".hdf5": _read_hdf5,
}


def load(path: str | os.PathLike[str], **options: Any) -> Dataset:
    """Read any supported file into a Dataset, dispatching on the suffix.

    Parameters
    ----------
    path : path-like
        ``.csv``/``.txt`` (:func:`read_csv`), ``.npz`` (:func:`read_npz`), ``.mat``
        (:func:`read_mat`) or ``.h5``/``.hdf5``
        (:func:`~bayeshyst.data.hdf5.read_hdf5`).
    **options
        Passed to the reader (``columns``, ``warmup``, ``metadata``, ``units``, ``name``,
        ``fittable``; ``delimiter`` for text; ``fs`` [Hz] for HDF5 without a time
        dataset). For HDF5, ``columns`` maps roles to dataset paths, e.g.
        ``{"u": "multisine/u", "y": "multisine/y"}``. ``require_output=False`` lets a
        text file hold an input alone (:func:`read_csv`); the other formats always need
        their output.

    Raises
    ------
    DataError
        Missing file, a directory, an unknown suffix, a malformed file, or (unless
        ``fittable=False``) data no model can be fitted to.
    """
    p = check_file(path)
    reader = SUFFIXES.get(p.suffix.lower())
    if reader is None:
        raise DataError(
            f"{p}: unknown file suffix {p.suffix!r}; expected one of {sorted(SUFFIXES)}"
        )
    if reader is not read_csv:
        # only a text file may hold an input alone: the other formats need their output
        options = {k: v for k, v in options.items() if k != "require_output"}
    data = reader(p, **options)
    _log.info("%s: %d record(s), %d samples, frequencies %s", p, len(data), data.n_samples,
              list(data.frequencies) or "none given")
    return data
