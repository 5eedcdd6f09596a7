"""Kernel of the Bouc–Wen oscillator: a second-order stage driven by ``k u - h``, in time.

The oscillator is integrated in time: each step propagates the linear stage exactly
(matrix exponential of the 2x2 system, stiffened by the local slope ``dz/dx``) under the
order-8 Taylor polynomial of the rest of ``z``, with steps as long as the local error of
``z`` allows (often the whole sample interval) and ending on the kinks of ``ż``; see
:class:`~bayeshyst.models.BoucWenOscillator`. Split from
:mod:`bayeshyst.models._kernels.bouc_wen` (the rate-independent kernels in the input),
whose validity check and step cap it shares.

The batched kernel takes per-walker parameter arrays (W,), a state (W, S) updated in
place, writes the output (W, N) and sets ``failed`` (W,) for parameter vectors outside the
model's valid region or whose state became non-finite (their rows are NaN).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.blocks import second_order_phi
from bayeshyst.models._kernels.bouc_wen import FASTMATH, MAX_STEPS, bw_valid

__all__ = ["OSC_PER_PERIOD", "OSC_TRAVEL", "bw_oscillator_batch"]

_FM = set(FASTMATH)


#: Order of the Taylor series in time of one oscillator step: ``z`` forces the exact
#: linear propagator as its polynomial of this degree (:func:`_osc_taylor` writes the
#: recurrence out order by order for this value).
OSC_ORDER = 8
#: Local error allowed per step on ``z`` (estimated by its last two Taylor terms),
#: relative to the saturation level ``z*``.
OSC_TOL = 1e-7
#: Largest step as a fraction of the time to ``z = 0``, the branch point of ``|z|^n``
#: (for ``n != 1``) where the Taylor series in time stops converging.
OSC_BRANCH = 0.85
#: Below this ``ω h`` the exact linear solution of a step is summed as its Taylor series
#: (no exponentials); above it, as the polynomial particular solution plus ``expm(A h)``
#: times the deviation from it, which amplifies the rounding of the k-th Taylor term of
#: the forcing by ~ ``k! / (ω h)^k`` (1e7 at ``ω h = 0.5``, k = 8: on a term that the error
#: control keeps below 1e-7 z*, ~1e-16 z*).
OSC_SERIES = 0.5
#: Most terms of that series (it needs ~20 at ``ω h = OSC_SERIES``).
OSC_TERMS = 40
#: Fewest steps per period of the (stiffened) natural frequency while ``z`` is being
#: integrated, i.e. ``ω h <= 2π / 2.5``: a step then holds at most one extremum of a
#: ringing ``ẋ`` (the kink search relies on it) and the order-8 Taylor terms shrink.
OSC_PER_PERIOD = 2.5
#: Default largest travel of ``x`` per step, in relaxation lengths of ``z``: only a guard
#: behind the error control, which at order 8 and 1e-7 z* takes 0.3-1 of them per step
#: where ``z`` relaxes (capping at 0.5 cost 15-40 % more steps for the same accuracy).
OSC_TRAVEL = 2.0
# expm(A h) is cached for h rounded to 2^-30 relative (~1e-9, as blocks.DT_RTOL): the
# intervals of a uniformly sampled record differ in their last bits
_QUANT = float(2**30)
_INV = np.array([0.0] + [1.0 / k for k in range(1, OSC_TERMS + 1)])  # 1/k: no divisions


@njit(cache=True, fastmath=_FM, inline="always")
def _osc_pk(pmode, rec, sz, zk):
    """Order ``k`` of ``P``: by the recurrence (mode 0), ``sz z_k`` (1) or 0 (2)."""
    if pmode == 0:
        return rec
    return sz * zk if pmode == 1 else 0.0


@njit(cache=True, fastmath=_FM)
def _osc_taylor(x0, v0, z0, p0, ua, sl, w2, dz, gain, alpha, bb, n, sz, pmode, X, V, Z):
    """Taylor coefficients in time of the oscillator about the current point.

    Writes ``X[k], V[k]`` (k <= 9) and ``Z[k]`` (k <= 8 = ``OSC_ORDER``) of ``x, ẋ, z``
    for ``ẍ + dz ẋ + w2 x = w2 (G u - z)``, ``ż = ẋ (α - bb P)`` (``bb`` fixed by the
    signs of ``ẋ`` and ``z``), ``u = ua + sl τ``, from ``x0, v0, z0`` and ``p0 = |z0|^n``::

        X_(k+1) = V_k / (k+1),   V_(k+1) = (w2 (q_k - X_k) - dz V_k) / (k+1),
        Z_(k+1) = (α V_k - bb (V*P)_k) / (k+1),
        k G_0 P_k = sum_(j=1..k) (n j - (k - j)) G_j P_(k-j)   (P = G^n, G = sz z)

    with ``q = G u - z`` and ``*`` the Cauchy product. ``pmode`` 0: ``P`` by that
    recurrence (``z0 != 0``); 1: ``n = 1``, ``P = sz z`` exactly; 2: leaving ``z = 0``
    with ``P`` dropped (the caller bounds what that costs). Written out order by order:
    the sums then stay in registers (a loop over arrays costs 2-3x more here).
    """
    ig = 1.0 / z0 if pmode == 0 else 0.0  # sz / |z0|
    x1 = v0
    v1 = w2 * (gain * ua - z0 - x0) - dz * v0
    z1 = alpha * v0 - bb * v0 * p0
    p1 = _osc_pk(pmode, n * z1 * p0 * ig, sz, z1)
    x2 = v1 * 0.5
    v2 = (w2 * (gain * sl - z1 - x1) - dz * v1) * 0.5
    z2 = (alpha * v1 - bb * (v0 * p1 + v1 * p0)) * 0.5
    p2 = _osc_pk(pmode, ((n - 1.0) * z1 * p1 + 2.0 * n * z2 * p0) * ig * 0.5, sz, z2)
    x3 = v2 * (1.0 / 3.0)
    v3 = (w2 * (-z2 - x2) - dz * v2) * (1.0 / 3.0)
    z3 = (alpha * v2 - bb * (v0 * p2 + v1 * p1 + v2 * p0)) * (1.0 / 3.0)
    rec = ((n - 2.0) * z1 * p2 + (2.0 * n - 1.0) * z2 * p1 + 3.0 * n * z3 * p0) * ig * (1.0 / 3.0)
    p3 = _osc_pk(pmode, rec, sz, z3)
    x4 = v3 * (1.0 / 4.0)
    v4 = (w2 * (-z3 - x3) - dz * v3) * (1.0 / 4.0)
    z4 = (alpha * v3 - bb * (v0 * p3 + v1 * p2 + v2 * p1 + v3 * p0)) * (1.0 / 4.0)
    rec = ((n - 3.0) * z1 * p3 + (2.0 * n - 2.0) * z2 * p2 + (3.0 * n - 1.0) * z3 * p1 +
           4.0 * n * z4 * p0) * ig * (1.0 / 4.0)
    p4 = _osc_pk(pmode, rec, sz, z4)
    x5 = v4 * (1.0 / 5.0)
    v5 = (w2 * (-z4 - x4) - dz * v4) * (1.0 / 5.0)
    z5 = (alpha * v4 - bb * (v0 * p4 + v1 * p3 + v2 * p2 + v3 * p1 + v4 * p0)) * (1.0 / 5.0)
    rec = ((n - 4.0) * z1 * p4 + (2.0 * n - 3.0) * z2 * p3 + (3.0 * n - 2.0) * z3 * p2 +
           (4.0 * n - 1.0) * z4 * p1 + 5.0 * n * z5 * p0) * ig * (1.0 / 5.0)
    p5 = _osc_pk(pmode, rec, sz, z5)
    x6 = v5 * (1.0 / 6.0)
    v6 = (w2 * (-z5 - x5) - dz * v5) * (1.0 / 6.0)
    vp = v0 * p5 + v1 * p4 + v2 * p3 + v3 * p2 + v4 * p1 + v5 * p0
    z6 = (alpha * v5 - bb * vp) * (1.0 / 6.0)
    rec = ((n - 5.0) * z1 * p5 + (2.0 * n - 4.0) * z2 * p4 + (3.0 * n - 3.0) * z3 * p3 +
           (4.0 * n - 2.0) * z4 * p2 + (5.0 * n - 1.0) * z5 * p1 +
           6.0 * n * z6 * p0) * ig * (1.0 / 6.0)
    p6 = _osc_pk(pmode, rec, sz, z6)
    x7 = v6 * (1.0 / 7.0)
    v7 = (w2 * (-z6 - x6) - dz * v6) * (1.0 / 7.0)
    vp = v0 * p6 + v1 * p5 + v2 * p4 + v3 * p3 + v4 * p2 + v5 * p1 + v6 * p0
    z7 = (alpha * v6 - bb * vp) * (1.0 / 7.0)
    rec = ((n - 6.0) * z1 * p6 + (2.0 * n - 5.0) * z2 * p5 + (3.0 * n - 4.0) * z3 * p4 +
           (4.0 * n - 3.0) * z4 * p3 + (5.0 * n - 2.0) * z5 * p2 + (6.0 * n - 1.0) * z6 * p1 +
           7.0 * n * z7 * p0) * ig * (1.0 / 7.0)
    p7 = _osc_pk(pmode, rec, sz, z7)
    x8 = v7 * (1.0 / 8.0)
    v8 = (w2 * (-z7 - x7) - dz * v7) * (1.0 / 8.0)
    vp = v0 * p7 + v1 * p6 + v2 * p5 + v3 * p4 + v4 * p3 + v5 * p2 + v6 * p1 + v7 * p0
    z8 = (alpha * v7 - bb * vp) * (1.0 / 8.0)
    x9 = v8 * (1.0 / 9.0)
    v9 = (w2 * (-z8 - x8) - dz * v8) * (1.0 / 9.0)
    X[0], X[1], X[2], X[3], X[4] = x0, x1, x2, x3, x4
    X[5], X[6], X[7], X[8], X[9] = x5, x6, x7, x8, x9
    V[0], V[1], V[2], V[3], V[4] = v0, v1, v2, v3, v4
    V[5], V[6], V[7], V[8], V[9] = v5, v6, v7, v8, v9
    Z[0], Z[1], Z[2], Z[3], Z[4] = z0, z1, z2, z3, z4
    Z[5], Z[6], Z[7], Z[8] = z5, z6, z7, z8


@njit(cache=True, fastmath=_FM)
def _osc_series(h, w2, dz, X, V, XS, VS):
    """Scaled coefficients ``XS[k] = X_k h^k`` (and ``VS``) of the exact solution.

    Past ``OSC_ORDER + 1`` the forcing polynomial has ended and the coefficients follow
    the free recurrence of the (stiffened) stage ``w2``; they are summed until below 1e-17
    of the state (for ``ω h < OSC_SERIES`` each is < ``ω h / k`` times the one before).
    Returns the last index and the sums ``x(h), ẋ(h)``.
    """
    hk = 1.0
    x1 = 0.0
    v1 = 0.0
    for k in range(OSC_ORDER + 2):
        XS[k] = X[k] * hk
        VS[k] = V[k] * hk
        x1 += XS[k]
        v1 += VS[k]
        hk *= h
    scale = abs(XS[0]) + abs(XS[1]) + abs(XS[2]) + abs(XS[3])
    m = OSC_ORDER + 1
    while m < OSC_TERMS - 1:
        r = h * _INV[m + 1]
        xs = r * VS[m]
        vs = -r * (w2 * XS[m] + dz * VS[m])
        m += 1
        XS[m] = xs
        VS[m] = vs
        x1 += xs
        v1 += vs
        if abs(xs) + h * abs(vs) <= 1e-17 * scale:
            break
    return m, x1, v1


@njit(cache=True, fastmath=_FM)
def _osc_poly(C, m, s):
    """``sum_{k<=m} C[k] s^k`` (Horner)."""
    acc = C[m]
    for k in range(m - 1, -1, -1):
        acc = acc * s + C[k]
    return acc


@njit(cache=True, fastmath=_FM)
def _osc_dpoly(C, m, s):
    """``d/ds sum_{k<=m} C[k] s^k``."""
    acc = m * C[m]
    for k in range(m - 1, 0, -1):
        acc = acc * s + k * C[k]
    return acc


@njit(cache=True, fastmath=_FM)
def _osc_particular(w2, w2c, dz, F, A):
    """Polynomial particular solution ``x_p = sum A[k] τ^k`` of ``ẍ + dz ẋ + w2c x =
    w2 sum_{k<=OSC_ORDER} F[k] τ^k``, solved from the top power down."""
    inv = 1.0 / w2c
    A[OSC_ORDER] = w2 * F[OSC_ORDER] * inv
    A[OSC_ORDER - 1] = (w2 * F[OSC_ORDER - 1] - dz * OSC_ORDER * A[OSC_ORDER]) * inv
    for k in range(OSC_ORDER - 2, -1, -1):
        A[k] = (w2 * F[k] - dz * (k + 1.0) * A[k + 1] - (k + 2.0) * (k + 1.0) * A[k + 2]) * inv


@njit(cache=True, fastmath=_FM)
def _osc_propagate(tau, A, e1, e2, phi):
    """``x, ẋ`` at ``τ`` from the particular solution ``A`` and the deviation ``(e1, e2)``
    from it at 0, which decays as ``phi = expm(A τ)``."""
    xp = A[OSC_ORDER]
    vp = OSC_ORDER * A[OSC_ORDER]
    for k in range(OSC_ORDER - 1, -1, -1):
        xp = xp * tau + A[k]
    for k in range(OSC_ORDER - 1, 0, -1):
        vp = vp * tau + k * A[k]
    return xp + phi[0] * e1 + phi[1] * e2, vp + phi[2] * e1 + phi[3] * e2


@njit(cache=True, fastmath=_FM)
def _osc_keeps_sign(sv, h, A, e1, e2, w2c):
    """Whether ``sv ẋ > 0`` all over a step of the particular-solution form: the
    particular velocity stays above the largest free one (the free oscillation's energy
    ``ẋ² + w2c x²`` never grows); a cheap sufficient test before searching."""
    vmin = sv * A[1]
    hk = h
    for k in range(2, OSC_ORDER + 1):
        vmin -= k * abs(A[k]) * hk
        hk *= h
    return vmin > 0.0 and vmin * vmin > e2 * e2 + w2c * e1 * e1


@njit(cache=True, fastmath=_FM)
def _osc_at(s, h, series, m, XS, VS, A, e1, e2, wc, zc, phi):
    """``x, ẋ`` at ``τ = s h`` of the current step (exact under its forcing)."""
    if series:
        return _osc_poly(XS, m, s), _osc_poly(VS, m, s)
    second_order_phi(wc, zc, s * h, phi)
    return _osc_propagate(s * h, A, e1, e2, phi)


@njit(cache=True, fastmath=_FM)
def _osc_search(kind, lo, hi, s, sg, h, x0, z0, fc, RS, ua, sl, gain, w2, dz, series, m,
                XS, VS, A, e1, e2, wc, zc, phi):
    """Zero in ``(lo, hi)`` (in units of the step) on the exact solution of the step of
    ``sg ẋ`` (``kind`` 0; positive at ``lo``, negative at ``hi``), ``sg ẍ`` (1; negative
    at ``lo``, positive at ``hi``) or ``sg z`` (2; positive at ``lo``, negative at
    ``hi``): Newton's method from ``s`` kept inside a shrinking bracket. Returns ``s`` and
    ``x, ẋ, z`` there."""
    x = 0.0
    v = 0.0
    zs = 0.0
    for _ in range(60):
        x, v = _osc_at(s, h, series, m, XS, VS, A, e1, e2, wc, zc, phi)
        zs = z0 + fc * (x - x0) + _osc_poly(RS, OSC_ORDER, s)
        dzs = fc * v + _osc_dpoly(RS, OSC_ORDER, s) / h
        acc = w2 * (gain * (ua + sl * s * h) - zs - x) - dz * v
        if kind == 0:
            f = sg * v
            df = sg * acc * h
        elif kind == 1:
            f = -sg * acc
            df = -sg * (w2 * (gain * sl - dzs - v) - dz * acc) * h
        else:
            f = sg * zs
            df = sg * dzs * h
        if f > 0.0:
            lo = s
        else:
            hi = s
        sn = s - f / df if df != 0.0 else 0.5 * (lo + hi)
        if not (lo < sn < hi):
            sn = 0.5 * (lo + hi)
        if abs(sn - s) <= 1e-14 or f == 0.0:
            break
        s = sn
    return s, x, v, zs


@njit(cache=True, fastmath=_FM)
def _osc_travel_cap(X, h, cap):
    """``h`` or less, so that the travel ``sum_{k>=1} |X_k| h^k`` stays within ``cap``
    (Newton's method from above on this convex bound)."""
    for _ in range(30):
        tr = abs(X[OSC_ORDER + 1])
        dtr = (OSC_ORDER + 1.0) * tr
        for k in range(OSC_ORDER, 0, -1):
            tr = tr * h + abs(X[k])
            if k > 1:
                dtr = dtr * h + k * abs(X[k])
        tr *= h
        dtr = dtr * h + abs(X[1])
        if tr <= 1.001 * cap:
            break
        h -= (tr - cap) / dtr
    return h


@njit(cache=True, fastmath=_FM)
def _osc_quant(h):
    m, e = math.frexp(h)
    return math.ldexp(math.floor(m * _QUANT + 0.5) / _QUANT, e)


@njit(cache=True, fastmath=_FM)
def _osc_one(u, t, fn, zeta, gain, alpha, beta, gamma, n, state, y, per_period, c_z):
    """One walker of :func:`bw_oscillator_batch`; returns False on failure."""
    wn = 2.0 * math.pi * fn
    w2 = wn * wn
    dz = 2.0 * zeta * wn
    lag = dz / w2  # lag of the quasi-static response behind a ramp, per unit slope
    bp = beta + gamma
    bm = beta - gamma
    zstar = math.exp(math.log(alpha / bp) / n)
    kappa = max(1.0, bm / bp)
    ellz = zstar / (n * alpha * kappa)  # relaxation length of z in travel of x
    tol = OSC_TOL * zstar
    l_cap = c_z * ellz  # longest travel of a Taylor step
    unit = n == 1.0
    # leaving z = 0 with |z|^n dropped costs (β+γ) α^n |ξ|^(n+1) / (n+1) on z after a
    # travel ξ, i.e. (|z|/z*)^n |z| / (n+1): below tol up to this travel
    l_leave = zstar * math.exp(math.log(OSC_TOL * (n + 1.0)) / (n + 1.0)) / alpha
    X = np.zeros(OSC_ORDER + 2)
    V = np.zeros(OSC_ORDER + 2)
    Z = np.zeros(OSC_ORDER + 1)
    R = np.zeros(OSC_ORDER + 1)
    F = np.zeros(OSC_ORDER + 1)
    XS = np.zeros(OSC_TERMS + 1)
    VS = np.zeros(OSC_TERMS + 1)
    RS = np.zeros(OSC_ORDER + 1)
    A = np.zeros(OSC_ORDER + 1)
    phi_a = np.empty(4)
    phi_b = np.empty(4)
    phi_t = np.empty(4)
    hq_a = -1.0
    hq_b = -1.0
    x = state[0]
    v = state[1]
    z = state[2]
    up = state[3]
    tp = state[4]
    for i in range(u.shape[0]):
        if math.isnan(tp):
            tp = t[i]  # relaxed start: the state is taken at the first sample
            up = u[i]
        dt = t[i] - tp
        if dt < 0.0:
            return False
        if dt > 0.0:
            sl = (u[i] - up) / dt
            gs = gain * sl
            tau = 0.0
            steps = 0
            while tau < dt:
                rem = dt - tau
                steps += 1
                if steps > MAX_STEPS:
                    return False
                ua = up + sl * tau
                az = abs(z)
                p0 = 0.0 if z == 0.0 else math.exp(n * math.log(az))
                fmax = alpha + bm * p0  # the steepest dz/dx on either branch
                # -- quiet step over the rest of the interval. With z held, x = G u - z -
                # lag G u' plus a free damped oscillation whose energy e2² + w2 e1²
                # never grows: that bounds the travel, and below (G u')² it rules out a
                # reversal of ẋ. Quiet if z cannot move by tol: the travel is that
                # small, or z is loading into saturation (|Δz| <= |dz/dx| travel)
                e1 = x - (gain * ua - z - lag * gs)
                e2 = v - gs
                en = e2 * e2 + w2 * e1 * e1
                travel = abs(gs) * rem + 2.0 * math.sqrt(en) / wn
                quiet = fmax * travel <= tol
                f0 = 0.0
                if not quiet and z * gs > 0.0 and gs * gs > en:
                    f0 = alpha - bp * p0
                    quiet = abs(f0) * travel <= tol
                if quiet:
                    hq = _osc_quant(rem)
                    if hq == hq_a:
                        ph = phi_a
                    elif hq == hq_b:
                        ph = phi_b
                    else:
                        second_order_phi(wn, zeta, hq, phi_b)
                        phi_a, phi_b, hq_a, hq_b = phi_b, phi_a, hq, hq_a
                        ph = phi_a
                    x1 = gain * (ua + sl * rem) - z - lag * gs + ph[0] * e1 + ph[1] * e2
                    v = gs + ph[2] * e1 + ph[3] * e2
                    z = z + f0 * (x1 - x)
                    x = x1
                    break
                # -- Taylor step. Branch of ż: the sign of ẋ, or of where it is heading
                # when the reversal is a negligible travel away (the residual velocity
                # left by a step that ended on a reversal)
                a0 = w2 * (gain * ua - z - x) - dz * v
                if v != 0.0 and not (v * a0 < 0.0 and fmax * v * v <= 2.0 * abs(a0) * tol):
                    sv = 1.0 if v > 0.0 else -1.0
                elif a0 != 0.0:
                    sv = 1.0 if a0 > 0.0 else -1.0
                else:
                    sv = -1.0 if gs < 0.0 else 1.0
                sz = sv if z == 0.0 else (1.0 if z > 0.0 else -1.0)
                pmode = 1 if unit else (2 if z == 0.0 else 0)
                bb = beta * sv * sz + gamma
                _osc_taylor(x, v, z, p0, ua, sl, w2, dz, gain, alpha, bb, n, sz, pmode, X, V,
                            Z)
                # the linearised feedback z ≈ z0 + fc (x - x0) joins the exact propagator
                # (stiffness w2 (1 + fc)); only the remainder R is a polynomial forcing.
                # That keeps the ringing of a stage that the step does not resolve
                # (ω h > 1) at its right frequency; as forcing it needs ω h < 1
                fc = max(alpha - bb * p0, 0.0)
                w2c = w2 * (1.0 + fc)
                wc = math.sqrt(w2c)
                for k in range(1, OSC_ORDER + 1):
                    R[k] = Z[k] - fc * X[k]
                h_tay = 2.0 * math.pi / (per_period * wc)  # longest Taylor step
                h = _osc_travel_cap(X, min(rem, h_tay), l_leave if pmode == 2 else l_cap)
                if pmode == 0:
                    # time to z = 0 (a lower bound, from |z| = |Z1| τ + |Z2| τ²); when
                    # heading there with |z|^n so small that its whole effect on the
                    # way is below tol, step straight onto the crossing instead
                    z1a = abs(Z[1])
                    den = z1a + math.sqrt(z1a * z1a + 4.0 * abs(Z[2]) * az)
                    cross = z * Z[1] < 0.0 and p0 * az * bp <= tol * alpha
                    if not cross and h * den > 2.0 * OSC_BRANCH * az:
                        h = 2.0 * OSC_BRANCH * az / den
                # local error: the last two terms of the remainder's series
                ra = abs(R[OSC_ORDER - 1])
                rb = abs(R[OSC_ORDER])
                h2 = h * h
                h7 = h2 * h2 * h2 * h
                if ra * h7 > tol:
                    h = min(h, math.exp(math.log(tol / ra) * (1.0 / (OSC_ORDER - 1))))
                if rb * h7 * h > tol:
                    h = min(h, math.exp(math.log(tol / rb) * (1.0 / OSC_ORDER)))
                if not h > 0.0:
                    return False  # the series overflowed: no step is small enough
                if h < rem:
                    h = rem / math.ceil(rem / h)  # equal sub-steps over the rest
                else:
                    h = rem
                series = wc * h < OSC_SERIES
                m = OSC_ORDER + 1
                e1 = 0.0
                e2 = 0.0
                zc = 0.0
                if series:
                    m, x1, v1 = _osc_series(h, w2c, dz, X, V, XS, VS)
                else:
                    F[0] = gain * ua - z + fc * x
                    F[1] = gain * sl - R[1]
                    for k in range(2, OSC_ORDER + 1):
                        F[k] = -R[k]
                    _osc_particular(w2, w2c, dz, F, A)
                    zc = 0.5 * dz / wc
                    second_order_phi(wc, zc, h, phi_t)
                    e1 = x - A[0]
                    e2 = v - A[1]
                    x1, v1 = _osc_propagate(h, A, e1, e2, phi_t)
                r1 = R[OSC_ORDER]
                for k in range(OSC_ORDER - 1, 0, -1):
                    r1 = r1 * h + R[k]
                z1 = z + fc * (x1 - x) + r1 * h
                # -- kinks of ż inside the step, where ẋ or z changes sign: end the step
                # on the first one, so that every step is smooth
                s_cut = 1.0
                a1 = w2 * (gain * (ua + sl * h) - z1 - x1) - dz * v1
                if sv * v1 < 0.0 or sv * a0 < 0.0 < sv * a1 or sz * z1 < 0.0:
                    hk = 1.0  # the remainder in units of the step, for the searches
                    for k in range(OSC_ORDER + 1):
                        RS[k] = R[k] * hk
                        hk *= h
                if sv * v1 < 0.0:
                    if sv * v > 0.0:
                        s_cut, x1, v1, z1 = _osc_search(
                            0, 0.0, 1.0, v / (v - v1), sv, h, x, z, fc, RS, ua, sl, gain,
                            w2, dz, series, m, XS, VS, A, e1, e2, wc, zc, phi_t)
                    elif sv * a1 < 0.0:
                        # began a negligible residual short of a reversal (sv is where
                        # ẋ heads) and came back within the step (a ringing stage): end
                        # the step where ẋ turns back across zero, after its extremum
                        s_m, xm, vm, zm = _osc_search(
                            1, 0.0, 1.0, a0 / (a0 - a1), -sv, h, x, z, fc, RS, ua, sl,
                            gain, w2, dz, series, m, XS, VS, A, e1, e2, wc, zc, phi_t)
                        if sv * vm > 0.0:
                            s_cut, x1, v1, z1 = _osc_search(
                                0, s_m, 1.0, 0.5 * (1.0 + s_m), sv, h, x, z, fc, RS, ua, sl,
                                gain, w2, dz, series, m, XS, VS, A, e1, e2, wc, zc, phi_t)
                        else:  # never crossed: |ẋ| <= its residual up to there
                            s_cut, x1, v1, z1 = s_m, xm, vm, zm
                    else:
                        s_cut = 0.5  # (not expected) halve the step and look again
                        x1, v1 = _osc_at(0.5, h, series, m, XS, VS, A, e1, e2, wc, zc,
                                         phi_t)
                        z1 = z + fc * (x1 - x) + _osc_poly(RS, OSC_ORDER, 0.5)
                elif sv * a0 < 0.0 and sv * a1 > 0.0 and (
                        series or not _osc_keeps_sign(sv, h, A, e1, e2, w2c)):
                    # |ẋ| has a minimum inside: does ẋ touch zero there?
                    s_m, xm, vm, zm = _osc_search(
                        1, 0.0, 1.0, a0 / (a0 - a1), sv, h, x, z, fc, RS, ua, sl, gain, w2,
                        dz, series, m, XS, VS, A, e1, e2, wc, zc, phi_t)
                    if sv * vm < 0.0:
                        s_cut, x1, v1, z1 = _osc_search(
                            0, 0.0, s_m, 0.5 * s_m, sv, h, x, z, fc, RS, ua, sl, gain, w2,
                            dz, series, m, XS, VS, A, e1, e2, wc, zc, phi_t)
                if pmode != 2 and sz * z1 < 0.0:
                    # z is monotone until a reversal: it crosses zero once, before s_cut
                    s_cut, x1, v1, z1 = _osc_search(
                        2, 0.0, s_cut, s_cut * z / (z - z1), sz, h, x, z, fc, RS, ua, sl,
                        gain, w2, dz, series, m, XS, VS, A, e1, e2, wc, zc, phi_t)
                    z1 = 0.0
                if s_cut < 1.0:
                    tau += s_cut * h
                elif h == rem:
                    tau = dt
                else:
                    tau += h
                if pmode == 2:
                    # z = α ξ - (β+γ) α^n |ξ|^n ξ / (n + 1) + O(ξ^(2n+1)) on the way out
                    xi = x1 - x
                    axi = abs(alpha * xi)
                    if axi > 0.0:
                        z1 -= bp * math.exp(n * math.log(axi)) * xi / (n + 1.0)
                x = x1
                v = v1
                z = z1
            if not (math.isfinite(x) and math.isfinite(v) and math.isfinite(z)):
                return False
        up = u[i]
        tp = t[i]
        y[i] = x
    state[0] = x
    state[1] = v
    state[2] = z
    state[3] = up
    state[4] = tp
    return True


@njit(cache=True)
def _osc_walker(j, u, t, fn, zeta, gain, alpha, beta, gamma, n, per_period, c_z, state,
                y, failed):
    """Walker ``j`` of :func:`bw_oscillator_batch` (the loop body, written once)."""
    ok = bw_valid(alpha[j], beta[j], gamma[j], n[j])
    ok = ok and math.isfinite(fn[j]) and fn[j] > 0.0 and math.isfinite(zeta[j])
    ok = ok and zeta[j] > 0.0 and math.isfinite(gain[j])
    for q in range(4):
        ok = ok and math.isfinite(state[j, q])
    if ok:
        ok = _osc_one(u, t, fn[j], zeta[j], gain[j], alpha[j], beta[j], gamma[j], n[j],
                      state[j], y[j], per_period, c_z)
    failed[j] = not ok
    if not ok:
        y[j, :] = np.nan


@njit(cache=True, parallel=True)
def _bw_oscillator_batch_par(u, t, fn, zeta, gain, alpha, beta, gamma, n, per_period, c_z,
                             state, y, failed):
    """Mass–spring–damper with a Bouc–Wen restoring term for W walkers.

    ``ẍ + 2ζω ẋ + ω² x = ω² (G u - z)``, ``ż = α ẋ - β|ẋ||z|^(n-1) z - γ ẋ|z|^n``;
    ``u`` linear between samples. Each step propagates the linear part exactly, stiffened
    by the local ``dz/dx`` and forced by the Taylor polynomial of the rest of ``z``; steps
    as long as the local error of ``z`` allows, ending on the kinks of ``ż``. See
    :class:`~bayeshyst.models.BoucWenOscillator`.

    Parameters
    ----------
    u, t : ndarray, shape (N,)
        Input (V) and strictly increasing times (s).
    fn, zeta : ndarray, shape (W,)
        Natural frequency (Hz) and damping ratio (1).
    gain : ndarray, shape (W,)
        Static gain ``G`` (output unit/V).
    alpha, beta, gamma, n : ndarray, shape (W,)
        BW parameters of ``z`` (1, 1/output-unit^n, 1/output-unit^n, 1).
    per_period : float
        Fewest steps per natural period while ``z`` is being integrated.
    c_z : float
        Largest displacement travel per step as a fraction of the BW relaxation length.
    state : ndarray, shape (W, 5)
        ``[x, ẋ, z, u_prev, t_prev]`` (``t_prev`` NaN: relaxed at the first sample);
        updated in place.
    y : ndarray, shape (W, N)
        Displacement ``x`` (output unit), written.
    failed : ndarray of bool, shape (W,)
        Written: invalid parameters, time running backwards, or a non-finite state.
    """
    for j in prange(fn.shape[0]):
        _osc_walker(j, u, t, fn, zeta, gain, alpha, beta, gamma, n, per_period, c_z, state,
                    y, failed)


@njit(cache=True)
def _bw_oscillator_batch_ser(u, t, fn, zeta, gain, alpha, beta, gamma, n, per_period, c_z,
                             state, y, failed):
    for j in range(fn.shape[0]):
        _osc_walker(j, u, t, fn, zeta, gain, alpha, beta, gamma, n, per_period, c_z, state,
                    y, failed)


# an oscillator sample costs 0.15-1 us (1 to ~5 steps of 150-200 ns; more for a resonance
# far above the sampling rate): 5 units of work per sample
bw_oscillator_batch = batch_kernel(_bw_oscillator_batch_par, _bw_oscillator_batch_ser,
                                   work_arg=-2, name="bw_oscillator_batch", cost=5)
