"""What every writer uses: CSV cells and rows, non-finite fields named, figures saved.

The JSON serialiser itself (:func:`jsonable`, :func:`json_text`, :func:`write_json`)
lives in :mod:`bayeshyst.files`, below every layer that writes JSON (the study stores
its per-fit records with it); it is re-exported here for the writers.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.files import atomic_path, json_text, jsonable, write_json
from bayeshyst.workers import run_forked

__all__ = ["atomic_path", "csv_cell", "json_text", "jsonable", "nonfinite_fields",
           "write_figures", "write_json", "write_rows_csv"]


def csv_cell(value: Any) -> Any:
    """A CSV cell: empty for None and non-finite numbers (no "nan" in tables).

    Plain ``bool``/``float`` for numpy scalars, anything else as is.
    """
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else ""
    return value


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


def write_rows_csv(path: str | Path, columns: Sequence[str],
                   rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write ``rows`` (dicts) under ``columns`` as CSV, atomically; return the path.

    Missing keys, None and non-finite numbers become empty cells (never "nan").
    """
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([csv_cell(row.get(c)) for c in columns])
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return Path(path)


def write_figures(out: str | Path, figures: Mapping[str, Any] | None, *,
                  n_jobs: int | None = None) -> list[str]:
    """Save each figure as PNG under ``out``, atomically, shared over the cores.

    Rendering a PNG is the writers' main cost (a report's 13 figures: 3.9 s in one
    process); the figures are saved by this process and forked children
    (:func:`~bayeshyst.workers.run_forked`: a child sees the figures without pickling
    them), the same files whatever the number of processes.

    Parameters
    ----------
    out : path-like
        The writer's output folder.
    figures : mapping of str to Figure, optional
        File name relative to ``out`` (``"loops.png"``, ``"figures/corner_final.png"``)
        -> the figure, as built by :mod:`bayeshyst.plotting`.
    n_jobs : int or None
        Processes (:func:`~bayeshyst.workers.resolve_jobs`; None: one per core).

    Returns
    -------
    list of str
        The file names, in the order written.
    """
    if figures is not None and not isinstance(figures, Mapping):
        # the writers took figures=True/False before they were given the figures
        raise ParameterError(f"figures: expected a mapping of file name to Figure (see "
                             f"bayeshyst.outputs.assemble), got {type(figures).__name__}")
    if not figures:
        return []
    # imported here: matplotlib is loaded only by a run that draws
    from bayeshyst.plotting import save_figure

    names = list(figures)
    run_forked(lambda name: save_figure(figures[name], Path(out) / name), names, n_jobs)
    return names
