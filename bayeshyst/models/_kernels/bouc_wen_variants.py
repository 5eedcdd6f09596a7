"""Kernels of the rate-dependent Bouc–Wen variants: review Eq. 49 as printed, and ref. [95].

**Eq. 49 with ``δ u sgn(u̇)``.** With the input linear between samples, over one interval
of length ``Δt`` the rate is constant, ``|u̇| = |Δu| / Δt``. Writing (as for the
classical kernel, :mod:`bayeshyst.models._kernels.bouc_wen`) ``s = sgn(Δu)``, ``x`` the
input travel and ``g = s h``, the time-domain equation

    ḣ = α u̇ - β |u̇| |h|^(n-1) h - γ u̇ |h|^n + δ u sgn(u̇)

divided by ``|u̇|`` is the classical travel equation with a drive that is linear in ``x``:

    dg/dx = a(x) - B(g) |g|^n,   a(x) = α + δ' u(x),   δ' = δ Δt / |Δu|

so the classical kernel's interval integrator (:func:`_bw_interval`, order-5 Taylor in
``x``) does the work, with ``δ'`` set per interval. Unlike the rate-independent reading,
``a`` may be negative here: at slow rates ``δ'`` is large, and ``δ u < 0`` can outweigh
``α``. The integrator needs ``a > 0``; where ``a < 0`` the interval is integrated in the
reflected frame ``g -> -g``, which is the same equation with ``a -> -a`` and ``γ -> -γ``
(``B+ = β - γ``, ``B- = -(β + γ)``), and an interval on which ``a`` changes sign is split
at its root. A sample with ``Δu = 0`` leaves ``h`` unchanged (``sgn(0) = 0``).

**First-order lag, first-order hold.** ``τ v̇ = u - v`` with ``u`` linear between samples
is solved exactly: ``v_k = u_k - τ S + (v_(k-1) - u_(k-1) + τ S) e^(-Δt/τ)``, ``S`` the
interval's slope; ``τ = 0`` gives ``v = u`` exactly (the frequency factor's neutral
value, :class:`~bayeshyst.models.bouc_wen_variants.FrequencyFactorBoucWen`).

Batched kernels take per-walker parameter arrays (W,), a state (W, S) updated in place,
write the output (W, N) and set ``failed`` (W,) (rows NaN) for parameter vectors outside
the valid region, time running backwards, or a non-finite state.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.bouc_wen import _bw_interval, branch_scales, bw_valid

__all__ = ["bw_sgn_batch", "lag_foh_batch"]


@njit(cache=True)
def _piece(g, length, a0, a1, beta, gamma, n, c_l, cnt):
    """Advance ``g`` over travel ``length`` where ``a = a0 + a1 x`` keeps one sign."""
    mid = a0 + 0.5 * a1 * length
    if mid > 0.0:
        sig = 1.0
        bp = beta + gamma
        bm = gamma - beta
    else:
        # reflected frame g -> -g: the same equation with a -> -a and gamma -> -gamma
        sig = -1.0
        bp = beta - gamma
        bm = -(beta + gamma)
    a0f = max(sig * a0, 0.0)  # a0 is 0 up to rounding when the piece starts at a root
    a1f = sig * a1
    a_hi = max(a0f, a0f + a1f * length)
    if not a_hi > 0.0:
        return g, cnt, False
    # step guards as in the classical kernel, for the largest drive of the piece (a
    # reflected beta = gamma has B+ = 0: no saturation on that branch, an infinite length)
    ellp, ellm, gcross, c_stiff, cb = branch_scales(a_hi, bp, bm, n, c_l)
    gf, _, cnt, ok = _bw_interval(sig * g, -1.0, length, a0f, a1f, bp, bm, n, ellp, ellm,
                                  gcross, cnt, c_l, c_stiff, cb)
    return sig * gf, cnt, ok


@njit(cache=True)
def _bw_sgn_one(u, t, k, alpha, beta, gamma, n, delta, state, y, c_l):
    """One walker of :func:`bw_sgn_batch`; returns False on failure."""
    h = state[0]
    up = state[1]
    tp = state[2]
    for i in range(u.shape[0]):
        if math.isnan(tp):
            tp = t[i]  # relaxed start: the state is taken at the first sample
            up = u[i]
        du = u[i] - up
        dt = t[i] - tp
        if dt < 0.0 or (du != 0.0 and dt == 0.0):
            return False
        if du != 0.0:
            s = 1.0 if du > 0.0 else -1.0
            X = abs(du)
            dp = delta * dt / X  # δ' = δ / |u̇| on this interval
            a0 = alpha + dp * up
            a1 = dp * s
            g = s * h
            end = a0 + a1 * X
            # |g|^n is recomputed at the start of every interval and the resync count
            # restarts: each interval depends on the state only (pieces == one run)
            cnt = 0
            if a0 * end < 0.0:
                xr = -a0 / a1  # a changes sign inside: split there
                g, cnt, ok = _piece(g, xr, a0, a1, beta, gamma, n, c_l, cnt)
                if ok:
                    g, cnt, ok = _piece(g, X - xr, 0.0, a1, beta, gamma, n, c_l, cnt)
            else:
                g, cnt, ok = _piece(g, X, a0, a1, beta, gamma, n, c_l, cnt)
            if not (ok and math.isfinite(g)):
                return False
            h = s * g
        up = u[i]
        tp = t[i]
        y[i] = k * u[i] - h
    state[0] = h
    state[1] = up
    state[2] = tp
    return math.isfinite(h)


@njit(cache=True)
def _bw_sgn_walker(j, u, t, k, alpha, beta, gamma, n, delta, c_l, state, y, failed):
    """Walker ``j`` of :func:`bw_sgn_batch` (the loop body, written once)."""
    ok = bw_valid(alpha[j], beta[j], gamma[j], n[j]) and math.isfinite(k[j])
    ok = ok and math.isfinite(delta[j]) and math.isfinite(state[j, 0])
    ok = ok and math.isfinite(state[j, 1]) and not math.isinf(state[j, 2])
    if ok:
        ok = _bw_sgn_one(u, t, k[j], alpha[j], beta[j], gamma[j], n[j], delta[j], state[j],
                         y[j], c_l)
    failed[j] = not ok
    if not ok:
        y[j, :] = np.nan


@njit(cache=True, parallel=True)
def _bw_sgn_batch_par(u, t, k, alpha, beta, gamma, n, delta, c_l, state, y, failed):
    """Bouc–Wen with the asymmetric term ``δ u sgn(u̇)`` of review Eq. 49, W walkers.

    ``y = k u - h``, ``ḣ = α u̇ - β|u̇||h|^(n-1) h - γ u̇|h|^n + δ u sgn(u̇)``, ``u``
    linear between samples.

    Parameters
    ----------
    u, t : ndarray, shape (N,)
        Input (V) and non-decreasing times (s); a change of ``u`` needs ``Δt > 0``.
    k, alpha : ndarray, shape (W,)
        Linear gain and hysteretic slope (output unit/V).
    beta, gamma : ndarray, shape (W,)
        Shape coefficients (1/(V output-unit^(n-1))).
    n : ndarray, shape (W,)
        Exponent (>= 1).
    delta : ndarray, shape (W,)
        Asymmetry (output unit/(V s)).
    c_l : float
        Largest step as a fraction of the relaxation length.
    state : ndarray, shape (W, 3)
        ``[h, u_prev, t_prev]`` (``t_prev`` NaN: relaxed at the first sample); updated.
    y : ndarray, shape (W, N)
        Output (output unit), written; NaN rows for failed walkers.
    failed : ndarray of bool, shape (W,)
        Written: parameters outside the stable region, time running backwards, a
        non-finite state.
    """
    for j in prange(k.shape[0]):
        _bw_sgn_walker(j, u, t, k, alpha, beta, gamma, n, delta, c_l, state, y, failed)


@njit(cache=True)
def _bw_sgn_batch_ser(u, t, k, alpha, beta, gamma, n, delta, c_l, state, y, failed):
    for j in range(k.shape[0]):
        _bw_sgn_walker(j, u, t, k, alpha, beta, gamma, n, delta, c_l, state, y, failed)


bw_sgn_batch = batch_kernel(_bw_sgn_batch_par, _bw_sgn_batch_ser, work_arg=-2,
                            name="bw_sgn_batch")


# ------------------------------------------------------------------ first-order lag


@njit(cache=True)
def _lag_foh_walker(j, u, t, tau, state, v, failed):
    """Walker ``j`` of :func:`lag_foh_batch`."""
    tj = tau[j]
    x = state[j, 0]
    up = state[j, 1]
    tp = state[j, 2]
    ok = math.isfinite(tj) and tj >= 0.0 and math.isfinite(x) and math.isfinite(up)
    if ok:
        for i in range(u.shape[0]):
            if math.isnan(tp):
                tp = t[i]
                up = u[i]
            dt = t[i] - tp
            if dt < 0.0:
                ok = False
                break
            if tj == 0.0:
                x = u[i]
            elif dt > 0.0:
                slope = (u[i] - up) / dt
                e = math.exp(-dt / tj)
                x = u[i] - tj * slope + (x - up + tj * slope) * e
            v[j, i] = x
            up = u[i]
            tp = t[i]
        ok = ok and math.isfinite(x)
    state[j, 0] = x
    state[j, 1] = up
    state[j, 2] = tp
    failed[j] = not ok
    if not ok:
        v[j, :] = np.nan


@njit(cache=True, parallel=True)
def _lag_foh_batch_par(u, t, tau, state, v, failed):
    """First-order lag ``τ v̇ = u - v``, exact for ``u`` linear between samples, W walkers.

    Parameters
    ----------
    u, t : ndarray, shape (N,)
        Input and non-decreasing times (s).
    tau : ndarray, shape (W,)
        Time constants (s), >= 0 (0: ``v = u``).
    state : ndarray, shape (W, 3)
        ``[v, u_prev, t_prev]`` (``t_prev`` NaN: relaxed at the first sample); updated.
    v : ndarray, shape (W, N)
        Lagged input, written.
    failed : ndarray of bool, shape (W,)
        Written: negative or non-finite ``tau``, time running backwards.
    """
    for j in prange(tau.shape[0]):
        _lag_foh_walker(j, u, t, tau, state, v, failed)


@njit(cache=True)
def _lag_foh_batch_ser(u, t, tau, state, v, failed):
    for j in range(tau.shape[0]):
        _lag_foh_walker(j, u, t, tau, state, v, failed)


lag_foh_batch = batch_kernel(_lag_foh_batch_par, _lag_foh_batch_ser, work_arg=-2,
                             name="lag_foh_batch")
