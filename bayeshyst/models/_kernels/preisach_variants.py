"""Kernels of the Preisach variants: the rate-weighted staircase and the diagonal grid.

Rate-weighted Preisach (review §5, refs. [39] [44]): the weight of every relay is
multiplied by a factor of the current input rate, so the relay sum ``P`` of the
rate-independent staircase (Eq. 7–8, :func:`staircase_one`) is rescaled per sample::

    F_k = 1 + c ln(1 + |u̇_k| / u̇_0),      u̇_k = (u_k - u_{k-1}) / (t_k - t_{k-1})
    y_k = c0 + c1 u_k + c2 P_k + (F_k - 1) (b0 + c2 P_k)

``c0 + c1 u + c2 P`` is the rate-free output exactly as the staircase kernel writes it
(``c = 0`` is bit for bit the parent model) and ``b0 + c2 P`` is the part the weights
carry (``b0 = -sum(mu)`` for ±1 relays, whose "off" state also carries its weight).

Diagonally weighted Preisach (ref. [42]): the weight ``mu_ij`` of grid cell ``(i, j)``
is spread uniformly along the cell's diagonal, the segment from ``(alpha, beta) =
(e_i, e_j)`` to ``(e_{i+1}, e_{j+1})`` on the uniform edges ``e_m = lo + m h``. All
cells with ``i - j = d`` lie on the line ``alpha - beta = d h``, and a relay of
half-width ``r`` centred at ``(alpha + beta) / 2 = x`` is on exactly when the play
operator of half-width ``r`` is at or above ``x`` (the classical identity, ties
included for the relay conventions of :mod:`bayeshyst.models._kernels.preisach`).
So diagonal ``d`` contributes a piecewise-linear function of one play::

    v_d = max(u - d h / 2, min(u + d h / 2, v_d)),   x_d = (v_d - lo) / h - d / 2
    y   = c0 + sum_d sum_j mu_{j+d, j} clamp(x_d - j, 0, 1)

which costs ``O(L)`` per sample with prefix sums along each diagonal.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.preisach import staircase_one

__all__ = ["diagonal_preisach_batch", "rate_staircase_batch"]


# error_model="numpy": a walker with an out-of-support u̇_0 = 0 must give inf/NaN that
# the model flags as failed, not raise ZeroDivisionError inside the parallel loop
@njit(cache=True, error_model="numpy")
def _rate_one(u, t, nodes, table, bilinear, c0, c1, c2, b0, c, ud0, st, y):
    """One walker of :func:`rate_staircase_batch`; returns True if an output was not finite."""
    mem_len = st.shape[0] - 3
    # the relay sum P first, written into y and then rescaled in place
    failed = staircase_one(u, nodes, table, bilinear, 0.0, 0.0, 1.0, st[:mem_len], y)
    # st tail = [u_prev, t_prev, has_prev]: the backward difference at the first sample
    # of a continued run needs the previous sample
    up = st[mem_len]
    tp = st[mem_len + 1]
    has_prev = st[mem_len + 2] != 0.0
    for k in range(u.shape[0]):
        uk = u[k]
        tk = t[k]
        rate = abs(uk - up) / (tk - tp) if has_prev else 0.0
        extra = c * math.log1p(rate / ud0)  # F_k - 1
        p = y[k]
        yk = c0 + c1 * uk + c2 * p + extra * (b0 + c2 * p)
        if not math.isfinite(yk):
            failed = True
        y[k] = yk
        up = uk
        tp = tk
        has_prev = True
    st[mem_len] = up
    st[mem_len + 1] = tp
    st[mem_len + 2] = 1.0
    return failed


@njit(cache=True, parallel=True)
def _rate_staircase_par(u, t, nodes, tables, bilinear, coef, rate, skip, state, y, failed):
    """Rate-weighted Preisach output for W walkers (module docstring).

    Parameters
    ----------
    u, t : (N,) input (V) and sample times (s), strictly increasing (also across state).
    nodes, tables, bilinear : Everett tables as for
        :func:`bayeshyst.models._kernels.preisach.staircase_batch`.
    coef : (W, 4) ``c0, c1, c2, b0``.
    rate : (W, 2) ``c`` (1) and ``u̇_0`` (V/s).
    skip : (W,) bool; walkers marked here are reported failed and not simulated.
    state : (W, 3 + D + 3) staircase memory, then ``u_prev, t_prev, has_prev``; updated.
    y : (W, N) output, written.
    failed : (W,) bool, written: True where an output was not finite.
    """
    for w in prange(tables.shape[0]):
        failed[w] = skip[w] or _rate_one(u, t, nodes[w], tables[w], bilinear, coef[w, 0],
                                         coef[w, 1], coef[w, 2], coef[w, 3], rate[w, 0],
                                         rate[w, 1], state[w], y[w])


@njit(cache=True)
def _rate_staircase_ser(u, t, nodes, tables, bilinear, coef, rate, skip, state, y, failed):
    for w in range(tables.shape[0]):
        failed[w] = skip[w] or _rate_one(u, t, nodes[w], tables[w], bilinear, coef[w, 0],
                                         coef[w, 1], coef[w, 2], coef[w, 3], rate[w, 0],
                                         rate[w, 1], state[w], y[w])


rate_staircase_batch = batch_kernel(_rate_staircase_par, _rate_staircase_ser, work_arg=-2,
                                    name="rate_staircase_batch")


@njit(cache=True)
def _diagonal_one(u, offset, mu, lo, h, v, y):
    """One walker of :func:`diagonal_preisach_batch`; returns True if an output was not finite."""
    n_lev = v.shape[0]
    # cum[d, j]: weight of the first j cells of diagonal d (cells (j + d, j) upwards)
    cum = np.zeros((n_lev, n_lev + 1))
    for d in range(n_lev):
        s = 0.0
        for j in range(n_lev - d):
            i = j + d
            s += mu[i * (i + 1) // 2 + j]
            cum[d, j + 1] = s
    failed = False
    for k in range(u.shape[0]):
        uk = u[k]
        acc = offset
        for d in range(n_lev):
            r = 0.5 * d * h
            vd = max(uk - r, min(uk + r, v[d]))
            v[d] = vd
            x = (vd - lo) / h - 0.5 * d
            m = n_lev - d
            if x >= m:
                acc += cum[d, m]
            elif x > 0.0:
                j = int(x)
                acc += cum[d, j] + (x - j) * (cum[d, j + 1] - cum[d, j])
        if not math.isfinite(acc):
            failed = True
        y[k] = acc
    return failed


@njit(cache=True, parallel=True)
def _diagonal_par(u, offset, mu, bounds, skip, state, y, failed):
    """Diagonally weighted Preisach output for W walkers (module docstring).

    Parameters
    ----------
    u : (N,) input (V).
    offset : (W,) output at negative saturation (output unit).
    mu : (W, L(L+1)/2) cell weights, cell ``(i, j)`` at ``i (i + 1) / 2 + j`` (output unit).
    bounds : (W, 2) ``lo, hi`` of the plane (V), ``h = (hi - lo) / L``.
    skip : (W,) bool; walkers marked here are reported failed and not simulated.
    state : (W, L) play outputs ``v_d`` (V), updated in place.
    y : (W, N) output, written.
    failed : (W,) bool, written: True where an output was not finite.
    """
    for w in prange(state.shape[0]):
        h = (bounds[w, 1] - bounds[w, 0]) / state.shape[1]
        failed[w] = skip[w] or _diagonal_one(u, offset[w], mu[w], bounds[w, 0], h, state[w],
                                             y[w])


@njit(cache=True)
def _diagonal_ser(u, offset, mu, bounds, skip, state, y, failed):
    for w in range(state.shape[0]):
        h = (bounds[w, 1] - bounds[w, 0]) / state.shape[1]
        failed[w] = skip[w] or _diagonal_one(u, offset[w], mu[w], bounds[w, 0], h, state[w],
                                             y[w])


diagonal_preisach_batch = batch_kernel(_diagonal_par, _diagonal_ser, work_arg=-2,
                                       name="diagonal_preisach_batch")
