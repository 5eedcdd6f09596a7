"""Closed-form Gaussian posterior of the weights of linear-in-parameter models.

For fixed nonlinear parameters (PI thresholds, Preisach grid, Maxwell-slip slip
deflections, a Duhem's alpha) the simulated output is linear in the remaining ones:
``y = Phi(u) beta (+ offset)``. With Gaussian noise of known ``sigma`` and independent
Normal priors the posterior of ``beta`` is Gaussian (MODELS.md §2)::

    S_N^-1 = S_0^-1 + Phi^T Phi / sigma^2
    m_N    = S_N (S_0^-1 m_0 + Phi^T y / sigma^2)

It is the oracle the MCMC sampler is tested against, and a fast path users can take
when the weights are all they need. The log marginal likelihood (evidence) comes with
it, for a cheap cross-check of model comparisons.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import linalg

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.inference.posterior import NOISE, OBS, Posterior, record_covariates
from bayeshyst.params import Normal

__all__ = ["GaussianPosterior", "conjugate_posterior"]


@dataclass(frozen=True)
class GaussianPosterior:
    """A multivariate normal posterior over named linear parameters.

    Attributes
    ----------
    names : tuple of str
        The parameters, in the order of the flat vector (e.g. ``("p0", "w")``).
    labels : tuple of str
        One label per element (``p0``, ``w[0]``, ...).
    mean : ndarray, shape (P,)
    cov : ndarray, shape (P, P)
    log_evidence : float
        ``log p(y | fixed parameters)`` with the weights integrated out.
    """

    names: tuple[str, ...]
    labels: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    log_evidence: float

    @property
    def sd(self) -> np.ndarray:
        """Marginal standard deviations."""
        return np.sqrt(np.diag(self.cov))

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """``size`` draws, shape (size, P)."""
        return rng.multivariate_normal(self.mean, self.cov, size=int(size), method="cholesky")

    def __str__(self) -> str:
        rows = [f"Gaussian posterior of {', '.join(self.names)} "
                f"(log evidence {self.log_evidence:.6g})"]
        for lab, m, s in zip(self.labels, self.mean, self.sd, strict=True):
            rows.append(f"  {lab:<16} {m:>13.6g} +- {s:.4g}")
        return "\n".join(rows)


def conjugate_posterior(
    post: Posterior, fixed: Mapping[str, Any] | None = None
) -> GaussianPosterior:
    """Exact posterior of the model's linear parameters (and the observation offset).

    Parameters
    ----------
    post : Posterior
        With a Gaussian likelihood and a model that declares ``linear_params`` and
        provides ``regressors(u, t, theta)``; every linear parameter (and
        ``obs.offset``) must have a Normal prior.
    fixed : mapping, optional
        Values of the nonlinear parameters and ``noise.sigma``; parameters held fixed
        in ``post.space`` are taken from there.

    Raises
    ------
    ModelError
        If the model is not linear in any of its parameters or the likelihood is not
        Gaussian.
    ParameterError
        If a linear parameter's prior is not Normal or a needed value is missing.
    """
    model = post.model
    linear = tuple(getattr(model, "linear_params", ()))
    if not linear or not hasattr(model, "regressors"):
        raise ModelError(f"{model.name} is not linear in any of its parameters")
    if post.likelihood.name != "gaussian":
        raise ModelError(f"the conjugate posterior needs a Gaussian likelihood, "
                         f"not {post.likelihood.name!r}")
    values = {k: v for k, v in post.space.fixed.items()}
    values.update(dict(fixed or {}))
    sigma_key = f"{NOISE}.sigma"
    if sigma_key not in values:
        raise ParameterError(f"conjugate_posterior needs {sigma_key!r} (fix it or pass it)")
    sigma = float(values[sigma_key])
    theta = {}
    for name in post.model_space.all_names:
        if name in linear:
            continue
        if name not in values:
            raise ParameterError(f"conjugate_posterior needs a value for nonlinear "
                                 f"parameter {name!r}")
        theta[name] = values[name]
    names = list(linear) + ([f"{OBS}.offset"] if post.offset else [])
    means, sds, labels = [], [], []
    for name in names:
        p = post.space[name]
        if not isinstance(p.prior, Normal):
            raise ParameterError(f"conjugacy needs a Normal prior on {name!r}, got {p.prior}")
        means.append(np.full(p.size, p.prior.mu))
        sds.append(np.full(p.size, p.prior.sigma))
        labels.extend(p.labels())
    m0 = np.concatenate(means)
    s0 = np.concatenate(sds)
    rows, ys = [], []
    for rec in post.data:
        s0_idx = rec.scored.start or 0
        # a model that reads a measured column gets the record's (None for the others)
        phi = model.regressors(rec.u, rec.t, theta,
                               covariates=record_covariates(model, rec))[s0_idx:]
        if post.offset:
            phi = np.column_stack([phi, np.ones(phi.shape[0])])
        rows.append(phi)
        ys.append(rec.y[s0_idx:])
    phi = np.vstack(rows)
    y = np.concatenate(ys)
    # posterior precision and mean via Cholesky (well conditioned: S_0^-1 is diagonal)
    prec = np.diag(1.0 / s0**2) + phi.T @ phi / sigma**2
    chol = linalg.cho_factor(prec, lower=True)
    mean = linalg.cho_solve(chol, m0 / s0**2 + phi.T @ y / sigma**2)
    cov = linalg.cho_solve(chol, np.eye(m0.size))
    # evidence: y ~ N(Phi m0, sigma^2 I + Phi S0 Phi^T), by the matrix determinant lemma
    r = y - phi @ m0
    n = y.size
    logdet_c = (2 * np.sum(np.log(np.diag(chol[0]))) + 2 * np.sum(np.log(s0))
                + 2 * n * math.log(sigma))
    proj = phi.T @ r / sigma**2
    quad = r @ r / sigma**2 - proj @ linalg.cho_solve(chol, proj)
    log_ev = -0.5 * (quad + logdet_c + n * math.log(2 * math.pi))
    return GaussianPosterior(tuple(names), tuple(labels), mean, 0.5 * (cov + cov.T),
                             float(log_ev))
