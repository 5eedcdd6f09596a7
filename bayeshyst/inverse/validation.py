"""Predictive checks on an input the model was not fitted on (does the band transfer).

A feedforward command drives the actuator along paths the identification data may never
have shown: minor loops of a narrower reference, nested loops of a growing amplitude, a
different rate. The calibration check (:mod:`bayeshyst.inference.calibration`) holds out
cycles *of the same excitation*; this check predicts **another record** -- a validation
file, or the measured response to a command -- from its applied input alone and asks
whether the measurement lies in the predicted bands.

The prediction of a sample is what a measurement would show: every posterior draw's
output (model, offset, discrepancy along the new input) plus the fit's own residual
resampled onto the new record (:class:`~bayeshyst.inference.residual.ResidualBlocks`);
with a discrepancy, a share of the draws drops it and takes the model's own residual
instead -- whether it holds along new paths is what is being checked
(:class:`~bayeshyst.inverse.feedforward.PredictionError`).
Per window (a record, or each of its segments) the result gives the coverage of the
central 50 % and 90 % bands with the range a calibrated predictive gives 95 % of the
time (binomial on the effective number of independent samples, from the PIT series'
autocorrelation), the prediction's NRMSE and its mean offset; with a reference
(desired output) also the measured tracking NRMSE against the 90 % band predicted for
it. A window outside its range is a warning: the model does not transfer to that input.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.calibration import (
    LEVELS,
    band_coverage,
    binomial_range,
    effective_size,
    pit_values,
)
from bayeshyst.inference.residual import RESIDUAL_DRAWS, ResidualBlocks, cycle_samples
from bayeshyst.inverse.feedforward import (
    BAND,
    DISCREPANCY_TRANSFER,
    Draws,
    PredictionError,
    predict_record,
)
from bayeshyst.tables import TableRecord, frame

__all__ = ["TransferCheck", "TransferWindow", "check_transfer"]

#: Shortest run of samples a learned residual series is taken from.
MIN_SERIES = 50


@dataclass(frozen=True)
class TransferWindow(TableRecord):
    """How one stretch of a validation record was predicted.

    Attributes
    ----------
    label : str
        ``record`` or ``record#segment``.
    n : int
        Scored samples in the window.
    n_effective : float
        Their worth in independent samples (from the PIT series' autocorrelation).
    coverage : dict
        ``level -> fraction`` of samples inside the central ``level`` predictive band.
    expected : dict
        ``level -> (lo, hi)``: the range a calibrated predictive gives 95 % of the time.
    nrmse_percent : float
        RMS of measurement minus mean prediction, % of the fitted data's output span
        (a window's own span can be nearly nil: a hold).
    bias : float
        Mean of measurement minus mean prediction (output unit).
    tracking_percent : float or None
        With a reference: the measured tracking RMS error, % of the fitted data's output
        span.
    tracking_band_percent : (float, float) or None
        Its predicted 90 % range.
    """

    label: str
    n: int
    n_effective: float
    coverage: dict[float, float]
    expected: dict[float, tuple[float, float]]
    nrmse_percent: float
    bias: float
    tracking_percent: float | None = None
    tracking_band_percent: tuple[float, float] | None = None

    @property
    def calibrated(self) -> bool:
        """Every band's coverage within its expected range."""
        return all(lo <= self.coverage[k] <= hi for k, (lo, hi) in self.expected.items())

    @property
    def tracking_inside(self) -> bool | None:
        """Whether the measured tracking error lies in its predicted band (None: no ref)."""
        if self.tracking_percent is None or self.tracking_band_percent is None:
            return None
        lo, hi = self.tracking_band_percent
        return bool(lo <= self.tracking_percent <= hi)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (levels as strings)."""
        return {"label": self.label, "n": self.n, "n_effective": self.n_effective,
                "coverage": {f"{k:g}": v for k, v in self.coverage.items()},
                "expected": {f"{k:g}": list(v) for k, v in self.expected.items()},
                "calibrated": self.calibrated, "nrmse_percent": self.nrmse_percent,
                "bias": self.bias, "tracking_percent": self.tracking_percent,
                "tracking_band_percent": (None if self.tracking_band_percent is None
                                          else list(self.tracking_band_percent)),
                "tracking_inside": self.tracking_inside}

    def to_dataframe(self) -> Any:
        """One row (bands as ``_lo``/``_hi`` columns)."""
        return frame([self.to_dict()])

    def __str__(self) -> str:
        cov = ", ".join(f"{100 * k:g} % band {100 * v:.1f} % (expected "
                        f"{100 * self.expected[k][0]:.0f}-{100 * self.expected[k][1]:.0f})"
                        for k, v in self.coverage.items())
        text = (f"{self.label}: {cov}; NRMSE {self.nrmse_percent:.3g} %, bias "
                f"{self.bias:.4g}")
        if self.tracking_percent is not None and self.tracking_band_percent is not None:
            lo, hi = self.tracking_band_percent
            text += (f"; tracking {self.tracking_percent:.3g} % vs band [{lo:.3g}, {hi:.3g}] "
                     + ("inside" if self.tracking_inside else "OUTSIDE"))
        return text


@dataclass(frozen=True)
class TransferCheck(TableRecord):
    """A posterior's predictions of records it was not fitted on.

    Attributes
    ----------
    model : str
    windows : tuple of TransferWindow
    residual : dict
        The resampled residual(s) and, with a discrepancy, the probability that it holds
        (:meth:`~bayeshyst.inverse.feedforward.PredictionError.to_dict`).
    """

    model: str
    windows: tuple[TransferWindow, ...]
    residual: dict[str, Any]

    @property
    def warnings(self) -> tuple[str, ...]:
        """One per window whose coverage leaves its expected range."""
        out = []
        for w in self.windows:
            for k, v in w.coverage.items():
                lo, hi = w.expected[k]
                if not lo <= v <= hi:
                    out.append(f"{w.label}: the {100 * k:g} % predictive band held "
                               f"{100 * v:.1f} % of the samples (a calibrated one holds "
                               f"{100 * lo:.0f}-{100 * hi:.0f} %): {self.model} does not "
                               "transfer to this input")
        return tuple(out)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"model": self.model, "windows": [w.to_dict() for w in self.windows],
                "residual": self.residual, "warnings": list(self.warnings)}

    def to_dataframe(self) -> Any:
        """One row per window."""
        return frame([w.to_dict() for w in self.windows])

    def __str__(self) -> str:
        return "\n".join([f"transfer check of {self.model}", *(f"  {w}" for w in self.windows),
                          *(f"warning: {w}" for w in self.warnings)])


def check_transfer(post: Any, z: np.ndarray, data: Dataset | Record, *,
                   reference: dict[str, np.ndarray] | None = None,
                   by_segment: bool = True, rezero: dict[str, np.ndarray] | None = None,
                   residual_from: dict[str, np.ndarray] | None = None,
                   n_draws: int = 400, seed: int = 0,
                   discrepancy_transfer: float = DISCREPANCY_TRANSFER) -> TransferCheck:
    """Predict ``data`` from its input with posterior ``post`` and check the bands.

    Parameters
    ----------
    post : Posterior
        The fitted posterior (its data give the residual that is resampled).
    z : ndarray, shape (S, ndim)
        Its draws (at least ``n_draws`` of them are used, thinned evenly, if there are
        more).
    data : Dataset or Record
        The records to predict: each is run from rest through its own input, and its
        scored samples are compared.
    reference : dict, optional
        ``record name -> desired output (N,)`` in the output unit, for records driven by
        a feedforward command: the measured tracking error is then set against the
        band predicted for it.
    by_segment : bool
        One window per segment label of a record that has them (else the whole record).
    rezero : dict, optional
        ``record name -> boolean mask (N,)`` of samples that re-estimate the record's
        output offset (a sensor re-zeroed or drifted between recordings, which no model
        term knows of): the prediction is shifted by the mean of measurement minus mean
        prediction over them, each draw by a further ``N(0, se^2)`` with ``se`` that
        mean's standard error (from the residual's effective sample size), and those
        samples are left out of every window.
    residual_from : dict, optional
        ``record name -> boolean mask (N,)`` of samples of *this* record whose residual
        (measurement minus mean prediction, after re-zeroing) replaces the fit's training
        residual in the record's predictive: the transfer error learned from a stretch
        driven like the windows (e.g. the validation run's uncompensated segments for its
        inverse-driven ones). Each contiguous run of the mask is one series; those
        samples are left out of every window.
    n_draws : int
        Predictive draws.
    seed : int
        Seeds the residual series and the PIT's tie-breaking: same seed, same result.
    discrepancy_transfer : float
        With a discrepancy: the probability that it holds along the new records' paths
        (default 0.5; :class:`~bayeshyst.inverse.feedforward.PredictionError`). Records
        with ``residual_from`` measure it: their draws all keep it.

    Returns
    -------
    TransferCheck
    """
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    z = np.atleast_2d(np.asarray(z, float))
    if z.shape[0] < 2:
        raise ParameterError(f"z: need at least 2 posterior draws, got {z.shape[0]}")
    z = _thinned(z, n_draws)
    errors = PredictionError.of(post, _thinned(z, RESIDUAL_DRAWS),
                                transfer=discrepancy_transfer)
    draws = Draws.of(post, z)
    reference = {} if reference is None else dict(reference)
    rezero = {} if rezero is None else dict(rezero)
    residual_from = {} if residual_from is None else dict(residual_from)
    for what, given in (("reference", reference), ("rezero", rezero),
                        ("residual_from", residual_from)):
        unknown = sorted(set(given) - {r.name for r in data})
        if unknown:
            raise ParameterError(f"{what}: no record named {unknown} in {data.name!r}")
    rng = np.random.default_rng(seed)
    span = float(np.ptp(np.concatenate([r.y[r.scored] for r in post.data]))) or 1.0
    windows = []
    for rec in data:
        learn = residual_from.get(rec.name)
        # with a discrepancy some draws drop it (PredictionError) -- unless this record
        # measures its transfer (residual_from), where every draw keeps it
        parts = [(draws, errors.residual)] if learn is not None else errors.split(draws)
        preds = [predict_record(post.model, rec, d) for d, _ in parts]
        pred = np.concatenate(preds)
        scored = rec.scored_mask.copy()
        zero = rezero.get(rec.name)
        if zero is not None:
            zero = _mask(zero, rec.n, f"rezero[{rec.name!r}]")
            gap = rec.y[zero] - np.mean(pred[:, zero], axis=0)
            se = float(np.std(gap) / np.sqrt(effective_size(gap)))
            pred = pred + float(np.mean(gap)) + rng.normal(0.0, se, (pred.shape[0], 1))
            scored &= ~zero
        if learn is not None:
            learn = _mask(learn, rec.n, f"residual_from[{rec.name!r}]")
            gap = rec.y - np.mean(pred, axis=0)
            runs = [gap[a:b] for a, b in _runs(learn & rec.scored_mask)
                    if b - a >= MIN_SERIES]
            if not runs:
                raise ParameterError(f"residual_from[{rec.name!r}]: no run of {MIN_SERIES} "
                                     "scored samples")
            source = ResidualBlocks.from_series(runs, [rec.frequency_hz] * len(runs),
                                                [cycle_samples(rec)] * len(runs))
            scored &= ~learn
            y_rep = pred + source.sample(pred.shape[0], rec.n, rec.frequency_hz, rng)
        else:
            y_rep = pred + np.concatenate([r.sample(p.shape[0], rec.n, rec.frequency_hz, rng)
                                           for (_, r), p in zip(parts, preds, strict=True)])
        y_d = reference.get(rec.name)
        if y_d is not None and np.shape(y_d) != (rec.n,):
            raise ParameterError(f"reference[{rec.name!r}]: expected {rec.n} samples, got "
                                 f"shape {np.shape(y_d)}")
        if by_segment and rec.segment is not None:
            spans = [(f"{rec.name}#{int(s)}", scored & (rec.segment == s))
                     for s in np.unique(rec.segment)]
        else:
            spans = [(rec.name, scored)]
        for label, mask in spans:
            if mask.sum() < 10:
                continue
            windows.append(_window(label, rec.y, pred, y_rep, mask, y_d, span, rng))
    if not windows:
        raise DataError(f"{data.name}: no window of 10 scored samples to check")
    return TransferCheck(post.model.name, tuple(windows), errors.to_dict())


def _thinned(z: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` rows of ``z``, evenly spaced."""
    if z.shape[0] <= n:
        return z
    return z[np.linspace(0, z.shape[0] - 1, n).round().astype(int)]


def _mask(values: Any, n: int, where: str) -> np.ndarray:
    """A boolean mask of ``n`` samples with at least 10 set, or ParameterError."""
    mask = np.asarray(values)
    if mask.dtype != bool or mask.shape != (n,) or mask.sum() < 10:
        raise ParameterError(f"{where}: expected a boolean mask of {n} samples with at least "
                             f"10 set, got {mask.dtype} of shape {mask.shape} with "
                             f"{int(np.count_nonzero(mask))} set")
    return mask


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _window(label: str, y: np.ndarray, pred: np.ndarray, y_rep: np.ndarray,
            mask: np.ndarray, y_d: np.ndarray | None, span: float,
            rng: np.random.Generator) -> TransferWindow:
    pit = pit_values(y[mask], y_rep[:, mask], rng)
    n_eff = effective_size(pit)
    coverage = {level: float(np.mean(band_coverage(pit, level))) for level in LEVELS}
    expected = {level: binomial_range(n_eff, level) for level in LEVELS}
    err = y[mask] - np.mean(pred[:, mask], axis=0)
    track = band = None
    if y_d is not None:
        track = float(100.0 * np.sqrt(np.mean((y[mask] - y_d[mask]) ** 2)) / span)
        spread = 100.0 * np.sqrt(np.mean((y_rep[:, mask] - y_d[mask]) ** 2, axis=1)) / span
        lo, hi = np.quantile(spread, [(1 - BAND) / 2, (1 + BAND) / 2])
        band = (float(lo), float(hi))
    return TransferWindow(label, int(mask.sum()), float(n_eff), coverage, expected,
                          float(100.0 * np.sqrt(np.mean(err ** 2)) / span),
                          float(np.mean(err)), track, band)
