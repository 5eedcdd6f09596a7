"""Closed-form inverses of the differential models, driven by the desired output.

* :func:`bouc_wen_inverse` -- the multiplicative-structure inverse of Bouc–Wen (review
  §9, ref. [93]): ``u = (y_d + h) / k`` for ``y = k u - h``. The review notes that
  solving it for ``u`` and ``h = H(u)`` at once is an algebraic loop, broken in [93] by
  a delay or a low-pass filter at the cost of an error. Here the hysteretic state is
  driven by the *output* instead: on a monotone stretch ``dh/du = f(h, u)`` and
  ``dy/du = k - f``, so ``dh/dy = f / (k - f)`` is integrated along ``y_d`` and
  ``u = (y_d + h) / k`` follows explicitly -- exact up to the integration tolerance, no
  loop and no delay. It exists where ``dy/du = k - f > 0`` (the loop does not fold back).
* :func:`duhem_inverse` -- the Coleman–Hodgdon model with its roles swapped (review §8,
  ref. [84]: the identified forward parameters used directly in the inverse model): from
  ``dw/ds = a sgn(ds) (F(s) - w) + G(s)``, ``ds/dw = 1 / (a sgn(dw) (F(s) - w) + G(s))``
  integrated along ``w = y_d``. It exists where ``dw/ds > 0``.

Kernels: :mod:`bayeshyst.models._kernels.hysteresis_inverse`. The models expose these as
their ``inverse`` method (``has_inverse``), like the play-PI and MBW inverses.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.models._kernels.hysteresis_inverse import bw_inverse, duhem_inverse

__all__ = ["INVERSE_TOL", "bouc_wen_inverse", "duhem_inverse_command"]

#: Local error allowed per integration step, relative to the state's natural scale
#: (the BW saturation level, the Duhem normalised input span 1).
INVERSE_TOL = 1e-11


def _scalar(theta: Mapping[str, Any], name: str) -> float:
    v = np.asarray(theta[name], dtype=float)
    if v.size != 1:
        raise ParameterError(f"{name!r} must be a scalar here, got shape {v.shape}")
    return float(v.reshape(-1)[0])


def _desired(y: Any) -> np.ndarray:
    y = np.ascontiguousarray(y, dtype=float).ravel()
    if y.size == 0 or not np.all(np.isfinite(y)):
        raise ParameterError("the desired output must be a non-empty finite array")
    return y


def bouc_wen_inverse(y: Any, theta: Mapping[str, Any], *, sign: int = -1,
                     delta: float = 0.0, state0: Any = None) -> np.ndarray:
    """Command ``u`` (N,) that drives Bouc–Wen ``y = k u + sign h`` to output ``y`` (N,).

    Parameters
    ----------
    y : array_like, shape (N,)
        Desired output.
    theta : mapping
        Scalar ``k``, ``alpha``, ``beta``, ``gamma``, ``n`` of the forward model.
    sign : {-1, 1}
        The forward model's output sign (``BoucWen.sign``).
    delta : float
        Asymmetry ``δ`` (drive ``α + δ u``; 0 for the classical model).
    state0 : array_like, shape (2,), optional
        The forward state ``[h, u_prev]`` before the first sample; default relaxed
        (``h = 0``) at ``u = y[0] / k``.

    Raises
    ------
    ParameterError
        Parameters outside the stable region, or a desired output the model cannot
        produce monotonically (``dy/du <= 0`` on the way: the sample is named).
    """
    y = _desired(y)
    k, a, b, c, n = (_scalar(theta, p) for p in ("k", "alpha", "beta", "gamma", "n"))
    if not (math.isfinite(k) and k != 0.0 and a > 0 and b + c > 0 and b - c >= 0 and n >= 1
            and math.isfinite(b) and math.isfinite(n) and math.isfinite(delta)):
        raise ParameterError(f"Bouc–Wen inverse needs k != 0 and the stable region alpha > 0, "
                             f"beta + gamma > 0, beta >= gamma, n >= 1; got k={k}, alpha={a}, "
                             f"beta={b}, gamma={c}, n={n}")
    if state0 is None:
        h0, u0 = 0.0, y[0] / k
    else:
        s0 = np.asarray(state0, dtype=float).ravel()
        if s0.size != 2 or not np.all(np.isfinite(s0)):
            raise ParameterError(f"state0 must be [h, u_prev], finite; got {state0!r}")
        h0, u0 = float(s0[0]), float(s0[1])
    h = np.empty_like(y)
    atol = INVERSE_TOL * (a / (b + c)) ** (1.0 / n)
    bad = bw_inverse(y, k, a, b, c, n, float(delta), float(sign), h0, k * u0 + sign * h0,
                     atol, h)
    if bad >= 0:
        raise ParameterError(f"Bouc–Wen has no inverse along this output: dy/du <= 0 before "
                             f"sample {bad} (y = {y[bad]:.6g}); the loop folds back there")
    u = (y - sign * h) / k
    if delta != 0.0 and not np.all(a + delta * u > 0):
        raise ParameterError("the asymmetric drive alpha + delta*u is not positive along the "
                             "command: no Bouc–Wen inverse")
    return u


def _relaxed_start(fc: np.ndarray, w0: float) -> float:
    """The normalised input where ``F(s) = w0`` (relaxed start), the real root nearest 0."""
    poly = np.polynomial.Polynomial(fc) - w0
    if poly.degree() < 1 or np.all(poly.coef[1:] == 0):
        raise ParameterError("F is constant: no relaxed state reaches the first desired "
                             "output; pass state0")
    roots = poly.roots()
    real = roots[np.abs(roots.imag) <= 1e-9 * max(1.0, float(np.max(np.abs(roots))))].real
    if real.size == 0:
        raise ParameterError(f"no relaxed state has output {w0:.6g} (F(s) never reaches it); "
                             "pass state0")
    return float(real[np.argmin(np.abs(real))])


def duhem_inverse_command(y: Any, theta: Mapping[str, Any], *,
                          state0: Any = None) -> np.ndarray:
    """Command ``u`` (N,) that drives the Coleman–Hodgdon model to output ``y`` (N,).

    Parameters
    ----------
    y : array_like, shape (N,)
        Desired output.
    theta : mapping
        ``alpha`` (scalar), ``f``, ``g`` (coefficients in the normalised input, ascending),
        ``u_centre``, ``u_half`` of :class:`~bayeshyst.models.duhem.Duhem`.
    state0 : array_like, shape (2,), optional
        The forward state ``[w, u_prev]`` before the first sample; default relaxed at the
        first desired output: ``w = F(s_0) = y[0]`` with ``s_0`` the real root nearest the
        centre of the input normalisation.

    Raises
    ------
    ParameterError
        ``alpha < 0``, no relaxed start, or ``dw/du <= 0`` on the way (sample named).
    """
    y = _desired(y)
    a = _scalar(theta, "alpha")
    centre, half = _scalar(theta, "u_centre"), _scalar(theta, "u_half")
    fc = np.ascontiguousarray(theta["f"], dtype=float).ravel()
    gc = np.ascontiguousarray(theta["g"], dtype=float).ravel()
    if not (a >= 0 and math.isfinite(a) and half > 0 and math.isfinite(centre)
            and np.all(np.isfinite(fc)) and np.all(np.isfinite(gc))):
        raise ParameterError(f"Duhem inverse needs finite parameters, alpha >= 0 and u_half "
                             f"> 0; got alpha={a}, u_half={half}")
    if state0 is None:
        x0, w0 = _relaxed_start(fc, float(y[0])), float(y[0])
    else:
        s0 = np.asarray(state0, dtype=float).ravel()
        if s0.size != 2 or not np.all(np.isfinite(s0)):
            raise ParameterError(f"state0 must be [w, u_prev], finite; got {state0!r}")
        w0, x0 = float(s0[0]), (float(s0[1]) - centre) / half
    x = np.empty_like(y)
    bad = duhem_inverse(y, a, fc, gc, x0, w0, INVERSE_TOL, x)
    if bad >= 0:
        raise ParameterError(f"the Duhem model has no inverse along this output: dw/du <= 0 "
                             f"before sample {bad} (y = {y[bad]:.6g}); the loop folds back")
    return centre + half * x
