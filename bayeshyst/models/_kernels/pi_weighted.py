"""Kernels of the weighted Prandtl–Ishlinskii models: polynomial input, rate-dependent
weights, covariate-dependent weights and thresholds.

Equations (review §6.4–6.5 Eq. 20, 28–32, §3, §10 ref. [106])::

    polynomial input   y_k = p0 u_k + sum_i w_i F_{r_i}[u]_k + sum_{j=2..d} g_j x_k^j,
                       x_k = (u_k - u_c) / u_h
    rate weights       y_k = W_k p0 u_k + G_k sum_i w_i F_{r̄_k,i}[u]_k,
                       W_k = exp(m1 u̇_k / u̇_ref + m2 x_k), G_k = exp(s1 u̇_k / u̇_ref + s2 x_k),
                       r̄_{k,i} = r_i (1 + c ln(1 + |u̇_k| / u̇_0)),
                       u̇_k = (u_k - u_{k-1}) / (t_k - t_{k-1})
    covariate          y_k = (1 + a Δc_k) (p0 u_k + sum_i w_i F_{r_i (1 + b Δc_k)}[u]_k),
                       Δc_k = c_k - c_0

Every kernel accumulates ``p0 u_k`` first and then the operators in order, with factors
that are exactly 1.0 at the classical parameters, so that those reproduce
``pi_play_batch`` (and the rate kernel ``pi_rate_batch``) bit for bit. The play clamp is
the ``max(lo, min(hi, v))`` of :mod:`bayeshyst.models._kernels.pi_variants`.

Batched kernels take parameters with a leading walker axis ``W``, write the output
``y`` (W, N) and update ``state`` (W, S) in place; serial or parallel by work size
(:func:`bayeshyst.models._kernels.batch_kernel`); nothing is allocated per sample.
"""

from __future__ import annotations

import math

from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.pi_variants import _clamp

__all__ = ["pi_covariate_batch", "pi_poly_batch", "pi_rate_weights_batch"]


@njit(cache=True, error_model="numpy")
def _poly_one(u, p0, w, r, g, uc, uh, v, y):
    n = w.shape[0]
    d = g.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        acc = p0 * uk
        for i in range(n):
            vi = _clamp(uk - r[i], uk + r[i], v[i])
            v[i] = vi
            acc += w[i] * vi
        # the memoryless polynomial after the operators: degree 1 adds nothing at all
        x = (uk - uc) / uh
        xp = x
        for j in range(d):
            xp *= x
            acc += g[j] * xp
        y[k] = acc


@njit(cache=True, parallel=True, error_model="numpy")
def _pi_poly_par(u, p0, w, r, g, uc, uh, state, y):
    """Play PI plus a polynomial input function, for W parameter vectors.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    p0 : ndarray, shape (W,)
        Linear weight (output unit/V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and thresholds (V).
    g : ndarray, shape (W, d - 1)
        Coefficients of ``x^2 .. x^d`` (output unit); ``d - 1 = 0`` columns for degree 1.
    uc, uh : ndarray, shape (W,)
        Centre and half-span of the polynomial's input scaling (V).
    state : ndarray, shape (W, n)
        Play outputs before ``u[0]`` (V); overwritten with those after ``u[-1]``.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _poly_one(u, p0[j], w[j], r[j], g[j], uc[j], uh[j], state[j], y[j])


@njit(cache=True, error_model="numpy")
def _pi_poly_ser(u, p0, w, r, g, uc, uh, state, y):
    for j in range(w.shape[0]):
        _poly_one(u, p0[j], w[j], r[j], g[j], uc[j], uh[j], state[j], y[j])


pi_poly_batch = batch_kernel(_pi_poly_par, _pi_poly_ser, work_arg=-1, name="pi_poly_batch")


# error_model="numpy": an overflowing exponential or u̇_0 = 0 gives inf/NaN that the model
# flags as failed, never an exception inside the parallel loop
@njit(cache=True, error_model="numpy")
def _rate_weights_one(u, t, p0, w, r, m1, m2, s1, s2, udr, uc, uh, c, ud0, s, y):
    n = w.shape[0]
    # s = [v_1..v_n, u_prev, t_prev, has_prev], the layout of pi_rate's state
    up = s[n]
    tp = s[n + 1]
    has_prev = s[n + 2] != 0.0
    for k in range(u.shape[0]):
        uk = u[k]
        tk = t[k]
        rate = (uk - up) / (tk - tp) if has_prev else 0.0
        x = (uk - uc) / uh
        q = rate / udr
        wk = math.exp(m1 * q + m2 * x)
        gk = math.exp(s1 * q + s2 * x)
        f = 1.0 + c * math.log1p(abs(rate) / ud0)
        acc = (wk * p0) * uk
        for i in range(n):
            ri = r[i] * f
            vi = _clamp(uk - ri, uk + ri, s[i])
            s[i] = vi
            acc += (gk * w[i]) * vi
        y[k] = acc
        up = uk
        tp = tk
        has_prev = True
    s[n] = up
    s[n + 1] = tp
    s[n + 2] = 1.0


@njit(cache=True, parallel=True, error_model="numpy")
def _pi_rate_weights_par(u, t, p0, w, r, m1, m2, s1, s2, udr, uc, uh, c, ud0, state, y):
    """Play PI with rate- and input-dependent weights (review Eq. 30–32), W vectors.

    Parameters
    ----------
    u, t : ndarray, shape (N,)
        Input (V) and sample times (s), strictly increasing (also across ``state``).
    p0 : ndarray, shape (W,)
        Linear weight at zero rate and ``u = u_c`` (output unit/V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and rate-free thresholds (V).
    m1, m2, s1, s2 : ndarray, shape (W,)
        Exponents of ``W_k`` and ``G_k`` per unit of ``u̇ / u̇_ref`` and of ``x``.
    udr : ndarray, shape (W,)
        Reference rate ``u̇_ref`` of the weights (V/s).
    uc, uh : ndarray, shape (W,)
        Centre and half-span of the input scaling (V).
    c, ud0 : ndarray, shape (W,)
        Threshold law ``1 + c ln(1 + |u̇| / u̇_0)``; ``c = 0`` keeps the thresholds.
    state : ndarray, shape (W, n + 3)
        Operator outputs, previous input, previous time, has-previous flag.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _rate_weights_one(u, t, p0[j], w[j], r[j], m1[j], m2[j], s1[j], s2[j], udr[j],
                          uc[j], uh[j], c[j], ud0[j], state[j], y[j])


@njit(cache=True, error_model="numpy")
def _pi_rate_weights_ser(u, t, p0, w, r, m1, m2, s1, s2, udr, uc, uh, c, ud0, state, y):
    for j in range(w.shape[0]):
        _rate_weights_one(u, t, p0[j], w[j], r[j], m1[j], m2[j], s1[j], s2[j], udr[j],
                          uc[j], uh[j], c[j], ud0[j], state[j], y[j])


pi_rate_weights_batch = batch_kernel(_pi_rate_weights_par, _pi_rate_weights_ser, work_arg=-1,
                                     name="pi_rate_weights_batch")


@njit(cache=True, error_model="numpy")
def _covariate_one(u, cv, has_cov, p0, w, r, a, b, c0, v, y):
    n = w.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        # nominal conditions (no column given): the covariate at its reference, where
        # both factors are exactly 1.0 and the model is pi_play to the last bit
        dc = cv[k] - c0 if has_cov else 0.0
        gain = 1.0 + a * dc
        f = 1.0 + b * dc
        acc = p0 * uk
        for i in range(n):
            ri = r[i] * f
            vi = _clamp(uk - ri, uk + ri, v[i])
            v[i] = vi
            acc += w[i] * vi
        y[k] = gain * acc


@njit(cache=True, parallel=True, error_model="numpy")
def _pi_covariate_par(u, cv, has_cov, p0, w, r, a, b, c0, state, y):
    """Play PI whose weights and thresholds follow a measured column, W vectors.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    cv : ndarray, shape (N,)
        The covariate per sample (its unit); ignored unless ``has_cov``.
    has_cov : bool
        Whether ``cv`` is given; else every sample is at the reference ``c0``.
    p0 : ndarray, shape (W,)
        Linear weight at ``c0`` (output unit/V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and thresholds (V) at ``c0``.
    a, b : ndarray, shape (W,)
        Relative change of the weights and of the thresholds per unit of the column.
    c0 : ndarray, shape (W,)
        Reference value of the column.
    state : ndarray, shape (W, n)
        Play outputs (V), updated in place.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _covariate_one(u, cv, has_cov, p0[j], w[j], r[j], a[j], b[j], c0[j], state[j], y[j])


@njit(cache=True, error_model="numpy")
def _pi_covariate_ser(u, cv, has_cov, p0, w, r, a, b, c0, state, y):
    for j in range(w.shape[0]):
        _covariate_one(u, cv, has_cov, p0[j], w[j], r[j], a[j], b[j], c0[j], state[j], y[j])


pi_covariate_batch = batch_kernel(_pi_covariate_par, _pi_covariate_ser, work_arg=-1,
                                  name="pi_covariate_batch")
