"""Kernels of the Duhem family: Coleman–Hodgdon (Eq. 45) and the improved Duhem (Eq. 46).

Both models have, along a monotone stretch of the (normalised) input ``s``, a state that
obeys a *linear* ODE in ``s`` (MODELS.md §5)::

    dw/ds = -kappa * sigma * w + P(s),     sigma = sgn(ds) = +-1,  kappa >= 0,

with a polynomial forcing ``P`` (which may itself depend on ``sigma``). Between two
samples the input is taken as a straight line, so each sample interval is monotone and
the integrating factor gives the exact update (with ``D = s_b - s_a``,
``mu = kappa |D| >= 0``)::

    w_b = exp(-mu) w_a + D * sum_k c_k J_k(mu),
    P(s_b - D xi) = sum_k c_k xi^k,         J_k(mu) = int_0^1 xi^k exp(-mu xi) dxi.

Nothing depends on the time step, so the rate independence of Eq. 45 is exact (bit for
bit under any monotone time warp). The moments ``J_k`` are evaluated without
cancellation (:func:`exp_moments`).

Each model is a one-walker function (returning True if the walker failed) plus a loop
over walkers that runs in parallel for large batches and serially otherwise
(:func:`bayeshyst.models._kernels.batch_kernel`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "duhem_batch",
    "exp_moments",
    "improved_duhem_batch",
    "poly_forced_step",
]


@njit(cache=True)
def exp_moments(mu, m, J):
    """``J_k(mu) = int_0^1 xi^k exp(-mu xi) dxi`` for ``k = 0..m`` and ``mu >= 0``.

    Written into ``J[:m + 1]``. For ``mu > m + 1`` the forward recurrence
    ``J_k = (k J_{k-1} - e^{-mu}) / mu`` shrinks errors (factor ``k / mu < 1``); below
    that it would amplify them, so ``J_m`` comes from the all-positive series
    ``J_m = m! e^{-mu} sum_n mu^n / (m + n + 1)!`` and the backward recurrence
    ``J_{k-1} = (mu J_k + e^{-mu}) / k``, which adds positive terms only (relative error
    never grows).
    """
    em = math.exp(-mu)
    if mu > m + 1.0:
        J[0] = -math.expm1(-mu) / mu
        for k in range(1, m + 1):
            J[k] = (k * J[k - 1] - em) / mu
        return
    term = 1.0 / (m + 1.0)
    acc = term
    n = 0
    # terms decrease from the start (mu / (m + n + 2) < 1), so stopping at the first
    # negligible one is safe; the cap only guards against NaN input
    while term > 1e-17 * acc and n < 400:
        n += 1
        term *= mu / (m + n + 1.0)
        acc += term
    J[m] = em * acc
    for k in range(m, 0, -1):
        J[k - 1] = (mu * J[k] + em) / k


@njit(cache=True)
def poly_forced_step(w, sa, sb, kappa, p, m, J):
    """Exact solution of ``dw/ds = -kappa sgn(sb - sa) w + P(s)`` from ``sa`` to ``sb``.

    Parameters
    ----------
    w : float
        State at ``s = sa``.
    sa, sb : float
        Start and end of the monotone stretch (normalised input).
    kappa : float
        Relaxation rate per unit ``s``, ``>= 0``.
    p : ndarray, shape (>= m + 1,)
        Coefficients of ``P`` in powers of ``s`` (ascending); overwritten (scratch).
    m : int
        Degree of ``P``.
    J : ndarray, shape (>= m + 1,)
        Scratch for the moments.

    Returns
    -------
    float
        State at ``s = sb``.
    """
    d = sb - sa
    if d == 0.0:
        return w
    # Taylor shift: after the loops p[k] = P^(k)(sb) / k!  (Horner, O(m^2), no allocation)
    for i in range(m):
        for j in range(m - 1, i - 1, -1):
            p[j] += sb * p[j + 1]
    mu = kappa * abs(d)
    exp_moments(mu, m, J)
    acc = 0.0
    scale = 1.0
    for k in range(m + 1):
        acc += p[k] * scale * J[k]
        scale *= -d
    return math.exp(-mu) * w + d * acc


@njit(cache=True)
def _duhem_one(u, a, f, g, uc, uh, state, y):
    if not (a >= 0.0 and uh > 0.0 and math.isfinite(a + uc + uh)):
        return True
    nf = f.shape[0]
    ng = g.shape[0]
    m = max(nf, ng) - 1
    p = np.empty(m + 1)
    J = np.empty(m + 1)
    w = state[0]
    sa = (state[1] - uc) / uh
    for k in range(u.shape[0]):
        sb = (u[k] - uc) / uh
        if sb != sa:
            lam = a if sb > sa else -a
            # dw/ds = a sgn (F - w) + G  ->  kappa = a, P = a sgn F + G
            for j in range(m + 1):
                p[j] = 0.0
            for j in range(nf):
                p[j] += lam * f[j]
            for j in range(ng):
                p[j] += g[j]
            w = poly_forced_step(w, sa, sb, a, p, m, J)
            if not math.isfinite(w):
                return True
        y[k] = w
        sa = sb
    state[0] = w
    state[1] = u[u.shape[0] - 1]
    return False


@njit(cache=True, parallel=True)
def _duhem_par(u, alpha, f, g, uc, uh, state, y, failed):
    """Coleman–Hodgdon model for W parameter vectors (normalised input, see module doc).

    Parameters
    ----------
    u : (N,) input (V); alpha : (W,) rate per unit normalised input, ``>= 0``;
    f : (W, nf), g : (W, ng) polynomial coefficients in ``s = (u - uc) / uh``;
    uc, uh : (W,) centre and half-span (V); state : (W, 2) ``[w, u_prev]``, updated in
    place; y : (W, N) output, written; failed : (W,) bool, written.
    """
    for j in prange(alpha.shape[0]):
        failed[j] = _duhem_one(u, alpha[j], f[j], g[j], uc[j], uh[j], state[j], y[j])


@njit(cache=True)
def _duhem_ser(u, alpha, f, g, uc, uh, state, y, failed):
    for j in range(alpha.shape[0]):
        failed[j] = _duhem_one(u, alpha[j], f[j], g[j], uc[j], uh[j], state[j], y[j])


duhem_batch = batch_kernel(_duhem_par, _duhem_ser, work_arg=-2, name="duhem_batch")


@njit(cache=True)
def _improved_one(u, t, k_lin, p_rate, a, b, c, uc, uh, state, y):
    if not (b >= 0.0 and uh > 0.0 and math.isfinite(k_lin + p_rate + a + b + c + uc + uh)):
        return True
    pp = np.empty(2)
    J = np.empty(2)
    h = state[0]
    u_prev = state[1]
    t_prev = state[2]
    sa = (u_prev - uc) / uh
    for k in range(u.shape[0]):
        sb = (u[k] - uc) / uh
        if sb != sa:
            # dh/ds = alpha - beta sgn h + gamma s: kappa = beta, P = alpha + gamma s
            pp[0] = a
            pp[1] = c
            h = poly_forced_step(h, sa, sb, b, pp, 1, J)
        # backward difference; t_prev = -inf (relaxed start) gives du/dt = 0
        dudt = (u[k] - u_prev) / (t[k] - t_prev)
        yk = k_lin * u[k] + p_rate * dudt - h
        if not math.isfinite(yk):
            return True
        y[k] = yk
        sa = sb
        u_prev = u[k]
        t_prev = t[k]
    state[0] = h
    state[1] = u_prev
    state[2] = t_prev
    return False


@njit(cache=True, parallel=True)
def _improved_duhem_par(u, t, k_lin, p_rate, alpha, beta, gamma, uc, uh, state, y, failed):
    """Improved Duhem model ``y = k u + p du/dt - h`` for W parameter vectors.

    Parameters
    ----------
    u, t : (N,) input (V) and times (s); k_lin, p_rate, alpha, beta, gamma, uc, uh : (W,);
    state : (W, 3) ``[h, u_prev, t_prev]``, updated in place; y : (W, N), written;
    failed : (W,) bool, written.
    """
    for j in prange(alpha.shape[0]):
        failed[j] = _improved_one(u, t, k_lin[j], p_rate[j], alpha[j], beta[j], gamma[j],
                                  uc[j], uh[j], state[j], y[j])


@njit(cache=True)
def _improved_duhem_ser(u, t, k_lin, p_rate, alpha, beta, gamma, uc, uh, state, y, failed):
    for j in range(alpha.shape[0]):
        failed[j] = _improved_one(u, t, k_lin[j], p_rate[j], alpha[j], beta[j], gamma[j],
                                  uc[j], uh[j], state[j], y[j])


improved_duhem_batch = batch_kernel(_improved_duhem_par, _improved_duhem_ser, work_arg=-2,
                                    name="improved_duhem_batch")
