"""Free-run prediction and per-cycle log densities of :class:`bayeshyst.gp.GPHysteresis`.

:class:`FreeRun` is the half of the estimator that works after a fit (a mixin: it
reads the fitted state and the feature code of :mod:`bayeshyst.gp.model`): the free
run, sequential over reversals only (:meth:`FreeRun.predict`,
:meth:`FreeRun.predict_records`), mixed over hyperparameter draws once they were
sampled; the free-run predictive log-density of each cycle of any records
(:meth:`FreeRun.log_density_units`, pointwise or with the GP's joint covariance over
the cycle); and exact leave-one-cycle-out on the fitted records
(:meth:`FreeRun.loo_units`). The cycles are the cross-validation units of
the parametric models (:func:`~bayeshyst.inference.posterior.cycle_units`), so the
numbers share a table with theirs (:mod:`bayeshyst.selection`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.special import logsumexp
from sklearn.utils.validation import check_is_fitted

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.gp.features import SignalRecord
from bayeshyst.gp.kernel import Conditioned, small_blas
from bayeshyst.inference.posterior import Unit, cycle_units
from bayeshyst.inference.protocols import Prediction, UnitLogDensity

__all__ = ["FreeRun"]

_LOG2PI = float(np.log(2 * np.pi))


class FreeRun:
    """Prediction and per-cycle log densities of a fitted :class:`~bayeshyst.gp.GPHysteresis`.

    A mixin: it uses the estimator's ``_split_X``, ``_from_records``, ``_layout`` and
    ``_features``, its training set ``_train``, fitted records ``_fit_data``, sklearn
    regressor ``gp_`` and kernel ``kernel_``, and the fitted standardisation.
    """

    # set by the estimator
    features: str
    kernel: str
    target_mean_: float
    target_scale_: float
    anchor_output_: float
    _train: dict[str, Any]
    _fit_data: list[SignalRecord]

    # ------------------------------------------------------------------ prediction
    def _thetas(self, hyperparameters: str) -> np.ndarray:
        """Log hyperparameters to mix, (S, p): the ML values or the stored draws."""
        check_is_fitted(self, "gp_")
        if hyperparameters not in ("auto", "ml", "samples"):
            raise ParameterError(f"hyperparameters: expected 'auto', 'ml' or 'samples', found "
                                 f"{hyperparameters!r}")
        draws = getattr(self, "hyperparameter_draws_", None)
        if hyperparameters == "samples" and draws is None:
            raise ParameterError("hyperparameters='samples': call sample_hyperparameters first")
        if hyperparameters == "ml" or draws is None:
            return self.kernel_.theta[None, :]
        return draws

    def _states(self, hyperparameters: str) -> list[Conditioned]:
        thetas = self._thetas(hyperparameters)
        if thetas.shape[0] == 1 and np.array_equal(thetas[0], self.kernel_.theta):
            return [Conditioned(self.kernel_.theta, self.kernel, self.gp_.X_train_,
                                self.gp_.y_train_, self.gp_.L_, self.gp_.alpha_)]
        return [Conditioned(th, self.kernel, self._train["z"], self._train["y"]) for th in thetas]

    def _free_run(self, state: Conditioned, lay: dict, s: np.ndarray, start: int = 0,
                  stop: int | None = None, var: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Free-run mean and latent variance of samples ``start:stop`` [target unit]."""
        stop = lay["n"] if stop is None else stop
        y_ref = None
        if self.features != "rate":
            y_ref = np.full(lay["n"], np.nan)
            y_ref[0] = self.anchor_output_
            for i in lay["refs"][lay["refs"] < stop]:  # sequential over reversals only
                zi, off = self._features(lay, s, y_ref, np.array([i]))
                y_ref[i] = state.predict(zi, var=False)[0][0] * self.target_scale_ \
                    + self.target_mean_ + off[0]
        z, off = self._features(lay, s, y_ref, slice(start, stop))
        mean, v = state.predict(z, var=var)
        mean = mean * self.target_scale_ + self.target_mean_ + off
        return mean, (v * self.target_scale_**2 if var else np.zeros_like(mean))

    @small_blas
    def _predict_recs(self, recs: list[SignalRecord], hyperparameters: str,
                      var: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per record: (S, n) means and latent variances, one row per state."""
        states, out = self._states(hyperparameters), []
        for rec in recs:
            lay = self._layout(rec)
            runs = [self._free_run(st, lay, rec.s, var=var) for st in states]
            out.append((np.array([r[0] for r in runs]), np.array([r[1] for r in runs])))
        return out

    @staticmethod
    def _mix(means: np.ndarray, variances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mixture mean and latent std over draws (law of total variance)."""
        mean = means.mean(axis=0)
        return mean, np.sqrt(variances.mean(axis=0) + means.var(axis=0))

    def predict(self, X: np.ndarray, return_std: bool = False, *,
                hyperparameters: str = "auto") -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Free-run simulation of the output from ``X`` (columns ``t``, input[, record id]).

        Parameters
        ----------
        X : ndarray, shape (N, 2) or (N, 3)
        return_std : bool, default False
            Also return the latent predictive standard deviation (noise excluded; add
            ``noise_std_**2`` to the variance for a measurement).
        hyperparameters : {"auto", "ml", "samples"}
            ``"auto"``: the mixture over ``hyperparameter_draws_`` if sampled, else the ML
            values.

        Returns
        -------
        mean : ndarray, shape (N,)
        std : ndarray, shape (N,), when ``return_std``
        """
        check_is_fitted(self, "gp_")
        runs = self._predict_recs(self._split_X(X, None), hyperparameters, var=return_std)
        mixed = [self._mix(m, v) for m, v in runs]
        mean = np.concatenate([m for m, _ in mixed])
        return (mean, np.concatenate([s for _, s in mixed])) if return_std else mean

    def predict_records(self, data: Dataset | Record, *,
                        hyperparameters: str = "auto") -> list[Prediction]:
        """Free-run prediction of every record (full length, warm-up included).

        With ``hyperparameters`` ``"auto"`` and sampled hyperparameters, the mixture over
        ``hyperparameter_draws_``: mean of the draws' means, variance the mean of their
        variances plus the variance of their means; ``noise_std`` the root mean of
        their noise variances.
        """
        recs = self._from_records(data, targets=False)
        runs = self._predict_recs(recs, hyperparameters)
        noise = np.sqrt(np.exp(self._thetas(hyperparameters)[:, -1])) * self.target_scale_
        return [Prediction(r.source.name, *self._mix(m, v), float(np.sqrt(np.mean(noise**2))))
                for r, (m, v) in zip(recs, runs, strict=True)]


    # ------------------------------------------------------------------ log densities
    @small_blas
    def log_density_units(self, data: Dataset | Record, *, covariance: str = "pointwise",
                          hyperparameters: str = "auto") -> UnitLogDensity:
        """Free-run predictive log-density of each cycle's scored samples.

        Per hyperparameter draw ``s`` and cycle ``c``, ``pointwise``:
        ``sum_i log N(y_i; mean_si, var_si + noise_s)`` over the cycle's scored samples
        (the product of the marginal predictives, the same per-sample form as the
        parametric models' Gaussian likelihood); ``joint``: ``log N(y_c; mean_sc,
        Sigma_sc + noise_s I)`` with the GP's joint latent covariance over the cycle
        (conditional on the fed-back outputs for the memory variants). Draws are mixed
        per cycle, ``log mean_s exp(.)``, because the hyperparameters are shared by the
        cycle's samples. The units are :func:`~bayeshyst.inference.posterior.cycle_units`.

        The pointwise form ignores the correlation of the GP's error along a cycle. It
        is the default because the parametric models are scored the same way and
        because the joint form is not available for the fed-back outputs; where the
        latent variance is small against the noise, the two agree closely. Measured
        (``tests/test_gp.py``, rate variant, 300 training points, 1 Hz sine): joint minus
        pointwise -0.006 and +0.0001 nats per sample (two cycles) against 1.73-1.78
        nats per sample.
        """
        if covariance not in ("pointwise", "joint"):
            raise ParameterError(f"covariance: expected 'pointwise' or 'joint', found "
                                 f"{covariance!r}")
        states = self._states(hyperparameters)

        def block(k: int, rec: SignalRecord, lay: dict, spans: list) -> np.ndarray:
            out = np.empty((len(states), len(spans)))
            for s, st in enumerate(states):
                mean, var = self._free_run(st, lay, rec.s)
                out[s] = [self._score(st, lay, rec, mean, var, a, b, covariance)
                          for a, b in spans]
            return out

        return self._per_unit(self._from_records(data), self._layout, block, "free-run",
                              covariance)

    @staticmethod
    def _per_unit(recs: list[SignalRecord], layout: Callable[[SignalRecord], dict],
                  block: Callable[[int, SignalRecord, dict, list], np.ndarray], method: str,
                  covariance: str) -> UnitLogDensity:
        """Collect ``block(k, rec, layout, spans) -> (S, n_spans)`` and mix draws per unit.

        ``block`` is collected over the records' cycle units.
        """
        units, cols = [], []
        for k, rec in enumerate(recs):
            spans = cycle_units(rec.source)
            units += [Unit(rec.source.name, i, a, b, rec.source.frequency_hz)
                      for i, (a, b) in enumerate(spans)]
            cols.append(block(k, rec, layout(rec), spans))
        per_draw = np.concatenate(cols, axis=1)
        values = logsumexp(per_draw, axis=0) - np.log(per_draw.shape[0])
        counts = np.array([u.stop - u.start for u in units])
        return UnitLogDensity(tuple(units), values, counts, per_draw, method, covariance)

    def _score(self, st: Conditioned, lay: dict, rec: SignalRecord, mean: np.ndarray,
               var: np.ndarray, a: int, b: int, covariance: str) -> float:
        """Log-density of samples a:b of a record given the free run ``mean``/``var``."""
        noise = st.noise * self.target_scale_**2
        r = rec.target[a:b] - mean[a:b]
        if covariance == "pointwise":
            v = var[a:b] + noise
            return float(-0.5 * np.sum(r * r / v + np.log(v) + _LOG2PI))
        y_ref = None
        if self.features != "rate":  # the fed-back outputs are those of this free run
            y_ref = mean.copy()
            y_ref[0] = self.anchor_output_
        z, _ = self._features(lay, rec.s, y_ref, slice(a, b))
        return st.joint_log_density(z, r / self.target_scale_) - (b - a) * np.log(
            self.target_scale_)

    @small_blas
    def loo_units(self, data: Dataset | Record, *, exclude_dependent: bool = True,
                  hyperparameters: str = "auto") -> UnitLogDensity:
        """Exact leave-one-cycle-out predictive log-density at fixed hyperparameters.

        For each cycle (unit) of the fitted data: drop the training points inside it
        (and, with ``exclude_dependent``, those whose memory features read a measured
        output inside it -- otherwise the cycle's outputs would still inform the GP
        through the next branch's inputs), re-condition the GP on the rest (one
        ``m x m`` Cholesky; hyperparameters, standardisation and threshold unchanged),
        free-run the record up to the cycle's end and score the cycle pointwise as in
        :meth:`log_density_units`. Cost per cycle and draw: ``O(m^3)`` plus the
        cycle's prediction.

        Parameters
        ----------
        data : Dataset or Record
            Exactly the data given to :meth:`fit_records`.
        """
        check_is_fitted(self, "gp_")
        recs, fitted = self._from_records(data), self._fit_data
        if len(recs) != len(fitted) or not all(
                f.source is not None and r.source.name == f.source.name and r.s.size == f.s.size
                and np.array_equal(r.s, f.s) and np.array_equal(r.target, f.target)
                for r, f in zip(recs, fitted, strict=True)):
            raise DataError("loo_units: data: expected the records given to fit_records "
                            f"({[f.source.name if f.source else '?' for f in fitted]}), found "
                            f"{[r.source.name for r in recs]} or different values")
        thetas, tr = self._thetas(hyperparameters), self._train

        def block(k: int, rec: SignalRecord, lay: dict, spans: list) -> np.ndarray:
            out = np.empty((len(thetas), len(spans)))
            for j, (a, b) in enumerate(spans):
                drop = (tr["pos"] >= a) & (tr["pos"] < b)
                if exclude_dependent and self.features != "rate":
                    drop |= ((tr["refs"] >= a) & (tr["refs"] < b) & (tr["refs"] > 0)).any(1)
                keep = ~(drop & (tr["rec"] == k))
                if not keep.any():
                    raise DataError(f"loo_units: record {rec.source.name!r}, cycle {j}: every "
                                    f"training point depends on it; nothing is left to "
                                    f"condition on (increase n_train)")
                for s, theta in enumerate(thetas):
                    st = Conditioned(theta, self.kernel, tr["z"][keep], tr["y"][keep])
                    mean, var = np.zeros(b), np.zeros(b)
                    mean[a:], var[a:] = self._free_run(st, lay, rec.s, a, b)
                    out[s, j] = self._score(st, lay, rec, mean, var, a, b, "pointwise")
            return out

        return self._per_unit(recs, self._layout, block, "leave-one-cycle-out", "pointwise")
