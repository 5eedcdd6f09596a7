"""A fit checked on records it never saw: the posterior predictive in free run.

The first thing anyone in system identification does with a fitted model is simulate
it on another record and compare. :func:`predict` does that for a parametric posterior
(a :class:`~bayeshyst.inference.saved.SavedFit`, a
:class:`~bayeshyst.inference.fit.FitResult`, or a :class:`Posterior` with draws) and
for any :class:`~bayeshyst.inference.protocols.Predictor` (the GP):

* every draw's noise-free simulation of the new record's **input alone** (free run: no
  measured output is fed back), with the fit's offset and discrepancy weights; the
  posterior predictive adds the fit's observation noise to each draw;
* the **initial state** is a choice, stated in the result (:class:`InitialCondition`):
  relaxed at the first sample (what the fit itself does), at rest (relaxed at zero
  input before the first sample), a warm-up span simulated and not scored, or periodic
  steady state (the record, whole periods of a periodic input, played several times
  and the last scored);
* scores per record, per excitation frequency (or band, for broadband records) and
  overall (:class:`PredictionScore`): RMSE, NRMSE, the identification "fit" percentage
  ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``, the largest error, the coverage of the
  central 50 % and 90 % predictive bands with the range a calibrated predictive gives
  (binomial on the effective number of independent samples, as the fit's own
  calibration check, :mod:`bayeshyst.inference.calibration`) and the PIT histogram.

The new records must be in the units of the fitted data; :func:`predict` converts
those that are not (:func:`bayeshyst.data.units.convert_units`) or refuses them in words.
An input outside the range the fit saw is a warning with the share of samples outside.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import special

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.groups import Band
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ModelError, ParameterError, SimulationError
from bayeshyst.inference.calibration import pit_values
from bayeshyst.inference.error_spectrum import SpectrumBand, band_spectra
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.predictive import (
    QUANTILES,
    InitialCondition,
    PredictionResult,
    PredictionScore,
    RecordPrediction,
    checked_request,
    score_records,
)
from bayeshyst.inference.protocols import Predictor
from bayeshyst.tables import TableRecord, frame

if TYPE_CHECKING:  # fit.py imports this module: the annotation only
    from bayeshyst.inference.fit import FitResult

__all__ = ["FULL_RATE_DRAWS", "FullRateCheck", "InitialCondition", "PredictionResult",
           "PredictionScore", "RecordPrediction", "check_at_full_rate", "checked_request",
           "predict", "predict_posterior", "predict_predictor"]

#: a periodic prediction whose last two periods differ by more than this share of the
#: median predictive standard deviation has not reached its steady state: the change
#: would shift the bands by a visible fraction of their width
STEADY_STATE_SHARE = 0.1

# ------------------------------------------------------------------------ computation


def _records(data: Dataset | Record) -> list[Record]:
    if isinstance(data, Record):
        return [data]
    if isinstance(data, Dataset):
        return list(data)
    raise DataError(f"data: expected a Dataset or a Record, found {type(data).__name__}")


def _in_units(records: list[Record], units: Mapping[str, str], notes: list[str]
              ) -> list[Record]:
    """The records in the fit's units: converted where they differ, else refused."""
    out = []
    for rec in records:
        if not rec.measured_output and "y" in units:
            # an input alone: its output is the model's, in the fit's unit
            rec = rec.with_(units={**rec.units, "y": units["y"]})
        target = {k: units[k] for k in ("t", "u", "y") if k in units}
        given = {k: rec.units.get(k) for k in target}
        if given == target:
            out.append(rec)
            continue
        from bayeshyst.data.units import convert_units  # the data layer's one converter

        out.append(convert_units(rec, target))
        changed = ", ".join(f"{k} {given[k]} -> {target[k]}" for k in target
                            if given[k] != target[k])
        notes.append(f"record {rec.name!r} converted to the fit's units ({changed})")
    return out


def _check_whole_periods(rec: Record) -> None:
    """Refuse a record that is not whole periods of its input (periodic prediction)."""
    u = rec.u
    steps = np.diff(u)
    if rec.frequency_hz is not None:
        per_period = 1.0 / (rec.frequency_hz * rec.dt)  # samples per period
        periods = rec.n / per_period
        if abs(periods - round(periods)) * per_period > 1.0 or round(periods) < 1:
            raise DataError(f"record {rec.name!r}: periodic prediction needs whole periods of "
                            f"the input; it holds {periods:.3f} periods of "
                            f"{rec.frequency_hz:g} Hz ({rec.n} samples, "
                            f"{per_period:.2f} per period). Trim it to whole periods or "
                            "choose another initial condition")
        return
    # without a frequency: the record played twice must join seamlessly, i.e. its last
    # sample must lead into its first like any other pair of samples (in value and in
    # slope); a record cut mid-period has a jump or a kink there
    jump = abs(u[0] - u[-1])
    # the change of slope at both samples next to the seam (a sine cut after half a
    # period joins without a jump and bends at its first sample)
    kink = max(abs((u[0] - u[-1]) - (u[-1] - u[-2])), abs((u[1] - u[0]) - (u[0] - u[-1])))
    tol = 1.5 * float(np.max(np.abs(steps))) if steps.size else 0.0
    tol2 = 1.5 * float(np.max(np.abs(np.diff(steps)))) if steps.size > 1 else 0.0
    if jump > tol or kink > tol2:
        raise DataError(f"record {rec.name!r}: periodic prediction needs whole periods of the "
                        f"input, but its last sample does not lead into its first (step "
                        f"{jump:.4g} against steps up to {tol / 1.5:.4g}, change of slope "
                        f"{kink:.4g} against up to {tol2 / 1.5:.4g}). Trim it to whole periods "
                        "or choose another initial condition")


def _extended(rec: Record, initial: InitialCondition) -> tuple[Record, slice]:
    """The record the model runs on, and where the given record lies in it."""
    n = rec.n
    if initial.kind in ("relaxed", "warmup"):
        return rec, slice(0, n)
    cov = dict(rec.covariates)
    if initial.kind == "rest":
        # the stage at rest before the record: zero input one sample before the first
        t = np.concatenate([[rec.t[0] - rec.dt], rec.t])
        u = np.concatenate([[0.0], rec.u])
        y = np.concatenate([[rec.y[0]], rec.y])
        cov = {k: np.concatenate([[v[0]], v]) for k, v in cov.items()}
        return Record(t, u, y, metadata=dict(rec.metadata), units=dict(rec.units),
                      name=rec.name, covariates=cov), slice(1, n + 1)
    _check_whole_periods(rec)
    k = int(initial.periods)
    period = rec.duration + rec.dt
    t = np.concatenate([rec.t + j * period for j in range(k)])
    tile = {k_: np.tile(v, k) for k_, v in cov.items()}
    return (Record(t, np.tile(rec.u, k), np.tile(rec.y, k), metadata=dict(rec.metadata),
                   units=dict(rec.units), name=rec.name, covariates=tile),
            slice((k - 1) * n, k * n))


def _scored(rec: Record, initial: InitialCondition) -> np.ndarray:
    mask = np.zeros(rec.n, dtype=bool)
    if initial.kind == "periodic":
        mask[:] = True  # the earlier periods are the warm-up
    else:
        mask[rec.warmup:] = True
        if initial.kind == "warmup":
            mask &= rec.t >= rec.t[0] + initial.warmup_s
    if mask.sum() < 2:
        raise DataError(f"record {rec.name!r}: {int(mask.sum())} sample(s) left to score after "
                        f"the warm-up ({initial.describe()}); expected at least 2")
    return mask


def _input_range(fit_data: Dataset | None) -> tuple[float, float] | None:
    if fit_data is None:
        return None
    return (min(float(r.u.min()) for r in fit_data), max(float(r.u.max()) for r in fit_data))


def _outside(rec: Record, scored: np.ndarray, lim: tuple[float, float] | None) -> float:
    if lim is None:
        return 0.0
    u = rec.u[scored]
    return float(np.mean((u < lim[0]) | (u > lim[1])))


def _measured(rec: Record, pit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The measured output and its PIT, both NaN for an input read alone."""
    if rec.measured_output:
        return rec.y, pit
    return np.full(rec.n, np.nan), np.full(rec.n, np.nan)


def _spectra(records: list[Record], preds: list[RecordPrediction]
             ) -> tuple[tuple[Band, tuple[SpectrumBand, ...]], ...]:
    """The error spectra of the band groups, over each record's scored samples."""
    scored, means = [], []
    for r, p in zip(records, preds, strict=True):
        if not p.measured:
            continue
        first = int(np.argmax(p.scored))  # the scored samples run from here to the end
        scored.append(r if first == r.warmup else r.with_(warmup=first))
        means.append(p.mean)
    return band_spectra(scored, means)


def _finish(model: str, source: str, initial: InitialCondition, records: list[Record],
            preds: list[RecordPrediction], n_draws: int, units: Mapping[str, str],
            method: str, lim: tuple[float, float] | None, steady: float | None,
            steady_limit: float | None, warnings: list[str], notes: list[str]
            ) -> PredictionResult:
    """Scores per record, group and overall, and the warnings every path gives."""
    u_unit = units.get("u", "")
    for p in preds:
        if p.outside_input > 0 and lim is not None:
            warnings.append(f"record {p.name!r}: {100 * p.outside_input:.1f} % of the scored "
                            f"samples have an input outside the range the fit saw "
                            f"({lim[0]:.4g} to {lim[1]:.4g} {u_unit}): the model extrapolates")
        if p.n_failed:
            warnings.append(f"record {p.name!r}: {p.n_failed} of {n_draws} draws' simulations "
                            "failed and were left out")
    if steady is not None and steady_limit is not None and steady > steady_limit:
        warnings.append(f"periodic steady state not reached after {initial.periods} periods: "
                        f"the last two differ by up to {steady:.4g} {units.get('y', '')} "
                        f"(more than {STEADY_STATE_SHARE:g} of the median predictive sd); "
                        "use more periods")
    measured = [p for p in preds if p.measured]
    per_record = tuple(score_records("record", p.name, [p]) for p in measured)
    groups: dict[str, list[RecordPrediction]] = {}
    for p in measured:
        groups.setdefault(p.group, []).append(p)
    per_group = tuple(score_records("group", g, ps) for g, ps in groups.items())
    overall = score_records("all", "all", measured) if measured else None
    # the groups when there are several, else the whole: one warning per miscalibration
    for s in per_group if len(groups) > 1 else (() if overall is None else (overall,)):
        if not s.calibrated:
            warnings.append(f"{s.name}: the predictive bands are not calibrated on these "
                            "records: " + ", ".join(
                                f"{int(100 * p)} % band covers {100 * c:.1f} % (a calibrated "
                                f"one {100 * s.expected_range[p][0]:.0f}-"
                                f"{100 * s.expected_range[p][1]:.0f} %)"
                                for p, c in s.coverage.items()))
    return PredictionResult(model, source, initial, tuple(preds), per_record, per_group,
                            overall, n_draws, {k: str(units.get(k, "")) for k in "tuy"},
                            method, steady, tuple(warnings), tuple(notes),
                            _spectra(records, preds))


def predict_posterior(posterior: Posterior, z: np.ndarray, data: Dataset | Record, *,
                      initial: InitialCondition | None = None, seed: int = 0,
                      source: str = "posterior", warnings: Sequence[str] = ()
                      ) -> PredictionResult:
    """The posterior predictive of draws ``z`` on ``data``, scored (see the module).

    Parameters
    ----------
    posterior : Posterior
        The fitted posterior (model, offset, discrepancy, noise).
    z : ndarray, shape (S, ndim)
        Its draws.
    data : Dataset or Record
        Records with measured outputs; converted to the fitted data's units.
    initial : InitialCondition, optional
        Default relaxed at each record's first input.
    seed : int
        Seeds the noise draws and the PIT's tie-breaking.
    source : str
        Said in the result.
    warnings : sequence of str
        Carried into the result (e.g. the fit did not converge).

    Returns
    -------
    PredictionResult

    Raises
    ------
    DataError
        A record in units that do not convert, without whole periods (periodic), with
        fewer than two samples to score, lacking a channel the model reads, or whose
        simulation failed for every draw.
    """
    initial = initial or InitialCondition()
    z = np.atleast_2d(np.asarray(z, dtype=float))
    notes: list[str] = []
    units = dict(posterior.data[0].units)
    records = _in_units(_records(data), units, notes)
    runs = [_extended(r, initial) for r in records]
    sims = posterior.predict_records(z, [ext for ext, _ in runs])
    rng = np.random.default_rng(seed)
    kept, reps = [], []
    for rec, (_, keep), s in zip(records, runs, sims, strict=True):
        ok = np.all(np.isfinite(s[:, keep]), axis=1)
        if not ok.any():
            raise DataError(f"record {rec.name!r}: the simulation failed for every one of the "
                            f"{z.shape[0]} draws")
        kept.append(ok)
        # every record's noise first, in record order: the same draws as the fit's own
        # posterior predictive (calibration.predictive_draws) on the fitted records
        reps.append(s[ok][:, keep] + posterior.noise_draws(z[ok], rec.n, rng))
    lim = _input_range(posterior.data)
    preds: list[RecordPrediction] = []
    steady, steady_limit = None, None
    for rec, (_, keep), s, ok, y_rep in zip(records, runs, sims, kept, reps, strict=True):
        scored = _scored(rec, initial)
        good = s[ok][:, keep]
        pit = pit_values(rec.y, y_rep, rng)
        pit[~scored] = np.nan
        y, pit = _measured(rec, pit)
        preds.append(RecordPrediction(
            rec.name, rec.group, rec.t, rec.u, y, scored, good.mean(axis=0), good.std(axis=0),
            np.quantile(y_rep, QUANTILES, axis=0), pit, int(np.count_nonzero(~ok)),
            _outside(rec, scored, lim), rec.measured_output))
        if initial.kind == "periodic":
            before = s[ok][:, keep.start - rec.n:keep.start].mean(axis=0)
            change = float(np.max(np.abs(before - preds[-1].mean)))
            limit = STEADY_STATE_SHARE * float(np.median(y_rep.std(axis=0)))
            steady = change if steady is None else max(steady, change)
            steady_limit = limit if steady_limit is None else min(steady_limit, limit)
    method = (f"{z.shape[0]} posterior draws simulated, {posterior.likelihood.name} noise "
              "added to each")
    return _finish(posterior.model.name, source, initial, records, preds, int(z.shape[0]),
                   units, method, lim, steady, steady_limit, list(warnings), notes)


def predict_predictor(predictor: Predictor, data: Dataset | Record, *,
                      fit_data: Dataset | None = None, model: str = "predictor",
                      initial: InitialCondition | None = None, source: str = "predictor",
                      warnings: Sequence[str] = ()) -> PredictionResult:
    """The predictive of any :class:`Predictor` (the GP) on ``data``, scored.

    The predictor gives a mean, a latent sd and a noise sd per sample; the bands and
    the PIT are those of the Gaussian with that mean and the total variance.

    Parameters
    ----------
    predictor : Predictor
    data : Dataset or Record
    fit_data : Dataset, optional
        The data it was fitted to: their units are the target units, their input range
        is checked. Default: the records' own units, no range check.
    model : str
        Its name, said in the result.
    initial : InitialCondition, optional
        ``"rest"`` is refused (a predictor has no state to set); the others as for
        :func:`predict_posterior`.
    source : str
    warnings : sequence of str

    Returns
    -------
    PredictionResult
    """
    initial = initial or InitialCondition()
    if initial.kind == "rest":
        raise ParameterError(f"initial condition 'rest': {model} exposes no state to set at "
                             "rest; use relaxed, warmup or periodic")
    notes: list[str] = []
    records = _records(data)
    if fit_data is not None:
        units = dict(fit_data[0].units)
        records = _in_units(records, units, notes)
    else:
        units = dict(records[0].units)
        notes.append("the fitted data were not given: units taken as they are, the input "
                     "range not checked")
    runs = [_extended(r, initial) for r in records]
    ext = Dataset([e for e, _ in runs], name="predict")
    out = predictor.predict_records(ext)
    lim = _input_range(fit_data)
    preds: list[RecordPrediction] = []
    steady, steady_limit = None, None
    for rec, (_, keep), p in zip(records, runs, out, strict=True):
        scored = _scored(rec, initial)
        mean, sd = np.asarray(p.mean, float)[keep], np.asarray(p.std, float)[keep]
        total = np.sqrt(sd**2 + float(p.noise_std) ** 2)
        bands = mean[None, :] + special.ndtri(np.asarray(QUANTILES))[:, None] * total[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            pit = special.ndtr((rec.y - mean) / total)
        pit[~scored] = np.nan
        y, pit = _measured(rec, pit)
        preds.append(RecordPrediction(rec.name, rec.group, rec.t, rec.u, y, scored, mean, sd,
                                      bands, pit, 0, _outside(rec, scored, lim),
                                      rec.measured_output))
        if initial.kind == "periodic":
            before = np.asarray(p.mean, float)[keep.start - rec.n:keep.start]
            steady = max(steady or 0.0, float(np.max(np.abs(before - mean))))
            limit = STEADY_STATE_SHARE * float(np.median(total))
            steady_limit = limit if steady_limit is None else min(steady_limit, limit)
    return _finish(model, source, initial, records, preds, 0, units,
                   "Gaussian predictive from the predictor's mean, latent and noise sd", lim,
                   steady, steady_limit, list(warnings), notes)


def predict(fit: Any, data: Dataset | Record, *, initial: InitialCondition | str | None = None,
            n_draws: int = 400, seed: int = 0) -> PredictionResult:
    """The posterior predictive of a fit on records it may never have seen, scored.

    Parameters
    ----------
    fit : SavedFit, FitResult, Predictor, or path
        A saved fit (or the path of one, :func:`bayeshyst.inference.saved.load_fit`), a
        fit in memory, or any :class:`Predictor` (the GP).
    data : Dataset or Record
        Records with their measured outputs.
    initial : InitialCondition or str, optional
        How each record's initial state is set (:class:`InitialCondition`, or its text
        form ``"periodic:3"``); default relaxed at the first input.
    n_draws : int
        Posterior draws simulated (at most the stored ones).
    seed : int
        Seeds the choice of draws, the noise and the PIT.

    Returns
    -------
    PredictionResult
    """
    from pathlib import Path

    from bayeshyst.inference.fit import FitResult
    from bayeshyst.inference.saved import SavedFit, load_fit

    initial, n_draws = checked_request(initial, n_draws)
    if isinstance(fit, str | Path):
        fit = load_fit(fit)
    if isinstance(fit, SavedFit):
        return fit.predict(data, initial=initial, n_draws=n_draws, seed=seed)
    if isinstance(fit, FitResult):
        return fit.predict(data, initial=initial, n_draws=n_draws, seed=seed)
    if isinstance(fit, Predictor):
        return predict_predictor(fit, data, initial=initial, model=type(fit).__name__,
                                 source=type(fit).__name__)
    raise ParameterError(f"fit: expected a SavedFit, a FitResult, a Predictor or the path of a "
                         f"saved fit, got {type(fit).__name__}")


# ---------------------------------------------------------------- at the full rate
#: posterior draws :func:`check_at_full_rate` scores a fit with by default
FULL_RATE_DRAWS = 100


@dataclass(frozen=True)
class FullRateCheck(TableRecord):
    """A fit made at a working rate, scored on the records at their full rate.

    The working rate (:func:`bayeshyst.data.working_rate.to_working_rate`) is a choice
    of the fit; the full-rate records are what was measured. :func:`check_at_full_rate`
    makes this record.

    Attributes
    ----------
    model : str
        The fitted model's name.
    n_draws : int
        Posterior draws each prediction simulated.
    rmse_working_rate, rmse_full_rate : float or None
        Free-run posterior-predictive RMSE on the working-rate and the full-rate records
        [unit of the output ``y``]; None when not scored.
    rmse_fit : float or None
        The fit's own RMSE (posterior mean, on the data it was fitted to) [unit of ``y``].
    n_scored_working_rate, n_scored_full_rate : int
        Samples scored at each rate (warm-up left out).
    error : str or None
        Why the fit was not scored (a failed prediction, no measured output); the
        numbers are None then.
    """

    model: str
    n_draws: int
    rmse_working_rate: float | None = None
    rmse_full_rate: float | None = None
    rmse_fit: float | None = None
    n_scored_working_rate: int = 0
    n_scored_full_rate: int = 0
    error: str | None = None

    #: how both RMSEs were computed (the same for each: they differ only by the rate)
    METHOD = ("posterior predictive in free run (FitResult.predict), relaxed at the first "
              "sample, warm-up not scored")

    def __str__(self) -> str:
        if self.error is not None:
            return self.error
        return (f"{self.model} scored at full rate: RMSE {self.rmse_full_rate:.4g} (working "
                f"rate {self.rmse_working_rate:.4g}; the fit's own {self.rmse_fit:.4g})")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``{"error"}`` alone when not scored, else the numbers and ``method``."""
        if self.error is not None:
            return {"error": self.error}
        return {"model": self.model, "n_draws": self.n_draws,
                "rmse_working_rate": self.rmse_working_rate,
                "rmse_full_rate": self.rmse_full_rate, "rmse_fit": self.rmse_fit,
                "n_scored_working_rate": self.n_scored_working_rate,
                "n_scored_full_rate": self.n_scored_full_rate, "method": self.METHOD}

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])


def check_at_full_rate(fit: FitResult, full: Dataset, working: Dataset, *,
                       n_draws: int = FULL_RATE_DRAWS, seed: int = 0) -> FullRateCheck:
    """A fit's free-run predictive RMSE on the full-rate and on the working-rate records.

    Both with :meth:`~bayeshyst.inference.fit.FitResult.predict` (the same draws, relaxed
    at the first sample, warm-up not scored), so the two numbers differ only by the rate;
    the fit's own posterior-mean RMSE is beside them.

    Parameters
    ----------
    fit : FitResult
        A fit made on ``working``.
    full : Dataset
        The records at their full rate, with their measured outputs.
    working : Dataset
        The same records at their working rate (what ``fit`` was fitted to).
    n_draws : int, default :data:`FULL_RATE_DRAWS`
        Posterior draws simulated for each prediction.
    seed : int, default 0
        Seeds the choice of draws, the noise and the PIT (the same for both rates).

    Returns
    -------
    FullRateCheck
        An error of the prediction (bad data, parameters, model or a failed simulation)
        is a record saying so, with no numbers: what the fit found stands without it.
    """
    model = fit.model.name
    try:
        at_full = fit.predict(full, n_draws=n_draws, seed=seed)
        at_working = fit.predict(working, n_draws=n_draws, seed=seed)
    except (DataError, ParameterError, ModelError, SimulationError) as exc:
        return FullRateCheck(model, n_draws,
                             error=f"the fit could not be scored at full rate: {exc}")
    if at_full.overall is None or at_working.overall is None:
        return FullRateCheck(model, n_draws, error="no measured output to score at full rate")
    return FullRateCheck(model, n_draws, rmse_working_rate=at_working.overall.rmse,
                         rmse_full_rate=at_full.overall.rmse, rmse_fit=fit.overall.rmse,
                         n_scored_working_rate=int(sum(r.n_scored for r in working)),
                         n_scored_full_rate=int(sum(r.n_scored for r in full)))
