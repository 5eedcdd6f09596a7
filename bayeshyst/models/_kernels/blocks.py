"""Kernels of the effect blocks: ARX, exact second-order and first-order lag banks, drift,
delay and the monotone output polynomial (MODELS.md §7, review Eq. 56–57).

Every batched kernel has the same shape of signature: the block input ``w`` (W, N), the
sample times ``t`` (N,), per-walker parameters with a leading ``W`` axis, the state
``state`` (W, S) updated in place to the state after the last sample, the output
``out`` (W, N) written, and ``failed`` (W,) written (``True`` for an invalid parameter
vector, a decreasing time axis or a non-finite output; such rows are left as NaN).
The loop over walkers runs in parallel (``prange``) when there is enough work to pay
for starting the threads; short calls (one walker, or the one-sample steps of numerical
inversion) run a serial twin of the same loop, see
:func:`bayeshyst.models._kernels.batch_kernel`. Each walker's time loop is sequential.

Continuous-time blocks share one convention. The state holds the previous input
``w_prev``, the previous sample time ``t_prev`` and the time step ``h_ref`` that the
cached discretisation was built for. Between samples the input is held (zero-order
hold, ``w(t) = w_{k-1}`` on ``[t_{k-1}, t_k)``) or, for the second-order block by
default, linear (first-order hold: no artificial one-sample delay), and the matrix
exponential propagates either exactly. ``t_prev = NaN`` means "at rest since forever,
now at the first sample's time": the first sample is not propagated (a steady state is
a fixed point of every step, so no step length is needed). The discretisation is
recomputed only when the step differs from ``h_ref`` by more than :data:`DT_RTOL`
relative (rounding of ``t``); since ``h_ref`` lives in the state, a run in pieces
equals one run bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "DT_RTOL",
    "arx_batch",
    "arx_polynomials",
    "asym_output_batch",
    "delay_batch",
    "drift_batch",
    "lag_bank_batch",
    "second_order_batch",
    "second_order_phi",
]

#: Steps equal to this relative tolerance share one discretisation (rounding of ``t``).
DT_RTOL = 1e-9
@njit(cache=True)
def _fail_row(out_row):
    for k in range(out_row.shape[0]):
        out_row[k] = np.nan


@njit(cache=True)
def _finish(ok, out_row, failed, j):
    """Flag walker ``j`` failed (row to NaN) if ``ok`` is False or an output is not finite."""
    if ok:
        for k in range(out_row.shape[0]):
            if not math.isfinite(out_row[k]):
                ok = False
                break
    failed[j] = not ok
    if not ok:
        _fail_row(out_row)


# ------------------------------------------------------------------------------- ARX


@njit(cache=True)
def arx_polynomials(kappa, beta, a, b):
    """Write ``A`` (na + 1,) from reflection coefficients and ``B`` (nb,) with ``B(1) = A(1)``.

    Step-up (Levinson) recursion: ``a^{(m)}_i = a^{(m-1)}_i + kappa_m a^{(m-1)}_{m-i}``,
    ``a^{(m)}_m = kappa_m``; ``A(z)`` has all roots inside the unit circle iff every
    ``|kappa_m| < 1``. ``b = A(1) [1 - sum(beta), beta_1, ..., beta_{nb-1}]``.
    Returns False if some ``|kappa_m| >= 1`` or a value is not finite.
    """
    na = kappa.shape[0]
    a[0] = 1.0
    for i in range(1, na + 1):
        a[i] = 0.0
    for m in range(1, na + 1):
        km = kappa[m - 1]
        if not abs(km) < 1.0:
            return False
        # in place: the pair (i, m - i) is updated from the old values of both
        for i in range(1, m // 2 + 1):
            ai = a[i]
            aj = a[m - i]
            a[i] = ai + km * aj
            if i != m - i:
                a[m - i] = aj + km * ai
        a[m] = km
    a1 = 0.0
    for i in range(na + 1):
        a1 += a[i]
    rest = 1.0
    for i in range(beta.shape[0]):
        if not math.isfinite(beta[i]):
            return False
        rest -= beta[i]
        b[i + 1] = a1 * beta[i]
    b[0] = a1 * rest
    return True


@njit(cache=True)
def _arx_one(w, kappa, beta, nk, state, out):
    na = kappa.shape[0]
    nb = beta.shape[0] + 1
    m = nk + nb - 1
    n = w.shape[0]
    a = np.empty(na + 1)
    b = np.empty(nb)
    if not arx_polynomials(kappa, beta, a, b):
        return False
    # histories (oldest first) followed by the signal: plain indexing, no shifting
    ey = np.empty(na + n)
    ew = np.empty(m + n)
    for i in range(na):
        ey[i] = state[i]
    for i in range(m):
        ew[i] = state[na + i]
    for k in range(n):
        ew[m + k] = w[k]
    for k in range(n):
        acc = 0.0
        base = m + k - nk
        for i in range(nb):
            acc += b[i] * ew[base - i]
        for i in range(1, na + 1):
            acc -= a[i] * ey[na + k - i]
        ey[na + k] = acc
        out[k] = acc
    for i in range(na):
        state[i] = ey[n + i]
    for i in range(m):
        state[na + i] = ew[n + i]
    return True


@njit(cache=True, parallel=True)
def _arx_par(w, kappa, beta, nk, state, out, failed):
    """``A(q^-1) y = B(q^-1) w`` (review Eq. 56–57) for W parameter vectors.

    Parameters
    ----------
    w : (W, N) block input; kappa : (W, na) reflection coefficients; beta : (W, nb - 1)
    shares of the DC gain on the lagged inputs; nk : int input delay in samples;
    state : (W, na + nk + nb - 1) ``[y_{-na} .. y_{-1}, w_{-m} .. w_{-1}]`` oldest first.
    """
    for j in prange(w.shape[0]):
        ok = _arx_one(w[j], kappa[j], beta[j], nk, state[j], out[j])
        _finish(ok, out[j], failed, j)


@njit(cache=True)
def _arx_ser(w, kappa, beta, nk, state, out, failed):
    for j in range(w.shape[0]):
        ok = _arx_one(w[j], kappa[j], beta[j], nk, state[j], out[j])
        _finish(ok, out[j], failed, j)


arx_batch = batch_kernel(_arx_par, _arx_ser, work_arg=0, name="arx_batch")


# ------------------------------------------------------------------- second order


@njit(cache=True)
def second_order_phi(wn, zeta, h, phi):
    """Write ``expm(A h)`` (4,) row-major for ``A = [[0, 1], [-wn^2, -2 zeta wn]]``.

    With ``sigma = zeta wn`` and ``N = A + sigma I``, ``N^2 = delta I``,
    ``delta = wn^2 (zeta^2 - 1)``, so ``expm(A h) = e^{-sigma h} (C I + S N)`` with
    ``C = cosh(sqrt(delta) h)``, ``S = sinh(sqrt(delta) h) / sqrt(delta)`` (cos/sin for
    ``delta < 0``). Near critical damping a series in ``z = delta h^2`` avoids the 0/0;
    in the over-damped branch the two real exponentials are formed separately (the slow
    rate as ``wn^2 / (sigma + r)``) so that nothing overflows or cancels.
    """
    sig = zeta * wn
    delta = sig * sig - wn * wn
    z = delta * h * h
    if abs(z) < 1e-2:
        e = math.exp(-sig * h)
        c = 1.0 + z * (1.0 / 2 + z * (1.0 / 24 + z * (1.0 / 720 + z * (1.0 / 40320))))
        s = h * (1.0 + z * (1.0 / 6 + z * (1.0 / 120 + z * (1.0 / 5040 + z * (1.0 / 362880)))))
        ce = e * c
        se = e * s
    elif z < 0.0:
        wd = math.sqrt(-delta)
        e = math.exp(-sig * h)
        ce = e * math.cos(wd * h)
        se = e * math.sin(wd * h) / wd
    else:
        r = math.sqrt(delta)
        slow = math.exp(-(wn * wn / (sig + r)) * h)
        fast = math.exp(-(sig + r) * h)
        ce = 0.5 * (slow + fast)
        se = (slow - fast) / (2.0 * r)
    phi[0] = ce + sig * se
    phi[1] = se
    phi[2] = -wn * wn * se
    phi[3] = ce - sig * se


@njit(cache=True)
def _second_order_one(w, t, wn, zeta, foh, state, out):
    if not (wn > 0.0 and math.isfinite(wn) and zeta >= 0.0 and math.isfinite(zeta)):
        return False
    y = state[0]
    v = state[1]
    wp = state[2]
    tp = state[3]
    href = state[4]
    phi = np.empty(4)
    if href > 0.0:
        second_order_phi(wn, zeta, href, phi)
    for k in range(w.shape[0]):
        if not math.isnan(tp):
            dt = t[k] - tp
            if dt < 0.0:
                return False
            if dt > 0.0:
                if not abs(dt - href) <= DT_RTOL * href:
                    href = dt
                    second_order_phi(wn, zeta, href, phi)
                if foh:
                    # input linear from w_prev to w_k: the ramp's particular solution is
                    # y_p = w(tau) - c s, v_p = s (c = 2 zeta / wn, s the slope); the
                    # deviation from it decays as expm(A h)
                    slope = (w[k] - wp) / dt
                    c = 2.0 * zeta / wn
                    e1 = y - (wp - c * slope)
                    e2 = v - slope
                    y = w[k] - c * slope + phi[0] * e1 + phi[1] * e2
                    v = slope + phi[2] * e1 + phi[3] * e2
                else:
                    # the error from the equilibrium of the held input decays as expm(A h)
                    e1 = y - wp
                    y = wp + phi[0] * e1 + phi[1] * v
                    v = phi[2] * e1 + phi[3] * v
        out[k] = y
        wp = w[k]
        tp = t[k]
    state[0] = y
    state[1] = v
    state[2] = wp
    state[3] = tp
    state[4] = href
    return True


@njit(cache=True, parallel=True)
def _second_order_par(w, t, wn, zeta, foh, state, out, failed):
    """``G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)``, exact, for W parameter vectors.

    ``wn`` (W,) natural angular frequency (rad/s), ``zeta`` (W,) damping ratio; ``foh``
    True: the input is linear between samples (first-order hold), False: held (ZOH);
    ``state`` (W, 5) ``[y, dy/dt, w_prev, t_prev, h_ref]``.
    """
    for j in prange(w.shape[0]):
        ok = _second_order_one(w[j], t, wn[j], zeta[j], foh, state[j], out[j])
        _finish(ok, out[j], failed, j)


@njit(cache=True)
def _second_order_ser(w, t, wn, zeta, foh, state, out, failed):
    for j in range(w.shape[0]):
        ok = _second_order_one(w[j], t, wn[j], zeta[j], foh, state[j], out[j])
        _finish(ok, out[j], failed, j)


second_order_batch = batch_kernel(_second_order_par, _second_order_ser, work_arg=0,
                                  name="second_order_batch")


# ------------------------------------------------------------------ first-order lags


@njit(cache=True)
def _lag_decays(tau, h, dec):
    for i in range(tau.shape[0]):
        dec[i] = math.exp(-h / tau[i])


@njit(cache=True)
def _lag_bank_one(w, t, c, tau, state, out):
    n = c.shape[0]
    for i in range(n):
        if not (tau[i] > 0.0 and math.isfinite(c[i])):
            return False
    x = state[:n]
    wp = state[n]
    tp = state[n + 1]
    href = state[n + 2]
    dec = np.empty(n)
    if href > 0.0:
        _lag_decays(tau, href, dec)
    for k in range(w.shape[0]):
        if not math.isnan(tp):
            dt = t[k] - tp
            if dt < 0.0:
                return False
            if dt > 0.0:
                if not abs(dt - href) <= DT_RTOL * href:
                    href = dt
                    _lag_decays(tau, href, dec)
                for i in range(n):
                    x[i] = wp + dec[i] * (x[i] - wp)
        wk = w[k]
        acc = wk
        for i in range(n):
            acc += c[i] * (x[i] - wk)
        out[k] = acc
        wp = wk
        tp = t[k]
    state[n] = wp
    state[n + 1] = tp
    state[n + 2] = href
    return True


@njit(cache=True, parallel=True)
def _lag_bank_par(w, t, c, tau, state, out, failed):
    """``y = w + sum_i c_i (x_i - w)``, ``tau_i dx_i/dt = w - x_i`` (exact ZOH), batched.

    ``c``, ``tau`` (W, n) gains and time constants (s); ``state`` (W, n + 3)
    ``[x_1 .. x_n, w_prev, t_prev, h_ref]``.
    """
    for j in prange(w.shape[0]):
        ok = _lag_bank_one(w[j], t, c[j], tau[j], state[j], out[j])
        _finish(ok, out[j], failed, j)


@njit(cache=True)
def _lag_bank_ser(w, t, c, tau, state, out, failed):
    for j in range(w.shape[0]):
        ok = _lag_bank_one(w[j], t, c[j], tau[j], state[j], out[j])
        _finish(ok, out[j], failed, j)


lag_bank_batch = batch_kernel(_lag_bank_par, _lag_bank_ser, work_arg=0, name="lag_bank_batch")


# ------------------------------------------------------------------------------ drift


@njit(cache=True)
def _drift_one(w, t, g, d, t_scale, state, out):
    if not (t_scale > 0.0 and math.isfinite(t_scale)):
        return False
    t0 = state[0]
    if math.isnan(t0):
        t0 = t[0]
    p = g.shape[0]
    for k in range(w.shape[0]):
        s = (t[k] - t0) / t_scale
        # Horner without a constant term: g(s) = s (g_1 + s (g_2 + ...))
        gs = 0.0
        ds = 0.0
        for i in range(p - 1, -1, -1):
            gs = s * (g[i] + gs)
            ds = s * (d[i] + ds)
        out[k] = (1.0 + gs) * w[k] + ds
    state[0] = t0
    return True


@njit(cache=True, parallel=True)
def _drift_par(w, t, g, d, t_scale, state, out, failed):
    """``y = (1 + g(s)) w + d(s)``, ``s = (t - t_origin) / t_scale``, batched.

    ``g``, ``d`` (W, order) polynomial coefficients of ``s^1 .. s^order``; ``t_scale``
    (W,) (s); ``state`` (W, 1) ``[t_origin]`` (NaN: the first sample's time).
    """
    for j in prange(w.shape[0]):
        ok = _drift_one(w[j], t, g[j], d[j], t_scale[j], state[j], out[j])
        _finish(ok, out[j], failed, j)


@njit(cache=True)
def _drift_ser(w, t, g, d, t_scale, state, out, failed):
    for j in range(w.shape[0]):
        ok = _drift_one(w[j], t, g[j], d[j], t_scale[j], state[j], out[j])
        _finish(ok, out[j], failed, j)


drift_batch = batch_kernel(_drift_par, _drift_ser, work_arg=0, name="drift_batch")


# ------------------------------------------------------------------------------ delay


@njit(cache=True)
def _delay_one(w, t, d, state, out):
    if not (d >= 0.0 and math.isfinite(d)):
        return False
    hn = state.shape[0] // 2
    n = w.shape[0]
    et = np.empty(hn + n)
    ew = np.empty(hn + n)
    for i in range(hn):
        et[i] = state[i]
        ew[i] = state[hn + i]
    for k in range(n):
        et[hn + k] = t[k]
        ew[hn + k] = w[k]
    p = 0  # the query time only grows, so the bracket index only moves forward
    for k in range(n):
        now = hn + k
        if not et[now] > et[now - 1]:
            return False
        s = t[k] - d
        if s >= et[now]:
            out[k] = ew[now]
            continue
        if s < et[now - hn]:
            # older than the H samples a state keeps: fail here too, or a run in pieces
            # would differ from one run
            return False
        while et[p + 1] <= s:
            p += 1
        t_lo = et[p]
        if t_lo == -np.inf:
            out[k] = ew[p]  # before the first sample the input was held at its start
        else:
            out[k] = ew[p] + (ew[p + 1] - ew[p]) * (s - t_lo) / (et[p + 1] - t_lo)
    for i in range(hn):
        state[i] = et[n + i]
        state[hn + i] = ew[n + i]
    return True


@njit(cache=True, parallel=True)
def _delay_par(w, t, d, state, out, failed):
    """``y(t) = w(t - d)`` with linear interpolation between stored samples, batched.

    ``d`` (W,) delay (s); ``state`` (W, 2 H) ``[t_{-H} .. t_{-1}, w_{-H} .. w_{-1}]``
    oldest first (``t = -inf``: held since forever). A delay reaching further back
    than the stored history fails the walker.
    """
    for j in prange(w.shape[0]):
        ok = _delay_one(w[j], t, d[j], state[j], out[j])
        _finish(ok, out[j], failed, j)


@njit(cache=True)
def _delay_ser(w, t, d, state, out, failed):
    for j in range(w.shape[0]):
        ok = _delay_one(w[j], t, d[j], state[j], out[j])
        _finish(ok, out[j], failed, j)


delay_batch = batch_kernel(_delay_par, _delay_ser, work_arg=0, name="delay_batch")


# ------------------------------------------------------------------ output polynomial


@njit(cache=True)
def _poly_monotone(a, n_grid):
    """Whether ``P'(x) = 1 + sum_i (i + 2) a_i x^(i + 1) > 0`` on all of ``[-1, 1]``.

    ``P'`` is evaluated on ``n_grid`` points; between them it can dip by at most
    ``max|P''| * spacing / 2 <= B * spacing / 2`` with ``B = sum (i+2)(i+1) |a_i|``, so
    a grid minimum above that margin proves monotonicity (a thin band of barely
    monotone coefficient vectors is refused along with the non-monotone ones).
    """
    p = a.shape[0]
    bound = 0.0
    for i in range(p):
        bound += (i + 2) * (i + 1) * abs(a[i])
    spacing = 2.0 / (n_grid - 1)
    lo = np.inf
    for g in range(n_grid):
        x = -1.0 + g * spacing
        dp = 0.0
        for i in range(p - 1, -1, -1):
            dp = x * ((i + 2) * a[i] + dp)
        dp += 1.0
        if dp < lo:
            lo = dp
    return lo > 0.5 * bound * spacing


@njit(cache=True)
def _asym_one(w, a, centre, half, out):
    if not (half > 0.0 and math.isfinite(centre)):
        return False
    for i in range(a.shape[0]):
        if not math.isfinite(a[i]):
            return False
    if not _poly_monotone(a, 513):
        return False
    p = a.shape[0]
    for k in range(w.shape[0]):
        x = (w[k] - centre) / half
        acc = 0.0
        for i in range(p - 1, -1, -1):
            acc = x * (a[i] + acc)
        out[k] = centre + half * x * (1.0 + acc)
    return True


@njit(cache=True, parallel=True)
def _asym_output_par(w, a, centre, half, out, failed):
    """``y = c + h P((w - c) / h)``, ``P(x) = x + a_2 x^2 + ... + a_n x^n``, batched.

    ``a`` (W, n - 1) coefficients ``a_2 .. a_n``; ``centre``, ``half`` (W,) the data's
    output centre and half-span. Walkers whose ``P`` is not increasing on ``[-1, 1]``
    fail.
    """
    for j in prange(w.shape[0]):
        ok = _asym_one(w[j], a[j], centre[j], half[j], out[j])
        _finish(ok, out[j], failed, j)


@njit(cache=True)
def _asym_output_ser(w, a, centre, half, out, failed):
    for j in range(w.shape[0]):
        ok = _asym_one(w[j], a[j], centre[j], half[j], out[j])
        _finish(ok, out[j], failed, j)


asym_output_batch = batch_kernel(_asym_output_par, _asym_output_ser, work_arg=0,
                                 name="asym_output_batch")
