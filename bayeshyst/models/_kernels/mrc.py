"""Kernel of the MRC electromechanical model (review Eq. 38–44, MODELS.md §4).

Normalised variables (see :class:`bayeshyst.models.mrc.MRCElectromechanical`)::

    xi'' / w^2 + 2 z xi' / w + xi = u_p          (mechanics, y = gain * xi)
    Q = u_p + c xi                               (charge / C, volts)
    u = H[Q] + u_p,   H[Q] = sum_i rho_i clamp(Q - Qb_i, -delta_i, delta_i)

``H`` is a Maxwell-slip on charge (elasto-slide elements, Eq. 38–39). At any instant
``xi`` and the slider positions ``Qb`` are known, so ``u_p`` follows from the scalar
equation ``G(Q) = Q + H(Q) = u + c xi`` (the algebraic loop): ``G`` is piecewise linear
and strictly increasing (slope ``1 + sum of rho_i over sticking elements >= 1``), so a
bracketed Newton iteration lands exactly on the root once it is in the right linear
piece (:func:`loop_solve`).

Time integration: classical RK4 on ``(xi, xi')`` with the input linearly interpolated
between samples, ``n_sub = ceil(dt * lam / step)`` sub-steps per sample interval with
``lam = w max(sqrt(1 + c), 2 z)`` the fastest rate of the mechanics (stiffened by the
back-coupling, or the fast pole of an overdamped system). Every RK4 stage solves the loop
against the sliders committed at the start of the sub-step; because ``clamp`` of the
old slider positions is the exact elasto-slide output for any monotone motion of ``Q``
within the sub-step, stages never need to commit. The sliders are committed once per
sub-step, after the solve at its end, with the Maxwell-slip kernel of
:mod:`bayeshyst.models._kernels.operators`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.operators import _maxwell_one

__all__ = ["loop_solve", "mrc_batch"]

_EPS = 2.220446049250313e-16


@njit(cache=True)
def loop_solve(r, rho, delta, qb, guess, hmax):
    """Solve ``Q + sum_i rho_i clamp(Q - qb_i, -delta_i, delta_i) = r`` for ``Q``.

    Parameters
    ----------
    r : float
        Right-hand side ``u + c xi`` (V).
    rho, delta, qb : ndarray, shape (n,)
        Element stiffness ratios (``>= 0``), slip deflections (V, ``>= 0``) and
        committed slider positions (V); not modified.
    guess : float
        Starting point (the previous solution: usually already in the right piece).
    hmax : float
        ``sum_i rho_i delta_i``, the largest ``|H|``: the root lies in
        ``[r - hmax, r + hmax]``.

    Returns
    -------
    q : float
        The root.
    ok : bool
        False if ``r`` is not finite or the iteration did not converge.
    """
    if not math.isfinite(r):
        return r, False
    lo = r - hmax
    hi = r + hmax
    q = min(max(guess, lo), hi)
    n = rho.shape[0]
    for _ in range(200):
        g = q
        mag = abs(q)
        slope = 1.0
        # the linear piece of G that contains q, [p_lo, p_hi], bounded by the nearest
        # breakpoints qb_i +- delta_i
        p_lo = -math.inf
        p_hi = math.inf
        for i in range(n):
            d = q - qb[i]
            if d >= delta[i]:
                term = rho[i] * delta[i]
                p_lo = max(p_lo, qb[i] + delta[i])
            elif d <= -delta[i]:
                term = -rho[i] * delta[i]
                p_hi = min(p_hi, qb[i] - delta[i])
            else:
                term = rho[i] * d
                slope += rho[i]
                p_lo = max(p_lo, qb[i] - delta[i])
                p_hi = min(p_hi, qb[i] + delta[i])
            g += term
            mag += abs(term)
        res = g - r
        # below the rounding floor of G itself no iteration can do better
        if abs(res) <= 8.0 * _EPS * (mag + abs(r)):
            return q, True
        qn = q - res / slope
        # G is linear on the piece: a Newton step that stays in it is the exact root
        # (the usual case with a warm start), no second evaluation needed
        if p_lo <= qn <= p_hi:
            return qn, True
        if res > 0.0:
            hi = q
        else:
            lo = q
        if not (qn > lo and qn < hi):
            qn = 0.5 * (lo + hi)
        if qn == q or hi - lo <= 4.0 * _EPS * (abs(lo) + abs(hi)):
            return q, True
        q = qn
    return q, False


@njit(cache=True)
def _accel(xi, v, ut, w2, zw2, c, rho, delta, qb, guess, hmax):
    q, ok = loop_solve(ut + c * xi, rho, delta, qb, guess, hmax)
    return w2 * (q - c * xi - xi) - zw2 * v, q, ok


@njit(cache=True)
def commit_sliders(q, rho, delta, qb, x1, y1):
    """Move the sliders ``qb`` to the loop's solved charge ``q``; ``y1[0]`` = ``G(q)``."""
    x1[0] = q
    _maxwell_one(x1, 1.0, rho, delta, qb, y1)


@njit(cache=True)
def commit_loop(r, rho, delta, qb, q, hmax, x1, y1):
    """Solve the loop at drive ``r`` from ``q`` and commit the sliders to it.

    Returns ``(Q, ok)``: the relaxed start of the MRC kernels, where the mechanics cannot
    move in no time and only the electrical side adjusts.
    """
    q, ok = loop_solve(r, rho, delta, qb, q, hmax)
    if ok:
        commit_sliders(q, rho, delta, qb, x1, y1)
    return q, ok


@njit(cache=True)
def record_loop(rec, k, q, c, xi, g, u_k):
    """Write sample ``k``'s ``u_p``, ``Q`` and loop residual ``G(Q) - (u + c xi)`` (V)."""
    if rec.shape[1] > 0:
        rec[0, k] = q - c * xi
        rec[1, k] = q
        rec[2, k] = g - (u_k + c * xi)


@njit(cache=True)
def _mrc_one(u, t, f_n, zeta, gain, c, rho, delta, state, y, step, max_sub, rec):
    """One walker of :func:`mrc_batch`; returns True if it failed."""
    ok = f_n > 0.0 and zeta >= 0.0 and c >= 0.0 and math.isfinite(f_n + zeta + gain + c)
    for i in range(rho.shape[0]):
        ok = ok and rho[i] >= 0.0 and delta[i] >= 0.0 and math.isfinite(rho[i] + delta[i])
    if not ok:
        return True
    omega = 2.0 * math.pi * f_n
    n = rho.shape[0]
    xi = state[0]
    v = state[1]
    qb = state[2:2 + n]
    u_prev = state[2 + n]
    t_prev = state[3 + n]
    hmax = 0.0
    for i in range(n):
        if rho[i] > 0.0:
            hmax += rho[i] * delta[i]
    w2 = omega * omega
    zw2 = 2.0 * zeta * omega
    lam = omega * max(math.sqrt(1.0 + c), 2.0 * zeta)
    x1 = np.empty(1)
    y1 = np.empty(1)
    # the loop solution at the state's instant is a function of the state: recompute it
    q, ok = loop_solve(u_prev + c * xi, rho, delta, qb, u_prev + c * xi, hmax)
    if not ok:
        return True
    for k in range(u.shape[0]):
        dt = t[k] - t_prev
        if math.isfinite(dt):
            nsub = math.ceil(dt * lam / step)
            if nsub > max_sub:
                return True
            nsub = max(nsub, 1)
            h = dt / nsub
            du = (u[k] - u_prev) / nsub
            a1 = w2 * (q - c * xi - xi) - zw2 * v
            for j in range(nsub):
                ua = u_prev + j * du
                ub = u[k] if j == nsub - 1 else ua + du
                um = 0.5 * (ua + ub)
                x2 = xi + 0.5 * h * v
                v2 = v + 0.5 * h * a1
                a2, q, ok2 = _accel(x2, v2, um, w2, zw2, c, rho, delta, qb, q, hmax)
                x3 = xi + 0.5 * h * v2
                v3 = v + 0.5 * h * a2
                a3, q, ok3 = _accel(x3, v3, um, w2, zw2, c, rho, delta, qb, q, hmax)
                x4 = xi + h * v3
                v4 = v + h * a3
                a4, q, ok4 = _accel(x4, v4, ub, w2, zw2, c, rho, delta, qb, q, hmax)
                xi += h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
                v += h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
                if not (ok2 and ok3 and ok4 and math.isfinite(xi) and math.isfinite(v)):
                    return True
                # solve at the sub-step's end, then commit the sliders (and only then)
                a1, q, ok = _accel(xi, v, ub, w2, zw2, c, rho, delta, qb, q, hmax)
                if not ok:
                    return True
                commit_sliders(q, rho, delta, qb, x1, y1)
        else:
            # relaxed start (t_prev = -inf): the mechanics cannot move in no time, only
            # the electrical side adjusts to u[k]
            q, ok = commit_loop(u[k] + c * xi, rho, delta, qb, q, hmax, x1, y1)
            if not ok:
                return True
        y[k] = gain * xi
        record_loop(rec, k, q, c, xi, y1[0], u[k])
        u_prev = u[k]
        t_prev = t[k]
    state[0] = xi
    state[1] = v
    state[2 + n] = u_prev
    state[3 + n] = t_prev
    return False


@njit(cache=True, parallel=True)
def _mrc_par(u, t, f_n, zeta, gain, coupling, rho, delta, state, y, failed, step, max_sub,
             rec):
    """MRC electromechanical model for W parameter vectors.

    Parameters
    ----------
    u, t : (N,) input (V) and times (s); f_n, zeta, gain, coupling : (W,) natural
    frequency (Hz), damping ratio, saturated gain (output unit/V), back-coupling
    ``T_F T_q / (k C)``; rho, delta : (W, n) element stiffness ratios ``C / C_i`` and slip
    deflections (V); state : (W, n + 4) ``[xi, xi', Qb_1..Qb_n, u_prev, t_prev]``,
    updated in place; y : (W, N), written; failed : (W,) bool, written; step : float,
    largest ``lam * h`` of an RK4 sub-step; max_sub : int, most sub-steps per sample
    (more is a failure); rec : (W, 3, N) or (W, 3, 0): if non-empty, receives per sample
    ``u_p``, ``Q`` and the loop residual ``G(Q) - (u + c xi)`` (V).
    """
    for j in prange(f_n.shape[0]):
        failed[j] = _mrc_one(u, t, f_n[j], zeta[j], gain[j], coupling[j], rho[j], delta[j],
                             state[j], y[j], step, max_sub, rec[j])


@njit(cache=True)
def _mrc_ser(u, t, f_n, zeta, gain, coupling, rho, delta, state, y, failed, step, max_sub,
             rec):
    for j in range(f_n.shape[0]):
        failed[j] = _mrc_one(u, t, f_n[j], zeta[j], gain[j], coupling[j], rho[j], delta[j],
                             state[j], y[j], step, max_sub, rec[j])


# a sample costs microseconds (RK4 sub-steps, each solving the loop), hundreds of times
# a PI sample: at 100 work units each, the switch to threads comes at about 200
# walker-samples, ~1 ms of serial work (bayeshyst.models._kernels.PARALLEL_MIN_WORK)
mrc_batch = batch_kernel(_mrc_par, _mrc_ser, work_arg=9, name="mrc_batch", cost=100)
