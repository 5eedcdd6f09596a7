"""Kernels of the Bouc–Wen family: classical/asymmetric BW in the input, MBW, BW oscillator.

Rate-independent models are integrated in the input ``u`` (linear between samples), not
in time (MODELS.md §5–6). Over one sample interval write ``s = sgn(Δu)``,
``x = s (u - u_start)`` (input travel, >= 0) and ``g = s h``. The BW equation (review
Eq. 48, plus the asymmetric term of Eq. 49 in the form ``δ u u̇``) becomes the scalar ODE

    dg/dx = a(x) - B(g) |g|^n,   a(x) = α + δ u(x),   B = β + γ (g > 0), γ - β (g < 0)

whose only non-smooth point is ``g = 0`` (``|g|^n`` is not analytic there unless n is an
integer; for n = 1 the slope jumps by 2β). The integrator is a Taylor-series method of
order 5 (coefficients by the recurrence of ``P = |g|^n``: ``G P' = n P G'``), which needs
one power per step instead of RK4's four; the step is limited to

* ``C_L`` times the relaxation length (local ``1 / |∂f/∂g|`` and the branch's
  ``ℓ = g_B / (n α)``, ``g_B = (α / |B|)^(1/n)`` the level at which ``|B| |g|^n``
  matches ``α``), so that the truncation error stays ~1e-7 of ``g_B`` per relaxation
  length -- less where ``|B| |g|^n > α`` (a sharp loop's return after a reversal), whose
  power-law descent has larger Taylor coefficients (:func:`branch_scales`);
* a fraction (at most ``C_G``, less where ``|g|^n`` is strongly nonlinear, see
  ``TOL_BRANCH``) of the distance ``|g| / |f|`` to the branch point ``g = 0``, where
  the Taylor series stops converging. Steps shrink geometrically towards a zero
  crossing and grow geometrically after it;

and the crossing itself is located analytically once ``|g| < TINY min(g*, g_-)`` (error
of order ``TINY^(n+1) g_-``, i.e. < 1e-12 g_-). ``P`` is carried by its own series between steps
and recomputed (``exp(n log|g|)``: 24 ns here against 27 ns for ``pow``, and no faster
for integer n) whenever that series would be inaccurate, after a crossing, and every
``RESYNC`` steps. Once ``h`` is within ~1e-6 of its saturation level (classical model)
the rest of an interval is its linearised relaxation, so large input steps cost a
bounded number of steps.

The MBW kernel is RK4 in ``u`` (its right-hand side is smooth). The oscillator is
integrated in time: each step propagates the linear stage exactly (matrix exponential of
the 2x2 system, stiffened by the local slope ``dz/dx``) under the order-8 Taylor polynomial
of the rest of ``z``, with steps as long as the local error of ``z`` allows (often the
whole sample interval) and ending on the kinks of ``ż``; see the section below and
:class:`~bayeshyst.models.BoucWenOscillator`.

Every batched kernel takes per-walker parameter arrays (W,), a state (W, S) updated in
place, writes the output (W, N) and sets ``failed`` (W,) for parameter vectors outside the
model's valid region or whose state became non-finite (their rows are NaN).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.blocks import second_order_phi

__all__ = [
    "C_G",
    "C_L",
    "OSC_PER_PERIOD",
    "OSC_TRAVEL",
    "TINY",
    "bw_batch",
    "bw_oscillator_batch",
    "bw_valid",
    "mbw_batch",
]

#: Largest step as a fraction of the relaxation length (Taylor order 5: local error
#: ~ C_L**6 / 720 of the deviation from the equilibrium, i.e. ~1e-7 at 0.2).
C_L = 0.2
#: Largest step as a fraction of the distance to the zero crossing of ``g``.
C_G = 0.5
#: Relative error allowed per step from the non-analytic part of g at its zero crossing.
TOL_BRANCH = 1e-11
#: Below ``TINY g*`` the zero crossing is stepped over analytically.
TINY = 1e-4
#: Recompute ``|g|^n`` from ``g`` at least every RESYNC steps (bounds the carry drift).
RESYNC = 16
#: Cap on the steps of one sample interval: a walker needing more has a transition
#: thousands of times narrower than one input step (a discontinuity at the data's
#: resolution) and is reported as failed rather than stalling the ensemble.
MAX_STEPS = 100_000
#: Within this fraction of ``α`` of the equilibrium (``|f| <= NEAR_EQ α``, i.e.
#: ``|g - g*| <~ NEAR_EQ g* / n``) the rest of an interval is the linearised relaxation.
NEAR_EQ = 1e-6
#: Carry ``P`` by series only while the step is below this fraction of its radii.
CARRY = 0.05
# fast-math flags without nnan/ninf, so that NaN/inf checks keep working
_FM = {"reassoc", "contract", "nsz", "arcp"}


@njit(cache=True)
def branch_scales(a, bp, bm, n, c_l):
    """Step guards of :func:`_bw_interval` for drive ``a`` and coefficients ``B+, B-``.

    Returns ``(ellp, ellm, gcross, c_stiff, cb)``: the relaxation length of each branch,
    ``g_B / (n a)`` with ``g_B = (a / |B|)^(1/n)`` the level at which ``|B| |g|^n``
    matches ``a`` (infinite for ``B = 0``, a linear branch); the level below which a
    negative ``g`` steps onto its zero crossing analytically, in units of ``TINY``
    (small against the returning branch's own ``g_-``, not only ``g*``, which grows
    without bound as ``β + γ -> 0``); the relaxation-rate step limit where ``|B| |g|^n
    > a``; and the branch-point error constant ``|binom(n+1, 6)| / (n+1)``.

    Where ``|B| |g|^n >> a`` the flow is ``G' = -|B| G^n``, whose solution ``G0 (1 +
    (n-1) f_g ξ / n)^(-1/(n-1))`` has order-6 Taylor coefficient ``prod_j (1 + j (n-1))
    / (720 n^6)`` in ``(f_g ξ)^6`` (``1/720`` for n = 1, the exponential): ``c_stiff``
    gives it the error ``(c_l / 2)^6 / 720`` per step, which a linear relaxation has at
    half of ``c_l``. (At ``c_l`` itself the descent's errors, which it does not damp as a
    relaxation does, added up to 4e-7 of the stroke against ``solve_ivp`` on the oracle
    case ``edge``; at half, 2e-8.)
    """
    gp = math.inf if bp <= 0.0 else math.exp(math.log(a / bp) / n)
    gm = math.inf if bm >= 0.0 else math.exp(math.log(a / -bm) / n)
    prod = 1.0
    for j in range(6):
        prod *= 1.0 + j * (n - 1.0)
    c_stiff = 0.5 * c_l * min(1.0, n / math.exp(math.log(prod) / 6.0))
    cb = 1.0 / (n + 1.0)
    for j in range(6):
        cb *= abs(n + 1.0 - j) / (j + 1.0)
    return gp / (n * a), gm / (n * a), min(gp, gm), c_stiff, cb


@njit(cache=True, fastmath=_FM)
def _bw_interval(g, P, X, a0, a1, bp, bm, n, ellp, ellm, gcross, cnt, c_l, c_stiff, cb):
    """Advance ``g`` over input travel ``X``; returns ``(g, P, cnt, ok)``.

    ``P`` is ``|g|^n`` or -1 (unknown); ``cnt`` the running step count (for RESYNC);
    the other guards as :func:`branch_scales` returns them.
    """
    x = 0.0
    steps = 0
    while x < X:
        steps += 1
        cnt += 1
        if steps > MAX_STEPS or not math.isfinite(g):
            return g, P, cnt, False
        rem = X - x
        a = a0 + a1 * x
        if g == 0.0:
            # leave zero along g = a d + a1 d^2/2 - B+ (a d)^n d/(n+1): the leading terms
            # of the exact solution; the next one is O((d/ℓ)^(2n+1)) relative
            if a <= 0.0:
                return g, P, cnt, False
            gs = math.exp(math.log(a / bp) / n)
            d = min(rem, TINY * gs / a)
            ad = a * d
            g = ad + 0.5 * a1 * d * d - bp * math.exp(n * math.log(ad)) * d / (n + 1.0)
            P = -1.0
            x += d
            continue
        G0 = abs(g)
        sg = 1.0 if g > 0.0 else -1.0
        B = bp if g > 0.0 else bm
        if P < 0.0 or cnt % RESYNC == 0:
            P = math.exp(n * math.log(G0))
        P0 = P
        F0 = a - B * P0
        if g < 0.0 and G0 <= TINY * gcross:
            # step onto the crossing: 0 = g + a d + a1 d^2/2 + C |g|^(n+1) / (a (n+1))
            if a <= 0.0:
                return g, P, cnt, False
            C = -bm
            d = (G0 - C * P0 * G0 / (a * (n + 1.0))) / a
            d = d - 0.5 * a1 * d * d / a
            if d <= rem:
                x += d
                g = 0.0
                continue
            # the interval ends just before the crossing: integrate C|g|^n along the
            # linear path |g| = G0 - a x (same order as the crossing formula)
            G1 = max(G0 - a * rem, 0.0)
            P1 = 0.0 if G1 == 0.0 else G1 * math.exp(n * math.log(G1))
            g = g + a * rem + 0.5 * a1 * rem * rem + C * (P0 * G0 - P1) / (a * (n + 1.0))
            P = -1.0
            break
        inv = 1.0 / G0
        aF = abs(F0)
        fg = abs(B) * n * P0 * inv  # |∂f/∂g|, the local relaxation rate
        if g > 0.0 and a1 == 0.0 and bp > 0.0 and aF <= NEAR_EQ * a:
            # within ~1e-6 of the equilibrium g* the flow is its linearisation: the rest
            # of the interval relaxes exponentially (error ~ (n-1)/2 (g - g*)^2 / g*,
            # < 1e-12 g*), instead of a step per 0.2 relaxation lengths on a saturated
            # loop (15-20 steps per sample of a sharp MR-damper loop)
            gs = math.exp(math.log(a / bp) / n)
            g = gs + (G0 - gs) * math.exp(-fg * rem)
            P = -1.0
            break
        # > 1: |B| |g|^n dominates the drive (stiff); a = 0 where a reflected piece of
        # the rate-dependent variant starts at a root of its drive
        eps = abs(B) * P0 / abs(a) if a != 0.0 else math.inf
        c_rate = c_stiff if eps > 1.0 else c_l
        d = rem
        if d * fg > c_rate:
            d = c_rate / fg
        # where |g| is still small against the branch's own saturation scale the local
        # rate underestimates the rate a step can reach (n > 1): cap by that branch's
        # relaxation length. (One length for both branches, the stiffer one's, made the
        # steps of a branch with beta + gamma -> 0 as short as those after a reversal:
        # an MR-damper least squares spent ~1 s per simulation there.)
        ell = ellp if g > 0.0 else ellm
        if d > c_l * ell:
            d = c_l * ell
        # the non-analytic part of g near its zero is ~ ε G |x - x_c|^(n+1) with
        # ε = |B| P / a; truncating its Taylor series at order 5 with r = step / branch
        # distance costs cb ε r^6 G (cb = |binom(n+1, 6)| / (n+1)): keep that < TOL_BRANCH
        if d * aF > 0.02 * G0:  # else no branch limit can bind (r >= 0.02 below)
            dist = G0 / aF  # the distance to the crossing, extrapolated linearly
            if eps > 1.0 and a != 0.0:
                # stiff: the path slows down as |g| falls, so the crossing is at least
                # g_B / (2 a) away, and the non-analytic part, which lives where |g| <~
                # g_B, is at most G (the linear extrapolation had held the steps of a
                # sharp loop's return to 2 % of G / |f|: ~500 steps per reversal)
                dist = max(dist, math.exp(math.log(abs(a) / abs(B)) / n) / (2.0 * abs(a)))
                eps = 1.0
            r = C_G
            q = cb * eps
            while q * (r * r * r) * (r * r * r) > TOL_BRANCH and r > 0.02:
                r *= 0.7
            if d > r * dist:
                d = r * dist
        # Taylor coefficients c_k of G = |g| and p_k of P = G^n (k G0 p_k =
        # sum_j (n j - (k - j)) c_j p_(k-j)); c_(k+1) = f_k / (k + 1)
        Bs = sg * B
        c1 = sg * F0
        p1 = n * c1 * P0 * inv
        c2 = (sg * a1 - Bs * p1) * 0.5
        p2 = ((n - 1.0) * c1 * p1 + 2.0 * n * c2 * P0) * inv * 0.5
        c3 = -Bs * p2 * (1.0 / 3.0)
        p3 = ((n - 2.0) * c1 * p2 + (2.0 * n - 1.0) * c2 * p1
              + 3.0 * n * c3 * P0) * inv * (1.0 / 3.0)
        c4 = -Bs * p3 * 0.25
        p4 = ((n - 3.0) * c1 * p3 + (2.0 * n - 2.0) * c2 * p2 + (3.0 * n - 1.0) * c3 * p1
              + 4.0 * n * c4 * P0) * inv * 0.25
        c5 = -Bs * p4 * 0.2
        Gn = G0 + d * (c1 + d * (c2 + d * (c3 + d * (c4 + d * c5))))
        g = sg * Gn
        # carry P by its series only when the step is short against both radii of
        # convergence (relaxation length, branch distance): its truncation error is then
        # < CARRY^6 / 720 ~ 1e-12 relative, so that carried and recomputed P agree
        if d * (fg + aF * inv) <= CARRY:
            p5 = ((n - 4.0) * c1 * p4 + (2.0 * n - 3.0) * c2 * p3
                  + (3.0 * n - 2.0) * c3 * p2 + (4.0 * n - 1.0) * c4 * p1
                  + 5.0 * n * c5 * P0) * inv * 0.2
            P = P0 + d * (p1 + d * (p2 + d * (p3 + d * (p4 + d * p5))))
        else:
            P = -1.0
        x += d
    return g, P, cnt, True


@njit(cache=True)
def bw_valid(alpha, beta, gamma, n):
    """Stable, dissipative region: α > 0, β + γ > 0, β - γ >= 0, n >= 1 (all finite)."""
    ok = math.isfinite(alpha) and math.isfinite(beta) and math.isfinite(gamma)
    ok = ok and math.isfinite(n)
    return ok and alpha > 0.0 and beta + gamma > 0.0 and beta - gamma >= 0.0 and n >= 1.0


@njit(cache=True)
def _bw_one(u, k, alpha, beta, gamma, n, delta, state, y, c_l):
    """One walker of :func:`bw_batch`; returns False on failure."""
    bp = beta + gamma
    bm = gamma - beta
    ellp, ellm, gcross, c_stiff, cb = branch_scales(alpha, bp, bm, n, c_l)
    h = state[0]
    up = state[1]
    P = -1.0
    cnt = 0
    for i in range(u.shape[0]):
        du = u[i] - up
        if du != 0.0:
            s = 1.0 if du > 0.0 else -1.0
            g, P, cnt, ok = _bw_interval(s * h, P, abs(du), alpha + delta * up, delta * s,
                                         bp, bm, n, ellp, ellm, gcross, cnt, c_l,
                                         c_stiff, cb)
            if not ok:
                return False
            h = s * g
        up = u[i]
        y[i] = k * u[i] - h
    state[0] = h
    state[1] = up
    return math.isfinite(h)


@njit(cache=True)
def _bw_walker(j, u, k, alpha, beta, gamma, n, delta, u_lo, u_hi, c_l, state, y, failed):
    """Walker ``j`` of :func:`bw_batch` (the loop body, written once)."""
    a_lo = min(alpha[j] + delta[j] * u_lo, alpha[j] + delta[j] * u_hi)
    ok = bw_valid(alpha[j], beta[j], gamma[j], n[j]) and math.isfinite(k[j])
    ok = ok and math.isfinite(delta[j]) and a_lo > 0.0
    ok = ok and math.isfinite(state[j, 0]) and math.isfinite(state[j, 1])
    if ok:
        ok = _bw_one(u, k[j], alpha[j], beta[j], gamma[j], n[j], delta[j],
                     state[j], y[j], c_l)
    failed[j] = not ok
    if not ok:
        y[j, :] = np.nan


@njit(cache=True, parallel=True)
def _bw_batch_par(u, k, alpha, beta, gamma, n, delta, u_lo, u_hi, c_l, state, y, failed):
    """Classical (δ = 0) or asymmetric Bouc–Wen ``y = k u - h`` for W walkers.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    k, alpha : ndarray, shape (W,)
        Linear gain and hysteretic slope (output unit/V).
    beta, gamma : ndarray, shape (W,)
        Shape coefficients (1/(V output-unit^(n-1))).
    n : ndarray, shape (W,)
        Exponent (>= 1).
    delta : ndarray, shape (W,)
        Asymmetry (output unit/V²); zeros for the classical model.
    u_lo, u_hi : float
        Input range (V) visited by the run, previous input included: ``α + δ u > 0``
        must hold on it.
    c_l : float
        Largest step as a fraction of the relaxation length (``C_L`` by default).
    state : ndarray, shape (W, 2)
        ``[h, u_prev]`` (output unit, V); updated in place to the final state.
    y : ndarray, shape (W, N)
        Output (output unit), written; NaN rows for failed walkers.
    failed : ndarray of bool, shape (W,)
        Written: parameters outside the stable region, or a non-finite state.
    """
    for j in prange(k.shape[0]):
        _bw_walker(j, u, k, alpha, beta, gamma, n, delta, u_lo, u_hi, c_l, state, y, failed)


@njit(cache=True)
def _bw_batch_ser(u, k, alpha, beta, gamma, n, delta, u_lo, u_hi, c_l, state, y, failed):
    for j in range(k.shape[0]):
        _bw_walker(j, u, k, alpha, beta, gamma, n, delta, u_lo, u_hi, c_l, state, y, failed)


bw_batch = batch_kernel(_bw_batch_par, _bw_batch_ser, work_arg=-2, name="bw_batch")


# ------------------------------------------------------------------------------ MBW


@njit(cache=True, fastmath=_FM)
def _mbw_one(u, rho, lam, c, state, y, c_m):
    """One walker of :func:`mbw_batch`; returns False on failure."""
    w = state[0]
    up = state[1]
    L = c.shape[0]
    for i in range(u.shape[0]):
        du = u[i] - up
        if du != 0.0:
            s = 1.0 if du > 0.0 else -1.0
            # the flow relaxes at rate λ (gauge μ = λ): RK4 error ~ (λ h)^5 / 120
            m = math.ceil(abs(du) * lam / c_m)
            h = du / m
            sr = s * rho * lam
            uu = up
            for _ in range(m):
                d1 = 1.0 - sr * (uu - w)
                d2 = 1.0 - sr * (uu + 0.5 * h - w - 0.5 * h * rho / d1)
                d3 = 1.0 - sr * (uu + 0.5 * h - w - 0.5 * h * rho / d2)
                d4 = 1.0 - sr * (uu + h - w - h * rho / d3)
                if not (d1 > 0.0 and d2 > 0.0 and d3 > 0.0 and d4 > 0.0):
                    return False  # left the band |e| < 1/ρ: Eq. 52 is singular there
                w += h * rho * (1.0 / d1 + 2.0 / d2 + 2.0 / d3 + 1.0 / d4) * (1.0 / 6.0)
                uu += h
            if not math.isfinite(w):
                return False
        up = u[i]
        acc = c[L - 1]
        for q in range(L - 2, -1, -1):
            acc = acc * w + c[q]
        y[i] = acc * w
    state[0] = w
    state[1] = up
    return True


@njit(cache=True)
def _mbw_walker(j, u, rho, lam, c, c_m, state, y, failed):
    """Walker ``j`` of :func:`mbw_batch` (the loop body, written once)."""
    ok = math.isfinite(rho[j]) and math.isfinite(lam[j]) and 0.0 < rho[j] < 2.0
    ok = ok and lam[j] > 0.0 and math.isfinite(state[j, 0])
    ok = ok and math.isfinite(state[j, 1])
    for q in range(c.shape[1]):
        ok = ok and math.isfinite(c[j, q])
    if ok:
        ok = _mbw_one(u, rho[j], lam[j], c[j], state[j], y[j], c_m)
    failed[j] = not ok
    if not ok:
        y[j, :] = np.nan


@njit(cache=True, parallel=True)
def _mbw_batch_par(u, rho, lam, c, c_m, state, y, failed):
    """Weighted-polynomial modified Bouc–Wen ``v = sum_i c_i w^i`` for W walkers.

    ``dw/du = ρ / (1 - sgn(u̇) ρ λ (u - w))`` (review Eq. 52 with μ = λ), RK4 in ``u``.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    rho : ndarray, shape (W,)
        Shape parameter (1), valid in (0, 2).
    lam : ndarray, shape (W,)
        Inverse relaxation length (1/V), > 0.
    c : ndarray, shape (W, L)
        Output polynomial weights ``c_1..c_L`` (output unit/V^i).
    c_m : float
        Largest RK4 step times ``λ``.
    state : ndarray, shape (W, 2)
        ``[w, u_prev]`` (V, V); updated in place.
    y : ndarray, shape (W, N)
        Output (output unit), written.
    failed : ndarray of bool, shape (W,)
        Written: invalid parameters or a state leaving the band ``|λ(u - w)| < 1/ρ``.
    """
    for j in prange(rho.shape[0]):
        _mbw_walker(j, u, rho, lam, c, c_m, state, y, failed)


@njit(cache=True)
def _mbw_batch_ser(u, rho, lam, c, c_m, state, y, failed):
    for j in range(rho.shape[0]):
        _mbw_walker(j, u, rho, lam, c, c_m, state, y, failed)


mbw_batch = batch_kernel(_mbw_batch_par, _mbw_batch_ser, work_arg=-2, name="mbw_batch")


# ----------------------------------------------------------------------- oscillator

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
