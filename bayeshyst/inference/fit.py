"""One call from data to a checked posterior: :func:`fit_model` and its :class:`FitResult`.

``fit_model`` builds the :class:`Posterior`, finds the MAP, samples with
:func:`sample_posterior`, and measures how well the posterior-mean prediction tracks
the measurement — overall and per excitation frequency, as users report it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.discrepancy import Discrepancy
from bayeshyst.inference.calibration import (
    Calibration,
    FrequencyBudget,
    check_calibration,
    uncertainty_budget,
)
from bayeshyst.inference.discrepancy_fit import DiscrepancyScales, attach_discrepancy
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.predict import (
    InitialCondition,
    PredictionResult,
    checked_request,
    predict_posterior,
)
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.sampling_result import SamplingResult
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.likelihoods import Likelihood
from bayeshyst.models.base import HysteresisModel
from bayeshyst.params import ParamSpace
from bayeshyst.tables import TableRecord, frame
from bayeshyst.threads import with_single_threaded_blas

__all__ = [
    "FitResult", "TrackingError", "calibrate_fit", "errors_by_frequency", "fit_model",
    "tracking_errors",
]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackingError:
    """Error of the posterior-mean prediction on the scored samples.

    Attributes
    ----------
    frequency_hz : float or None
        ``None`` for the whole dataset (or records without a frequency).
    rmse, max_error : float
        Root-mean-square and largest absolute error (output unit).
    nrmse_percent, max_error_percent : float
        The same in per cent of the measured peak-to-peak output of that group.
    n_samples : int
    """

    frequency_hz: float | None
    rmse: float
    max_error: float
    nrmse_percent: float
    max_error_percent: float
    n_samples: int

    def __str__(self) -> str:
        f = "all" if self.frequency_hz is None else f"{self.frequency_hz:g} Hz"
        return (f"{f:>10}: RMSE {self.rmse:.4g} ({self.nrmse_percent:.3f} %), max "
                f"{self.max_error:.4g} ({self.max_error_percent:.3f} %), n={self.n_samples}")


def _errors(freq: float | None, measured: np.ndarray, predicted: np.ndarray) -> TrackingError:
    e = measured - predicted
    ptp = float(np.ptp(measured)) or math.nan
    rmse = float(np.sqrt(np.mean(e**2)))
    mx = float(np.max(np.abs(e)))
    return TrackingError(freq, rmse, mx, 100 * rmse / ptp, 100 * mx / ptp, int(e.size))


def errors_by_frequency(
    data: Dataset, predictions: list[np.ndarray]
) -> tuple[TrackingError, list[TrackingError]]:
    """Errors of one prediction per record, overall and per excitation frequency.

    Parameters
    ----------
    data : Dataset
        The measured records.
    predictions : list of ndarray, each (N_record,)
        Full-record predictions (warm-up included; only scored samples count).

    Returns
    -------
    overall : TrackingError
    per_frequency : list of TrackingError
        Sorted by frequency; records without a frequency are grouped under ``None``,
        last.
    """
    groups: dict[float | None, tuple[list, list]] = {}
    all_m, all_p = [], []
    for rec, pred in zip(data, predictions, strict=True):
        s0 = rec.scored.start or 0
        groups.setdefault(rec.frequency_hz, ([], []))
        groups[rec.frequency_hz][0].append(rec.y[s0:])
        groups[rec.frequency_hz][1].append(pred[s0:])
        all_m.append(rec.y[s0:])
        all_p.append(pred[s0:])
    overall = _errors(None, np.concatenate(all_m), np.concatenate(all_p))
    keys = sorted(k for k in groups if k is not None) + ([None] if None in groups else [])
    per = [_errors(k, np.concatenate(groups[k][0]), np.concatenate(groups[k][1])) for k in keys]
    return overall, per


def tracking_errors(
    post: Posterior, z: np.ndarray, predictions: list[np.ndarray] | None = None
) -> tuple[TrackingError, list[TrackingError], list[np.ndarray]]:
    """Errors of the mean noise-free prediction over draws ``z`` (M, ndim).

    Returns the overall error, one per excitation frequency (sorted; records without
    a frequency are grouped under ``None`` last), and the mean prediction per record.
    Failed draws (NaN rows) are left out of the mean. ``predictions`` (per record,
    (M, N)) are ``post.predict(z)`` when the caller has them already.
    """
    preds = post.predict(z) if predictions is None else predictions
    means = [np.nanmean(p, axis=0) for p in preds]
    overall, per = errors_by_frequency(post.data, means)
    return overall, per, means


@dataclass(frozen=True)
class FitResult(TableRecord):
    """A fitted posterior with its tracking errors: the one fit record.

    :func:`fit_model` returns it; a diagnosis fit (:class:`~bayeshyst.diagnosis.DiagnosisFit`)
    holds one with its residual analysis; the compensation designs from one; the writers
    write one. What a caller scored or saved on top of sampling travels with it.

    Attributes
    ----------
    posterior : Posterior
    sampling : SamplingResult
    overall : TrackingError
        Of the posterior-mean prediction over all scored samples.
    per_frequency : list of TrackingError
    mean_prediction : list of ndarray, each shape (N_record,)
        Posterior-mean noise-free prediction per record (full records, output units).
    pointwise_elpd : ndarray, shape (n_cycles,), optional
        Cycle-wise leave-one-cycle-out elpd (nats), when the fit was scored.
    warnings : tuple of str
        What the fitting code noticed (non-convergence, failed simulations, LOO notes).
    idata : arviz.InferenceData, optional
        The thinned posterior with its log-likelihood, when one was built.
    discrepancy_scales : DiscrepancyScales, optional
        The model discrepancy's fixed scales, when the fit has one.
    calibration : Calibration, optional
        The leave-cycles-out calibration check, when it was run.
    budget : tuple of FrequencyBudget
        The predictive variance split into noise, parameters and discrepancy, per
        excitation frequency.
    """

    posterior: Posterior
    sampling: SamplingResult
    overall: TrackingError
    per_frequency: list[TrackingError]
    mean_prediction: list[np.ndarray]
    pointwise_elpd: np.ndarray | None = field(default=None, repr=False)
    warnings: tuple[str, ...] = ()
    idata: Any = field(default=None, repr=False)
    discrepancy_scales: DiscrepancyScales | None = field(default=None, repr=False)
    calibration: Calibration | None = field(default=None, repr=False)
    budget: tuple[FrequencyBudget, ...] = field(default=(), repr=False)

    @property
    def model(self) -> HysteresisModel:
        """The fitted model."""
        return self.posterior.model

    @property
    def likelihood(self) -> str:
        """The likelihood's name (``"gaussian"``, ``"ar1"``, ...)."""
        return self.posterior.likelihood.name

    @property
    def converged(self) -> bool:
        """Whether the sampler's convergence criteria all held."""
        return self.sampling.converged

    @property
    def elpd(self) -> float:
        """Summed cycle-wise elpd (NaN when the fit was not scored)."""
        return math.nan if self.pointwise_elpd is None else float(np.sum(self.pointwise_elpd))

    def predict(self, data: Dataset | Record, *, initial: InitialCondition | str | None = None,
                n_draws: int = 400, seed: int = 0) -> PredictionResult:
        """The posterior predictive on ``data`` in free run, scored against its outputs.

        See :func:`bayeshyst.inference.predict.predict_posterior`; the parameters are
        those of :meth:`bayeshyst.inference.saved.SavedFit.predict`. The draws are
        :meth:`SamplingResult.draws` ``(n_draws, seed=seed)``; a fit that did not converge
        says so in the result's warnings.
        """
        initial, n_draws = checked_request(initial, n_draws)
        warnings = () if self.converged else (
            "the fit did NOT converge: " + "; ".join(self.sampling.convergence.reasons),)
        return predict_posterior(self.posterior, self.sampling.draws(int(n_draws), seed=seed),
                                 data, initial=initial, seed=seed, source="fit",
                                 warnings=warnings)

    def to_dataframe(self, prob: float = 0.9) -> Any:
        """One row per scalar parameter: mean, sd and the ``prob`` HDI, with its unit."""
        return frame([{"parameter": p.label, "mean": p.mean, "sd": p.sd,
                       f"hdi_{round(100 * (1 - prob) / 2)}": p.hdi_lo,
                       f"hdi_{round(100 * (1 + prob) / 2)}": p.hdi_hi, "unit": p.unit}
                      for p in self.sampling.summary(prob)])

    def __str__(self) -> str:
        lines = [str(self.sampling), "tracking error of the posterior mean:", str(self.overall)]
        lines += [str(e) for e in self.per_frequency if e.frequency_hz is not None]
        if self.budget:
            lines += ["uncertainty budget of the predictive:", *[str(b) for b in self.budget]]
        if self.calibration is not None:
            lines.append(str(self.calibration))
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


@with_single_threaded_blas
def fit_model(
    data: Dataset | Record,
    model: HysteresisModel | str,
    likelihood: Likelihood | str = "gaussian",
    *,
    sampler: SamplerSettings | None = None,
    n_prediction_draws: int = 200,
    space: ParamSpace | None = None,
    offset: bool | None = None,
    discrepancy: str | Discrepancy | None = None,
    calibration: bool = False,
) -> FitResult:
    """Posterior of ``model`` given ``data``, sampled to convergence (or the budget).

    Parameters
    ----------
    data : Dataset or Record
    model : HysteresisModel or str
        Model or spec string (``"bouc_wen+second_order"``).
    likelihood : Likelihood or str
        ``"gaussian"``, ``"student_t"`` or ``"ar1"``.
    sampler : SamplerSettings, optional
        Moves, walkers, budget, convergence criteria, seed, checkpoint, progress
        (default :class:`SamplerSettings`). Same seed, same result.
    n_prediction_draws : int
        Posterior draws averaged for the mean prediction and its errors.
    space, offset, discrepancy
        As :class:`Posterior` (edited priors; observation offset on/off; a model
        discrepancy ``"hsgp"`` or none).
    calibration : bool
        Run the leave-cycles-out calibration check
        (:func:`~bayeshyst.inference.calibration.check_calibration`: one more posterior
        run without the last cycle of every record). The CLI always does.
    """
    sampler = SamplerSettings() if sampler is None else sampler
    post = Posterior(data, model, likelihood, space=space, offset=offset)
    _log.info("fitting %s (%s likelihood, %d parameters) to %s", post.model.name,
              post.likelihood.name, post.ndim, post.data.name)
    scales = start = None
    if discrepancy is not None and discrepancy != "none":
        # anchored at the MAP without it, its scales by held-out prediction, then fixed
        start = find_map(post, seed=np.random.default_rng(sampler.seed))
        post, scales, start = attach_discrepancy(post, start, discrepancy)
    res = sample_posterior(post, sampler, start=start)
    z = res.draws(n_prediction_draws, seed=sampler.seed)
    # one simulation of the draws serves the errors (model + discrepancy) and the budget
    # (the two apart)
    model_preds, deltas = post.predict(z, discrepancy=False), post.discrepancy_draws(z)
    preds = (model_preds if deltas is None
             else [f + d for f, d in zip(model_preds, deltas, strict=True)])
    overall, per, means = tracking_errors(post, z, preds)
    budget = uncertainty_budget(post, z, parts=(model_preds, deltas))
    fit = FitResult(post, res, overall, per, means, discrepancy_scales=scales,
                    budget=tuple(budget))
    _log.info("%s: %s after %d steps in %.1f s; RMSE %.4g", post.model.name,
              "converged" if res.converged else "NOT converged", res.convergence.n_steps,
              res.runtime_s, overall.rmse)
    return calibrate_fit(fit, sampler, n_draws=4 * n_prediction_draws) if calibration else fit


def calibrate_fit(fit: FitResult, sampler: SamplerSettings | None = None, *,
                  n_draws: int = 800) -> FitResult:
    """``fit`` with its leave-cycles-out calibration check run (and its warnings added).

    Parameters
    ----------
    fit : FitResult
    sampler : SamplerSettings, optional
        How the check's posterior (without the last cycle of every record) is sampled;
        default :class:`SamplerSettings`. Its seed also seeds the predictive draws.
    n_draws : int
        Draws of ``fit``'s posterior the check starts its walkers around.

    Returns
    -------
    FitResult
        The same fit with ``calibration`` set
        (:func:`~bayeshyst.inference.calibration.check_calibration`).
    """
    sampler = SamplerSettings() if sampler is None else sampler
    res = fit.sampling
    check = check_calibration(fit.posterior, res.draws(n_draws, seed=sampler.seed), sampler,
                              start=res.start)
    return replace(fit, calibration=check, warnings=(*fit.warnings, *check.warnings))
