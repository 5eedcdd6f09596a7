"""The records of a prediction: how its initial state is set, and what it scored.

:class:`InitialCondition` says how a model's state before a record is set (and which
samples are scored); :class:`RecordPrediction` holds one record's posterior predictive
sample by sample; :class:`PredictionScore` the scores of a record, a group (frequency
or band) or all; :class:`PredictionResult` the whole prediction. The computation that
fills them is :mod:`bayeshyst.inference.predict`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from bayeshyst.data.groups import Band
from bayeshyst.errors import ParameterError
from bayeshyst.inference.calibration import LEVELS, PIT_BINS, binomial_range, effective_size
from bayeshyst.inference.error_spectrum import SpectrumBand
from bayeshyst.tables import TableRecord, frame

__all__ = ["QUANTILES", "InitialCondition", "PredictionResult", "PredictionScore",
           "RecordPrediction", "checked_request", "score_records"]

#: quantiles of the central 50 % and 90 % predictive bands, in the order the records keep
QUANTILES = (0.05, 0.25, 0.75, 0.95)

Kind = Literal["relaxed", "rest", "warmup", "periodic"]
_KINDS = ("relaxed", "rest", "warmup", "periodic")


@dataclass(frozen=True)
class InitialCondition:
    """How the model's state before a record is set, and which samples are scored.

    Parameters
    ----------
    kind : {"relaxed", "rest", "warmup", "periodic"}
        ``"relaxed"`` (default): the model's relaxed state at the record's first input,
        as in the fit; the record's own warm-up is not scored. ``"rest"``: relaxed at
        zero input before the first sample (a stage switched on from rest; the input
        steps from 0 to its first value). ``"warmup"``: relaxed at the first input,
        and the first ``warmup_s`` seconds simulated but not scored. ``"periodic"``:
        the record holds whole periods of a periodic input; it is simulated
        ``periods`` times in a row from the relaxed state and the last repetition is
        scored whole (periodic steady state).
    warmup_s : float
        Leading seconds not scored (``"warmup"`` only) [s].
    periods : int
        Repetitions of the record simulated (``"periodic"`` only), at least 2.
    """

    kind: Kind = "relaxed"
    warmup_s: float = 0.0
    periods: int = 3

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ParameterError(f"initial condition: expected one of {_KINDS}, got "
                                 f"{self.kind!r}")
        w = self.warmup_s
        if isinstance(w, bool) or not isinstance(w, int | float) or not math.isfinite(w) \
                or w < 0:
            raise ParameterError(f"initial condition: warmup_s must be a finite number of "
                                 f"seconds >= 0, got {w!r}")
        if self.kind == "warmup" and w <= 0:
            raise ParameterError("initial condition 'warmup' needs warmup_s > 0 seconds")
        k = self.periods
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 2:
            raise ParameterError(f"initial condition: periods must be an integer >= 2 (the "
                                 f"last of them is scored), got {k!r}")

    @classmethod
    def parse(cls, text: str) -> InitialCondition:
        """From ``"relaxed"``, ``"rest"``, ``"warmup:0.5"`` (seconds) or ``"periodic:3"``.

        Raises
        ------
        ParameterError
            Anything else, naming what was given.
        """
        m = re.fullmatch(r"\s*(relaxed|rest|warmup|periodic)\s*(?::\s*([^\s]+)\s*)?", text)
        if m is None:
            raise ParameterError(f"initial condition: expected relaxed, rest, warmup:SECONDS "
                                 f"or periodic[:PERIODS], got {text!r}")
        kind, arg = m.group(1), m.group(2)
        try:
            if kind == "warmup":
                if arg is None:
                    raise ParameterError("initial condition 'warmup' needs its span: "
                                         "warmup:SECONDS, e.g. warmup:0.5")
                return cls("warmup", warmup_s=float(arg))
            if kind == "periodic":
                return cls("periodic", periods=3 if arg is None else int(arg))
        except ValueError as exc:
            raise ParameterError(f"initial condition {text!r}: {arg!r} is not a number") \
                from exc
        if arg is not None:
            raise ParameterError(f"initial condition {kind!r} takes no argument, got {text!r}")
        return cls(kind)

    def describe(self) -> str:
        """One line saying how the state was set, for outputs."""
        return {
            "relaxed": "relaxed at each record's first input (as in the fit); the record's "
                       "warm-up not scored",
            "rest": "at rest: relaxed at zero input before the first sample",
            "warmup": f"relaxed at the first input; the first {self.warmup_s:g} s simulated, "
                      "not scored",
            "periodic": f"periodic steady state: each record played {self.periods} times "
                        "from the relaxed state, the last scored",
        }[self.kind]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields with :meth:`describe`."""
        out: dict[str, Any] = {"kind": self.kind, "description": self.describe()}
        if self.kind == "warmup":
            out["warmup_s"] = self.warmup_s
        if self.kind == "periodic":
            out["periods"] = int(self.periods)
        return out


# ------------------------------------------------------------------------ records


@dataclass(frozen=True)
class RecordPrediction:
    """The posterior predictive of one record, sample by sample.

    Attributes
    ----------
    name : str
    group : str
        Its frequency or band (:attr:`Record.group`).
    t, u, y : ndarray, shape (n,)
        Time [s], input and measured output [the fit's units].
    scored : ndarray of bool, shape (n,)
        The samples the scores count.
    mean, sd : ndarray, shape (n,)
        Mean and standard deviation of the noise-free prediction over draws [output].
    bands : ndarray, shape (4, n)
        Quantiles 5, 25, 75 and 95 % of the predictive (noise included) [output].
    pit : ndarray, shape (n,)
        ``P(y_rep <= y)`` under the predictive; NaN where not scored.
    n_failed : int
        Draws whose simulation of this record failed (left out).
    outside_input : float
        Share of the scored samples whose input lies outside the range the fit saw.
    measured : bool
        Whether the record has a measured output (else ``y`` and ``pit`` are NaN and it
        is not scored).
    """

    name: str
    group: str
    t: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    scored: np.ndarray = field(repr=False)
    mean: np.ndarray = field(repr=False)
    sd: np.ndarray = field(repr=False)
    bands: np.ndarray = field(repr=False)
    pit: np.ndarray = field(repr=False)
    n_failed: int = 0
    outside_input: float = 0.0
    measured: bool = True

    def band(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper edge of the central ``level`` (0.5 or 0.9) band."""
        if level == 0.9:
            return self.bands[0], self.bands[3]
        if level == 0.5:
            return self.bands[1], self.bands[2]
        raise ParameterError(f"band level: expected 0.5 or 0.9, got {level!r}")

    def to_dataframe(self) -> Any:
        """One row per sample: t, u, y, mean, sd, the band edges, PIT, scored."""
        import pandas as pd

        return pd.DataFrame({"record": self.name, "t": self.t, "u": self.u, "y": self.y,
                             "mean": self.mean, "sd": self.sd, "lo90": self.bands[0],
                             "lo50": self.bands[1], "hi50": self.bands[2],
                             "hi90": self.bands[3], "pit": self.pit, "scored": self.scored})


@dataclass(frozen=True)
class PredictionScore(TableRecord):
    """How well the predictive matched the measurement over a set of scored samples.

    Attributes
    ----------
    scope : str
        ``"record"``, ``"group"`` (a frequency or band) or ``"all"``.
    name : str
        The record's name, the group's label or ``"all"``.
    n_samples : int
    rmse, max_error : float
        Of the predictive mean [output unit].
    nrmse_percent : float
        RMSE in per cent of the measured peak-to-peak output.
    fit_percent : float
        ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``: 100 is a perfect fit, 0 no better
        than the measured mean.
    coverage : dict
        ``level -> share`` of the samples inside the central 50 % and 90 % bands.
    expected_range : dict
        ``level -> (lo, hi)`` where a calibrated predictive's coverage falls 95 % of the
        time (binomial on ``n_effective``).
    n_effective : float
        Effective number of independent samples of the PIT series.
    pit_histogram : tuple of float
        Share of the PIT values in 10 equal bins (0.1 each when calibrated).
    """

    scope: str
    name: str
    n_samples: int
    rmse: float
    nrmse_percent: float
    fit_percent: float
    max_error: float
    coverage: dict[float, float]
    expected_range: dict[float, tuple[float, float]]
    n_effective: float
    pit_histogram: tuple[float, ...]

    @property
    def calibrated(self) -> bool:
        """Whether every band's coverage is inside its expected range."""
        return all(lo <= self.coverage[p] <= hi for p, (lo, hi) in self.expected_range.items())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (coverage keyed ``coverage_50``, ``coverage_90``)."""
        out: dict[str, Any] = {
            "scope": self.scope, "name": self.name, "n_samples": self.n_samples,
            "rmse": self.rmse, "nrmse_percent": self.nrmse_percent,
            "fit_percent": self.fit_percent, "max_error": self.max_error,
            "n_effective": self.n_effective, "calibrated": self.calibrated}
        for p in LEVELS:
            out[f"coverage_{int(100 * p)}"] = self.coverage[p]
            out[f"expected_{int(100 * p)}"] = list(self.expected_range[p])
        out["pit_histogram"] = list(self.pit_histogram)
        return out

    def to_dataframe(self) -> Any:
        """One row: the fields of :meth:`to_dict` without the histogram."""
        return frame([self.to_dict()], drop=("pit_histogram",))

    def __str__(self) -> str:
        cov = ", ".join(f"{int(100 * p)} % band {100 * c:.1f} % (calibrated "
                        f"{100 * self.expected_range[p][0]:.0f}-"
                        f"{100 * self.expected_range[p][1]:.0f} %)"
                        for p, c in self.coverage.items())
        return (f"{self.name:>16}: RMSE {self.rmse:.4g} ({self.nrmse_percent:.3g} %), fit "
                f"{self.fit_percent:.2f} %, max {self.max_error:.4g}; {cov}; n={self.n_samples}")


def score_records(scope: str, name: str, parts: Sequence[RecordPrediction]) -> PredictionScore:
    """The scores of the scored samples of ``parts`` pooled (see :class:`PredictionScore`).

    ``scope`` and ``name`` label it (a record, a group, or ``"all"``); the coverage is the
    share of samples inside the bands as written, its expected range binomial on the
    effective number of independent samples of the PIT series.
    """
    y = np.concatenate([p.y[p.scored] for p in parts])
    yhat = np.concatenate([p.mean[p.scored] for p in parts])
    pits = [p.pit[p.scored] for p in parts]
    e = y - yhat
    ptp = float(np.ptp(y))
    rmse = float(np.sqrt(np.mean(e**2)))
    spread = float(np.linalg.norm(y - y.mean()))
    fit = 100.0 * (1.0 - float(np.linalg.norm(e)) / spread) if spread > 0 else math.nan
    allp = np.concatenate(pits)
    ok = np.isfinite(allp)
    n_eff = float(sum(effective_size(p[np.isfinite(p)]) for p in pits))
    cov, expected = {}, {}
    for level in LEVELS:
        # the share inside the bands as written (not |PIT - 1/2| <= level / 2, which
        # differs from the interpolated quantiles of a few hundred draws by a sample or so)
        inside = [((p.y >= p.band(level)[0]) & (p.y <= p.band(level)[1]))[p.scored]
                  for p in parts]
        cov[level] = float(np.mean(np.concatenate(inside)))
        expected[level] = binomial_range(n_eff, level)
    hist, _ = np.histogram(allp[ok], bins=PIT_BINS, range=(0.0, 1.0))
    return PredictionScore(scope, name, int(y.size), rmse,
                           100.0 * rmse / ptp if ptp > 0 else math.nan, fit,
                           float(np.max(np.abs(e))), cov, expected, n_eff,
                           tuple(float(h) for h in hist / max(1, int(ok.sum()))))


@dataclass(frozen=True)
class PredictionResult(TableRecord):
    """A fit's posterior predictive on records, scored against their measurements.

    Attributes
    ----------
    model : str
        The fitted model's spec.
    source : str
        What predicted (a saved fit's path, "fit", a GP's name).
    initial : InitialCondition
    records : tuple of RecordPrediction
    per_record, per_group : tuple of PredictionScore
        Scores of each record with a measured output (in record order) and of each
        frequency or band (:attr:`Record.group`).
    overall : PredictionScore or None
        Of every measured record; None when no record has a measured output (an input
        read alone: predictions only).
    n_draws : int
        Posterior draws simulated (0 for a predictor given as mean and sd).
    units : dict
        ``t``, ``u``, ``y`` units of the predictions (the fit's).
    method : str
        How the bands were made (draws + noise, or a Gaussian from mean and sd).
    steady_state_change : float or None
        Periodic prediction only: largest change of the mean between the last two
        periods [output unit].
    spectra : tuple of (Band, tuple of SpectrumBand)
        For each band group (multisine and broadband records), the RMS of the error of
        the predictive mean and of the input per octave
        (:func:`bayeshyst.inference.error_spectrum.band_spectra`): where in frequency
        the model misses, which a per-frequency error cannot say for such records.
    warnings : tuple of str
    notes : tuple of str
        Unit conversions and other facts worth saying.
    """

    model: str
    source: str
    initial: InitialCondition
    records: tuple[RecordPrediction, ...] = field(repr=False)
    per_record: tuple[PredictionScore, ...]
    per_group: tuple[PredictionScore, ...]
    overall: PredictionScore | None
    n_draws: int
    units: dict[str, str]
    method: str
    steady_state_change: float | None = None
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    spectra: tuple[tuple[Band, tuple[SpectrumBand, ...]], ...] = ()

    def __getitem__(self, name: str) -> RecordPrediction:
        for r in self.records:
            if r.name == name:
                return r
        raise KeyError(f"no record {name!r}; records: {[r.name for r in self.records]}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no per-sample arrays)."""
        scores = {sc.name: sc for sc in self.per_record}
        return {"model": self.model, "source": self.source,
                "initial_condition": self.initial.to_dict(), "n_draws": self.n_draws,
                "method": self.method, "units": dict(self.units),
                "overall": None if self.overall is None else self.overall.to_dict(),
                "per_group": [s.to_dict() for s in self.per_group],
                "per_record": [{**(scores[r.name].to_dict() if r.name in scores else
                                   {"scope": "record", "name": r.name}),
                                "measured": r.measured, "group": r.group,
                                "n_failed": r.n_failed, "outside_input": r.outside_input}
                               for r in self.records],
                "steady_state_change": self.steady_state_change,
                "error_spectra": [{"group": band.label, "band_hz": band.to_list(),
                                   "octaves": [row.to_dict() for row in rows]}
                                  for band, rows in self.spectra],
                "warnings": list(self.warnings), "notes": list(self.notes)}

    def to_dataframe(self) -> Any:
        """One row per score: every measured record, every group, then overall."""
        rows = (*self.per_record, *self.per_group, *(() if self.overall is None
                                                     else (self.overall,)))
        return frame([s.to_dict() for s in rows], drop=("pit_histogram",))

    def predictions_frame(self) -> Any:
        """Every record's samples (:meth:`RecordPrediction.to_dataframe`), end to end."""
        import pandas as pd

        return pd.concat([r.to_dataframe() for r in self.records], ignore_index=True)

    def __str__(self) -> str:
        y = self.units.get("y", "")
        lines = [f"prediction of {len(self.records)} record(s) by {self.model} ({self.source}; "
                 f"{self.method}); initial state {self.initial.describe()}; output in {y}",
                 "no measured output: predictions only" if self.overall is None
                 else str(self.overall)]
        if len(self.per_group) > 1 or len(self.records) > 1:
            lines += [str(s) for s in self.per_group]
        for band, rows in self.spectra:
            lines.append(f"error spectrum of {band.label} (RMS per octave, error [{y}] / "
                         f"input [{self.units.get('u', '')}]): " + ", ".join(
                             f"{r.lo_hz:.3g}-{r.hi_hz:.3g} Hz {r.error_rms:.3g} / "
                             f"{r.input_rms:.3g}" for r in rows))
        lines += [f"note: {n}" for n in self.notes]
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def checked_request(initial: InitialCondition | str | None, n_draws: Any
                    ) -> tuple[InitialCondition, int]:
    """The initial condition (parsed from text) and the number of draws, checked once.

    Raises
    ------
    ParameterError
        An initial condition that does not parse, or ``n_draws`` not an integer >= 1.
    """
    if isinstance(initial, str):
        initial = InitialCondition.parse(initial)
    elif initial is None:
        initial = InitialCondition()
    elif not isinstance(initial, InitialCondition):
        raise ParameterError(f"initial: expected an InitialCondition or its text form, got "
                             f"{type(initial).__name__}")
    if isinstance(n_draws, bool) or not isinstance(n_draws, int | np.integer) or n_draws < 1:
        raise ParameterError(f"n_draws: expected an integer >= 1, got {n_draws!r}")
    return initial, int(n_draws)
