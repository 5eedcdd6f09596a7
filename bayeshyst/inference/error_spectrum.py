"""The error spectrum of a prediction: RMS of the error and of the input in octave bands.

A broadband or multisine record has no excitation frequency, so the per-frequency error
of a periodic record has no meaning for it; what the report shows instead is where in
frequency the model's error lies, next to where the input drove the plant:
:func:`error_spectrum` (one record) and :func:`group_error_spectrum` (the records of one
band group).

Method: the plain periodogram (rectangular window, the whole scored part of the record
as one segment) of the error ``y - prediction`` and of the input ``u``, one-sided, so
that by Parseval the band powers sum to the signal's mean square. The DC bin and
everything below the lower edge are left out (the bands start at the group's lower
band edge); the last band ends at Nyquist. Welch's averaging would lower the variance
of each bin, but an octave already sums many bins, and a single segment keeps Parseval
exact (a sine on a bin of the record falls entirely into its octave).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.groups import Band, group_key
from bayeshyst.data.record import Record
from bayeshyst.errors import ParameterError
from bayeshyst.tables import TableRecord, frame

__all__ = ["SpectrumBand", "band_spectra", "error_spectrum", "group_error_spectrum", "octave_edges"]


@dataclass(frozen=True)
class SpectrumBand(TableRecord):
    """One octave of an error spectrum.

    Attributes
    ----------
    lo_hz, hi_hz : float
        The octave's edges [Hz]; bins with ``lo_hz <= f < hi_hz`` (the last band up to
        and including Nyquist).
    error_rms : float
        RMS of the prediction error in the band [``units["y"]``].
    input_rms : float
        RMS of the input in the band [``units["u"]``].
    n_samples : int
        Scored samples behind the numbers (the weight when records are pooled).
    """

    lo_hz: float
    hi_hz: float
    error_rms: float
    input_rms: float
    n_samples: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return dict(self.__dict__)

    def to_dataframe(self) -> Any:
        """One row: the fields of :meth:`to_dict`."""
        return frame([self.to_dict()])

    def __str__(self) -> str:
        return (f"{self.lo_hz:.3g}-{self.hi_hz:.3g} Hz: error RMS {self.error_rms:.4g}, "
                f"input RMS {self.input_rms:.4g} (n={self.n_samples})")


def octave_edges(lo_hz: float, nyquist_hz: float) -> np.ndarray:
    """Edges ``lo, 2 lo, 4 lo, ...`` up to Nyquist (the last edge is Nyquist itself)."""
    if not (math.isfinite(lo_hz) and lo_hz > 0 and nyquist_hz > lo_hz):
        raise ParameterError(f"octave bands need 0 < lo_hz < Nyquist, got lo_hz={lo_hz!r}, "
                             f"Nyquist {nyquist_hz!r}")
    n = math.ceil(math.log2(nyquist_hz / lo_hz) - 1e-12)
    edges = lo_hz * 2.0 ** np.arange(n + 1)
    edges[-1] = nyquist_hz
    return edges


def _band_power(x: np.ndarray, fs: float, edges: np.ndarray) -> np.ndarray:
    """Mean-square of ``x`` in each band of ``edges`` (one-sided periodogram, Parseval)."""
    n = x.size
    power = np.abs(np.fft.rfft(x)) ** 2 / n**2
    # one-sided: every bin but DC (and Nyquist for even n) stands for two of the full FFT
    power[1:(n + 1) // 2] *= 2.0
    f = np.fft.rfftfreq(n, d=1.0 / fs)
    idx = np.searchsorted(edges, f, side="right") - 1
    idx[np.isclose(f, edges[-1])] = edges.size - 2  # Nyquist belongs to the last band
    ok = (idx >= 0) & (idx < edges.size - 1) & (f > 0)
    return np.bincount(idx[ok], weights=power[ok], minlength=edges.size - 1)


def error_spectrum(record: Record, prediction: np.ndarray, lo_hz: float | None = None
                   ) -> tuple[SpectrumBand, ...]:
    """RMS of ``record.y - prediction`` and of ``record.u`` in octaves from ``lo_hz``.

    Parameters
    ----------
    record : Record
        Uniformly sampled (its sampling rate :attr:`Record.fs` is used).
    prediction : ndarray, shape (n,)
        The prediction of the whole record (the posterior mean); its scored samples are
        compared.
    lo_hz : float, optional
        Lower edge of the first octave; default the record's band's lower edge.

    Returns
    -------
    tuple of SpectrumBand
        Octaves ``[lo, 2 lo), [2 lo, 4 lo), ...`` up to Nyquist.

    Raises
    ------
    ParameterError
        If the prediction's length is not the record's, or there is no lower edge.
    """
    pred = np.asarray(prediction, dtype=float)
    if pred.shape != (record.n,):
        raise ParameterError(f"{record.name}: prediction of shape {pred.shape}, expected "
                             f"({record.n},)")
    if lo_hz is None:
        if record.band_hz is None:
            raise ParameterError(f"{record.name}: no band; give lo_hz")
        lo_hz = record.band_hz[0]
    edges = octave_edges(float(lo_hz), record.fs / 2.0)
    s = record.scored
    err = _band_power(record.y[s] - pred[s], record.fs, edges)
    inp = _band_power(record.u[s], record.fs, edges)
    n = record.n_scored
    return tuple(SpectrumBand(float(a), float(b), float(np.sqrt(e)), float(np.sqrt(i)), n)
                 for a, b, e, i in zip(edges[:-1], edges[1:], err, inp, strict=True))


def group_error_spectrum(records: Sequence[Record], predictions: Sequence[np.ndarray],
                         lo_hz: float) -> tuple[SpectrumBand, ...]:
    """The error spectrum of a group of records, pooled.

    Each record's octaves (:func:`error_spectrum`, edges from ``lo_hz`` to the highest
    Nyquist of the group) are pooled as mean squares weighted by scored samples; an
    octave above a record's own Nyquist gets nothing from it.
    """
    if not records:
        return ()
    nyquist = max(r.fs for r in records) / 2.0
    edges = octave_edges(float(lo_hz), nyquist)
    err = np.zeros(edges.size - 1)
    inp = np.zeros(edges.size - 1)
    weight = np.zeros(edges.size - 1)
    for rec, pred in zip(records, predictions, strict=True):
        rows = error_spectrum(rec, pred, lo_hz)
        for row in rows:
            # a record's octave lies in the group's octave of the same lower edge
            j = int(np.argmin(np.abs(edges[:-1] - row.lo_hz)))
            err[j] += row.error_rms**2 * row.n_samples
            inp[j] += row.input_rms**2 * row.n_samples
            weight[j] += row.n_samples
    out = []
    for j in range(edges.size - 1):
        w = weight[j]
        out.append(SpectrumBand(float(edges[j]), float(edges[j + 1]),
                                float(np.sqrt(err[j] / w)) if w else math.nan,
                                float(np.sqrt(inp[j] / w)) if w else math.nan, int(w)))
    return tuple(out)


def band_spectra(records: Iterable[Record], predictions: Iterable[np.ndarray]
                 ) -> tuple[tuple[Band, tuple[SpectrumBand, ...]], ...]:
    """The error spectrum of each band group among ``records``, bands in order.

    ``predictions`` holds one full-record prediction per record. Records of a frequency
    or of no group are skipped, and so is a band whose lower edge is at or above the
    records' Nyquist (no octave to show).
    """
    pooled: dict[Band, tuple[list[Record], list[np.ndarray]]] = {}
    for rec, pred in zip(records, predictions, strict=True):
        key = group_key(rec)
        if isinstance(key, Band):
            recs, preds = pooled.setdefault(key, ([], []))
            recs.append(rec)
            preds.append(np.asarray(pred, dtype=float))
    out = []
    for band in sorted(pooled):
        recs, preds = pooled[band]
        if band.lo_hz < min(r.fs for r in recs) / 2.0:
            out.append((band, group_error_spectrum(recs, preds, band.lo_hz)))
    return tuple(out)
