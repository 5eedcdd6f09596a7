"""What a sampler needs from a density, and what a fitted model offers for scoring.

Two small protocols, so that code asks an object what it can do instead of testing
which model it is:

* :class:`SamplingTarget` -- what :func:`~bayeshyst.inference.sampling.sample_posterior`
  (and :func:`~bayeshyst.inference.optimize.find_map`, should a run restart) reads from
  its ``post`` argument. :class:`~bayeshyst.inference.posterior.Posterior` satisfies it,
  and so does the GP's log-hyperparameter posterior
  (:class:`bayeshyst.gp.hyperparameters.HyperparameterTarget`), which is therefore
  sampled by the same ensembles, moves and convergence criteria as every model.
* :class:`Predictor` -- a fitted model that predicts records (mean and standard
  deviation in output units) and scores cycles: the log predictive density of held-out
  data and leave-one-cycle-out. The GP (:class:`bayeshyst.gp.GPHysteresis`) and a
  sampled parametric posterior (:class:`~bayeshyst.selection.predictor.ParametricPredictor`)
  both satisfy it.

with the records they return: :class:`Prediction` (one record) and
:class:`UnitLogDensity` (per cycle, per draw).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.inference.posterior import EvalCounts, Unit
from bayeshyst.params import ParamSpace

__all__ = ["Prediction", "Predictor", "SamplingTarget", "UnitLogDensity"]


@runtime_checkable
class SamplingTarget(Protocol):
    """A log density over an unconstrained vector ``z`` that the sampler can run on.

    Attributes
    ----------
    space : ParamSpace
        Declared parameters: ``z`` to named values, the prior (with the transforms'
        Jacobians) and its draws.
    ndim : int
        Length of ``z``.
    counts : EvalCounts
        Evaluations so far (the sampling result reports the difference).
    model, likelihood : object
        Each with a ``name`` (str) for the sampling result. A likelihood named
        ``"gaussian"`` or ``"ar1"`` (with ``beta == 1``) tells the sampler to look for
        a linear block, which only a :class:`~bayeshyst.inference.posterior.Posterior`
        has; any other name runs the moves on every coordinate.
    beta : float
        Power of the likelihood (1: the posterior).
    data : iterable of Record
        Hashed into a checkpoint's fingerprint.
    held_out : tuple of int
        Left-out cycles (fingerprint).
    """

    space: ParamSpace
    model: Any
    likelihood: Any
    beta: float
    data: Any
    held_out: tuple[int, ...]

    @property
    def ndim(self) -> int:
        """Length of ``z``."""

    @property
    def counts(self) -> EvalCounts:
        """Evaluation counters."""

    def log_prob_batch(self, z: np.ndarray) -> np.ndarray:
        """Log density (W,) of ``W`` points ``z`` (W, ndim): finite or ``-inf``."""

    def log_prob(self, z: np.ndarray) -> float:
        """Log density of one point ``z`` (ndim,)."""


@dataclass(frozen=True)
class Prediction:
    """Prediction of one record (full length, warm-up included).

    Attributes
    ----------
    name : str
        Record name.
    mean, std : ndarray, shape (n,)
        Predictive mean and latent standard deviation (noise excluded) of the output
        [output unit]; over hyperparameter or parameter draws when there are several
        (mixture: ``std**2`` is the mean of the draws' variances plus the variance of
        their means).
    noise_std : float
        Observation noise standard deviation [output unit]; add ``noise_std**2`` to
        ``std**2`` for the predictive density of a measurement.
    """

    name: str
    mean: np.ndarray
    std: np.ndarray
    noise_std: float

    def __str__(self) -> str:
        return (f"Prediction {self.name!r}: {self.mean.size} samples, mean std "
                f"{float(np.mean(self.std)):.4g}, noise std {self.noise_std:.4g}")


@dataclass(frozen=True)
class UnitLogDensity:
    """Predictive log-density of each cycle (the cross-validation units of the models).

    Attributes
    ----------
    units : tuple of Unit
        From :func:`bayeshyst.inference.posterior.cycle_units`, in record order.
    values : ndarray, shape (n_units,)
        ``log p(y_unit)`` [nats], draws mixed per unit.
    n_samples : ndarray of int, shape (n_units,)
        Scored samples per unit.
    per_draw : ndarray, shape (n_draws, n_units)
        The same per draw (one row for a single point estimate).
    method : str
        ``"free-run"`` (GP), ``"leave-one-cycle-out"`` (GP, exact), ``"posterior
        predictive"`` or ``"PSIS-LOO"`` (parametric).
    covariance : str
        How a unit's samples combine: ``"pointwise"`` (sum of marginal
        log-densities), ``"joint"`` (the GP's joint covariance over the cycle) or
        ``"likelihood"`` (the parametric model's likelihood, e.g. AR(1) noise).
    """

    units: tuple[Unit, ...]
    values: np.ndarray
    n_samples: np.ndarray
    per_draw: np.ndarray
    method: str
    covariance: str

    @property
    def total(self) -> float:
        """Sum over units [nats]."""
        return float(np.sum(self.values))

    def __str__(self) -> str:
        return (f"UnitLogDensity ({self.method}, {self.covariance}, {self.per_draw.shape[0]} "
                f"draw(s)): {len(self.units)} units, total {self.total:.2f} "
                f"nats, {self.total / max(1, int(self.n_samples.sum())):.4f} per sample")


@runtime_checkable
class Predictor(Protocol):
    """A fitted model that predicts records and scores their cycles.

    Every method takes a :class:`~bayeshyst.data.dataset.Dataset` or one
    :class:`~bayeshyst.data.record.Record` and works in the data's output units.
    """

    def predict_records(self, data: Dataset | Record) -> list[Prediction]:
        """Prediction of every record of ``data`` (full length), from its inputs alone."""

    def log_density_units(self, data: Dataset | Record) -> UnitLogDensity:
        """Log predictive density of each cycle of ``data`` given the fitted data.

        ``data`` is held out, or the fitted data themselves (in-sample).
        """

    def loo_units(self, data: Dataset | Record) -> UnitLogDensity:
        """Leave-one-cycle-out log predictive density of each cycle of the fitted data.

        ``data`` must be the data the model was fitted to.
        """
