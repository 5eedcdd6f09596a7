"""Kernels of the PI operator variants: right/left play, dead-zone MPI, one-side play (MPI, MRPI).

Equations (review §6.5, Eq. 23–27; refs. [56] [62] [63] [106])::

    right play   v_k = max(R_r(u_k), min(u_k, v_{k-1})),
                 R_r(u) = u_lo + (u - u_lo - r) S / (S - r)
    left play    v_k = min(L_r(u_k), max(u_k, v_{k-1})),
                 L_r(u) = u_lo + (u - u_lo) S / (S - r)
    dead zone    S_d(z) = max(z - d, 0) (d > 0),  min(z - d, 0) (d < 0),  z (d = 0)
    one-side play        v_k = max(u_k - r, min(u_k, v_{k-1}))
    rate one-side play   v_k = max(u_k - τ_l |q_{k-1}| - r, v_{k-1})   if u_k > u_{k-1}
                         v_k = min(u_k + τ_r |q_{k-1}|, v_{k-1})       if u_k < u_{k-1}
                         v_k = v_{k-1}                                 otherwise,
                         q_k = (u_k - u_{k-1}) / (t_k - t_{k-1})

``S`` is the data's input span and ``u_lo`` its lower end (the review's normalised input
``v in [0, 1]`` written in volts). The models' docstrings give the outputs built from
these operators.

As in :mod:`bayeshyst.models._kernels.pi_variants`, clamps are evaluated as written
(outer ``max`` for the right and one-side plays, outer ``min`` for the left play), which
decides which boundary wins where a band is inverted. Batched kernels take parameters
with a leading walker axis ``W``, write ``y`` (W, N) and update ``state`` (W, S) in
place; the loop over walkers runs in parallel for large batches and serially otherwise
(:func:`bayeshyst.models._kernels.batch_kernel`), and nothing is allocated per sample.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "dead_zone",
    "pi_deadzone_batch",
    "pi_osp_batch",
    "pi_osp_rate_batch",
    "pi_right_left_batch",
]


# error_model="numpy": a walker with a threshold at the span (out of support) must give
# inf/NaN that the model flags as failed, not raise ZeroDivisionError in the parallel loop
@njit(cache=True, error_model="numpy")
def _right_left_one(u, p0, wr, wl, rr, rl, ulo, span, s, y):
    n = wr.shape[0]
    # the boundaries' slopes S / (S - r), once per walker rather than per sample
    slope_r = np.empty(n)
    slope_l = np.empty(n)
    for i in range(n):
        slope_r[i] = span / (span - rr[i])
        slope_l[i] = span / (span - rl[i])
    for k in range(u.shape[0]):
        uk = u[k]
        acc = p0 * uk
        x = uk - ulo
        for i in range(n):
            # right play: rises along the line from (u_lo + r, u_lo) to (u_hi, u_hi),
            # falls along u; max outermost (the rising boundary wins if inverted)
            lo = ulo + (x - rr[i]) * slope_r[i]
            vi = s[i]
            vi = uk if vi > uk else vi
            vi = lo if vi < lo else vi
            s[i] = vi
            acc += wr[i] * vi
        for i in range(n):
            # left play: falls along the line from (u_lo, u_lo) to (u_hi - r, u_hi),
            # rises along u; min outermost (the falling boundary wins if inverted)
            hi = ulo + x * slope_l[i]
            vi = s[n + i]
            vi = uk if vi < uk else vi
            vi = hi if vi > hi else vi
            s[n + i] = vi
            acc += wl[i] * vi
        y[k] = acc


@njit(cache=True, parallel=True)
def _pi_right_left_par(u, p0, wr, wl, rr, rl, ulo, span, state, y):
    """Right/left-play PI ``y = p0 u + sum_i wr_i F^R_i[u] + sum_i wl_i F^L_i[u]``.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    p0 : ndarray, shape (W,)
        Linear weight (output unit/V).
    wr, wl : ndarray, shape (W, n)
        Weights of the right and left plays (output unit/V).
    rr, rl : ndarray, shape (W, n)
        Thresholds of the right and left plays (V), in ``(0, span)``.
    ulo, span : ndarray, shape (W,)
        Lower end and span of the input range the operators are anchored to (V).
    state : ndarray, shape (W, 2 n)
        Right-play outputs then left-play outputs (V); updated in place.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(wr.shape[0]):
        _right_left_one(u, p0[j], wr[j], wl[j], rr[j], rl[j], ulo[j], span[j], state[j], y[j])


@njit(cache=True)
def _pi_right_left_ser(u, p0, wr, wl, rr, rl, ulo, span, state, y):
    for j in range(wr.shape[0]):
        _right_left_one(u, p0[j], wr[j], wl[j], rr[j], rl[j], ulo[j], span[j], state[j], y[j])


pi_right_left_batch = batch_kernel(_pi_right_left_par, _pi_right_left_ser, work_arg=-1,
                                   name="pi_right_left_batch")


@njit(cache=True)
def dead_zone(z, d):
    """One-sided dead-zone operator ``S_d(z)`` of Kuhnen's modified PI (output unit)."""
    if d > 0.0:
        return z - d if z > d else 0.0
    if d < 0.0:
        return z - d if z < d else 0.0
    return z


@njit(cache=True)
def _deadzone_one(u, p0, w, r, g, d, v, y):
    n = w.shape[0]
    m = g.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        z = p0 * uk
        for i in range(n):
            lo = uk - r[i]
            hi = uk + r[i]
            vi = v[i]
            vi = lo if vi < lo else (hi if vi > hi else vi)
            v[i] = vi
            z += w[i] * vi
        acc = z
        for j in range(m):
            acc += g[j] * dead_zone(z, d[j])
        y[k] = acc


@njit(cache=True, parallel=True)
def _pi_deadzone_par(u, p0, w, r, g, d, state, y):
    """Dead-zone modified PI ``y = z + sum_j g_j S_{d_j}(z)``, ``z = p0 u + sum_i w_i F_{r_i}[u]``.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    p0 : ndarray, shape (W,)
        Linear weight of the play part (output unit/V).
    w, r : ndarray, shape (W, n)
        Play weights (output unit/V) and thresholds (V).
    g, d : ndarray, shape (W, m)
        Dead-zone weights (dimensionless) and thresholds (output unit).
    state : ndarray, shape (W, n)
        Play outputs (V); updated in place.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _deadzone_one(u, p0[j], w[j], r[j], g[j], d[j], state[j], y[j])


@njit(cache=True)
def _pi_deadzone_ser(u, p0, w, r, g, d, state, y):
    for j in range(w.shape[0]):
        _deadzone_one(u, p0[j], w[j], r[j], g[j], d[j], state[j], y[j])


pi_deadzone_batch = batch_kernel(_pi_deadzone_par, _pi_deadzone_ser, work_arg=-1,
                                 name="pi_deadzone_batch")


@njit(cache=True)
def _polynomial(uk, p0, a2, a3, uc, uh):
    # written as p0 u + (correction) so that a2 = a3 = 0 adds an exact zero
    x = (uk - uc) / uh
    return p0 * uk + uh * (a2 * x * x + a3 * x * x * x)


@njit(cache=True)
def _osp_one(u, p0, a2, a3, uc, uh, w, r, v, y):
    n = w.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        acc = _polynomial(uk, p0, a2, a3, uc, uh)
        for i in range(n):
            lo = uk - r[i]
            vi = v[i]
            vi = uk if vi > uk else vi
            vi = lo if vi < lo else vi
            v[i] = vi
            acc += w[i] * vi
        y[k] = acc


@njit(cache=True, parallel=True)
def _pi_osp_par(u, p0, a2, a3, uc, uh, w, r, state, y):
    """One-side-play MPI ``y = p(u) + sum_i w_i max(u - r_i, min(u, v_i))``.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    p0, a2, a3 : ndarray, shape (W,)
        Coefficients of ``p(u) = p0 u + u_h (a2 x² + a3 x³)`` (output unit/V).
    uc, uh : ndarray, shape (W,)
        Centre and half-span of ``x = (u - u_c) / u_h`` (V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and thresholds (V).
    state : ndarray, shape (W, n)
        Operator outputs (V); updated in place.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _osp_one(u, p0[j], a2[j], a3[j], uc[j], uh[j], w[j], r[j], state[j], y[j])


@njit(cache=True)
def _pi_osp_ser(u, p0, a2, a3, uc, uh, w, r, state, y):
    for j in range(w.shape[0]):
        _osp_one(u, p0[j], a2[j], a3[j], uc[j], uh[j], w[j], r[j], state[j], y[j])


pi_osp_batch = batch_kernel(_pi_osp_par, _pi_osp_ser, work_arg=-1, name="pi_osp_batch")


@njit(cache=True)
def _osp_rate_one(u, t, p0, a2, a3, uc, uh, w, r, tau_l, tau_r, s, y):
    n = w.shape[0]
    # s = [v_1..v_n, u_prev, t_prev, q_prev, has_prev]: the envelopes use the rate of
    # the previous step, so a continued run needs the last sample and that rate
    up = s[n]
    tp = s[n + 1]
    q = s[n + 2]
    has_prev = s[n + 3] != 0.0
    for k in range(u.shape[0]):
        uk = u[k]
        tk = t[k]
        # per monotone step: a rising step only raises v, a falling one only lowers it;
        # the envelopes' rate shift is shared by all operators (tau = 0 adds an exact 0)
        aq = abs(q)
        acc = _polynomial(uk, p0, a2, a3, uc, uh)
        if uk > up:
            gl = uk - tau_l * aq
            for i in range(n):
                lo = gl - r[i]
                if s[i] < lo:
                    s[i] = lo
                acc += w[i] * s[i]
        elif uk < up:
            gr = uk + tau_r * aq
            for i in range(n):
                if s[i] > gr:
                    s[i] = gr
                acc += w[i] * s[i]
        else:
            for i in range(n):
                acc += w[i] * s[i]
        y[k] = acc
        q = (uk - up) / (tk - tp) if has_prev else 0.0
        up = uk
        tp = tk
        has_prev = True
    s[n] = up
    s[n + 1] = tp
    s[n + 2] = q
    s[n + 3] = 1.0


@njit(cache=True, parallel=True)
def _pi_osp_rate_par(u, t, p0, a2, a3, uc, uh, w, r, tau_l, tau_r, state, y):
    """MRPI: one-side plays with the rate envelopes ``u ∓ τ |q|``, per monotone step.

    Parameters
    ----------
    u, t : ndarray, shape (N,)
        Input (V) and sample times (s), strictly increasing (also across ``state``).
    p0, a2, a3, uc, uh : ndarray, shape (W,)
        The polynomial part as in :func:`pi_osp_batch`.
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and thresholds (V).
    tau_l, tau_r : ndarray, shape (W,)
        Rate coefficients of the rising and falling envelopes (s).
    state : ndarray, shape (W, n + 4)
        Operator outputs (V), previous input (V), previous time (s), previous step's
        rate (V/s) and a flag (1.0 once there is a previous sample); updated in place.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _osp_rate_one(u, t, p0[j], a2[j], a3[j], uc[j], uh[j], w[j], r[j], tau_l[j],
                      tau_r[j], state[j], y[j])


@njit(cache=True)
def _pi_osp_rate_ser(u, t, p0, a2, a3, uc, uh, w, r, tau_l, tau_r, state, y):
    for j in range(w.shape[0]):
        _osp_rate_one(u, t, p0[j], a2[j], a3[j], uc[j], uh[j], w[j], r[j], tau_l[j],
                      tau_r[j], state[j], y[j])


pi_osp_rate_batch = batch_kernel(_pi_osp_rate_par, _pi_osp_rate_ser, work_arg=-1,
                                 name="pi_osp_rate_batch")
