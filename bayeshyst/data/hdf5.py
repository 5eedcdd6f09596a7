"""Reading HDF5 files (``.h5``, ``.hdf5``) of input/output records.

An HDF5 file holds named datasets, possibly inside groups: the Bouc-Wen benchmark's
``train.h5`` has ``multisine/u``, ``multisine/y`` and ``multisine/fs``, each stored as a
column ``(n, 1)``. :func:`read_hdf5` maps roles to such dataset paths and hands the
vectors to the same assembly as the CSV, ``.npz`` and ``.mat`` readers
(:mod:`bayeshyst.data.io`): the split into Records, the JSON sidecar, the warm-up,
units and the fittability check behave, and their errors read, the same way. Positions
in error messages are 0-based indices, and every message names the file and the dataset.

Roles
-----
``columns`` maps roles (``t``, ``u``, ``y``; optional ``segment``, ``frequency_hz``,
``record``) to dataset paths (``{"u": "multisine/u", "y": "multisine/y"}``). A role that
is not mapped is looked for by name (the last component of the path, the names of
:data:`~bayeshyst.data.units.ROLE_NAMES`) among the datasets at the top level and one
group deep. Once the input is placed in a group, the other roles are looked for in that
group, then at the top level, never in another group (a group is one recording); with
the input at the top level, at the top level first, then one group deep. Several
candidates at the same place are an error that names them.

Time
----
A ``t`` dataset, or else a sampling rate: the ``fs`` argument, else a one-element
dataset ``fs`` beside the input (in the input's group), else an attribute ``fs`` of the
input dataset, else of its group; then ``t = arange(n) / fs``. ``metadata
["sampling_rate_hz"]`` and ``metadata["sampling_rate_from"]`` say which was used.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.io import _assemble, _vector
from bayeshyst.data.parsing import (
    OPTIONAL_ROLES,
    REQUIRED_ROLES,
    check_file,
    explicit_roles,
    read_sidecar,
)
from bayeshyst.data.units import ROLE_NAMES, split_header
from bayeshyst.errors import DataError

__all__ = ["FS_NAME", "read_hdf5"]

#: Name of the sampling-rate dataset or attribute next to the input (any letter case).
FS_NAME = "fs"

_KIND = "dataset"
_ROLES = (*REQUIRED_ROLES, *OPTIONAL_ROLES)
_INTEGER_ROLES = ("segment", "record")  # datasets whose values must be integers
# the order roles are placed in: the input first, because its group anchors the rest
_ORDER = ("u", "y", "t", *OPTIONAL_ROLES)


def _group_of(name: str) -> str:
    """The group part of a dataset path ("" for the top level)."""
    return name.rpartition("/")[0]


def _leaf(name: str) -> str:
    return name.rpartition("/")[2]


def _datasets(f: h5py.File) -> list[str]:
    """Paths of the datasets at the top level and one group deep, in file order."""
    found = []
    for key, obj in f.items():
        if isinstance(obj, h5py.Dataset):
            found.append(key)
        elif isinstance(obj, h5py.Group):
            found.extend(f"{key}/{k}" for k, o in obj.items() if isinstance(o, h5py.Dataset))
    return found


def _fits(role: str, name: str) -> bool:
    """Whether a dataset's own name says it holds ``role``."""
    base = split_header(_leaf(name))[0].strip().lower()
    return base in ROLE_NAMES.get(role, (role,))


def _resolve(
    path: Path,
    f: h5py.File,
    columns: Mapping[str, str] | None,
    side: tuple[Path, dict[str, Any]] | None,
) -> dict[str, str]:
    """Role -> dataset path (explicit > sidecar > found by name); ``t`` may be absent."""
    available = _datasets(f)
    mapping: dict[str, str] = {}
    for role, name in explicit_roles(columns, side, path).items():
        if not name.strip("/"):
            raise DataError(f"{path}: role {role!r}: expected a dataset path, got {name!r}")
        mapping[role] = name.strip("/")  # "/multisine/u" and "multisine/u" are one path
    resolved: dict[str, str] = {}
    for role, name in mapping.items():
        obj = f.get(name)
        if not isinstance(obj, h5py.Dataset):
            what = "is a group, not a dataset" if isinstance(obj, h5py.Group) else "missing"
            raise DataError(
                f"{path}: {_KIND} {name!r} (role {role!r}): {what}; found datasets {available}"
            )
        resolved[role] = name
    anchor = next((_group_of(resolved[r]) for r in ("u", "y", "t") if r in resolved), None)
    for role in _ORDER:
        if role in resolved:
            continue
        free = [c for c in available if c not in resolved.values() and _fits(role, c)]
        if anchor is not None:
            near = [c for c in free if _group_of(c) == anchor]
            top = [c for c in free if _group_of(c) == ""]
            # another group is another recording: its t or y never belongs to this u
            fits = near or (top if anchor else free)
        else:
            fits = free
        if len(fits) > 1:
            raise DataError(
                f"{path}: several {_KIND}s could be {role!r}: {fits}; name one "
                f"(columns={{'{role}': ...}}, CLI --columns {role}=PATH)"
            )
        if fits:
            resolved[role] = fits[0]
            if anchor is None:
                anchor = _group_of(fits[0])
        elif role in ("u", "y"):
            raise DataError(
                f"{path}: {_KIND} {role!r}: missing; expected datasets u and y (or names "
                f"such as {', '.join(repr(n) for n in ROLE_NAMES[role][1:4])}) at the top "
                f"level or one group deep, or mapped paths (columns={{'u': 'group/u', "
                f"'y': 'group/y'}}, CLI --columns u=...,y=...), found {available}"
            )
    for name in set(resolved.values()):
        roles = [r for r, c in resolved.items() if c == name]
        if len(roles) > 1:
            raise DataError(f"{path}: {_KIND} {name!r}: mapped to several roles {roles}")
    return resolved


def _shape_ok(shape: tuple[int, ...]) -> bool:
    return len(shape) == 1 or (len(shape) == 2 and shape[1] == 1)


def _read_vector(path: Path, f: h5py.File, name: str) -> np.ndarray:
    """A dataset as a float64 vector: shape (n,) or a column (n, 1), real, finite."""
    ds = f[name]
    if not _shape_ok(ds.shape):
        raise DataError(
            f"{path}: {_KIND} {name!r}: expected a vector (n,) or a column (n, 1), got "
            f"shape {ds.shape}"
        )
    if ds.dtype.kind not in "iuf":  # check before reading: strings, compounds, references
        raise DataError(
            f"{path}: {_KIND} {name!r}: expected a real numeric array, got dtype {ds.dtype}"
        )
    try:
        values = ds[()]
    except OSError as exc:  # a damaged chunk or a missing filter plugin (compression)
        raise DataError(f"{path}: {_KIND} {name!r}: could not read it ({exc})") from exc
    return _vector(path, name, values, _KIND)


def _rate(path: Path, where: str, value: Any) -> float:
    """A sampling rate [Hz] from one value: a single finite positive real number."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf" or arr.size != 1:
        raise DataError(
            f"{path}: {where}: expected one positive sampling rate [Hz], got "
            f"{arr.dtype} of shape {arr.shape}"
        )
    fs = float(arr.reshape(()))
    if not (math.isfinite(fs) and fs > 0):
        raise DataError(f"{path}: {where}: expected a positive finite sampling rate [Hz], "
                        f"got {fs!r}")
    return fs


def _named_fs(path: Path, names: Any, where: str) -> str | None:
    """The one key of ``names`` spelled ``fs`` in any letter case, or None."""
    hits = [k for k in names if k.lower() == FS_NAME]
    if len(hits) > 1:
        raise DataError(f"{path}: {where}: several sampling rates {hits}; give fs= instead")
    return hits[0] if hits else None


def _sampling_rate(
    path: Path, f: h5py.File, u_name: str
) -> tuple[float, str, str | None] | None:
    """The sampling rate stored beside the input, where it was found, its dataset."""
    group = f[_group_of(u_name) or "/"]
    gname = _group_of(u_name)
    key = _named_fs(path, [k for k, o in group.items() if isinstance(o, h5py.Dataset)],
                    f"group {gname or '/'!r}")
    if key is not None:
        name = f"{gname}/{key}" if gname else key
        return _rate(path, f"{_KIND} {name!r}", group[key][()]), f"{_KIND} {name!r}", name
    for owner, label in ((f[u_name], f"{_KIND} {u_name!r}"),
                         (group, f"group {gname or '/'!r}")):
        key = _named_fs(path, owner.attrs.keys(), label)
        if key is not None:
            where = f"attribute {key!r} of {label}"
            return _rate(path, where, owner.attrs[key]), where, None
    return None


def read_hdf5(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    fs: float | None = None,
    warmup: int | None = None,
    metadata: Mapping[str, Any] | None = None,
    units: Mapping[str, str] | None = None,
    name: str | None = None,
    fittable: bool = True,
) -> Dataset:
    """Read an HDF5 file (``.h5``/``.hdf5``) with datasets for ``u``, ``y`` and time.

    Sidecar handling and the split into Records are those of
    :func:`~bayeshyst.data.io.read_csv`; positions in error messages are 0-based
    indices. How roles and time are found: see the module docstring.

    Parameters
    ----------
    path : path-like
        The HDF5 file. Datasets of shape (n,) or (n, 1), real numeric (any integer or
        float type; read as float64).
    columns : mapping of str to str, optional
        Role -> dataset path in the file, e.g. ``{"u": "multisine/u", "y":
        "multisine/y"}``; a leading ``/`` is optional. Roles: ``t``, ``u``, ``y``,
        ``segment``, ``frequency_hz``, ``record``. Roles not mapped are found by name
        (top level or one group deep, the input's group first).
    fs : float, optional
        Sampling rate [Hz] when the file has no ``t`` dataset; overrides an ``fs``
        dataset or attribute in the file. Refused together with a ``t`` dataset.
    warmup : int, optional
        Warm-up samples of every Record (None: sidecar value, else 0).
    metadata : mapping, optional
        Merged over the sidecar metadata and over the ``sampling_rate_hz`` /
        ``sampling_rate_from`` entries this reader adds (explicit keys win).
    units : mapping of str to str, optional
        Merged over sidecar units and defaults, e.g. ``{"u": "N", "y": "m"}``.
    name : str, optional
        Dataset name (default: sidecar ``name``, else the file stem).
    fittable : bool, default True
        As in :func:`~bayeshyst.data.io.read_csv`.

    Returns
    -------
    Dataset
        One Record per maximal run of constant ``record``/``frequency_hz`` values (one
        Record when those datasets are absent). Datasets of the input's group with the
        record's length become covariates (named by path); the other datasets are
        listed in ``metadata["ignored_columns"]``.

    Raises
    ------
    DataError
        Not an HDF5 file; a role missing, ambiguous or mapped to a missing dataset; a
        dataset of another shape than (n,)/(n, 1), not real numeric, or not finite; no
        time information; the errors of :func:`~bayeshyst.data.io.read_csv`. The
        message names the file and the dataset.
    """
    p = check_file(path)
    side = read_sidecar(p)
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise DataError(f"{p}: expected an HDF5 file, could not read it ({exc})") from exc
    with f:
        resolved = _resolve(p, f, columns, side)
        cols = {role: _read_vector(p, f, key) for role, key in resolved.items()}
        for role in _INTEGER_ROLES:
            if role in cols and not (cols[role] == np.round(cols[role])).all():
                i = int(np.argmax(cols[role] != np.round(cols[role])))
                raise DataError(
                    f"{p}: index {i} (0-based), {_KIND} {resolved[role]!r}: expected an "
                    f"integer label, got {float(cols[role][i])!r}"
                )
        derived: dict[str, Any] = {}
        fs_dataset: str | None = None  # the fs dataset used: not a covariate, not ignored
        if "t" in resolved:
            if fs is not None:
                raise DataError(
                    f"{p}: fs argument ({fs!r}) given, but the file has a time {_KIND} "
                    f"{resolved['t']!r}; give one of the two (map t to another dataset "
                    f"with columns= if {resolved['t']!r} is not time)"
                )
        else:
            u_name, n = resolved["u"], cols["u"].size
            if fs is not None:
                found = (_rate(p, "fs argument", fs), "fs argument", None)
            else:
                found = _sampling_rate(p, f, u_name)
            if found is None:
                group = _group_of(u_name) or "/"
                raise DataError(
                    f"{p}: no time information for {_KIND} {u_name!r} (u): expected a time "
                    f"{_KIND} ('t', mapped with columns={{'t': ...}}), a sampling rate "
                    f"{_KIND} or attribute {FS_NAME!r} in group {group!r} or on {u_name!r}, "
                    f"or the fs argument (CLI: a sidecar or t column)"
                )
            rate, fs_used, fs_dataset = found
            if (units or {}).get("t", "s").strip() != "s":
                raise DataError(
                    f"{p}: units argument: t in {units['t']!r}, but the time axis is built "
                    f"from the sampling rate ({fs_used}) in s"
                )
            units = {**(units or {}), "t": "s"}
            if cols["y"].size != n:
                # checked here because the time axis is built from the input's length
                raise DataError(
                    f"{p}: {_KIND} {resolved['y']!r} (y): expected {n} samples (the length "
                    f"of {_KIND} {u_name!r} (u)), got {cols['y'].size}"
                )
            cols["t"] = np.arange(n) / rate
            # messages about the time axis (too few samples) name the dataset giving n
            resolved = {"t": u_name, **resolved}
            derived = {"sampling_rate_hz": rate, "sampling_rate_from": fs_used}
        n = cols["t"].size
        anchor = _group_of(resolved["u"])
        used = {*resolved.values(), fs_dataset}
        covariates: dict[str, np.ndarray] = {}
        ignored: list[str] = []
        for key in _datasets(f):
            if key in used:
                continue
            ds = f[key]
            # a covariate is a real vector of the record's length from the same recording
            # (another group is another recording); names the Record reserves are left out
            if (_group_of(key) == anchor and _shape_ok(ds.shape) and ds.shape[0] == n
                    and ds.dtype.kind in "iuf" and key not in ("t", "u", "y", "segment")):
                try:
                    covariates[key] = _vector(p, key, ds[()], _KIND)
                    continue
                except (DataError, OSError):  # not finite or unreadable: left out
                    pass
            ignored.append(key)
    # The assembly reads a unit from a name written "name/unit" (a CSV header "U/V"), and
    # an HDF5 path "multisine/u" would read as a unit "u": with all roles in one group
    # (a recording) it gets the names inside the group and the group goes into the label.
    groups = {_group_of(v) for v in resolved.values()}
    kind = _KIND
    if len(groups) == 1:
        group = groups.pop()
        resolved = {r: _leaf(v) for r, v in resolved.items()}
        kind = f"group {group!r}, {_KIND}" if group else _KIND
    return _assemble(
        p, cols, lambda i: f"index {i} (0-based)", resolved, side,
        warmup=warmup, metadata={**derived, **(metadata or {})}, units=units, name=name,
        ignored=ignored, covariates=covariates, kind=kind, fittable=fittable,
    )
