"""Kernel of the fractional-order MRC model (review §7.4, ref. [68]).

Normalised variables as in :mod:`bayeshyst.models._kernels.mrc`, with the mechanical
damping of order ``lam`` (see :class:`bayeshyst.models.mrc_fractional.FractionalMRC`)::

    xi'' / w^2 + 2 z w^-lam D^lam xi + xi = u_p      (mechanics, y = gain * xi)
    Q = u_p + c xi,   u = H[Q] + u_p                  (MRC loop, as in ``mrc``)

``D^lam xi`` is the diffusive representation of
:func:`bayeshyst.models.fractional.derivative_modes`:
``D^lam xi = t_ref^(lam - 1) (sum_i W_i z_i + C_inf xi')`` with ``z_i' = xi' - r_i z_i``,
rates ``r_i`` on a log grid around ``1 / t_ref``. The grid reaches rates far above the
sampling rate, so an explicit integrator on the modes would need steps of ``1 / r_max``.

**Exact mode update.** The mechanics ``(xi, xi')`` is advanced by RK4 sub-steps exactly as
in ``mrc`` (same sub-step rule, same loop solves, the loop function ``_accel`` of
:mod:`bayeshyst.models._kernels.mrc`); only the damping force changes. Across a sub-step
``[0, h]`` the velocity is taken linear between the start value ``v_0`` and the value
``v_tau`` of the RK4 stage at ``tau`` (``h / 2`` or ``h``), and every mode is integrated
exactly along it::

    z_i(tau) = e^(-r tau) z_i(0) + tau (phi1 - phi2)(r tau) v_0 + tau phi2(r tau) v_tau,
    phi1(x) = (1 - e^-x) / x,  phi2(x) = (x - 1 + e^-x) / x^2,

so a stage's ``D^lam xi`` is ``S(tau) + v_0 A(tau) + v_tau B(tau)``: the fast modes
(``r h >> 1``, ``z = xi' / r``) enter as the instantaneous damping they are, the slow ones
as the memory they are, and no mode limits the step. The modes are committed after the
sub-step with the velocity linear from ``v_0`` to the new ``v``. At ``lam = 1`` every
``W_i`` is zero and ``C_inf = 1``: the damping is ``2 z w xi'`` and every operation is
``mrc``'s, so the output is ``mrc``'s bit for bit.

The sub-step count is ``mrc``'s rule, ``ceil(dt lam_max / step)``, with the fastest rate
``lam_max = w max(sqrt(1 + c + s_2), g)``: ``g`` the damping rate per ``w`` of the modes
over one sample interval (a mode contributes ``W_i min(1 / r_i, dt)``) and ``s_2`` the
stiffness per ``w^2`` of the modes slower than the sample interval (their ``z`` grows as
the displacement). At ``lam = 1``, ``g = 2 z`` and ``s_2 = 0``: ``mrc``'s rule.
The mode coefficients are cached for the sample interval ``h_ref`` (kept in the state,
so a run in pieces equals one run) and its sub-step count; an interval within
:data:`bayeshyst.models._kernels.blocks.DT_RTOL` of ``h_ref`` reuses them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.blocks import DT_RTOL
from bayeshyst.models._kernels.mrc import (
    _accel,
    commit_loop,
    commit_sliders,
    loop_solve,
    record_loop,
)

__all__ = ["fractional_mrc_batch", "mode_coefficients"]


@njit(cache=True)
def _phi12(x):
    """``phi1 = (1 - e^-x) / x`` and ``phi2 = (x - 1 + e^-x) / x^2`` without cancellation."""
    if x < 1e-3:
        # the series: truncation below x^4 / 720 < 2e-15
        return (1.0 - x / 2.0 + x * x / 6.0 - x * x * x / 24.0,
                0.5 - x / 6.0 + x * x / 24.0 - x * x * x / 120.0)
    p1 = -math.expm1(-x) / x
    return p1, (1.0 - p1) / x


@njit(cache=True)
def mode_coefficients(rates, tau, e, a, b):
    """Exact update of ``z' = v - r z`` over ``tau`` with ``v`` linear from ``v_0`` to ``v_tau``.

    Writes ``e = exp(-r tau)``, ``a`` (coefficient of ``v_0``) and ``b`` (of ``v_tau``),
    so that ``z(tau) = e z(0) + a v_0 + b v_tau``; all shape ``(n,)``.
    """
    for i in range(rates.shape[0]):
        x = rates[i] * tau
        p1, p2 = _phi12(x)
        e[i] = math.exp(-x)
        a[i] = tau * (p1 - p2)
        b[i] = tau * p2


@njit(cache=True)
def _fastest_rate(omega, c, kk, rates, weights, c_inf, dt):
    """``lam_max / w`` of the module docstring (``kk = 2 z w^(1 - lam) t_ref^(lam - 1)``)."""
    g = c_inf
    s2 = 0.0
    for i in range(rates.shape[0]):
        g += weights[i] * min(1.0 / rates[i], dt)
        if rates[i] * dt < 1.0:
            s2 += weights[i]
    return max(math.sqrt(1.0 + c + s2 * kk / omega), g * kk)


@njit(cache=True)
def _fractional_mrc_one(u, t, f_n, zeta, gain, c, lam, t_ref, rho, delta, rates, weights,
                        c_inf, state, y, step, max_sub, rec):
    """One walker of :func:`fractional_mrc_batch`; returns True if it failed."""
    ok = (f_n > 0.0 and zeta >= 0.0 and c >= 0.0 and 0.0 < lam <= 1.0 and t_ref > 0.0
          and math.isfinite(f_n + zeta + gain + c + t_ref + c_inf))
    m = rates.shape[0]
    for i in range(m):
        ok = ok and rates[i] > 0.0 and math.isfinite(rates[i] + weights[i])
    n = rho.shape[0]
    for i in range(n):
        ok = ok and rho[i] >= 0.0 and delta[i] >= 0.0 and math.isfinite(rho[i] + delta[i])
    if not ok:
        return True
    omega = 2.0 * math.pi * f_n
    xi = state[0]
    v = state[1]
    qb = state[2:2 + n]
    u_prev = state[2 + n]
    t_prev = state[3 + n]
    href = state[4 + n]
    z = state[5 + n:5 + n + m]
    hmax = 0.0
    for i in range(n):
        if rho[i] > 0.0:
            hmax += rho[i] * delta[i]
    w2 = omega * omega
    # the damping force per unit of t_ref^(1 - lam) D^lam xi (at lam = 1: mrc's 2 z w)
    kdamp = 2.0 * zeta * omega ** (2.0 - lam) * t_ref ** (lam - 1.0)
    kk = 2.0 * zeta * omega ** (1.0 - lam) * t_ref ** (lam - 1.0)
    e_half = np.empty(m)
    a_half = np.empty(m)
    b_half = np.empty(m)
    e_full = np.empty(m)
    a_full = np.empty(m)
    b_full = np.empty(m)
    sa_half = sa_full = 0.0
    cb_half = cb_full = c_inf
    lam_max = 0.0
    nsub_ref = -1
    if href > 0.0:
        lam_max = omega * _fastest_rate(omega, c, kk, rates, weights, c_inf, href)
    x1 = np.empty(1)
    y1 = np.empty(1)
    # the damping memory carried by the modes
    s0 = 0.0
    for i in range(m):
        s0 += weights[i] * z[i]
    q, ok = loop_solve(u_prev + c * xi, rho, delta, qb, u_prev + c * xi, hmax)
    if not ok:
        return True
    for k in range(u.shape[0]):
        dt = t[k] - t_prev
        if math.isfinite(dt):
            if not abs(dt - href) <= DT_RTOL * href:
                href = dt
                nsub_ref = -1
                lam_max = omega * _fastest_rate(omega, c, kk, rates, weights, c_inf, href)
            nsub = math.ceil(dt * lam_max / step)
            if nsub > max_sub:
                return True
            nsub = max(nsub, 1)
            if nsub != nsub_ref:
                hh = href / nsub
                mode_coefficients(rates, 0.5 * hh, e_half, a_half, b_half)
                mode_coefficients(rates, hh, e_full, a_full, b_full)
                sa_half = sa_full = 0.0
                cb_half = cb_full = c_inf
                for i in range(m):
                    sa_half += weights[i] * a_half[i]
                    sa_full += weights[i] * a_full[i]
                    cb_half += weights[i] * b_half[i]
                    cb_full += weights[i] * b_full[i]
                nsub_ref = nsub
            h = dt / nsub
            du = (u[k] - u_prev) / nsub
            a1 = w2 * (q - c * xi - xi) - kdamp * (c_inf * v + s0)
            for j in range(nsub):
                ua = u_prev + j * du
                ub = u[k] if j == nsub - 1 else ua + du
                um = 0.5 * (ua + ub)
                # the modes' memory decayed to the stage times, plus v_0's share
                s_half = v * sa_half
                s_full = v * sa_full
                for i in range(m):
                    s_half += weights[i] * e_half[i] * z[i]
                    s_full += weights[i] * e_full[i] * z[i]
                x2 = xi + 0.5 * h * v
                v2 = v + 0.5 * h * a1
                a2, q, ok2 = _accel(x2, v2 * cb_half + s_half, um, w2, kdamp, c, rho, delta,
                                    qb, q, hmax)
                x3 = xi + 0.5 * h * v2
                v3 = v + 0.5 * h * a2
                a3, q, ok3 = _accel(x3, v3 * cb_half + s_half, um, w2, kdamp, c, rho, delta,
                                    qb, q, hmax)
                x4 = xi + h * v3
                v4 = v + h * a3
                a4, q, ok4 = _accel(x4, v4 * cb_full + s_full, ub, w2, kdamp,
                                    c, rho, delta, qb, q, hmax)
                v_old = v
                xi += h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
                v += h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
                if not (ok2 and ok3 and ok4 and math.isfinite(xi) and math.isfinite(v)):
                    return True
                # commit the modes along the sub-step's velocity, linear from v_old to v
                s0 = 0.0
                for i in range(m):
                    z[i] = e_full[i] * z[i] + a_full[i] * v_old + b_full[i] * v
                    s0 += weights[i] * z[i]
                # solve at the sub-step's end, then commit the sliders (and only then)
                a1, q, ok = _accel(xi, c_inf * v + s0, ub, w2, kdamp, c, rho, delta, qb, q,
                                   hmax)
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
    state[4 + n] = href
    return False


@njit(cache=True, parallel=True)
def _fractional_mrc_par(u, t, f_n, zeta, gain, coupling, lam, t_ref, rho, delta, rates,
                        weights, c_inf, state, y, failed, step, max_sub, rec):
    """Fractional-order MRC model for W parameter vectors.

    Parameters
    ----------
    u, t : (N,) input (V) and times (s); f_n, zeta, gain, coupling, lam, t_ref : (W,)
    natural frequency (Hz), damping coefficient, saturated gain (output unit/V),
    back-coupling, damping order and the rate grid's reference time (s); rho, delta :
    (W, n) element stiffness ratios and slip deflections (V); rates, weights : (W, m) and
    c_inf : (W,) from :func:`bayeshyst.models.fractional.derivative_modes`; state :
    (W, n + 5 + m) ``[xi, xi', Qb_1..Qb_n, u_prev, t_prev, h_ref, z_1..z_m]``, updated in
    place; y : (W, N), written; failed : (W,) bool, written; step, max_sub : sub-step rule
    as in ``mrc``; rec : (W, 3, N) or (W, 3, 0), as in ``mrc``.
    """
    for j in prange(f_n.shape[0]):
        failed[j] = _fractional_mrc_one(u, t, f_n[j], zeta[j], gain[j], coupling[j], lam[j],
                                        t_ref[j], rho[j], delta[j], rates[j], weights[j],
                                        c_inf[j], state[j], y[j], step, max_sub, rec[j])


@njit(cache=True)
def _fractional_mrc_ser(u, t, f_n, zeta, gain, coupling, lam, t_ref, rho, delta, rates,
                        weights, c_inf, state, y, failed, step, max_sub, rec):
    for j in range(f_n.shape[0]):
        failed[j] = _fractional_mrc_one(u, t, f_n[j], zeta[j], gain[j], coupling[j], lam[j],
                                        t_ref[j], rho[j], delta[j], rates[j], weights[j],
                                        c_inf[j], state[j], y[j], step, max_sub, rec[j])


# an MRC sample (RK4 sub-steps with loop solves) plus three passes over the modes per
# sub-step: a few times mrc's cost (benchmarks/bench_kernels.py)
fractional_mrc_batch = batch_kernel(_fractional_mrc_par, _fractional_mrc_ser, work_arg=14,
                                    name="fractional_mrc_batch", cost=200)
