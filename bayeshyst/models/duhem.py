"""Duhem-type differential hysteresis: Coleman–Hodgdon and improved Duhem (MODELS.md §5).

The Coleman–Hodgdon model is review Eq. 45, the improved Duhem model review Eq. 46.

Both are integrated *in the input*, not in time: between samples the input is a
straight line, and along it the state obeys a linear ODE in the input that is solved
exactly (:mod:`bayeshyst.models._kernels.duhem`). Polynomial coefficients act on the
normalised input ``s = (u - u_centre) / u_half`` (fixed from the data's input range) so
that the same priors fit a 0–150 V unipolar drive and a ±10 V bipolar one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.polynomial import Polynomial

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.duhem import duhem_batch, improved_duhem_batch
from bayeshyst.models.base import (
    DataScales,
    HysteresisModel,
    LinearInParams,
    data_scales,
    kernel_buffers,
    sample_period,
)
from bayeshyst.models.output_driven_inverse import duhem_inverse_command
from bayeshyst.models.registry import register
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace

__all__ = ["MAX_ORDER", "Duhem", "ImprovedDuhem"]

#: Highest polynomial order accepted for ``f`` and ``g``. Monomials on ``[-1, 1]`` grow
#: collinear with the order (condition number of their Gram matrix: 67 at order 3,
#: 3e5 at order 8, 3e8 at order 12), and strongly correlated coefficients are what an
#: ensemble sampler mixes through worst.
MAX_ORDER = 8


def _normalisation(sc: DataScales) -> tuple[list[Param], dict[str, float]]:
    centre = 0.5 * (sc.u_min + sc.u_max)
    half = 0.5 * sc.u_span
    params = [
        Param("u_centre", Normal(centre, sc.u_span), unit=sc.u_unit,
              description="centre of the input normalisation s = (u - u_centre) / u_half"),
        Param("u_half", LogNormal.from_median(half, 1.0), unit=sc.u_unit,
              description="half-span of the input normalisation"),
    ]
    return params, {"u_centre": centre, "u_half": half}


def _check_order(n: Any, what: str) -> None:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or not 0 <= n <= MAX_ORDER:
        raise ModelError(f"{what} must be an integer in [0, {MAX_ORDER}], got {n!r}")


def _check_time(t: np.ndarray, state0: np.ndarray, col: int) -> None:
    # the backward-difference derivative needs strictly increasing time, including the
    # step from the state's last sample to t[0]
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise ParameterError("t must be strictly increasing for a rate-dependent model")
    # NaN rows (walkers that failed earlier) are left to the kernel, which flags them
    late = state0[:, col] >= t[0]
    if np.any(late):
        raise ParameterError(f"t[0] = {t[0]} is not after the state's last sample time "
                             f"{state0[late, col].max()}")


@register
@dataclass(frozen=True)
class Duhem(LinearInParams, HysteresisModel):
    r"""Coleman–Hodgdon (classical Duhem) model, review Eq. 45.

    .. math::  \dot w = \alpha |\dot s| (f(s) - w) + \dot s\, g(s), \qquad y = w,

    with polynomials ``f(s) = sum_j f_j s^j`` (the curve that ``w`` relaxes to, output
    unit) and ``g(s) = sum_j g_j s^j`` (output unit per unit ``s``) in the normalised
    input ``s = (u - u_centre) / u_half``.

    Parameters
    ----------
    f_order : int
        Order of ``f`` (``f_order + 1`` coefficients), 0..8.
    g_order : int
        Order of ``g`` (``g_order + 1`` coefficients), 0..8.

    Notes
    -----
    Parameters: ``alpha`` (per unit ``s``, ``>= 0``), ``f`` (f_order + 1,) and ``g``
    (g_order + 1,) in the output unit, and the fixed normalisation ``u_centre``,
    ``u_half`` (V). In the review's variables (input ``v = u`` in V) the same model has
    ``alpha_V = alpha / u_half`` (1/V), ``f_V(v) = f(s)`` and ``g_V(v) = g(s) / u_half``
    (see :meth:`polynomials`).

    Integration: on each sample interval the input is a straight line, so
    ``dw/ds = alpha sgn(ds) (f(s) - w) + g(s)`` is a linear ODE in ``s`` solved exactly
    (integrating factor, closed-form polynomial moments). Time stamps are ignored: the
    model is rate-independent exactly.

    Linearity: for fixed ``alpha`` the output is linear in ``(f, g)`` jointly (the
    update is linear in ``P = alpha sgn f + g`` and in ``w``, and the relaxed start
    ``w_0 = f(s_0)`` is linear in ``f``), so ``y = Phi(alpha) [f; g]``
    (:meth:`regressors`): the coefficients have a conjugate Gaussian posterior given
    ``alpha``.

    State ``[w, u_prev]``. Relaxed initial state: ``w_0 = f(s_0)`` (on the curve ``f``,
    where the hysteretic term vanishes), ``u_prev = u_0``. ``alpha < 0`` (loops that
    grow without bound) is flagged as a failed simulation.
    """

    name: ClassVar[str] = "duhem"
    # f's constant term shifts w one-for-one (w starts at f(s0)): an output offset
    has_output_offset: ClassVar[bool] = True
    # for fixed alpha the output (from the relaxed start w0 = f(s0)) is linear in [f, g]
    linear_params: ClassVar[tuple[str, ...]] = ("f", "g")
    equation: ClassVar[str] = "review Eq. 45, inverse ref. [84]"
    rate_dependent: ClassVar[bool] = False
    has_inverse: ClassVar[bool] = True
    f_order: int = 3
    g_order: int = 1

    def __post_init__(self) -> None:
        _check_order(self.f_order, "f_order")
        _check_order(self.g_order, "g_order")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``alpha``, ``f`` (f_order + 1,), ``g`` (g_order + 1,), fixed ``u_centre``, ``u_half``.

        Priors: ``alpha ~ LogNormal(median 3, 1)``; every coefficient of ``f`` and ``g``
        ``Normal(0, y_ref)`` with ``y_ref`` the largest output magnitude of ``data``, so that
        the constant term reaches the offset of a unipolar output as easily as the linear
        term reaches its span. ``u_centre`` and ``u_half`` (V) are the centre and half-span
        of the data's input range; ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        # coefficient scale: the output magnitude, so that the constant term can reach
        # the offset of a unipolar output as easily as the linear term reaches its span
        ys = max(abs(sc.y_min), abs(sc.y_max))
        norm, fixed = _normalisation(sc)
        return ParamSpace(
            (
                Param("alpha", LogNormal.from_median(3.0, 1.0),
                      description="relaxation rate towards f per unit of normalised input"),
                Param("f", Normal(0.0, ys), shape=(self.f_order + 1,), unit=sc.y_unit,
                      description="coefficients of f(s), ascending powers of s"),
                Param("g", Normal(0.0, ys), shape=(self.g_order + 1,), unit=sc.y_unit,
                      description="coefficients of g(s), ascending powers of s"),
            ),
            fixed=fixed,
            fixed_params=tuple(norm),
        )

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s0 = (u0 - theta["u_centre"]) / theta["u_half"]
        powers = s0[:, None] ** np.arange(self.f_order + 1)
        return np.stack([np.sum(theta["f"] * powers, axis=1),
                         np.full(s0.shape, u0)], axis=1)

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0])
        duhem_batch(u, theta["alpha"], theta["f"], theta["g"], theta["u_centre"],
                    theta["u_half"], state, y, failed)
        state[failed] = np.nan
        return y, state, failed

    def inverse(self, y: Any, t: Any, theta: Mapping[str, Any], *,
                state0: np.ndarray | None = None) -> np.ndarray:
        """Feedforward input ``u`` (N,) that drives the model to output ``y`` (N,).

        The Duhem model with its roles swapped, in the forward parameters (review ref.
        [84]): ``ds/dw = 1 / (alpha sgn(dw) (f(s) - w) + g(s))`` integrated along ``y``
        (:func:`~bayeshyst.models.output_driven_inverse.duhem_inverse_command`).

        Parameters
        ----------
        y : array_like, shape (N,)
            Desired output.
        t : array_like, shape (N,)
            Times (s), unused (rate-independent).
        theta : mapping
            Forward parameters (one vector).
        state0 : ndarray, shape (2,), optional
            The forward state ``[w, u_prev]``; default relaxed at ``w = y[0]``.

        Raises
        ------
        ParameterError
            Where the loop folds back (``dw/du <= 0``) or no relaxed state fits ``y[0]``.
        """
        return duhem_inverse_command(y, theta, state0=state0)

    def polynomials(self, theta: Mapping[str, Any]) -> tuple[float, Polynomial, Polynomial]:
        """The review's ``(alpha_V, f_V, g_V)`` in the raw input ``v`` (V).

        Parameters
        ----------
        theta : mapping
            One parameter vector of this model.

        Returns
        -------
        alpha_V : float
            ``alpha / u_half`` (1/V).
        f_V, g_V : numpy.polynomial.Polynomial
            ``f_V(v) = f(s)`` (output unit) and ``g_V(v) = g(s) / u_half`` (output unit
            per V), with ``s = (v - u_centre) / u_half``.
        """
        c, h = float(theta["u_centre"]), float(theta["u_half"])
        s = Polynomial([-c / h, 1.0 / h])
        f_v = Polynomial(np.asarray(theta["f"], float))(s)
        g_v = Polynomial(np.asarray(theta["g"], float))(s) / h
        return float(theta["alpha"]) / h, f_v, g_v


@register
@dataclass(frozen=True)
class ImprovedDuhem(LinearInParams, HysteresisModel):
    r"""Improved Duhem model, review Eq. 46 (ref. [85]), MODELS.md §5.

    .. math::  y = k u + p \dot u - h, \qquad
               \dot h = \alpha \dot s - \beta |\dot s| h + \gamma s \dot s,

    with the normalised input ``s = (u - u_centre) / u_half``. The review's text lost
    the absolute-value bars; this is the form commonly published (the dissipative term
    ``-beta |du/dt| h`` as in Bouc–Wen, the others odd in ``du/dt``). In the review's raw
    variables, ``hdot = a u' - b |u'| h + c u u'`` with
    ``a = alpha / u_half - gamma u_centre / u_half^2``, ``b = beta / u_half``,
    ``c = gamma / u_half^2`` (:meth:`published_parameters`).

    Notes
    -----
    Parameters: ``k`` (output unit/V), ``p`` (output unit s/V), ``alpha`` and ``gamma``
    (output unit), ``beta`` (per unit ``s``, ``>= 0``; negative values are flagged as
    failed), fixed ``u_centre``, ``u_half`` (V).
    Rate dependence enters only through ``p du/dt``; ``du/dt`` is the backward
    difference ``(u_k - u_{k-1}) / (t_k - t_{k-1})``. The ``h`` equation is integrated
    exactly in ``s`` (linear ODE along each monotone sample interval).
    For fixed ``beta`` the output is linear in ``(k, p, alpha, gamma)``.

    State ``[h, u_prev, t_prev]``. Relaxed initial state: ``h = 0``, ``u_prev = u_0``,
    ``t_prev = -inf`` (so the first sample's derivative is 0).
    """

    name: ClassVar[str] = "duhem_improved"
    # for fixed beta, h is linear in (alpha, gamma) from h0 = 0 and the rate term in p:
    # the sampler draws these four exactly and explores beta alone
    linear_params: ClassVar[tuple[str, ...]] = ("k", "p", "alpha", "gamma")
    equation: ClassVar[str] = "review Eq. 46"
    rate_dependent: ClassVar[bool] = True

    def param_space(self, data: Any = None) -> ParamSpace:
        """``k``, ``p``, ``alpha``, ``beta``, ``gamma`` and the fixed ``u_centre``, ``u_half``.

        Priors scaled from ``data``: ``k ~ Normal(g, |g|)`` (secant gain ``g``); ``p`` such
        that ``p du/dt`` reaches the full stroke at 1 sd for an excitation at 1 % of the
        sampling rate; ``alpha`` and ``gamma`` ``Normal(0, y_span / 2)``;
        ``beta ~ LogNormal(median 2, 1)``. ``data`` as in
        :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        g = abs(sc.gain)
        gu = sc.gain_unit
        # p du/dt reaches the full stroke at 1 sigma for an excitation at 1 % of the
        # sampling rate: weakly informative, and scaled by the data's time base
        tau = 100.0 * sample_period(data, 1e-4) / (2.0 * np.pi)
        yh = 0.5 * sc.y_span
        norm, fixed = _normalisation(sc)
        return ParamSpace(
            (
                Param("k", Normal(sc.gain, g), unit=gu, description="linear gain"),
                Param("p", Normal(0.0, g * tau), unit=f"{gu} s",
                      description="rate term p du/dt (rate dependence)"),
                Param("alpha", Normal(0.0, yh), unit=sc.y_unit,
                      description="hysteretic drive alpha ds"),
                Param("beta", LogNormal.from_median(2.0, 1.0),
                      description="dissipation beta |ds| h (loop rounding)"),
                Param("gamma", Normal(0.0, yh), unit=sc.y_unit,
                      description="asymmetry term gamma s ds"),
            ),
            fixed=fixed,
            fixed_params=tuple(norm),
        )

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s = np.zeros((theta["k"].shape[0], 3))
        s[:, 1] = u0
        s[:, 2] = -np.inf
        return s

    def _run(self, u, t, theta, state0):
        _check_time(t, state0, 2)
        y, state, failed = kernel_buffers(state0, u.shape[0])
        improved_duhem_batch(u, t, theta["k"], theta["p"], theta["alpha"], theta["beta"],
                             theta["gamma"], theta["u_centre"], theta["u_half"], state, y,
                             failed)
        state[failed] = np.nan
        return y, state, failed

    def published_parameters(self, theta: Mapping[str, Any]) -> dict[str, float]:
        """The review's raw-variable parameters of Eq. 46.

        Parameters
        ----------
        theta : mapping
            One parameter vector of this model.

        Returns
        -------
        dict
            ``k`` (output unit/V), ``p`` (output unit s/V), ``a`` (output unit/V), ``b``
            (1/V), ``c`` (output unit/V^2) of ``y = k u + p u' - h``,
            ``h' = a u' - b |u'| h + c u u'``.
        """
        c, h = float(theta["u_centre"]), float(theta["u_half"])
        gam = float(theta["gamma"])
        return {"k": float(theta["k"]), "p": float(theta["p"]),
                "a": float(theta["alpha"]) / h - gam * c / h**2,
                "b": float(theta["beta"]) / h, "c": gam / h**2}

