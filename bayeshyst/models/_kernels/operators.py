"""Kernels of the rate-independent operators: play, stop, PI sums, elasto-slide.

Equations (MODELS.md §1–2, review Eq. 11–14, 20, 36–37)::

    play  v_k = max(u_k - r, min(u_k + r, v_{k-1}))
    stop  e_k = min(r, max(-r, e_{k-1} + u_k - u_{k-1}))

Batched kernels take parameters of shape (W, n), a state of shape (W, n), and write the
output (W, N) and the final state in place. The inner loop over operators has no
dependence between operators, so numba vectorises it; the outer loop over walkers runs
in parallel for large batches and serially otherwise
(:func:`bayeshyst.models._kernels.batch_kernel`).
"""

from __future__ import annotations

from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "maxwell_slip_batch",
    "pi_play_batch",
    "pi_stop_batch",
    "play_operator",
    "stop_operator",
]


@njit(cache=True)
def play_operator(u, r, v0, out):
    """One play operator of threshold ``r``; writes ``out`` (N,) and returns the last state."""
    v = v0
    for k in range(u.shape[0]):
        lo = u[k] - r
        hi = u[k] + r
        if v < lo:
            v = lo
        elif v > hi:
            v = hi
        out[k] = v
    return v


@njit(cache=True)
def stop_operator(u, r, e0, u_prev, out):
    """One stop operator of threshold ``r``; ``u_prev`` is the input before ``u[0]``."""
    e = e0
    up = u_prev
    for k in range(u.shape[0]):
        e = e + u[k] - up
        if e > r:
            e = r
        elif e < -r:
            e = -r
        up = u[k]
        out[k] = e
    return e


@njit(cache=True, fastmath=False)
def _pi_play_one(u, p0, w, r, v, y):
    n = w.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        acc = p0 * uk
        for i in range(n):
            lo = uk - r[i]
            hi = uk + r[i]
            vi = v[i]
            vi = lo if vi < lo else (hi if vi > hi else vi)
            v[i] = vi
            acc += w[i] * vi
        y[k] = acc


@njit(cache=True, parallel=True)
def _pi_play_par(u, p0, w, r, state, y):
    """Play-PI ``y = p0 u + sum_i w_i F_{r_i}[u]`` for W parameter vectors.

    Parameters
    ----------
    u : (N,) input; p0 : (W,); w, r : (W, n); state : (W, n) play outputs, updated in
    place to the final state; y : (W, N) output, written.
    """
    for j in prange(w.shape[0]):
        _pi_play_one(u, p0[j], w[j], r[j], state[j], y[j])


@njit(cache=True)
def _pi_play_ser(u, p0, w, r, state, y):
    for j in range(w.shape[0]):
        _pi_play_one(u, p0[j], w[j], r[j], state[j], y[j])


pi_play_batch = batch_kernel(_pi_play_par, _pi_play_ser, work_arg=-1, name="pi_play_batch")


@njit(cache=True)
def _pi_stop_one(u, p0, w, r, s, y):
    # s = [e_1 .. e_n, u_prev]: the stop integrates input increments, so it must
    # remember the last input
    n = w.shape[0]
    up = s[n]
    for k in range(u.shape[0]):
        uk = u[k]
        du = uk - up
        up = uk
        acc = p0 * uk
        for i in range(n):
            ei = s[i] + du
            ri = r[i]
            ei = ri if ei > ri else (-ri if ei < -ri else ei)
            s[i] = ei
            acc += w[i] * ei
        y[k] = acc
    s[n] = u[u.shape[0] - 1]


@njit(cache=True, parallel=True)
def _pi_stop_par(u, p0, w, r, state, y):
    """Stop-PI ``y = p0 u + sum_i w_i E_{r_i}[u]`` for W parameter vectors.

    ``state`` is (W, n + 1): the n stop outputs followed by the previous input value
    (the stop operator integrates input increments, so it must remember the last input).
    """
    for j in prange(w.shape[0]):
        _pi_stop_one(u, p0[j], w[j], r[j], state[j], y[j])


@njit(cache=True)
def _pi_stop_ser(u, p0, w, r, state, y):
    for j in range(w.shape[0]):
        _pi_stop_one(u, p0[j], w[j], r[j], state[j], y[j])


pi_stop_batch = batch_kernel(_pi_stop_par, _pi_stop_ser, work_arg=-1, name="pi_stop_batch")


@njit(cache=True)
def _maxwell_one(x, k0, k, delta, xs, y):
    n = k.shape[0]
    for t in range(x.shape[0]):
        xt = x[t]
        acc = k0 * xt
        for i in range(n):
            # the spring stretches until its deflection reaches the slip deflection
            # delta_i = f_i / |k_i|; beyond it the slider is dragged along (Eq. 36)
            d = xt - xs[i]
            if d > delta[i]:
                xs[i] = xt - delta[i]
            elif d < -delta[i]:
                xs[i] = xt + delta[i]
            acc += k[i] * (xt - xs[i])
        y[t] = acc


@njit(cache=True, parallel=True)
def _maxwell_slip_par(x, k0, k, delta, state, y):
    """Maxwell-slip ``y = k0 x + sum_i k_i (x - x_i)`` with elasto-slide elements.

    ``k`` (W, n) element stiffnesses, ``delta`` (W, n) slip deflections
    ``f_i / |k_i|`` (>= 0); ``state`` (W, n) slider positions ``x_i``, updated in place.
    """
    for j in prange(k.shape[0]):
        _maxwell_one(x, k0[j], k[j], delta[j], state[j], y[j])


@njit(cache=True)
def _maxwell_slip_ser(x, k0, k, delta, state, y):
    for j in range(k.shape[0]):
        _maxwell_one(x, k0[j], k[j], delta[j], state[j], y[j])


maxwell_slip_batch = batch_kernel(_maxwell_slip_par, _maxwell_slip_ser, work_arg=-1,
                                  name="maxwell_slip_batch")
