"""Kernel of the fractional-order Duhem model (review §8, ref. [87]).

The hysteretic state ``h`` of the improved Duhem model (review Eq. 46) is integrated
exactly in the normalised input, as in :mod:`bayeshyst.models._kernels.duhem`. The rate
term uses a fractional derivative ``D^lam u`` (``0 < lam <= 1``) in its *diffusive
representation* (the approach of the ``creep_fractional`` block)::

    D^lam u(t) = sum_i c_i z_i(t) + c_inf du/dt,     dz_i/dt = du/dt - r_i z_i,

``z_i`` the output of a first-order high-pass of rate ``r_i`` (``s / (s + r_i)``) on a
fixed log grid, ``c_i`` the mass of ``sin(pi (1 - lam)) / pi r^(lam - 1)`` in each cell,
and ``c_inf du/dt`` the cells above the grid, where ``z_i = du/dt / r_i``
(:func:`bayeshyst.models.fractional.derivative_modes`). Between samples the input is a
straight line (slope ``m``, the backward difference), so each high-pass is advanced
exactly: ``z <- exp(-r h) z + m (1 - exp(-r h)) / r``. At ``lam = 1`` every ``c_i`` is
zero and ``c_inf = 1``: the backward difference of ``duhem_improved`` exactly. The cost
is the number of modes per sample, with no growing Grünwald–Letnikov memory, and any
sampling is handled exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.blocks import DT_RTOL
from bayeshyst.models._kernels.duhem import poly_forced_step

__all__ = ["fractional_duhem_batch"]


@njit(cache=True)
def _mode_steps(rates, h, dec, gain):
    for i in range(rates.shape[0]):
        dec[i] = math.exp(-rates[i] * h)
        gain[i] = -math.expm1(-rates[i] * h) / rates[i]


@njit(cache=True)
def _fractional_one(u, t, k_lin, p_rate, a, b, c, uc, uh, rates, cw, c_inf, state, y):
    ok = b >= 0.0 and uh > 0.0 and math.isfinite(k_lin + p_rate + a + b + c + uc + uh + c_inf)
    n = rates.shape[0]
    for i in range(n):
        ok = ok and rates[i] > 0.0 and math.isfinite(rates[i] + cw[i])
    if not ok:
        return True
    pp = np.empty(2)
    J = np.empty(2)
    dec = np.empty(n)
    gain = np.empty(n)
    h = state[0]
    u_prev = state[1]
    t_prev = state[2]
    href = state[3]
    z = state[4:4 + n]
    if href > 0.0:
        _mode_steps(rates, href, dec, gain)
    sa = (u_prev - uc) / uh
    for k in range(u.shape[0]):
        sb = (u[k] - uc) / uh
        if sb != sa:
            # dh/ds = alpha - beta sgn h + gamma s: kappa = beta, P = alpha + gamma s
            pp[0] = a
            pp[1] = c
            h = poly_forced_step(h, sa, sb, b, pp, 1, J)
        dt = t[k] - t_prev
        # t_prev = -inf (relaxed start): at rest before, nothing to propagate, slope 0
        if math.isfinite(dt):
            slope = (u[k] - u_prev) / dt
            if not abs(dt - href) <= DT_RTOL * href:
                href = dt
                _mode_steps(rates, href, dec, gain)
            frac = c_inf * slope
            for i in range(n):
                z[i] = dec[i] * z[i] + slope * gain[i]
                frac += cw[i] * z[i]
        else:
            frac = 0.0
            for i in range(n):
                frac += cw[i] * z[i]
        yk = k_lin * u[k] + p_rate * frac - h
        if not math.isfinite(yk):
            return True
        y[k] = yk
        sa = sb
        u_prev = u[k]
        t_prev = t[k]
    state[0] = h
    state[1] = u_prev
    state[2] = t_prev
    state[3] = href
    return False


@njit(cache=True, parallel=True)
def _fractional_par(u, t, k_lin, p_rate, alpha, beta, gamma, uc, uh, rates, cw, c_inf, state,
                    y, failed):
    """Fractional-order Duhem ``y = k u + p D^lam u - h`` for W parameter vectors.

    Parameters
    ----------
    u, t : (N,) input (V) and times (s); k_lin, p_rate, alpha, beta, gamma, uc, uh : (W,);
    rates (W, n) mode rates (1/s); cw (W, n) mode weights and c_inf (W,) the weight of
    ``du/dt``, both already scaled by ``t_ref^(1 - lam)``; state : (W, n + 4)
    ``[h, u_prev, t_prev, h_ref, z_1 .. z_n]``, updated in place; y : (W, N), written;
    failed : (W,) bool, written.
    """
    for j in prange(alpha.shape[0]):
        failed[j] = _fractional_one(u, t, k_lin[j], p_rate[j], alpha[j], beta[j], gamma[j],
                                    uc[j], uh[j], rates[j], cw[j], c_inf[j], state[j], y[j])


@njit(cache=True)
def _fractional_ser(u, t, k_lin, p_rate, alpha, beta, gamma, uc, uh, rates, cw, c_inf, state,
                    y, failed):
    for j in range(alpha.shape[0]):
        failed[j] = _fractional_one(u, t, k_lin[j], p_rate[j], alpha[j], beta[j], gamma[j],
                                    uc[j], uh[j], rates[j], cw[j], c_inf[j], state[j], y[j])


# a sample advances every mode: with the default 41 modes about twice a Duhem sample
# (~80 ns, benchmarks/bench_kernels.py), still in the range of cost 1 kernels
fractional_duhem_batch = batch_kernel(_fractional_par, _fractional_ser, work_arg=-2,
                                      name="fractional_duhem_batch")
