"""PI models built from other operators: right/left play, dead-zone MPI, one-side-play MPI/MRPI.

Review §6.5: the right and left play operators of ref. [56] (Eq. 23–26), Kuhnen's
modified PI with one-sided dead-zone operators (refs. [62], [106]) and the one-side-play
MPI with its rate-dependent form MRPI (ref. [63]). The review gives the last two in
words only and flattens Eq. 23–26 into text; every model's docstring says which form
was implemented and why. Kernels: :mod:`bayeshyst.models._kernels.pi_operators`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.models._kernels.pi_operators import (
    pi_deadzone_batch,
    pi_osp_batch,
    pi_osp_rate_batch,
    pi_right_left_batch,
)
from bayeshyst.models.base import (
    DataScales,
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.pi import default_thresholds, operator_space
from bayeshyst.models.pi_variants import _extended, _not_finite, typical_rate
from bayeshyst.models.registry import register
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = [
    "DeadZonePrandtlIshlinskii",
    "OneSidePlayPrandtlIshlinskii",
    "RateDependentOneSidePlayPI",
    "RightLeftPrandtlIshlinskii",
    "dead_zone_thresholds",
]


def dead_zone_thresholds(m: int, scales: DataScales) -> np.ndarray:
    """Dead-zone thresholds ``d_j = y_min + j y_span / (m + 1)``, ``j = 1..m`` (output unit).

    Spread evenly inside the data's output range, so that every dead zone bends the
    output somewhere the data reach.
    """
    return scales.y_min + np.arange(1, m + 1) * scales.y_span / (m + 1)


@register
@dataclass(frozen=True)
class RightLeftPrandtlIshlinskii(LinearInParams, HysteresisModel):
    r"""Prandtl–Ishlinskii model with right and left play operators (review Eq. 23–26, [56]).

    .. math::  y_k = p_0 u_k + \sum_{i=1}^{n} w^R_i F^R_{i,k} + \sum_{i=1}^{n} w^L_i F^L_{i,k}

    .. math::  F^R_{i,k} = \max(R_i(u_k),\ \min(u_k,\ F^R_{i,k-1})), \quad
               F^L_{i,k} = \min(L_i(u_k),\ \max(u_k,\ F^L_{i,k-1}))

    with ``R_i(u) = u_lo + (u - u_lo - r^R_i) S / (S - r^R_i)`` and
    ``L_i(u) = u_lo + (u - u_lo) S / (S - r^L_i)`` over the input range
    ``[u_lo, u_lo + S]``. The right play rises late, along the line from
    ``(u_lo + r, u_lo)`` to the top corner; the left play falls early, along the line
    from the bottom corner to ``(u_hi - r, u_hi)``. Each side has its own weights and
    thresholds, so the bottom and the top of the loop get their own widths and the loop
    is asymmetric; with equal sides (``w^R = w^L``, ``r^R = r^L``) it is point-symmetric
    about the range centre, as the classical play's (the left play is the right play
    reflected through the centre, ``F^L[u] = 2 u_m - F^R[2 u_m - u]``).

    Form chosen: the review's flattened Eq. 23–24 read
    ``F^R = max{(v - r)/(1 - r), min{κ v + λ, F^R(t - T)}}`` and
    ``F^L = min{v/(1 - r), max{κ v + λ, F^L(t - T)}}`` on the input normalised to
    ``[0, 1]``, where ``κ v + λ`` is the chord through the minimum and maximum input and
    output of the current up-down period (Eq. 25). That chord is not causal (it needs the
    extremum the period has not reached yet) and is refitted per period from the data.
    We use its value for a full-range period, the diagonal ``F = v`` (chord through
    ``(0, 0)`` and ``(1, 1)``), and write the normalisation in volts with the data's input
    range. A causal chord through the operator's outputs at the input's last maximum and
    minimum was tried and dropped: whenever the amplitude grows it has to be
    extrapolated past the last extremum (in a trial on a 0–100 V range the left play's
    output reached 150 V), and neither source says how. The output is Eq. 26 as
    written. Outside the range the bands close and invert; the outer ``max`` (right) /
    ``min`` (left) then win, as the nesting says. This form has no parameter value that
    is the classical ``pi_play``; equal sides give its point symmetry instead.

    Parameters
    ----------
    n_operators : int
        Number of right and of left play operators ``n`` (``2 n`` operators in all).

    Notes
    -----
    Parameters: ``p0``, ``w_right`` (n,), ``w_left`` (n,) (output unit/V), priors as
    ``pi_play``'s; fixed ``r_right``, ``r_left`` (n,) (V) at ``i S / (n + 1)``, and
    ``u_lo``, ``u_span`` (V), the data's input minimum and span. Linear in
    ``[p0, w_right, w_left]``. Monotone (invertible) for ``p0 > 0`` and non-negative
    weights; a draw with negative weights may fold, as in ``pi_play``. Walkers with a
    threshold outside ``(0, u_span)`` are reported failed. Initial state: each operator
    at the middle of its band at ``u_0``.
    """

    name: ClassVar[str] = "pi_right_left"
    equation: ClassVar[str] = "review Eq. 23-26, ref. [56]"
    linear_params: ClassVar[tuple[str, ...]] = ("p0", "w_right", "w_left")
    n_operators: int = 6

    def __post_init__(self) -> None:
        check_count(self.n_operators)

    def param_space(self, data: Any = None) -> ParamSpace:
        """``p0``, ``w_right``, ``w_left`` and the fixed thresholds and input range."""
        sc = data_scales(data)
        n, g, span = self.n_operators, sc.gain, sc.u_span
        gu, uu = sc.gain_unit, sc.u_unit
        r = np.arange(1, n + 1) * span / (n + 1)
        return ParamSpace(
            (Param("p0", Normal(g, abs(g)), unit=gu,
                   description="weight of the linear (p0 u) term"),
             Param("w_right", Normal(0.0, abs(g)), shape=(n,), unit=gu,
                   description="weights of the right plays (late rise: bottom of the loop)"),
             Param("w_left", Normal(0.0, abs(g)), shape=(n,), unit=gu,
                   description="weights of the left plays (early fall: top of the loop)")),
            {"r_right": r, "r_left": r, "u_lo": sc.u_min, "u_span": span},
            (Param("r_right", Uniform(0.0, span), shape=(n,), unit=uu,
                   description="right-play thresholds (fixed at i span / (n + 1))"),
             Param("r_left", Uniform(0.0, span), shape=(n,), unit=uu,
                   description="left-play thresholds (fixed at i span / (n + 1))"),
             Param("u_lo", Normal(sc.u_min, span), unit=uu,
                   description="lower end of the input range the plays are anchored to"),
             Param("u_span", LogNormal.from_median(span, 1.0), unit=uu,
                   description="span of the input range the plays are anchored to")),
        )

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        lo, span = theta["u_lo"][:, None], theta["u_span"][:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            right = lo + (u0 - lo - theta["r_right"]) * (span / (span - theta["r_right"]))
            left = lo + (u0 - lo) * (span / (span - theta["r_left"]))
        v_right = np.maximum(right, np.minimum(u0, 0.5 * (right + u0)))
        v_left = np.minimum(left, np.maximum(u0, 0.5 * (left + u0)))
        return np.ascontiguousarray(np.concatenate([v_right, v_left], axis=1))

    def _run(self, u, t, theta, state0):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        span = theta["u_span"]
        pi_right_left_batch(u, theta["p0"], theta["w_right"], theta["w_left"],
                            theta["r_right"], theta["r_left"], theta["u_lo"], span, state, y)
        ok = np.ones(span.shape[0], dtype=bool)
        for r in (theta["r_right"], theta["r_left"]):
            ok &= np.all((r > 0) & (r < span[:, None]), axis=1)
        return y, state, ~ok | _not_finite(y, state)


@register
@dataclass(frozen=True)
class DeadZonePrandtlIshlinskii(LinearInParams, HysteresisModel):
    r"""Kuhnen's modified PI: a play PI followed by one-sided dead zones (refs. [62], [106]).

    .. math::  y_k = z_k + \sum_{j=1}^{m} g_j S_{d_j}(z_k), \quad
               z_k = p_0 u_k + \sum_{i=1}^{n} w_i F_{r_i}[u]_k

    with the classical play ``F_r`` (review Eq. 11–12, 20) and the one-sided dead zone
    ``S_d(z) = max(z - d, 0)`` for ``d > 0``, ``min(z - d, 0)`` for ``d < 0``, ``z`` for
    ``d = 0``. The superposition ``z + sum g_j S_{d_j}(z)`` is a piecewise-linear map
    whose slope changes by ``g_j`` at ``d_j``; it is not odd, so the loops are asymmetric
    (Kuhnen 2003, the "modified PI" the review cites as [62] and uses in the Hammerstein
    model of [106]).

    Form chosen: Kuhnen writes ``y = sum_j g_j S_{d_j}[sum_i w_i F_{r_i}[u]]`` with
    ``d_0 = 0``; that product is degenerate (scaling ``w`` and ``d`` by ``c`` and ``g``
    by ``1/c`` changes nothing), so the ``d_0 = 0`` weight is fixed at 1 (``y = z + …``)
    and the play part keeps ``pi_play``'s parameters and priors. The model is bilinear:
    linear in ``g`` for fixed play parameters (``z`` is then a fixed signal), *not* in
    ``[p0, w]`` (``S_d`` bends ``z``). So ``g`` is the exactly sampled linear group
    (with the constant ``z``) and ``p0``, ``w`` are sampled with the rest. [62]'s
    slope-dependent weight function (its rate-dependent part) is not included.

    Parameters
    ----------
    n_operators : int
        Number of play operators ``n``.
    n_deadzones : int
        Number of dead-zone operators ``m``.

    Notes
    -----
    Parameters: ``p0``, ``w`` (n,) (output unit/V) and fixed ``r`` (n,) (V) as in
    ``pi_play``; ``g`` (m,) (dimensionless, ``Normal(0, 0.5)``); fixed ``d`` (m,) (output
    unit) at :func:`dead_zone_thresholds` of the data. ``g = 0`` is ``pi_play`` exactly.
    The map ``z -> y`` is increasing while ``1 + sum g_j`` over the dead zones active on
    each piece is > 0; the prior allows draws where it is not. As for ``pi_play`` with
    negative partial sums, such draws are simulated, not failed (whether a walker fails
    may not depend on the linear group ``g``, or its exact conditional would be wrong);
    the numerical inverse needs a monotone draw. Initial state: plays relaxed at ``u_0``.

    Fitting: being bilinear, the posterior can have a minor mode (the play part scaled
    up, traded against the output offset and a negative first dead-zone weight). In
    recovery tests the MAP screen's two local searches both ended there for 3 of 6
    seeds, agreeing, so nothing looked wrong; the model therefore declares
    ``multimodal_posterior`` and the MAP search always adds its global search (12 of 12
    seeds found the major mode that way).
    """

    name: ClassVar[str] = "pi_deadzone"
    multimodal_posterior: ClassVar[bool] = True
    equation: ClassVar[str] = "review Eq. 20 + dead-zone operators, refs. [62] [106]"
    linear_params: ClassVar[tuple[str, ...]] = ("g",)
    linear_affine: ClassVar[bool] = True
    n_operators: int = 8
    n_deadzones: int = 4

    def __post_init__(self) -> None:
        check_count(self.n_operators)
        check_count(self.n_deadzones, "n_deadzones")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``pi_play``'s parameters plus the dead-zone weights ``g`` and thresholds ``d``."""
        sc = data_scales(data)
        m = self.n_deadzones
        return _extended(
            operator_space(self.n_operators, sc, linear="linear (p0 u) in the play part"),
            (Param("g", Normal(0.0, 0.5), shape=(m,), unit="1",
                   description="dead-zone weights (slope changes of the output map)"),),
            {"d": dead_zone_thresholds(m, sc)},
            (Param("d", Uniform(sc.y_min, sc.y_max), shape=(m,), unit=sc.y_unit,
                   description="dead-zone thresholds (fixed inside the output range)"),),
        )

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return np.full((theta["w"].shape[0], self.n_operators), u0)

    def _run(self, u, t, theta, state0):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        pi_deadzone_batch(u, theta["p0"], theta["w"], theta["r"], theta["g"], theta["d"],
                          state, y)
        return y, state, _not_finite(y, state)


def _osp_space(n: int, data: Any) -> ParamSpace:
    """OSP-MPI parameters ``p0``, ``a2``, ``a3``, ``w``; fixed ``r``, ``u_c``, ``u_h``."""
    sc = data_scales(data)
    g, uu = sc.gain, sc.u_unit
    gu = sc.gain_unit
    base = operator_space(n, sc, linear="linear (p0 u) in the input polynomial")
    # a one-side play of width r acts like a play of threshold r / 2: twice pi_play's
    base = base.free("r").fix("r", 2.0 * default_thresholds(n, sc)).replace(
        "r", description="one-side-play thresholds (fixed at i span / (n + 1))")
    u_c, u_h = 0.5 * (sc.u_min + sc.u_max), 0.5 * sc.u_span
    return _extended(
        base,
        (Param("a2", Normal(0.0, 0.25 * abs(g)), unit=gu,
               description="quadratic coefficient of the input polynomial"),
         Param("a3", Normal(0.0, 0.25 * abs(g)), unit=gu,
               description="cubic coefficient of the input polynomial")),
        {"u_c": u_c, "u_h": u_h},
        (Param("u_c", Normal(u_c, sc.u_span), unit=uu,
               description="centre of the polynomial's input scaling (data centre)"),
         Param("u_h", LogNormal.from_median(u_h, 1.0), unit=uu,
               description="half-span of the polynomial's input scaling")),
    )


def _osp_initial(theta: Mapping[str, np.ndarray], u0: float, extra: int) -> np.ndarray:
    # the middle of the band [u0 - r, u0]: a relaxed one-side play, as pi_play's u0
    width = theta["w"].shape[0]
    v = u0 - 0.5 * np.asarray(theta["r"], dtype=float).reshape(width, -1)
    return np.ascontiguousarray(np.concatenate([v, np.zeros((width, extra))], axis=1))




@register
@dataclass(frozen=True)
class OneSidePlayPrandtlIshlinskii(LinearInParams, HysteresisModel):
    r"""Modified PI (MPI) with one-side play operators and an input polynomial (ref. [63]).

    .. math::  y_k = p_0 u_k + u_h (a_2 x_k^2 + a_3 x_k^3) + \sum_{i=1}^{n} w_i v_{i,k},
               \quad v_{i,k} = \max(u_k - r_i,\ \min(u_k,\ v_{i,k-1}))

    Form chosen (the review gives no equation): the one-side play (OSP) is Eq. 27 with
    ``m = 1``, the band ``[u - r, u]`` instead of ``[u - r, u + r]``; alone it is only a
    shifted play (``F_{r/2}[u] - r/2``), so the MPI of ref. [63] (as in Gu, Zhu et al.'s
    modified PI) gets its asymmetry from a polynomial input function
    ``p(u) = p0 u + u_h (a2 x² + a3 x³)``, ``x = (u - u_c) / u_h``. A constant and a
    linear term of ``x`` are left out: they trade off exactly with the output offset and
    ``p0``. The polynomial may be non-monotone for prior draws; as in ``pi_play`` such
    draws are simulated, not failed (the coefficients are in the linear group).
    With ``a2 = a3 = 0`` it is ``pi_play`` with thresholds ``r_i / 2`` minus the constant
    ``sum_i w_i r_i / 2``; the default ``r`` is twice ``pi_play``'s, so that is ``pi_play``'s
    own placement.

    Parameters
    ----------
    n_operators : int
        Number of one-side play operators ``n``.

    Notes
    -----
    Parameters: ``p0``, ``a2``, ``a3``, ``w`` (n,) (output unit/V; linear group); fixed
    ``r`` (n,) (V) at ``i S / (n + 1)``, ``u_c``, ``u_h`` (V) the centre and half-span of
    the data's input range. Initial state: each operator at ``u_0 - r_i / 2``, the middle
    of its band.
    """

    name: ClassVar[str] = "pi_osp"
    equation: ClassVar[str] = "review Eq. 27 (m = 1) + input polynomial, ref. [63]"
    linear_params: ClassVar[tuple[str, ...]] = ("p0", "a2", "a3", "w")
    n_operators: int = 8

    def __post_init__(self) -> None:
        check_count(self.n_operators)

    def param_space(self, data: Any = None) -> ParamSpace:
        """Polynomial ``p0``, ``a2``, ``a3``, weights ``w``; fixed ``r``, ``u_c``, ``u_h``."""
        return _osp_space(self.n_operators, data)

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return _osp_initial(theta, u0, 0)

    def _run(self, u, t, theta, state0):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        pi_osp_batch(u, theta["p0"], theta["a2"], theta["a3"], theta["u_c"], theta["u_h"],
                     theta["w"], theta["r"], state, y)
        return y, state, ~(theta["u_h"] > 0) | _not_finite(y, state)


@register
@dataclass(frozen=True)
class RateDependentOneSidePlayPI(LinearInParams, HysteresisModel):
    r"""MRPI: the one-side-play MPI with rate-dependent envelopes (ref. [63]).

    .. math::  v_{i,k} = \begin{cases}
                   \max(u_k - \tau_l |\dot u_{k-1}| - r_i,\ v_{i,k-1}) & u_k > u_{k-1} \\
                   \min(u_k + \tau_r |\dot u_{k-1}|,\ v_{i,k-1}) & u_k < u_{k-1} \\
                   v_{i,k-1} & u_k = u_{k-1}
               \end{cases}, \quad
               \dot u_{k-1} = \frac{u_{k-1} - u_{k-2}}{t_{k-1} - t_{k-2}}

    and the output as in ``pi_osp``. The review says only that [63] "introduced two
    envelope functions related to input voltage derivatives in the OSP operator".
    Form chosen: the rising envelope is ``u - τ_l |u̇|`` and the falling one
    ``u + τ_r |u̇|``: the faster the input moves, the later a rising branch starts and
    the later a falling one, so loops widen with frequency; ``τ_l != τ_r`` widens the
    bottom and the top differently. The shift is the same for every operator (also for a
    zero threshold), which is what makes it an envelope and not a rate-dependent
    threshold ``r̄(u̇)`` (the review contrasts [63] with [53]'s thresholds). A signed
    ``u - τ u̇`` was tried and rejected: it is the input delayed by ``τ`` to first order,
    so the output keeps rising after the input has turned (a phase lag, not a
    hysteresis loop: the output is no longer monotone along the input's monotone
    pieces). ``τ_l = τ_r = 0`` is ``pi_osp``
    exactly from any state inside the bands. The input polynomial and the one-side play
    are ``pi_osp``'s (see there for that form).

    Discretisation: the operator is written per monotone step, as the play is defined on
    monotone pieces of the input (review Eq. 11): a rising step can only raise ``v``, a
    falling one only lower it. With constant envelopes that is the clamp
    ``max(lo, min(hi, v))``; with envelopes that move with the rate, the clamp would let
    a narrowing band push ``v`` against the input's direction. The rate is the backward
    difference of the *previous* step: with the current step's ``(u_k - u_{k-1}) / Δt``
    the envelope ``u_k - τ |u_k - u_{k-1}| / Δt`` falls as ``u_k`` rises whenever
    ``τ > Δt`` (typical at kHz sampling), and the one-step map ``u_k -> y_k`` the
    numerical inverse solves would not be monotone; the lagged rate differs by
    ``O(Δt ü)``. So each operator is non-decreasing in ``u_k`` given the state, and the
    output is monotone along every monotone piece of the input for non-negative weights
    and a monotone polynomial. The state carries the last sample and rate, so runs in
    pieces equal one run; the first two samples use ``u̇ = 0`` (no two earlier samples).

    Inverse: on a branch ``y ≈ g (u - τ |u̇|)``, a right-half-plane zero at ``s = 1/τ``
    (the price of any lag that depends on ``u̇`` directly). The numerical inverse
    solves a monotone one-step map, but its recursion
    ``u_k = y_k / g + τ (u_{k-1} - u_{k-2}) / Δt`` grows errors by about
    ``sqrt(τ / Δt)`` per sample: it is exact for ``τ`` up to about the sample period and
    diverges, with a large reported ``max_error`` (not hidden), for ``τ >> Δt``. Such
    fits need a preview-based compensator; the model is therefore not in
    ``tests/test_inverse.py``'s generic inversion, like the models with internal dynamics.

    Parameters
    ----------
    n_operators : int
        Number of one-side play operators ``n``.

    Notes
    -----
    Parameters: as ``pi_osp`` (linear group ``p0``, ``a2``, ``a3``, ``w``), plus
    ``tau_l``, ``tau_r`` (s, >= 0; ``HalfNormal`` with scale ``0.1 S / u̇_typ``, the time
    in which the data's typical rate :func:`typical_rate` covers a tenth of the input
    span). ``t`` must increase strictly. Walkers with a negative ``τ`` are failed.
    Initial state: operators at ``u_0 - r_i / 2``, no previous sample.
    """

    name: ClassVar[str] = "pi_osp_rate"
    equation: ClassVar[str] = "review Eq. 27 (m = 1) + rate envelopes, ref. [63]"
    rate_dependent: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("p0", "a2", "a3", "w")
    n_operators: int = 8

    def __post_init__(self) -> None:
        check_count(self.n_operators)

    def param_space(self, data: Any = None) -> ParamSpace:
        """``pi_osp``'s parameters plus the envelope rate coefficients ``tau_l``, ``tau_r`` (s)."""
        scale = 0.1 * data_scales(data).u_span / typical_rate(data)
        return _extended(_osp_space(self.n_operators, data), (
            Param("tau_l", HalfNormal(scale), unit="s",
                  description="rate shift of the rising envelope u - tau_l du/dt"),
            Param("tau_r", HalfNormal(scale), unit="s",
                  description="rate shift of the falling envelope u - tau_r du/dt")))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s = _osp_initial(theta, u0, 4)
        s[:, self.n_operators] = u0
        return s  # t_prev = 0, rate 0 and flag 0: no previous sample yet

    def _run(self, u, t, theta, state0):
        n = self.n_operators
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ParameterError(f"{self.name}: t must be strictly increasing (the input "
                                 "rate is a backward difference in time)")
        has_prev = state0[:, n + 3] != 0.0
        if np.any(has_prev & ~(t[0] > state0[:, n + 1])):
            raise ParameterError(f"{self.name}: t[0] = {t[0]} is not after the time of the "
                                 "state's previous sample; continue with later times")
        y, state, _ = kernel_buffers(state0, u.shape[0])
        tl, tr = theta["tau_l"], theta["tau_r"]
        pi_osp_rate_batch(u, t, theta["p0"], theta["a2"], theta["a3"], theta["u_c"],
                          theta["u_h"], theta["w"], theta["r"], tl, tr, state, y)
        failed = ~((tl >= 0) & (tr >= 0) & (theta["u_h"] > 0)) | _not_finite(y, state)
        return y, state, failed
