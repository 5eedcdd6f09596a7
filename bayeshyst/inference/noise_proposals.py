"""Proposals for the noise parameters that use the linear block's Grams.

Given the linear coefficients ``beta``, the likelihood's shape in ``sigma`` is an
inverse gamma and in the AR(1) ``phi`` a Gaussian regression on the lagged residual;
the structured moves (:mod:`bayeshyst.inference.moves`) propose from them and keep
only the priors (and the first sample) in the Metropolis–Hastings ratio.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import special

from bayeshyst.inference.conditional import LOG_2PI, LinearStats
from bayeshyst.inference.linear import LinearStructure

__all__ = ["phi_proposal", "sigma_proposal"]


def sigma_proposal(lin: LinearStructure, st: LinearStats, z: np.ndarray, beta: np.ndarray,
                   random: np.random.RandomState
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw ``sigma'`` from ``sigma^2 ~ InvGamma(n/2, Q/2)``.

    That is the likelihood's own shape in ``sigma``, so only the prior is left in the
    MH ratio.

    Returns the proposed ``sigma`` (W,), and the proposal's log density in the
    parameter's ``z`` coordinate at the proposed and at the current value.
    """
    sigma, phi = lin.noise(z)
    m = lin.whitened(st, phi)
    v = np.concatenate([-(beta - lin.beta_ref), np.ones((z.shape[0], 1))], axis=1)
    quad = np.einsum("wi,wij,wj->w", v, m, v)
    a = 0.5 * st.n
    b = 0.5 * np.where(np.isfinite(quad) & (quad > 0), quad, np.nan)
    g = random.standard_gamma(a, size=z.shape[0])
    with np.errstate(divide="ignore", invalid="ignore"):
        new = np.sqrt(b / g)
    param = lin.post.space[lin.sigma_name]
    return new, _sigma_logq(new, a, b, param), _sigma_logq(sigma, a, b, param)


def _sigma_logq(sigma: np.ndarray, a: float, b: np.ndarray, param: Any) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        s2 = sigma * sigma
        # density of sigma when sigma^2 ~ InvGamma(a, b): p(s2) * 2 sigma
        log_q = (math.log(2.0) + np.log(sigma) + a * np.log(b) - special.gammaln(a)
                 - (a + 1.0) * np.log(s2) - b / s2)
        zc = param.transform.forward(sigma)
        log_q = log_q + param.transform.log_jacobian(zc)
    return np.where(np.isfinite(log_q), log_q, -np.inf)


def phi_proposal(lin: LinearStructure, st: LinearStats, z: np.ndarray, beta: np.ndarray,
                 random: np.random.RandomState
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw the AR(1) coefficient from its regression on the lagged residual.

    Given the innovation scale ``s = sigma sqrt(1 - phi^2)`` the residuals after
    the first follow ``e_k = phi e_{k-1} + N(0, s^2)``, whose likelihood in ``phi``
    is ``N(b/c, s^2/c)`` (``b``, ``c``: lag-one and lagged sums of squares of the
    residual at ``beta``). Returns the proposed ``phi`` (W,) and the proposal's log
    density (in ``phi`` itself) at the proposed and at the current value; the move
    keeps ``s`` fixed and corrects for the first sample and the priors.
    """
    sigma, phi = lin.noise(z)
    v = np.concatenate([-(beta - lin.beta_ref), np.ones((z.shape[0], 1))], axis=1)
    bb = np.einsum("wi,wij,wj->w", v, st.cross, v)
    cc = np.einsum("wi,wij,wj->w", v, st.prev, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_innov = sigma * np.sqrt(1.0 - phi**2)
        hat = bb / cc
        sd = s_innov / np.sqrt(cc)
    new = hat + sd * random.randn(z.shape[0])

    def log_q(x: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            out = -0.5 * ((x - hat) / sd) ** 2 - np.log(sd) - 0.5 * LOG_2PI
        return np.where(np.isfinite(out), out, -np.inf)

    return new, log_q(new), log_q(phi)
