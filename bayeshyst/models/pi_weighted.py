"""Prandtl–Ishlinskii models with extra input terms or varying weights.

* :class:`PolynomialInputPI` (``pi_poly``): play PI plus a memoryless polynomial of the
  input, the "modified PI" used as the static part of Hammerstein models (review §10,
  ref. [106]);
* :class:`RateWeightedPI` (``pi_rate_weights``): the weights ``w_k``, ``g_k`` of the
  review's rate-dependent PI (Eq. 30–32, ref. [53]), optionally with the threshold law
  of Eq. 28 (``pi_rate``'s);
* :class:`CovariatePI` (``pi_covariate``): weights (slope) and thresholds (width) that
  follow a measured column such as temperature or load (review §3).

All three keep the PI sum linear in ``[p0, w]`` (and ``pi_poly`` in its polynomial
coefficients too), so the sampler draws those exactly (:class:`LinearInParams`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.pi_weighted import (
    pi_covariate_batch,
    pi_poly_batch,
    pi_rate_weights_batch,
)
from bayeshyst.models.base import (
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.blocks.external import _COLUMN, GAIN_PRIOR, column_scales
from bayeshyst.models.pi import LinearInWeights, PrandtlIshlinskii, operator_space
from bayeshyst.models.pi_variants import (
    RateDependentPrandtlIshlinskii,
    _extended,
    _not_finite,
    typical_rate,
)
from bayeshyst.models.registry import register
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace

__all__ = ["CovariatePI", "PolynomialInputPI", "RateWeightedPI"]

_LINEAR = "linear (p0 u)"
#: Prior sd of the polynomial coefficients, as a fraction of the output span: the
#: polynomial bends the loop's centre line by ~10 % of the stroke per sd.
POLY_PRIOR = 0.1
#: Prior sd of the weight exponents m1, m2, s1, s2: a 20 % change of a weight at the
#: data's typical rate (or at the edge of the input range) per sd.
EXPONENT_PRIOR = 0.2
#: Prior sd of the relative threshold (width) change per sd of the covariate: 10 %.
WIDTH_PRIOR = 0.1


def _input_scaling(data: Any) -> tuple[dict[str, float], tuple[Param, ...]]:
    """Fixed centre ``u_c`` and half-span ``u_h`` of the data's input (V), as params."""
    sc = data_scales(data)
    u_c, u_h = 0.5 * (sc.u_min + sc.u_max), 0.5 * sc.u_span
    uu = sc.u_unit
    return {"u_c": u_c, "u_h": u_h}, (
        Param("u_c", Normal(u_c, sc.u_span), unit=uu,
              description="centre of the input scaling x = (u - u_c) / u_h (data centre)"),
        Param("u_h", LogNormal.from_median(u_h, 1.0), unit=uu,
              description="half-span of the input scaling (data half-span)"))


@register
@dataclass(frozen=True)
class PolynomialInputPI(LinearInParams, HysteresisModel):
    r"""Play Prandtl–Ishlinskii model plus a polynomial input function.

    .. math::  y_k = p(u_k) + \sum_{i=1}^{n} w_i F_{r_i}[u]_k, \quad
               p(u) = p_0 u + \sum_{j=2}^{d} g_j x^j, \quad x = (u - u_c) / u_h

    The "modified PI" that the review names as the static part of a Hammerstein model
    (§10, ref. [106]): the play PI of Eq. 20 with a memoryless polynomial of the input
    added, which bends the loop's centre line (saturation, asymmetry) without operators.
    The review gives no equation for it; the form here is the literature's
    ``y = P(u) + sum p_i F_{r_i}[u]``, written so that every coefficient is linear:
    ``[p0, w, g]`` is one linear block for the sampler.

    Choices where the source is silent:

    * the polynomial's terms of degree 2 and more are written in the scaled input
      ``x`` (centre ``u_c`` and half-span ``u_h`` of the data, fixed), so ``g_j`` is in
      output units and the columns are of the same size (powers of 150 V would make the
      design matrix ill-conditioned); ``p0 u`` keeps the linear term in ``u`` itself;
    * no constant term: it trades off exactly with the observation offset;
    * ``degree = 1`` is ``pi_play`` exactly (no ``g``).

    Parameters
    ----------
    n_operators : int
        Number of play operators ``n``.
    degree : int
        Degree ``d >= 1`` of the polynomial ``p``.

    Notes
    -----
    Parameters: ``p0``, ``w`` (n,) (output unit/V), ``g`` (d - 1,) (output unit; prior
    Normal(0, 0.1 y_span)); fixed thresholds ``r`` (n,) (V) as in ``pi_play``, ``u_c``,
    ``u_h`` (V). Initial state: every operator relaxed at ``u_0`` (as ``pi_play``).
    The model is monotone (and invertible) where ``p'(u) + sum`` of the active weights
    stays positive; a folding loop is left to the inverse's monotonicity check.
    """

    name: ClassVar[str] = "pi_poly"
    equation: ClassVar[str] = "review Eq. 20 + polynomial input, ref. [106]"
    n_operators: int = 10
    degree: int = 3

    def __post_init__(self) -> None:
        check_count(self.n_operators)
        check_count(self.degree, "degree")

    @property
    def linear_params(self) -> tuple[str, ...]:  # type: ignore[override]
        """``p0``, ``w`` and, for ``degree >= 2``, the polynomial coefficients ``g``."""
        return ("p0", "w", "g") if self.degree > 1 else ("p0", "w")

    def param_space(self, data: Any = None) -> ParamSpace:
        """The shared operator parameters, ``g`` (d - 1,), and fixed ``u_c``, ``u_h``."""
        sc = data_scales(data)
        fixed, fixed_params = _input_scaling(sc)
        params = () if self.degree == 1 else (Param(
            "g", Normal(0.0, POLY_PRIOR * sc.y_span), shape=(self.degree - 1,),
            unit=sc.y_unit, description="coefficients of x^2 .. x^d of the input polynomial"),)
        return _extended(operator_space(self.n_operators, sc, linear=_LINEAR), params, fixed,
                         fixed_params)

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return PrandtlIshlinskii._initial_state(self, theta, u0)

    def _run(self, u, t, theta, state0):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        g = theta["g"] if self.degree > 1 else np.zeros((state.shape[0], 0))
        pi_poly_batch(u, theta["p0"], theta["w"], theta["r"], g, theta["u_c"], theta["u_h"],
                      state, y)
        return y, state, ~(theta["u_h"] > 0) | _not_finite(y, state)


@register
@dataclass(frozen=True)
class RateWeightedPI(LinearInWeights, HysteresisModel):
    r"""Play Prandtl–Ishlinskii model with rate-dependent weights (review Eq. 30–32).

    .. math::  y_k = W_k\, p_0 u_k + G_k \sum_{i=1}^{n} w_i F_{\bar r_i}[u]_k,

    .. math::  W_k = e^{m_1 \dot u_k / \dot u_{ref}}\, e^{m_2 x_k}, \quad
               G_k = e^{s_1 \dot u_k / \dot u_{ref}}\, e^{s_2 x_k}, \quad
               x_k = (u_k - u_c) / u_h, \quad
               \dot u_k = \frac{u_k - u_{k-1}}{t_k - t_{k-1}}

    How the flattened review text is read (ref. [53]):

    * Eq. 30 prints ``y_P(k) = w_k u_k + sum_{k=1}^N g_k p̄_k F_r̄k``, reusing ``k`` for
      the operator index; it is read as one time-varying weight ``w_k`` of the linear
      term and one time-varying factor ``g_k`` of the whole operator sum, with constant
      operator weights ``p̄_i`` (``w`` here): ``y_k = w_k u_k + g_k sum_i p̄_i F_i``.
    * Eq. 31–32 print ``w_k = a1 e m1 u̇k e m2 uk``: read as
      ``a1 exp(m1 u̇_k) exp(m2 u_k)``. The flattening drops minus signs elsewhere (the
      play's ``u - r``), so the signs of the exponents are unknown; here ``m1, m2, s1,
      s2`` are real of either sign with priors symmetric about 0, which contains both
      readings, and the data choose. The review says "positive constants"; with free
      signs the model also contains that case.
    * ``a1`` is ``p0``, and ``a2`` is absorbed into the operator weights (``a2 p̄_i`` is
      one number per operator, not identifiable apart): the model stays linear in
      ``[p0, w]``.
    * Scaling: ``u̇`` is divided by the data's typical rate ``u̇_ref`` (fixed,
      :func:`~bayeshyst.models.pi_variants.typical_rate`) and ``u`` enters as the scaled
      ``x`` (data centre and half-span, fixed), so the exponents are dimensionless and
      ``p0`` is the weight at rest at the centre of the data. Ref. [53]'s ``m1`` is
      ``m1 / u̇_ref`` here; its ``m2`` is ``m2 / u_h`` (and ``a1`` absorbs ``e^{-m2 u_c}``).
    * ``u̇_k`` is the signed backward difference the review defines (so rising and
      falling branches get different weights: that is what makes the loop change with
      frequency); the first sample of a relaxed start has ``u̇ = 0``.
    * ``rate_thresholds=True`` adds the rate-dependent thresholds of Eq. 28–29 in
      ``pi_rate``'s one-term form ``r̄_i = r_i (1 + c ln(1 + |u̇_k| / u̇_0))``, which is
      the review's complete model; the default keeps the thresholds constant.

    With ``m1 = m2 = s1 = s2 = 0`` the model is ``pi_play`` exactly (and ``pi_rate``
    exactly with ``rate_thresholds=True``). With ``m1 = s1 = 0`` it is rate-independent.

    Parameters
    ----------
    n_operators : int
        Number of play operators ``n``.
    rate_thresholds : bool
        Whether the thresholds follow Eq. 28 too (adds ``c``, ``udot0``).

    Notes
    -----
    Parameters: ``p0``, ``w`` (n,) (output unit/V); ``m1``, ``m2``, ``s1``, ``s2``
    (dimensionless, Normal(0, 0.2)); with ``rate_thresholds`` also ``c`` (>= 0) and
    ``udot0`` (V/s) with ``pi_rate``'s priors; fixed ``r`` (n,) (V), ``udot_ref`` (V/s),
    ``u_c``, ``u_h`` (V). State and discretisation as ``pi_rate``: the operator outputs
    and the previous sample ``(u, t)``, so pieces and sample-by-sample runs equal one
    run; ``t`` must increase strictly. Initial state: operators relaxed at ``u_0``, no
    previous sample. Walkers with an overflowing weight, ``c < 0`` or ``udot0 <= 0`` are
    reported failed.

    Not invertible over its range when ``m1`` or ``s1`` is nonzero: the signed rate
    passes through zero at every reversal while the weight multiplies the absolute input,
    so within about ``|m1| u / u̇_ref`` seconds of a reversal away from ``u = 0`` the
    output moves against the input (``d(W u)/du = W (1 + m1 u (dq/du))`` with
    ``dq/du`` unbounded there). That is a property of Eq. 30–31 as read here, not of
    the discretisation; the generic numerical-inversion test leaves this model out and
    its own test shows it. With ``m1 = s1 = 0`` the model is rate-independent and
    inverts numerically like ``pi_play``.
    """

    name: ClassVar[str] = "pi_rate_weights"
    equation: ClassVar[str] = "review Eq. 30-32, 28-29, 20"
    rate_dependent: ClassVar[bool] = True
    # the weights follow the signed rate into the sample: the one-step map is not monotone
    monotone_in_input: ClassVar[bool] = False
    n_operators: int = 10
    rate_thresholds: bool = False

    def __post_init__(self) -> None:
        check_count(self.n_operators)
        if not isinstance(self.rate_thresholds, bool | np.bool_):
            raise ModelError(f"rate_thresholds must be a bool, got {self.rate_thresholds!r}")

    def param_space(self, data: Any = None) -> ParamSpace:
        """Operator parameters, the four weight exponents, fixed scalings (and Eq. 28's)."""
        sc = data_scales(data)
        fixed, fixed_params = _input_scaling(sc)
        rate = typical_rate(data)
        exps = tuple(Param(k, Normal(0.0, EXPONENT_PRIOR), unit="1", description=d) for k, d in (
            ("m1", "rate exponent of the linear weight W_k (per udot_ref)"),
            ("m2", "input exponent of the linear weight W_k (per u_h)"),
            ("s1", "rate exponent of the operator factor G_k (per udot_ref)"),
            ("s2", "input exponent of the operator factor G_k (per u_h)")))
        if self.rate_thresholds:
            exps += (Param("c", HalfNormal(0.5), unit="1",
                           description="rate sensitivity of the thresholds (0: constant)"),
                     Param("udot0", LogNormal.from_median(rate, 2.3), unit=sc.rate_unit,
                           description="reference input rate of the thresholds"))
        return _extended(
            operator_space(self.n_operators, sc, linear=_LINEAR), exps,
            {**fixed, "udot_ref": rate},
            (*fixed_params, Param("udot_ref", LogNormal.from_median(rate, 1.0),
                                  unit=sc.rate_unit,
                                  description="rate scale of the weights (data's typical)")))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return RateDependentPrandtlIshlinskii._initial_state(self, theta, u0)

    def _run(self, u, t, theta, state0):
        n = self.n_operators
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ParameterError(f"{self.name}: t must be strictly increasing (the input "
                                 "rate is a backward difference in time)")
        if np.any((state0[:, n + 2] != 0.0) & ~(t[0] > state0[:, n + 1])):
            raise ParameterError(f"{self.name}: t[0] = {t[0]} is not after the time of the "
                                 "state's previous sample; continue with later times")
        y, state, _ = kernel_buffers(state0, u.shape[0])
        width = state.shape[0]
        c = theta["c"] if self.rate_thresholds else np.zeros(width)
        ud0 = theta["udot0"] if self.rate_thresholds else np.ones(width)
        pi_rate_weights_batch(u, t, theta["p0"], theta["w"], theta["r"], theta["m1"],
                              theta["m2"], theta["s1"], theta["s2"], theta["udot_ref"],
                              theta["u_c"], theta["u_h"], c, ud0, state, y)
        ok = (c >= 0) & (ud0 > 0) & (theta["udot_ref"] > 0) & (theta["u_h"] > 0)
        return y, state, ~ok | _not_finite(y, state)


@register
@dataclass(frozen=True)
class CovariatePI(LinearInWeights, HysteresisModel):
    r"""Play Prandtl–Ishlinskii model whose slope and width follow a measured column.

    .. math::  y_k = (1 + a\,\Delta c_k) \Big(p_0 u_k + \sum_{i=1}^{n} w_i
               F_{r_i (1 + b\,\Delta c_k)}[u]_k\Big), \quad \Delta c_k = c_k - c_0

    Review §3: temperature and mechanical load change the loop's average slope
    (refs. [117]–[119]) and a load also its width. Here every weight (``p0`` and ``w_i``:
    the slope) scales by ``1 + a Δc`` and every threshold (the width) by ``1 + b Δc``,
    with ``c`` the column named by ``column`` (a temperature in °C, a load in N) and
    ``c_0`` the column's mean over the fitted data (fixed). Unlike the ``aux`` block,
    which scales the model's *output* after the hysteresis, the column here changes the
    loop itself: a wider threshold changes the memory, not only the gain.

    The threshold of a play operator changing while it runs is applied like ``pi_rate``'s:
    each sample clamps the operator to the band of that sample's thresholds. With
    ``a = b = 0`` the model is ``pi_play`` exactly; with a constant column it is
    ``pi_play`` with weights ``(1 + a Δc) [p0, w]`` and thresholds ``(1 + b Δc) r``.

    Parameters
    ----------
    n_operators : int
        Number of play operators ``n``.
    column : str
        Name of the measured column (``Record.covariates``, an extra column of the data
        file), e.g. ``"temperature_c"`` or ``"load_n"``.

    Notes
    -----
    Parameters: ``p0``, ``w`` (n,) (output unit/V); ``a`` and ``b`` (per unit of the
    column), priors Normal(0, 0.05 / sd) and Normal(0, 0.1 / sd) with ``sd`` the column's
    standard deviation over the data (5 % slope, 10 % width change per sd); fixed ``r``
    (n,) (V) as in ``pi_play`` and ``c0`` (the column's mean). Initial state: operators
    relaxed at ``u_0``. Walkers whose slope factor ``1 + a Δc`` is not positive or whose
    width factor ``1 + b Δc`` is negative anywhere on the run are reported failed.

    Fitting needs the column in every record (:func:`record_covariates` refuses a record
    without it, by name). Simulated without it (``covariates=None``: a feedforward
    command for a future run, the numerical inverse) the model runs at nominal
    conditions ``c = c0``, as the ``aux`` block does; given a mapping that lacks the
    column, it raises :class:`~bayeshyst.errors.ModelError` naming it.
    """

    name: ClassVar[str] = "pi_covariate"
    equation: ClassVar[str] = "review Eq. 20 with weights and thresholds of a measured column (§3)"
    n_operators: int = 10
    column: str = "temperature_c"

    def __post_init__(self) -> None:
        check_count(self.n_operators)
        if not isinstance(self.column, str) or not _COLUMN.match(self.column):
            raise ModelError(f"{self.name}: column must name a data column (no '=', '+', "
                             f"parentheses, commas or quotes), got {self.column!r}")

    @property
    def covariates(self) -> tuple[str, ...]:
        """The one column the model reads."""
        return (self.column,)

    def param_space(self, data: Any = None) -> ParamSpace:
        """Operator parameters, slope and width sensitivities ``a``, ``b``, fixed ``c0``."""
        sc = data_scales(data)
        ref, scale = column_scales(data, self.column)
        col = self.column
        return _extended(
            operator_space(self.n_operators, sc, linear=_LINEAR),
            (Param("a", Normal(0.0, GAIN_PRIOR / scale), unit=f"1/{col}",
                   description=f"relative change of every weight (slope) per unit of {col}"),
             Param("b", Normal(0.0, WIDTH_PRIOR / scale), unit=f"1/{col}",
                   description=f"relative change of every threshold (width) per unit of "
                               f"{col}")),
            {"c0": ref},
            (Param("c0", Normal(ref, scale), unit=col,
                   description=f"reference value of {col} (fixed: its mean over the data)"),))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return PrandtlIshlinskii._initial_state(self, theta, u0)

    def _run(self, u, t, theta, state0):
        return self._run_with(u, t, theta, state0, None)

    def _run_with(self, u, t, theta, state0, covariates):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        a, b, c0 = theta["a"], theta["b"], theta["c0"]
        if covariates is None:
            cv, has = np.zeros(0), False
            ok = np.isfinite(a) & np.isfinite(b)
        else:
            cv, has = np.ascontiguousarray(covariates[self.column], dtype=np.float64), True
            # both factors are affine in the column: their extremes are at its extremes
            lo, hi = float(cv.min()) - c0, float(cv.max()) - c0
            with np.errstate(invalid="ignore"):
                ok = ((np.minimum(a * lo, a * hi) > -1.0)
                      & (np.minimum(b * lo, b * hi) >= -1.0))
        pi_covariate_batch(u, cv, has, theta["p0"], theta["w"], theta["r"], a, b, c0, state, y)
        return y, state, ~ok | _not_finite(y, state)
