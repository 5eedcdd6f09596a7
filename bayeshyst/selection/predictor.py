"""A sampled parametric posterior as a :class:`~bayeshyst.inference.protocols.Predictor`.

:class:`ParametricPredictor` wraps a :class:`~bayeshyst.inference.posterior.Posterior`
and the :class:`~bayeshyst.inference.sampling_result.SamplingResult` of its draws and offers
what the GP offers (:class:`bayeshyst.gp.GPHysteresis`): predictions per record with
mean and standard deviation, the log predictive density of each cycle of held-out
data, and leave-one-cycle-out. The numbers are the ones the comparison computes for
parametric models (:mod:`bayeshyst.selection.tasks`): the mean noise-free simulation
over draws, ``log mean_s p(y_c | theta_s)`` per cycle, and PSIS-LOO over cycles
(:func:`bayeshyst.diagnostics.loo`, without the comparison's exact refits of cycles
whose Pareto k is too high).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.diagnostics import loo, to_inference_data
from bayeshyst.errors import DataError
from bayeshyst.inference.posterior import NOISE, Posterior
from bayeshyst.inference.protocols import Prediction, UnitLogDensity
from bayeshyst.inference.sampling_result import SamplingResult

__all__ = ["ParametricPredictor", "noise_variance", "transfer_draws"]


def transfer_draws(train: Posterior, test: Posterior, z: np.ndarray) -> np.ndarray:
    """The points ``z`` (S, train.ndim) of ``train`` in the coordinates of ``test``.

    Both posteriors share the model's parameter space; the noise and offset spaces
    are rebuilt for the test data, so go through the physical values.

    Returns
    -------
    ndarray, shape (S, test.ndim)
    """
    theta = train.space.unpack(z)
    names = test.space.names
    out = np.empty((z.shape[0], test.ndim))
    for i in range(z.shape[0]):
        out[i] = test.space.pack({k: np.asarray(theta[k])[i] for k in names})
    return out


def noise_variance(post: Posterior, z: np.ndarray) -> np.ndarray:
    """Marginal variance of the observation noise at each draw [output unit^2].

    ``sigma^2`` for the Gaussian and the AR(1) likelihood (whose ``sigma`` is the
    marginal standard deviation), ``sigma^2 nu / (nu - 2)`` for Student-t (infinite
    for ``nu <= 2``).

    Parameters
    ----------
    post : Posterior
    z : ndarray, shape (S, ndim)

    Returns
    -------
    ndarray, shape (S,)
    """
    theta = post.space.unpack(np.atleast_2d(z))
    sigma = np.asarray(theta[f"{NOISE}.sigma"], dtype=float).reshape(-1)
    var = sigma**2
    nu_name = f"{NOISE}.nu"
    if nu_name in theta:
        nu = np.asarray(theta[nu_name], dtype=float).reshape(-1)
        with np.errstate(divide="ignore"):
            var = np.where(nu > 2.0, var * nu / np.maximum(nu - 2.0, 1e-300), np.inf)
    return var


def _logmeanexp(ll: np.ndarray) -> np.ndarray:
    """``log mean exp`` over axis 0 (failed draws, ``-inf``, count as zero density)."""
    return logsumexp(ll, axis=0) - math.log(ll.shape[0])


def _dataset(data: Dataset | Record) -> Dataset:
    if isinstance(data, Record):
        return Dataset((data,), name=data.name)
    if isinstance(data, Dataset):
        return data
    raise DataError(f"data: expected a Dataset or a Record, found {type(data).__name__}")


@dataclass(frozen=True)
class ParametricPredictor:
    """A sampled posterior as a :class:`~bayeshyst.inference.protocols.Predictor`.

    Parameters
    ----------
    posterior : Posterior
        The posterior that ``sampling`` sampled (its data are the fitted data).
    sampling : SamplingResult
        Its draws.
    n_draws : int, default 400
        Draws the predictions and held-out densities average over
        (:meth:`SamplingResult.draws`, a deterministic thinning).
    draws_per_chain : int, default 30
        Draws per walker of the PSIS-LOO (:func:`bayeshyst.diagnostics.to_inference_data`).
    seed : int, default 0
        Seeds the thinning.
    """

    posterior: Posterior
    sampling: SamplingResult
    n_draws: int = 400
    draws_per_chain: int = 30
    seed: int = 0

    def _draws(self) -> np.ndarray:
        return self.sampling.draws(self.n_draws, seed=self.seed)

    def _on(self, data: Dataset | Record) -> tuple[Posterior, np.ndarray]:
        """The posterior's model on ``data`` and the draws in its coordinates.

        The model on ``data`` has the same model space and offset.
        """
        post = self.posterior
        test = Posterior(_dataset(data), post.model, post.likelihood, space=post.model_space,
                         offset=post.offset)
        return test, transfer_draws(post, test, self._draws())

    def predict_records(self, data: Dataset | Record) -> list[Prediction]:
        """Mean and sd over draws of every record's noise-free simulation, and the noise sd.

        The simulation includes the offset, and failed draws are left out. The noise's
        marginal standard deviation is the root mean of :func:`noise_variance` over the
        draws.
        """
        # the simulation of :func:`bayeshyst.inference.predict.predict`: the fitted
        # posterior's draws run on the records' inputs (no discrepancy: the physical model)
        post, z, given = self.posterior, self._draws(), _dataset(data)
        noise = float(np.sqrt(np.mean(noise_variance(post, z))))
        out = []
        for rec, sims in zip(given, post.predict_records(z, given, discrepancy=False),
                             strict=True):
            out.append(Prediction(rec.name, np.nanmean(sims, axis=0), np.nanstd(sims, axis=0),
                                  noise))
        return out

    def log_density_units(self, data: Dataset | Record) -> UnitLogDensity:
        """``log mean_s p(y_c | theta_s)`` of every cycle ``c`` of ``data``.

        Each cycle's samples are taken jointly under the likelihood (the unit of the
        comparison's LOFO score, :func:`bayeshyst.selection.tasks.heldout_log_density`).
        """
        test, z = self._on(data)
        per_draw = test.log_likelihood_units(z)
        counts = np.array([u.stop - u.start for u in test.units])
        return UnitLogDensity(tuple(test.units), _logmeanexp(per_draw), counts, per_draw,
                              "posterior predictive", "likelihood")

    def loo_units(self, data: Dataset | Record) -> UnitLogDensity:
        """PSIS-LOO of every cycle of the fitted data (:func:`bayeshyst.diagnostics.loo`).

        Raises
        ------
        DataError
            When ``data`` are not the posterior's data.
        """
        post = self.posterior
        given = _dataset(data)
        if len(given) != len(post.data) or not all(
                a.name == b.name and a.n == b.n and np.array_equal(a.u, b.u)
                and np.array_equal(a.y, b.y) for a, b in zip(given, post.data, strict=True)):
            raise DataError(f"loo_units: data: expected the fitted records "
                            f"{[r.name for r in post.data]}, found {[r.name for r in given]} "
                            f"or different values")
        idata = to_inference_data(post, self.sampling, draws_per_chain=self.draws_per_chain,
                                  n_predictive=1, seed=self.seed)
        res = loo(idata)
        ll = np.asarray(idata.log_likelihood["y"].values, dtype=float)
        counts = np.array([u.stop - u.start for u in post.units])
        return UnitLogDensity(tuple(post.units), np.asarray(res.pointwise, dtype=float), counts,
                              ll.reshape(-1, ll.shape[-1]), "PSIS-LOO", "likelihood")
