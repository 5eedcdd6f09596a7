"""A named collection of validated records, and the check that data can be fitted.

A :class:`Dataset` is an ordered, named collection of :class:`~bayeshyst.data.record.\
Record` objects, typically one per excitation frequency, with helpers to group and
select by frequency. :func:`check_fittable` refuses data no model can be fitted to (the
readers call it at the boundary).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.groups import group_key, group_label, group_order
from bayeshyst.data.record import MAGNITUDE_MAX, RESOLUTION_MIN, SPAN_MIN, Record
from bayeshyst.errors import DataError

__all__ = ["Dataset", "check_fittable"]


def check_fittable(data: Record | Dataset, source: str,
                   labels: Mapping[str, str] | None = None) -> None:
    """Refuse data that no model can be fitted to, naming the file and the column.

    Over all records together (as the models' priors see them), the input ``u`` and
    the output ``y`` must each vary, and lie inside the magnitudes a fit handles:
    ``max|x| <= MAGNITUDE_MAX``, ``span(x) >= SPAN_MIN`` and
    ``span(x) >= RESOLUTION_MIN * max|x|`` (``span`` = peak-to-peak).

    Parameters
    ----------
    data : Record or Dataset
        Validated data.
    source : str
        Where the data came from (the file), the start of every message.
    labels : mapping of str to str, optional
        How to name the ``"u"`` and ``"y"`` columns, e.g. ``{"y": "column 'disp' (y)"}``
        (default ``"column 'u'"``, ``"column 'y'"``).

    Raises
    ------
    DataError
        If a column is constant, or a magnitude is outside the supported range; the
        message names ``source``, the column, the magnitude found and the range.

    Notes
    -----
    Records built in memory are not checked (a constant input is a valid Record); the
    models refuse a constant input or output when they scale their priors.
    """
    records = [data] if isinstance(data, Record) else list(data)
    supported = (f"max|x| <= {MAGNITUDE_MAX:g}, peak-to-peak >= {SPAN_MIN:g} and >= "
                 f"{RESOLUTION_MIN:g} max|x|")
    for col, what in (("u", "input"), ("y", "output")):
        label = (labels or {}).get(col, f"column {col!r}")
        x = np.concatenate([getattr(r, col) for r in records])
        lo, hi = float(x.min()), float(x.max())
        if lo == hi:
            raise DataError(f"{source}: {label}: constant ({lo!r} in every sample); the "
                            f"{what} must vary for any hysteresis to be identified")
        # max|x| first: for |x| near the float64 limit the span itself would overflow
        big = max(abs(lo), abs(hi))
        if big > MAGNITUDE_MAX:
            raise DataError(f"{source}: {label}: largest |value| {big:.3g} is outside the "
                            f"supported range ({supported}); express it in a larger unit")
        span = hi - lo
        if span < SPAN_MIN:
            raise DataError(f"{source}: {label}: peak-to-peak {span:.3g} is outside the "
                            f"supported range ({supported}); express it in a smaller unit")
        if span < RESOLUTION_MIN * big:
            raise DataError(f"{source}: {label}: peak-to-peak {span:.3g} is only "
                            f"{span / big:.2g} of its largest |value| {big:.3g}, outside the "
                            f"supported range ({supported}): float64 barely resolves the "
                            f"variation; subtract the constant level before fitting")


@dataclass(frozen=True, eq=False, repr=False)
class Dataset:
    """An ordered, named, non-empty collection of Records with unique names.

    Parameters
    ----------
    records : Record or iterable of Record
        The measurements, in order. Stored as a tuple.
    name : str, default "dataset"
        Identifier used in reports.

    Raises
    ------
    DataError
        If empty, if an item is not a Record, or if two records share a name.
    """

    records: tuple[Record, ...]
    name: str = "dataset"

    def __post_init__(self) -> None:
        records = self.records
        if isinstance(records, Record):
            records = (records,)
        records = tuple(records)
        if not isinstance(self.name, str) or not self.name:
            raise DataError(f"dataset name: expected a non-empty string, found {self.name!r}")
        if not records:
            raise DataError(f"dataset {self.name!r}: expected at least one record, found none")
        for i, rec in enumerate(records):
            if not isinstance(rec, Record):
                raise DataError(
                    f"dataset {self.name!r}: item {i}: expected a Record, "
                    f"found {type(rec).__name__}"
                )
        seen: dict[str, int] = {}
        for i, rec in enumerate(records):
            if rec.name in seen:
                raise DataError(
                    f"dataset {self.name!r}: expected unique record names, found {rec.name!r} "
                    f"at positions {seen[rec.name]} and {i}"
                )
            seen[rec.name] = i
        object.__setattr__(self, "records", records)

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self) -> Iterator[Record]:
        return iter(self.records)

    def __getitem__(self, key: int | slice | str) -> Any:
        """Record by position or by name; a slice gives a Dataset."""
        if isinstance(key, str):
            for rec in self.records:
                if rec.name == key:
                    return rec
            raise KeyError(f"dataset {self.name!r} has no record named {key!r}")
        if isinstance(key, slice):
            return Dataset(self.records[key], name=self.name)
        return self.records[key]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Dataset):
            return NotImplemented
        return self.name == other.name and self.records == other.records

    __hash__ = None  # type: ignore[assignment]

    @property
    def names(self) -> tuple[str, ...]:
        """Record names in order."""
        return tuple(r.name for r in self.records)

    @property
    def n_samples(self) -> int:
        """Total number of samples over all records."""
        return sum(r.n for r in self.records)

    @property
    def frequencies(self) -> tuple[float, ...]:
        """Sorted unique excitation frequencies [Hz]; records without one are ignored."""
        return tuple(sorted({r.frequency_hz for r in self.records if r.frequency_hz is not None}))

    def by_frequency(self) -> dict[float | None, Dataset]:
        """Group records by ``frequency_hz``, ascending; records without one go under None.

        Returns
        -------
        dict
            ``{frequency_hz: Dataset}``, each named ``"<name>@<f>Hz"`` (``"<name>@?Hz"``
            for the None group, which comes last).
        """
        groups: dict[float | None, list[Record]] = {}
        for rec in self.records:
            groups.setdefault(rec.frequency_hz, []).append(rec)
        keys = sorted(k for k in groups if k is not None)
        if None in groups:
            keys.append(None)
        return {
            k: Dataset(groups[k], name=f"{self.name}@{'?' if k is None else f'{k:g}'}Hz")
            for k in keys
        }

    def by_group(self) -> dict[Any, Dataset]:
        """Group records by :func:`~bayeshyst.data.groups.group_key`, in group order.

        As :meth:`by_frequency`, but records without a frequency that carry a band
        (multisine, broadband) form one group per band label; only records with neither
        go under None.

        Returns
        -------
        dict
            ``{key: Dataset}`` (key a frequency, a :class:`~bayeshyst.data.groups.Band`
            or None), frequencies ascending, then bands by lower edge, None last; a
            frequency group is named as in :meth:`by_frequency`, a band group
            ``"<name>@band5-150Hz"``.
        """
        groups: dict[Any, list[Record]] = {}
        for rec in self.records:
            groups.setdefault(group_key(rec), []).append(rec)

        def name(k: Any) -> str:
            if k is None or isinstance(k, float):
                return f"{self.name}@{'?' if k is None else f'{k:g}'}Hz"
            return f"{self.name}@{group_label(k).replace(' ', '')}"

        return {k: Dataset(groups[k], name=name(k)) for k in sorted(groups, key=group_order)}

    def select(
        self,
        frequency_hz: float | Iterable[float] | None = None,
        *,
        names: Iterable[str] | None = None,
        rtol: float = 1e-9,
    ) -> Dataset:
        """Records matching every given criterion, in the original order.

        Parameters
        ----------
        frequency_hz : float or iterable of float, optional
            Keep records whose ``frequency_hz`` equals one of these [Hz] within ``rtol``.
        names : iterable of str, optional
            Keep records with these names.
        rtol : float, default 1e-9
            Relative tolerance of the frequency comparison.

        Raises
        ------
        DataError
            If nothing matches (the message lists what is available).
        """
        keep = list(self.records)
        if frequency_hz is not None:
            wanted = (
                [float(frequency_hz)]
                if isinstance(frequency_hz, int | float)
                else [float(f) for f in frequency_hz]
            )
            keep = [
                r
                for r in keep
                if r.frequency_hz is not None
                and any(math.isclose(r.frequency_hz, f, rel_tol=rtol) for f in wanted)
            ]
        if names is not None:
            wanted_names = set(names)
            keep = [r for r in keep if r.name in wanted_names]
        if not keep:
            raise DataError(
                f"dataset {self.name!r}: no record matches frequency_hz={frequency_hz!r}, "
                f"names={names!r}; available frequencies {list(self.frequencies)}, "
                f"names {list(self.names)}"
            )
        return Dataset(keep, name=self.name)

    def concat(self, *others: Dataset | Record, name: str | None = None) -> Dataset:
        """Append the records of ``others`` (Datasets or Records); names must stay unique."""
        records = list(self.records)
        for other in others:
            records.extend([other] if isinstance(other, Record) else list(other))
        return Dataset(records, name=self.name if name is None else name)

    def __str__(self) -> str:
        width = max(8, *(len(r.name) for r in self.records))
        lines = [
            f"Dataset {self.name!r}: {len(self)} record(s), {self.n_samples} samples",
            f"  {'name':<{width}} {'n':>8} {'fs [Hz]':>10} {'f [Hz]':>8} {'stroke':>12}",
        ]
        for r in self.records:
            f = "-" if r.frequency_hz is None else f"{r.frequency_hz:g}"
            stroke = f"{r.stroke:.4g} {r.units['y']}"
            lines.append(f"  {r.name:<{width}} {r.n:>8} {r.fs:>10.6g} {f:>8} {stroke:>12}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Dataset(name={self.name!r}, records={list(self.names)!r})"
