"""Kernels of the Prandtl–Ishlinskii variants: generalised, asymmetric and rate-dependent play.

Equations (MODELS.md §1–2, review Eq. 22, 27, 28–30)::

    generalised play     v_k = max(γ_l(u_k) - r, min(γ_r(u_k) + r, v_{k-1}))
    unilateral play      v_k = max(u_k - r, min(m u_k, v_{k-1}))
    rate-dependent play  v_k = max(u_k - r̄_k, min(u_k + r̄_k, v_{k-1})),
                         r̄_k = r (1 + c ln(1 + |u̇_k| / u̇_0)),
                         u̇_k = (u_k - u_{k-1}) / (t_k - t_{k-1})

and in every case ``y_k = p0 u_k + sum_i w_i v_{i,k}``.

The clamp is always evaluated as written, ``max(lo, min(hi, v))``, *not* as
"``lo`` if below, ``hi`` if above": the two differ when the band is inverted
(``hi < lo``), which these operators allow (the envelopes of the generalised play can
cross, and the unilateral play's band closes where ``(m - 1) u + r < 0``). The nesting
makes the rising boundary win, as the equations say. While ``lo <= hi`` (classical play)
both forms select the same number, so the generalised play with identity envelopes and
the rate-dependent play with ``c = 0`` reproduce ``pi_play_batch`` bit for bit.

Batched kernels take parameters with a leading walker axis ``W``, write the output
``y`` (W, N) and update ``state`` (W, S) in place; the loop over walkers runs in
parallel for large batches and serially otherwise
(:func:`bayeshyst.models._kernels.batch_kernel`), and nothing is allocated per sample.
"""

from __future__ import annotations

import math

from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "ENVELOPE_CUBIC",
    "ENVELOPE_QUADRATIC",
    "envelope",
    "pi_asymmetric_batch",
    "pi_generalized_batch",
    "pi_rate_batch",
]

#: ``γ(u) = u + h (b x² + b² x³ / 3)``, ``x = (u - u_c) / h``: ``γ' = (1 + b x)² >= 0``.
ENVELOPE_CUBIC = 0
#: ``γ(u) = u + h b x²``: monotone only while ``1 + 2 b x >= 0`` (checked by the model).
ENVELOPE_QUADRATIC = 1


@njit(cache=True, error_model="numpy")
def envelope(u, b, uc, uh, kind):
    """Envelope ``γ(u)`` of the generalised play (V).

    Parameters
    ----------
    u : float
        Input (V).
    b : float
        Bend coefficient (dimensionless); ``b = 0`` gives ``γ(u) = u`` exactly.
    uc : float
        Centre of the data's input range (V).
    uh : float
        Half of the data's input span (V), > 0.
    kind : int
        :data:`ENVELOPE_CUBIC` or :data:`ENVELOPE_QUADRATIC`.

    Returns
    -------
    float
        ``γ(u)`` (V).
    """
    x = (u - uc) / uh
    if kind == ENVELOPE_CUBIC:
        # written as u + (correction) so that b = 0 adds an exact zero: the identity
        # envelope must give the classical play to the last bit
        return u + uh * (b * x * x + b * b * x * x * x / 3.0)
    return u + uh * (b * x * x)


@njit(cache=True)
def _clamp(lo, hi, v):
    # max(lo, min(hi, v)): the lower (rising) boundary wins when the band is inverted
    t = hi if v > hi else v
    return lo if t < lo else t


@njit(cache=True)
def _generalized_one(u, p0, w, r, bl, br, uc, uh, kind, v, y):
    n = w.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        # the envelopes are shared by all operators: evaluate them once per sample
        gl = envelope(uk, bl, uc, uh, kind)
        gr = envelope(uk, br, uc, uh, kind)
        acc = p0 * uk
        for i in range(n):
            vi = _clamp(gl - r[i], gr + r[i], v[i])
            v[i] = vi
            acc += w[i] * vi
        y[k] = acc


@njit(cache=True, parallel=True)
def _pi_generalized_par(u, p0, w, r, bl, br, uc, uh, kind, state, y):
    """Generalised-play PI ``y = p0 u + sum_i w_i F^γ_{r_i}[u]`` for W parameter vectors.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    p0 : ndarray, shape (W,)
        Linear weight (output unit/V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and thresholds (V).
    bl, br : ndarray, shape (W,)
        Bend coefficients of the rising (``γ_l``) and falling (``γ_r``) envelopes.
    uc, uh : ndarray, shape (W,)
        Centre and half-span of the envelopes' input scaling (V).
    kind : int
        Envelope family (:data:`ENVELOPE_CUBIC`, :data:`ENVELOPE_QUADRATIC`).
    state : ndarray, shape (W, n)
        Operator outputs before ``u[0]`` (V); overwritten with those after ``u[-1]``.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _generalized_one(u, p0[j], w[j], r[j], bl[j], br[j], uc[j], uh[j], kind,
                         state[j], y[j])


@njit(cache=True)
def _pi_generalized_ser(u, p0, w, r, bl, br, uc, uh, kind, state, y):
    for j in range(w.shape[0]):
        _generalized_one(u, p0[j], w[j], r[j], bl[j], br[j], uc[j], uh[j], kind,
                         state[j], y[j])


pi_generalized_batch = batch_kernel(_pi_generalized_par, _pi_generalized_ser, work_arg=-1,
                                    name="pi_generalized_batch")


@njit(cache=True)
def _asymmetric_one(u, p0, w, r, m, v, y):
    n = w.shape[0]
    for k in range(u.shape[0]):
        uk = u[k]
        acc = p0 * uk
        for i in range(n):
            vi = _clamp(uk - r[i], m[i] * uk, v[i])
            v[i] = vi
            acc += w[i] * vi
        y[k] = acc


@njit(cache=True, parallel=True)
def _pi_asymmetric_par(u, p0, w, r, m, state, y):
    """Unilateral-play PI ``y = p0 u + sum_i w_i max(u - r_i, min(m_i u, v_i))``.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input (V).
    p0 : ndarray, shape (W,)
        Linear weight (output unit/V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and thresholds (V).
    m : ndarray, shape (W, n)
        Slopes of the falling boundaries ``m_i u`` (dimensionless); a shared slope is
        passed repeated along the operator axis.
    state : ndarray, shape (W, n)
        Operator outputs before ``u[0]`` (V); overwritten with those after ``u[-1]``.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _asymmetric_one(u, p0[j], w[j], r[j], m[j], state[j], y[j])


@njit(cache=True)
def _pi_asymmetric_ser(u, p0, w, r, m, state, y):
    for j in range(w.shape[0]):
        _asymmetric_one(u, p0[j], w[j], r[j], m[j], state[j], y[j])


pi_asymmetric_batch = batch_kernel(_pi_asymmetric_par, _pi_asymmetric_ser, work_arg=-1,
                                   name="pi_asymmetric_batch")


# error_model="numpy": a walker with an out-of-support u̇_0 = 0 must give inf/NaN that
# the model flags as failed, not raise ZeroDivisionError inside the parallel loop
@njit(cache=True, error_model="numpy")
def _rate_one(u, t, p0, w, r, c, ud0, s, y):
    n = w.shape[0]
    # s = [v_1..v_n, u_prev, t_prev, has_prev]: the backward difference at the first
    # sample needs the previous sample, which a continued run takes from the state
    up = s[n]
    tp = s[n + 1]
    has_prev = s[n + 2] != 0.0
    for k in range(u.shape[0]):
        uk = u[k]
        tk = t[k]
        if has_prev:
            rate = abs(uk - up) / (tk - tp)
        else:
            rate = 0.0
        # one logarithm per sample, shared by all operators (they scale alike)
        f = 1.0 + c * math.log1p(rate / ud0)
        acc = p0 * uk
        for i in range(n):
            ri = r[i] * f
            vi = _clamp(uk - ri, uk + ri, s[i])
            s[i] = vi
            acc += w[i] * vi
        y[k] = acc
        up = uk
        tp = tk
        has_prev = True
    s[n] = up
    s[n + 1] = tp
    s[n + 2] = 1.0


@njit(cache=True, parallel=True)
def _pi_rate_par(u, t, p0, w, r, c, ud0, state, y):
    """Rate-dependent play PI with thresholds ``r_i (1 + c ln(1 + |u̇| / u̇_0))``.

    Parameters
    ----------
    u, t : ndarray, shape (N,)
        Input (V) and sample times (s), strictly increasing (also across ``state``).
    p0 : ndarray, shape (W,)
        Linear weight (output unit/V).
    w, r : ndarray, shape (W, n)
        Operator weights (output unit/V) and rate-free thresholds (V).
    c : ndarray, shape (W,)
        Rate sensitivity of the thresholds (dimensionless), >= 0.
    ud0 : ndarray, shape (W,)
        Reference input rate ``u̇_0`` (V/s), > 0.
    state : ndarray, shape (W, n + 3)
        Operator outputs (V), previous input (V), previous time (s) and a flag (1.0 if
        there is a previous sample, 0.0 before the first); updated in place.
    y : ndarray, shape (W, N)
        Output, written.
    """
    for j in prange(w.shape[0]):
        _rate_one(u, t, p0[j], w[j], r[j], c[j], ud0[j], state[j], y[j])


@njit(cache=True)
def _pi_rate_ser(u, t, p0, w, r, c, ud0, state, y):
    for j in range(w.shape[0]):
        _rate_one(u, t, p0[j], w[j], r[j], c[j], ud0[j], state[j], y[j])


pi_rate_batch = batch_kernel(_pi_rate_par, _pi_rate_ser, work_arg=-1, name="pi_rate_batch")
