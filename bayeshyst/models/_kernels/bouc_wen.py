"""Kernels of the Bouc–Wen family in the input: classical/asymmetric BW and MBW.

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

The MBW kernel is RK4 in ``u`` (its right-hand side is smooth). The BW oscillator,
integrated in time, is in :mod:`bayeshyst.models._kernels.bouc_wen_oscillator`.

Every batched kernel takes per-walker parameter arrays (W,), a state (W, S) updated in
place, writes the output (W, N) and sets ``failed`` (W,) for parameter vectors outside the
model's valid region or whose state became non-finite (their rows are NaN).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "C_G",
    "C_L",
    "FASTMATH",
    "MAX_STEPS",
    "TINY",
    "bw_batch",
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
#: Fast-math flags without nnan/ninf, so that NaN/inf checks keep working.
FASTMATH = frozenset({"reassoc", "contract", "nsz", "arcp"})
_FM = set(FASTMATH)


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
