"""JSON output: plain types, no NaN, written atomically (:mod:`bayeshyst.files`)."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.files import atomic_path

__all__ = ["atomic_path", "csv_cell", "jsonable", "nonfinite_fields", "write_json",
           "write_rows_csv"]


def csv_cell(value: Any) -> Any:
    """A CSV cell: empty for None and non-finite numbers (no "nan" in tables), plain
    ``bool``/``float`` for numpy scalars, anything else as is."""
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else ""
    return value


def jsonable(obj: Any) -> Any:
    """``obj`` with NumPy types made plain and non-finite floats made ``None``.

    JSON has no NaN or infinity; writing them would make files that strict parsers
    reject, so a missing number is ``null``.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        x = float(obj)
        return x if math.isfinite(x) else None
    return obj


def nonfinite_fields(obj: Any, prefix: str = "") -> list[str]:
    """Where ``obj`` holds a non-finite float, as paths like ``params.w[0].sd``.

    :func:`jsonable` writes these as ``null``; a summary lists them in a warning so that
    a reader learns why a number is missing (an overflow, an undefined statistic).

    Parameters
    ----------
    obj : any
        Nested dicts, lists, tuples, arrays and scalars, as given to :func:`jsonable`.
    prefix : str
        Path of ``obj`` itself (default: the top level).

    Returns
    -------
    list of str
        The paths, in the order of ``obj``.
    """
    if isinstance(obj, dict):
        return [path for k, v in obj.items()
                for path in nonfinite_fields(v, f"{prefix}.{k}" if prefix else str(k))]
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, list | tuple):
        return [path for i, v in enumerate(obj)
                for path in nonfinite_fields(v, f"{prefix}[{i}]")]
    if isinstance(obj, float | np.floating) and not math.isfinite(obj):
        return [prefix]
    return []


def write_json(path: str | Path, obj: Any, *, default: Callable[[Any], Any] = str) -> Path:
    """Write ``obj`` as indented JSON atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(jsonable(obj), indent=2, default=default, allow_nan=False)
                       + "\n")
    return Path(path)


def write_rows_csv(path: str | Path, columns: Sequence[str],
                   rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write ``rows`` (dicts) under ``columns`` as CSV, atomically; missing keys, None
    and non-finite numbers become empty cells (never "nan"). Returns the path."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([csv_cell(row.get(c)) for c in columns])
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return Path(path)
