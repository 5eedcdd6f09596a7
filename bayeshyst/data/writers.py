"""Writing Records and Datasets as CSV or ``.npz`` files with JSON sidecars.

What :func:`~bayeshyst.data.io.read_csv` and :func:`~bayeshyst.data.io.read_npz` read
back exactly (the layout is described in :mod:`bayeshyst.data.io`). Every file is
written to a temp file beside its target and renamed only when all are complete.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.parsing import encode_sidecar, sidecar_path
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError
from bayeshyst.files import atomic_paths

__all__ = ["write_csv", "write_npz"]


def _records(data: Dataset | Record) -> tuple[str, tuple[Record, ...]]:
    if isinstance(data, Record):
        return data.name, (data,)
    if isinstance(data, Dataset):
        return data.name, data.records
    raise TypeError(f"expected a Record or Dataset, got {type(data).__name__}")


def _columns(records: Sequence[Record]) -> dict[str, np.ndarray]:
    cols = {c: np.concatenate([getattr(r, c) for r in records]) for c in ("t", "u", "y")}
    if any(r.segment is not None for r in records):
        cols["segment"] = np.concatenate(
            [r.segment if r.segment is not None else np.zeros(r.n, np.int64) for r in records]
        )
    if len(records) > 1:
        cols["record"] = np.repeat(np.arange(len(records)), [r.n for r in records])
    # covariates every record has are written (and read back as covariates)
    shared = [k for k in records[0].covariates if all(k in r.covariates for r in records)]
    for k in shared:
        if k not in cols:
            cols[k] = np.concatenate([r.covariates[k] for r in records])
    return cols


def _atomic_write(files: Sequence[tuple[Path, Callable[[io.BufferedWriter], None]]]) -> None:
    """Write every file to a temp file beside it, then ``os.replace`` them all.

    Nothing is renamed until every temp file is complete, so a failure leaves the
    targets untouched (and the temps removed).
    """
    with atomic_paths([target for target, _ in files]) as temps:
        for (_, write), tmp in zip(files, temps, strict=True):
            with open(tmp, "wb") as fh:
                write(fh)
                fh.flush()
                os.fsync(fh.fileno())


def _target(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if p.suffix.lower() == ".json":
        raise DataError(f"{p}: a data file cannot have suffix .json (used by the sidecar)")
    if p.is_dir():
        raise DataError(f"{p}: is a directory; expected a file path")
    return p


def write_csv(data: Dataset | Record, path: str | os.PathLike[str]) -> Path:
    """Write a Record or Dataset as CSV plus JSON sidecar; :func:`read_csv` restores it.

    Floats are written with ``repr`` (shortest string that round-trips float64
    exactly). A multi-record dataset gets an integer ``record`` column. Both files are
    written atomically (temp file + ``os.replace``).

    Parameters
    ----------
    data : Record or Dataset
        What to write.
    path : path-like
        Target file; the sidecar goes to ``sidecar_path(path)``.

    Returns
    -------
    Path
        The data file written.
    """
    p = _target(path)
    name, records = _records(data)
    cols = _columns(records)
    lists = [cols[c].tolist() for c in cols]

    def write(fh: io.BufferedWriter) -> None:
        lines = [",".join(cols)]
        lines.extend(",".join(map(repr, row)) for row in zip(*lists, strict=True))
        fh.write(("\n".join(lines) + "\n").encode("utf-8"))

    side = encode_sidecar(name, records, p)
    _atomic_write([(p, write), (sidecar_path(p), lambda fh: fh.write(side))])
    return p


def write_npz(data: Dataset | Record, path: str | os.PathLike[str]) -> Path:
    """Write a Record or Dataset as ``.npz`` plus JSON sidecar; :func:`read_npz` restores it.

    Arrays are stored uncompressed, float64 (``segment``/``record`` int64); both files
    are written atomically.

    Parameters
    ----------
    data : Record or Dataset
        What to write.
    path : path-like
        Target ``.npz`` file; the sidecar goes to ``sidecar_path(path)``.

    Returns
    -------
    Path
        The data file written.
    """
    p = _target(path)
    name, records = _records(data)
    cols = _columns(records)
    side = encode_sidecar(name, records, p)
    _atomic_write(
        [(p, lambda fh: np.savez(fh, **cols)), (sidecar_path(p), lambda fh: fh.write(side))]
    )
    return p
