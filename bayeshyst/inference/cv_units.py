"""The leave-one-out units of a record: its cycles, its periods, or time blocks.

Cross-validation leaves out one unit of a record at a time, and the likelihood keeps
its pointwise values per unit. A periodic record's unit is one input cycle; a
multisine's one period; a broadband record's (or one without whole cycles) a contiguous
time block. :func:`cycle_units` cuts them, :func:`unit_kind` says in words what they are.
"""

from __future__ import annotations

import numpy as np

from bayeshyst.data.classify import block_bounds
from bayeshyst.data.record import Record
from bayeshyst.data.segment import cycle_labels
from bayeshyst.errors import DataError

__all__ = ["cycle_units", "unit_kind"]


def cycle_units(record: Record) -> list[tuple[int, int]]:
    """Scored sample ranges ``[a, b)``, the leave-one-out units of a record's likelihood.

    * A record whose input repeats (sines, triangles, a stepped sine's pieces, records
      not classified): one unit per input cycle
      (:func:`bayeshyst.data.segment.cycle_labels`), partial cycles at the ends of the
      scored part joining their neighbouring whole cycle, so that the units partition
      the scored samples.
    * ``metadata["excitation"] == "multisine"`` with ``metadata["period_s"]``: one unit
      per whole period from the first scored sample (the partial rest joins the last),
      when at least two periods fit.
    * ``"broadband"``, a multisine without two known periods, or any record without
      whole cycles (steps, holds, random inputs): contiguous blocks of equal length,
      about 8, none shorter than 256 samples, one unit when the scored part is shorter
      than 512 samples (:func:`bayeshyst.data.classify.block_bounds`).

    The units only group the scored samples for cross-validation: the model still
    simulates the whole record from its start, so the hysteretic state is carried
    across block (and cycle) boundaries, never reset.

    Parameters
    ----------
    record : Record
        The measurement.

    Returns
    -------
    list of (int, int)
        Consecutive ranges covering the scored samples ``[warmup, n)``.
    """
    return _units(record)[0]


def unit_kind(record: Record) -> str:
    """What the leave-one-out units of ``record`` are, in words: ``"8 time blocks"``.

    ``"<n> cycles"``, ``"<n> periods"`` (a multisine) or ``"<n> time blocks"`` (a
    broadband record, or one without whole cycles), as :func:`cycle_units` cuts them;
    said in the outputs so that a reader knows what a held-out unit was.
    """
    spans, kind = _units(record)
    return f"{len(spans)} {kind}" if len(spans) != 1 else f"1 {kind.rstrip('s')}"


def _units(record: Record) -> tuple[list[tuple[int, int]], str]:
    start, stop = record.scored.start or 0, record.n
    kind = record.metadata.get("excitation")
    if kind == "multisine" and record.metadata.get("period_s"):
        period = round(float(record.metadata["period_s"]) / record.dt)
        # one block per period where two or more are scored, else time blocks
        return (block_bounds(stop, start, period=period),
                "periods" if (stop - start) // max(period, 1) >= 2 else "time blocks")
    if kind in ("broadband", "multisine"):
        return block_bounds(stop, start), "time blocks"
    try:
        labels = cycle_labels(record)
    except DataError:
        return block_bounds(stop, start), "time blocks"
    labels = labels[start:stop]
    ids = np.unique(labels[labels >= 0])
    if ids.size == 0:
        return block_bounds(stop, start), "time blocks"
    bounds = [start + int(np.flatnonzero(labels == i)[0]) for i in ids] + [stop]
    bounds[0] = start
    return [(bounds[j], bounds[j + 1]) for j in range(len(ids))], "cycles"
