"""Kernels of the closed-form inverses driven by the output (Bouc–Wen, Duhem).

Both forward models are differential equations *in the input* on every monotone
stretch. Where the output rises with the input, the same equations written with the
output as the independent variable give the inverse without an algebraic loop:

* Bouc–Wen, ``y = k u + eps h`` with ``dh/du = f(h, u, s)``: ``dh/dy = f / (k + eps f)``
  and ``u = (y - eps h) / k`` (the multiplicative structure ``u = (y_d + H(u)) / k`` of
  review ref. [93] for ``eps = -1``, with ``H`` driven by the output instead of the
  unknown input);
* Duhem (Coleman–Hodgdon), ``dw/ds = a sgn(ds) (F(s) - w) + G(s)``: ``ds/dw = 1 /
  (a sgn(dw) (F(s) - w) + G(s))`` (review ref. [84]: the forward parameters used
  directly in the inverse model).

Both are integrated along the desired output with the classical Runge–Kutta step and
step doubling (local error below ``tol`` times the integrated variable's scale). A
non-positive slope ``dy/du`` means the forward model folds back there (no inverse):
the kernel stops and returns the sample index.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["bw_inverse", "duhem_inverse"]

#: Smallest step as a fraction of the step over the sample interval (a stall guard).
_MIN_FRACTION = 1e-12


@njit(cache=True)
def _bw_rhs(h, y, s, k, a, b, c, n, d, eps):
    """``dh/dy`` of Bouc–Wen along the output (NaN where ``dy/du <= 0``)."""
    u = (y - eps * h) / k
    ah = abs(h)
    sg = 1.0 if h > 0 else (-1.0 if h < 0 else 0.0)
    f = a + d * u - (b * s * sg + c) * ah ** n
    slope = k + eps * f
    if not slope > 0.0:
        return np.nan
    return f / slope


@njit(cache=True)
def _duhem_rhs(x, w, s, a, fc, gc):
    """``ds/dw`` of Coleman–Hodgdon along the output (NaN where ``dw/ds <= 0``)."""
    fv = 0.0
    for j in range(fc.shape[0] - 1, -1, -1):
        fv = fv * x + fc[j]
    gv = 0.0
    for j in range(gc.shape[0] - 1, -1, -1):
        gv = gv * x + gc[j]
    slope = a * s * (fv - w) + gv
    if not slope > 0.0:
        return np.nan
    return 1.0 / slope


@njit(cache=True)
def _rk4(kind, x, v, hstep, s, p, fc, gc):
    """One classical RK4 step of ``dx/dv`` from ``(v, x)`` over ``hstep``."""
    if kind == 0:
        k1 = _bw_rhs(x, v, s, p[0], p[1], p[2], p[3], p[4], p[5], p[6])
        k2 = _bw_rhs(x + 0.5 * hstep * k1, v + 0.5 * hstep, s, p[0], p[1], p[2], p[3],
                     p[4], p[5], p[6])
        k3 = _bw_rhs(x + 0.5 * hstep * k2, v + 0.5 * hstep, s, p[0], p[1], p[2], p[3],
                     p[4], p[5], p[6])
        k4 = _bw_rhs(x + hstep * k3, v + hstep, s, p[0], p[1], p[2], p[3], p[4], p[5], p[6])
    else:
        k1 = _duhem_rhs(x, v, s, p[0], fc, gc)
        k2 = _duhem_rhs(x + 0.5 * hstep * k1, v + 0.5 * hstep, s, p[0], fc, gc)
        k3 = _duhem_rhs(x + 0.5 * hstep * k2, v + 0.5 * hstep, s, p[0], fc, gc)
        k4 = _duhem_rhs(x + hstep * k3, v + hstep, s, p[0], fc, gc)
    return x + hstep * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0


@njit(cache=True)
def _integrate(kind, v, x0, v0, p, fc, gc, atol, xs):
    """``x`` at every ``v[i]`` (into ``xs``), from ``x0`` at ``v0``; -1 or the failed index."""
    x = x0
    vp = v0
    step = 0.0
    for i in range(v.shape[0]):
        dv = v[i] - vp
        if dv != 0.0:
            s = 1.0 if dv > 0 else -1.0
            left = abs(dv)
            if step <= 0.0 or step > left:
                step = left
            floor = _MIN_FRACTION * left
            while left > 0.0:
                hs = min(step, left)
                one = _rk4(kind, x, vp, s * hs, s, p, fc, gc)
                half = _rk4(kind, x, vp, 0.5 * s * hs, s, p, fc, gc)
                two = _rk4(kind, half, vp + 0.5 * s * hs, 0.5 * s * hs, s, p, fc, gc)
                if not (math.isfinite(one) and math.isfinite(two)):
                    if hs <= floor:
                        return i
                    step = 0.5 * hs
                    continue
                err = abs(two - one) / 15.0
                if err <= atol or hs <= floor:
                    # Richardson: the two half steps corrected by the error estimate
                    x = two + (two - one) / 15.0
                    vp = vp + s * hs if hs < left else v[i]
                    left -= hs
                    grow = 2.0 if err == 0.0 else min(2.0, 0.9 * (atol / err) ** 0.2)
                    step = hs * grow
                else:
                    step = hs * max(0.2, 0.9 * (atol / err) ** 0.2)
            vp = v[i]
        xs[i] = x
    return -1


@njit(cache=True)
def bw_inverse(y, k, a, b, c, n, d, eps, h0, y0, atol, h_out):
    """Bouc–Wen hysteretic state ``h`` along the desired output ``y`` (N,).

    ``h_out`` (N,) is written; the command is ``u = (y - eps h) / k``. Starts from ``h0``
    at output ``y0`` (the forward model's last output). Returns -1, or the index of the
    first sample where ``dy/du <= 0`` (no inverse).
    """
    p = np.array([k, a, b, c, n, d, eps])
    empty = np.zeros(0)
    return _integrate(0, y, h0, y0, p, empty, empty, atol, h_out)


@njit(cache=True)
def duhem_inverse(w, a, fc, gc, x0, w0, atol, x_out):
    """Coleman–Hodgdon normalised input ``s`` along the desired output ``w`` (N,).

    ``fc``, ``gc``: polynomial coefficients of ``F`` and ``G`` in ``s``, ascending. Starts
    from ``x0`` at output ``w0``; ``x_out`` (N,) written. Returns -1 or the index of the
    first sample where ``dw/ds <= 0``.
    """
    p = np.array([a])
    return _integrate(1, w, x0, w0, p, fc, gc, atol, x_out)
