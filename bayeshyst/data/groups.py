"""The group a record is compared and reported in: a frequency, a band, or unknown.

Model selection and the report group records by excitation: a periodic or stepped
record by its frequency (:func:`~bayeshyst.data.record.frequency_key`), a multisine or
broadband record by the band its input covers (``metadata["band_hz"]``, set by
:func:`~bayeshyst.data.label_frequencies`), any other record in one "unknown" group.

A group's identity (:data:`GroupKey`) is a float for a frequency, a :class:`Band` for a
band and None for "unknown". Every grouping, comparison and label of groups goes through
:func:`group_key`, :func:`group_label` and :func:`group_order`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeAlias

from bayeshyst.data.record import frequency_label

if TYPE_CHECKING:
    from bayeshyst.data.record import Record

__all__ = ["Band", "GroupKey", "band_of", "frequency_of", "group_key", "group_label",
           "group_order"]


def _round3(x: float) -> float:
    return float(f"{float(x):.3g}")


@dataclass(frozen=True, order=True)
class Band:
    """A band group's identity: its edges [Hz], each to 3 significant digits.

    Two records are in one band group exactly when their labels
    (``"band 5-150 Hz"``) agree, so the edges are rounded to the digits the label
    shows; build one with :meth:`of`. Ordered by the lower edge, then the upper.
    """

    lo_hz: float
    hi_hz: float

    @classmethod
    def of(cls, lo_hz: float, hi_hz: float) -> Band:
        """The band ``(lo_hz, hi_hz)`` rounded to its identity (3 significant digits)."""
        return cls(_round3(lo_hz), _round3(hi_hz))

    @property
    def label(self) -> str:
        """``"band 5-150 Hz"``."""
        return f"band {self.lo_hz:.3g}-{self.hi_hz:.3g} Hz"

    def to_list(self) -> list[float]:
        """``[lo_hz, hi_hz]`` (the ``band_hz`` of ``summary.json``)."""
        return [self.lo_hz, self.hi_hz]


#: A group's identity: a frequency [Hz], a band, or None ("unknown").
GroupKey: TypeAlias = "float | Band | None"


def group_key(rec: Record) -> float | Band | None:
    """The group of a record: its frequency, else its band, else None.

    Parameters
    ----------
    rec : Record

    Returns
    -------
    float, Band or None
        ``rec.frequency_hz`` when set (a frequency outranks a band); else
        ``Band.of(*rec.band_hz)`` when the record was classified multisine or broadband;
        else None.
    """
    if rec.frequency_hz is not None:
        return rec.frequency_hz
    band = rec.band_hz
    return None if band is None else Band.of(*band)


def group_label(key: Any) -> str:
    """``"10 Hz"``, ``"band 5-150 Hz"`` or ``"unknown"`` (the label of a :data:`GroupKey`)."""
    if isinstance(key, Band):
        return key.label
    return frequency_label(key)


def group_order(key: Any) -> tuple[Any, ...]:
    """Sort key of groups: frequencies ascending, then bands by lower edge, unknown last."""
    if key is None:
        return (2,)
    if isinstance(key, Band):
        return (1, key.lo_hz, key.hi_hz)
    return (0, float(key))


def frequency_of(key: Any) -> float | None:
    """The frequency of a frequency group, None for a band or the unknown group."""
    return None if key is None or isinstance(key, Band) else float(key)


def band_of(key: Any) -> Band | None:
    """The band of a band group, None otherwise."""
    return key if isinstance(key, Band) else None
