"""The GP's log hyperparameters as a posterior that the shared sampler runs on.

:class:`HyperparameterTarget` declares the log hyperparameters as
:class:`~bayeshyst.params.Param` objects -- ``log_signal_variance``,
``log_length_scale`` (one per feature) and ``log_noise_level``, in the order of
sklearn's ``kernel.theta`` -- each with a uniform prior on the log inside
:data:`~bayeshyst.gp.kernel.BOUNDS` and the logit transform to the real line, and
evaluates the training subset's log marginal likelihood. It satisfies
:class:`~bayeshyst.inference.protocols.SamplingTarget`, so
:func:`~bayeshyst.inference.sampling.sample_posterior` samples it exactly as it samples
every model: independent ensembles, the adaptive independence and
differential-evolution moves (there is no linear block; the moves then act on every
coordinate), the R-hat, ESS and autocorrelation criteria of
:class:`~bayeshyst.inference.settings.SamplerSettings`, and a
:class:`~bayeshyst.inference.sampling_result.SamplingResult`.

The start is the GP's own optimum (the one :meth:`bayeshyst.gp.GPHysteresis.fit`
kept, whose free run reproduces the training records), polished in ``z`` where the
logit's Jacobian moves the mode (:meth:`HyperparameterTarget.start_at`): the sampler's
generic MAP search would not know that the highest optimum of the marginal
likelihood can be an unstable recurrence.

:class:`HyperparameterReport` is a view of the shared result in the GP's terms (per
hyperparameter: mean, sd, R-hat and bulk ESS of its log, under sklearn's names).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special

from bayeshyst.gp.kernel import BOUNDS, log_marginal_likelihood
from bayeshyst.inference.convergence import ess_bulk, rhat
from bayeshyst.inference.optimize import MAPResult
from bayeshyst.inference.posterior import EvalCounts
from bayeshyst.inference.sampling_result import SamplingResult
from bayeshyst.params import LogitTransform, Param, ParamSpace, Uniform

__all__ = ["HyperparameterReport", "HyperparameterTarget"]

#: Keeps a start that the optimiser left on a bound inside it (fraction of the log
#: interval): the logit of a bound is infinite.
_INSIDE = 1e-6

#: Smallest curvature of ``-log p`` in ``z`` given to the start's Laplace covariance:
#: a direction the data do not resolve gets a standard deviation of 2, about the width
#: (pi / sqrt(3) = 1.8) of the logistic density a flat likelihood has in ``z``.
_MIN_CURVATURE = 0.25


@dataclass(frozen=True)
class _Named:
    """What the sampling result reads from a target's ``model`` and ``likelihood``."""

    name: str


class HyperparameterTarget:
    """Log posterior of the GP's log hyperparameters in unconstrained coordinates ``z``.

    ``log p(z) = lml(theta(z)) + sum_j log |dtheta_j / dz_j| + const``, ``theta`` the
    log hyperparameters (uniform prior inside :data:`~bayeshyst.gp.kernel.BOUNDS`).

    Parameters
    ----------
    kind : {"rbf", "matern52"}
        Correlation function.
    z_train : ndarray, shape (m, d)
        Standardised training inputs.
    y_train : ndarray, shape (m,)
        Standardised training targets.
    name : str
        Shown as the result's model name (e.g. ``"gp(memory)"``).

    Notes
    -----
    Satisfies :class:`~bayeshyst.inference.protocols.SamplingTarget`; its likelihood is
    named ``"marginal_likelihood"``, so the sampler finds no linear block. It holds no
    records (``data`` is empty): the sampler's checkpoints, which fingerprint the
    data, are not offered for it.
    """

    def __init__(self, kind: str, z_train: np.ndarray, y_train: np.ndarray,
                 name: str = "gp") -> None:
        self.kind = kind
        self.z_train = np.asarray(z_train, dtype=float)
        self.y_train = np.asarray(y_train, dtype=float)
        d = self.z_train.shape[1]

        def param(pname: str, key: str, shape: tuple[int, ...], what: str) -> Param:
            lo, hi = (math.log(b) for b in BOUNDS[key])
            return Param(pname, Uniform(lo, hi), shape=shape, unit="1", description=what,
                         transform=LogitTransform(lo, hi))

        self.space = ParamSpace((
            param("log_signal_variance", "signal_variance", (), "log amplitude of the kernel"),
            param("log_length_scale", "length_scale", (d,),
                  "log length-scale of each standardised feature"),
            param("log_noise_level", "noise_level", (), "log white-noise variance")))
        self.model = _Named(name)
        self.likelihood = _Named("marginal_likelihood")
        self.beta = 1.0
        self.data: tuple = ()
        self.held_out: tuple[int, ...] = ()
        self._n_evals = self._n_prior = self._n_failed = 0

    # ------------------------------------------------------------------ protocol
    @property
    def ndim(self) -> int:
        """Number of log hyperparameters, ``d + 2``."""
        return self.space.ndim

    @property
    def counts(self) -> EvalCounts:
        """Evaluations; ``failed``: kernel matrices that were not positive definite."""
        return EvalCounts(self._n_evals, self._n_prior, self._n_failed)

    def theta(self, z: np.ndarray) -> np.ndarray:
        """Log hyperparameters (W, d + 2), ``kernel.theta`` order, of points ``z`` (W, d + 2)."""
        values = self.space.unpack(np.atleast_2d(np.asarray(z, dtype=float)))
        return np.column_stack([np.reshape(values[p.name], (values[p.name].shape[0], -1))
                                for p in self.space.params])

    def z_of(self, theta: np.ndarray) -> np.ndarray:
        """``z`` (d + 2,) of log hyperparameters ``theta`` (d + 2,).

        ``theta`` is first pulled inside the bounds by a millionth of their log interval.
        """
        out, i = np.empty(self.ndim), 0
        for p in self.space.params:
            lo, hi = p.prior.support
            x = np.clip(theta[i:i + p.size], lo + _INSIDE * (hi - lo), hi - _INSIDE * (hi - lo))
            out[i:i + p.size] = p.transform.forward(x)
            i += p.size
        return out

    def log_prob_batch(self, z: np.ndarray) -> np.ndarray:
        """Log posterior density (W,) of ``W`` points ``z`` (W, d + 2), finite or ``-inf``."""
        z = np.atleast_2d(np.asarray(z, dtype=float))
        lp = np.atleast_1d(self.space.log_prior(z)).astype(float)
        inside = np.isfinite(lp)
        self._n_evals += z.shape[0]
        self._n_prior += int(np.count_nonzero(~inside))
        idx = np.flatnonzero(inside)
        for i, theta in zip(idx, self.theta(z[idx]) if idx.size else (), strict=True):
            lp[i] += log_marginal_likelihood(theta, self.kind, self.z_train, self.y_train,
                                             gradient=False)
        failed = inside & ~np.isfinite(lp)
        self._n_failed += int(np.count_nonzero(failed))
        return np.where(np.isfinite(lp), lp, -np.inf)

    def log_prob(self, z: np.ndarray) -> float:
        """Log posterior density of one point ``z`` (d + 2,)."""
        return float(self.log_prob_batch(np.asarray(z, dtype=float)[None, :])[0])

    def __repr__(self) -> str:
        return (f"HyperparameterTarget({self.model.name!r}, kernel={self.kind!r}, "
                f"m={self.y_train.size}, ndim={self.ndim})")

    # ------------------------------------------------------------------ start
    def _value_and_grad(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """``-log p(z)`` and its gradient.

        The gradient is the analytic gradient of the marginal likelihood through the logit
        (``dtheta/dz = w s(z) s(-z)``) plus that of its log-Jacobian (``1 - 2 s(z)``),
        ``s`` the logistic function.
        """
        theta = self.theta(z)[0]
        lml, grad = log_marginal_likelihood(theta, self.kind, self.z_train, self.y_train)
        lp = float(self.space.log_prior(z))
        if not (np.isfinite(lml) and np.isfinite(lp)):
            return math.inf, np.zeros_like(z)
        width = np.concatenate([np.full(p.size, np.diff(p.prior.support)[0])
                                for p in self.space.params])
        s = special.expit(z)
        return -(lml + lp), -(grad * width * s * (1.0 - s) + 1.0 - 2.0 * s)

    def start_at(self, theta: np.ndarray) -> MAPResult:
        """The sampler's start: the mode in ``z`` of the basin of ``theta``, and its covariance.

        ``theta`` (d + 2,) is the kept optimum of the marginal likelihood; the covariance is
        the Laplace covariance at the mode.

        L-BFGS from ``theta`` on ``-log p(z)`` with its analytic gradient; the Hessian by
        central differences of that gradient, its eigenvalues floored at
        :data:`_MIN_CURVATURE`.
        """
        z0 = self.z_of(np.asarray(theta, dtype=float))
        f0, _ = self._value_and_grad(z0)
        res = optimize.minimize(self._value_and_grad, z0, jac=True, method="L-BFGS-B",
                                options={"maxiter": 500})
        z = res.x if np.isfinite(res.fun) and res.fun <= f0 else z0
        h = 1e-4
        hess = np.array([(self._value_and_grad(z + h * e)[1] - self._value_and_grad(z - h * e)[1])
                         / (2 * h) for e in np.eye(self.ndim)])
        lam, vec = np.linalg.eigh(0.5 * (hess + hess.T))
        ok = bool(np.all(np.isfinite(lam)) and np.all(lam > _MIN_CURVATURE))
        lam = np.where(np.isfinite(lam), np.maximum(lam, _MIN_CURVATURE), 1.0)
        cov = (vec / lam) @ vec.T
        lp = self.log_prob(z)
        notes = () if ok else (
            "the marginal likelihood leaves some log hyperparameters nearly unresolved "
            "(a length-scale whose feature does not matter); the start's covariance gives "
            "them the width of their prior",)
        return MAPResult(z, self.space.unpack(z), lp, 0.5 * (cov + cov.T), ok,
                         int(res.nfev) + 2 * self.ndim + 2, (lp,), notes)


@dataclass(frozen=True)
class HyperparameterReport:
    """The shared sampling result of the GP's log hyperparameters, in the GP's terms.

    Attributes
    ----------
    sampling : SamplingResult
        The run (:func:`~bayeshyst.inference.sampling.sample_posterior`): chains of
        ``z``, convergence by the shared criteria, start, acceptance, settings.
    names : tuple of str
        Hyperparameter names (sklearn's, e.g. ``k1__k2__length_scale[0]``), in
        ``kernel.theta`` order.
    target : HyperparameterTarget
        What was sampled (maps ``z`` to the log hyperparameters).
    n_draws : int
        Draws the estimator keeps for its predictions.
    """

    sampling: SamplingResult
    names: tuple[str, ...]
    target: HyperparameterTarget
    n_draws: int

    @property
    def converged(self) -> bool:
        """Whether every convergence criterion of the sampler held."""
        return self.sampling.converged

    @property
    def reasons(self) -> tuple[str, ...]:
        """Why not converged (empty when converged)."""
        return self.sampling.convergence.reasons

    @property
    def samples(self) -> np.ndarray:
        """All kept draws of the log hyperparameters, (M, d + 2)."""
        return self.target.theta(self.sampling.flat_z)

    @property
    def mean(self) -> np.ndarray:
        """Posterior mean of each log hyperparameter, (d + 2,)."""
        return self.samples.mean(axis=0)

    @property
    def sd(self) -> np.ndarray:
        """Posterior standard deviation of each log hyperparameter, (d + 2,)."""
        return self.samples.std(axis=0)

    def _chains(self) -> tuple[np.ndarray, np.ndarray]:
        """Log hyperparameters with walkers as chains and with ensembles as chains.

        Shapes (chains, S, p) and (E, S * W, p) respectively, as
        :func:`~bayeshyst.inference.convergence.assess` forms them.
        """
        ch = self.sampling.chains  # (E, S, W, p) of z
        e, s, w, p = ch.shape
        theta = self.target.theta(ch.reshape(-1, p)).reshape(e, s, w, p)
        return (theta.transpose(0, 2, 1, 3).reshape(e * w, s, p), theta.reshape(e, s * w, p))

    @property
    def rhat(self) -> np.ndarray:
        """Rank-normalised split R-hat of each log hyperparameter, (d + 2,).

        The larger of walkers-as-chains and ensembles-as-chains (the sampler's criterion).
        """
        walkers, ensembles = self._chains()
        return np.array([max(rhat(walkers[:, :, i]), rhat(ensembles[:, :, i]))
                         for i in range(walkers.shape[2])])

    @property
    def ess_bulk(self) -> np.ndarray:
        """Bulk ESS of each log hyperparameter, walkers as chains, (d + 2,)."""
        walkers, _ = self._chains()
        return np.array([ess_bulk(walkers[:, :, i]) for i in range(walkers.shape[2])])

    def __str__(self) -> str:
        res = self.sampling
        lines = [f"GP hyperparameters, {res.chains.shape[0]} ensembles x {res.chains.shape[2]} "
                 f"walkers, acceptance {float(np.mean(res.acceptance)):.2f}, "
                 f"{res.runtime_s:.1f} s: {res.convergence}",
                 f"  {'log hyperparameter':<32} {'mean':>9} {'sd':>8} {'R-hat':>7} {'ESS':>7}"]
        mean, sd, rh, ess = self.mean, self.sd, self.rhat, self.ess_bulk
        for i, n in enumerate(self.names):
            lines.append(f"  {n:<32} {mean[i]:9.3f} {sd[i]:8.3f} {rh[i]:7.4f} {ess[i]:7.0f}")
        return "\n".join(lines)
