"""Prandtl–Ishlinskii variants: generalised play, asymmetric unilateral play, rate-dependent play.

Review §6.5, Eq. 22 (generalised play, ref. [55]), Eq. 27 (asymmetric unilateral
backlash, ref. [61]) and Eq. 28–30 (rate-dependent thresholds, ref. [53]); MODELS.md §1–2.
All three keep the classical sum ``y = p0 u + sum_i w_i v_i`` (review Eq. 20), so for
fixed thresholds and shape parameters they are linear in ``[p0, w]`` and provide
:meth:`regressors`. Thresholds ``r`` are fixed over the data's input span as in
``pi_play``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models._kernels.pi_variants import (
    ENVELOPE_CUBIC,
    ENVELOPE_QUADRATIC,
    envelope,
    pi_asymmetric_batch,
    pi_generalized_batch,
    pi_rate_batch,
)
from bayeshyst.models.base import (
    DataScales,
    HysteresisModel,
    Trajectory,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.pi import LinearInWeights, default_thresholds, operator_space
from bayeshyst.models.registry import register
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace

__all__ = [
    "ENVELOPES",
    "AsymmetricPrandtlIshlinskii",
    "GeneralizedPrandtlIshlinskii",
    "RateDependentPrandtlIshlinskii",
    "typical_rate",
]

#: Envelope families of :class:`GeneralizedPrandtlIshlinskii` and their kernel codes.
ENVELOPES: dict[str, int] = {"cubic": ENVELOPE_CUBIC, "quadratic": ENVELOPE_QUADRATIC}

_LINEAR = "linear (p0 u)"


def _extended(space: ParamSpace, params: tuple[Param, ...] = (),
              fixed: Mapping[str, Any] | None = None,
              fixed_params: tuple[Param, ...] = ()) -> ParamSpace:
    """``space`` with more free and fixed parameters appended."""
    return ParamSpace((*space.params, *params), {**space.fixed, **(fixed or {})},
                      (*space.fixed_params, *fixed_params))


def _not_finite(y: np.ndarray, state: np.ndarray) -> np.ndarray:
    # the last line of defence: a walker whose output or state is not finite is failed,
    # never handed to the likelihood as numbers
    return ~(np.all(np.isfinite(y), axis=1) & np.all(np.isfinite(state), axis=1))


def typical_rate(data: Any = None) -> float:
    """Typical input rate ``|u̇|`` of ``data`` (V/s), the scale of the ``u̇_0`` prior.

    Parameters
    ----------
    data : Record, Dataset, DataScales or None
        Anything with ``.u`` (V) and ``.t`` (s), or a Dataset of such records. For
        ``None`` or a :class:`DataScales` (no time axis) the rate of a 1 Hz triangle
        over the input span, ``2 * span * 1 Hz``, is returned.

    Returns
    -------
    float
        Median over samples of the nonzero ``|Δu / Δt|`` (backward differences within
        each record, never across records). The median ignores the few steep samples of
        a step or a glitch; zero differences (held input) are left out because they say
        nothing about how fast the input moves when it does.

    Raises
    ------
    ParameterError
        If the data hold no two samples with different inputs and increasing times.
    """
    if data is None or isinstance(data, DataScales):
        return 2.0 * data_scales(data).u_span * 1.0
    records = list(data) if hasattr(data, "records") else [data]
    rates = []
    for rec in records:
        u = np.asarray(rec.u, dtype=float).ravel()
        t = np.asarray(rec.t, dtype=float).ravel()
        if u.size < 2 or u.shape != t.shape:
            continue
        dt = np.diff(t)
        ok = dt > 0
        rates.append(np.abs(np.diff(u)[ok] / dt[ok]))
    allr = np.concatenate(rates) if rates else np.empty(0)
    allr = allr[np.isfinite(allr) & (allr > 0)]
    if allr.size == 0:
        raise ParameterError("cannot scale the rate prior: the data have no two samples "
                             "with increasing time and different input")
    return float(np.median(allr))


@register
@dataclass(frozen=True)
class GeneralizedPrandtlIshlinskii(LinearInWeights, HysteresisModel):
    r"""Prandtl–Ishlinskii model with generalised play operators (review Eq. 22, 20).

    .. math::  y_k = p_0 u_k + \sum_{i=1}^{n} w_i v_{i,k}, \quad
               v_{i,k} = \max(\gamma_l(u_k) - r_i,\ \min(\gamma_r(u_k) + r_i,\ v_{i,k-1}))

    The rising branches follow ``γ_l(u) - r_i`` and the falling ones ``γ_r(u) + r_i``;
    different or non-odd envelopes give the asymmetric loops of piezo actuators.
    Envelopes, with ``x = (u - u_c) / u_h`` over the data's input range:

    ``"cubic"`` (default)
        ``γ(u) = u + u_h (b x² + b² x³ / 3)``. Its slope is ``(1 + b x)² >= 0``, so it is
        monotone by construction for *every* real ``b``: the bend coefficients are
        unconstrained, get a Normal prior and there is no region of the sampler's space
        to reject. ``b`` bends the branch (even part); the cubic term is what keeps it
        monotone.
    ``"quadratic"``
        ``γ(u) = u + u_h b x²``: the literature's polynomial envelope, monotone only
        while ``1 + 2 b x >= 0``. The model checks this on the union of the data range
        ``x in [-1, 1]`` and the simulated input's range; a violating walker is reported
        ``failed`` (the posterior makes it ``-inf``) and :meth:`run` raises
        :class:`~bayeshyst.errors.SimulationError` saying which bound is violated.

    In both, ``b = 0`` is the identity ``γ(u) = u`` exactly, so ``b_l = b_r = 0``
    reproduces ``pi_play`` to the last bit. The linear part ``p0 u`` is kept outside the
    envelopes: the model stays linear in ``[p0, w]`` (:meth:`regressors`) and the
    envelopes only shape the operators. A constant and a common linear term of ``γ``
    are left out on purpose: they trade off exactly with an output offset and with the
    weights and thresholds, and would only make the posterior degenerate.

    Parameters
    ----------
    n_operators : int
        Number of generalised play operators ``n``.
    envelope : {"cubic", "quadratic"}
        Envelope family shared by ``γ_l`` and ``γ_r``.

    Notes
    -----
    Parameters: ``p0``, ``w`` (n,) (output unit/V); ``b_l``, ``b_r`` (dimensionless);
    fixed: thresholds ``r`` (n,) (V) as in ``pi_play``, and the envelope centre ``u_c``
    and half-span ``u_h`` (V) of the data. Where the envelopes cross so that
    ``γ_l - r > γ_r + r``, the rising boundary wins (the ``max`` is outermost, as in
    Eq. 22) and that operator has no memory there. Initial state: every operator at the
    middle of its band at ``u_0``, ``(γ_l(u_0) + γ_r(u_0)) / 2`` (``u_0`` for identity
    envelopes, as in ``pi_play``).
    """

    name: ClassVar[str] = "pi_generalized"
    equation: ClassVar[str] = "review Eq. 22, 20"
    n_operators: int = 10
    envelope: str = "cubic"

    def __post_init__(self) -> None:
        check_count(self.n_operators)
        if self.envelope not in ENVELOPES:
            raise ModelError(f"envelope must be one of {sorted(ENVELOPES)}, "
                             f"got {self.envelope!r}")

    def param_space(self, data: Any = None) -> ParamSpace:
        """The shared operator parameters plus the envelope bends ``b_l``, ``b_r``.

        :func:`~bayeshyst.models.pi.operator_space` gives ``p0``, ``w`` and the fixed ``r``;
        ``b_l`` and ``b_r`` get ``Normal(0, 0.3)`` (cubic) or ``Normal(0, 0.25)``
        (quadratic), and the fixed ``u_c``, ``u_h`` are the centre and half-span of the
        data's input range.
        """
        sc = data_scales(data)
        # quadratic: |b| <= 1/2 keeps it monotone over the data; a prior sd of 1/4 puts
        # ~95 % of the mass there. Cubic: 0.3 bends the branch by up to ~30 % of u_h.
        sd = 0.3 if self.envelope == "cubic" else 0.25
        u_c, u_h = 0.5 * (sc.u_min + sc.u_max), 0.5 * sc.u_span
        uu = sc.u_unit
        return _extended(
            operator_space(self.n_operators, sc, linear=_LINEAR),
            (Param("b_l", Normal(0.0, sd), unit="1",
                   description="bend of the rising envelope gamma_l (0: straight)"),
             Param("b_r", Normal(0.0, sd), unit="1",
                   description="bend of the falling envelope gamma_r (0: straight)")),
            {"u_c": u_c, "u_h": u_h},
            (Param("u_c", Normal(u_c, sc.u_span), unit=uu,
                   description="centre of the envelopes' input scaling (data centre)"),
             Param("u_h", LogNormal.from_median(u_h, 1.0), unit=uu,
                   description="half-span of the envelopes' input scaling")),
        )

    def _gamma(self, u0: float, b: np.ndarray, theta: Mapping[str, np.ndarray]) -> np.ndarray:
        kind = ENVELOPES[self.envelope]
        return np.array([envelope(u0, b[j], theta["u_c"][j], theta["u_h"][j], kind)
                         for j in range(b.shape[0])])

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        gl = self._gamma(u0, theta["b_l"], theta)[:, None]
        gr = self._gamma(u0, theta["b_r"], theta)[:, None]
        r = theta["r"]
        mid = 0.5 * (gl + gr)
        return np.ascontiguousarray(np.maximum(gl - r, np.minimum(gr + r, mid)))

    def _monotone(self, theta: Mapping[str, np.ndarray], u: np.ndarray) -> np.ndarray:
        """Per walker, whether both envelopes are non-decreasing where they are evaluated."""
        uc, uh = theta["u_c"], theta["u_h"]
        ok = uh > 0
        if self.envelope == "cubic":
            return ok
        with np.errstate(divide="ignore", invalid="ignore"):
            x_lo = np.minimum(-1.0, (float(u.min()) - uc) / uh)
            x_hi = np.maximum(1.0, (float(u.max()) - uc) / uh)
        for b in (theta["b_l"], theta["b_r"]):
            # the slope 1 + 2 b x is linear in x: checking the two ends covers the range
            ok &= (1.0 + 2.0 * b * x_lo >= 0.0) & (1.0 + 2.0 * b * x_hi >= 0.0)
        return ok

    def _run(self, u, t, theta, state0):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        pi_generalized_batch(u, theta["p0"], theta["w"], theta["r"], theta["b_l"],
                             theta["b_r"], theta["u_c"], theta["u_h"],
                             ENVELOPES[self.envelope], state, y)
        failed = ~self._monotone(theta, u) | _not_finite(y, state)
        return y, state, failed

    def run(self, u: Any, t: Any, theta: Mapping[str, Any], *,
            state0: np.ndarray | None = None,
            covariates: Mapping[str, Any] | None = None) -> Trajectory:
        """As :meth:`HysteresisModel.run`; a non-monotone envelope raises with the reason.

        Raises
        ------
        SimulationError
            If an envelope is not monotone over the data and input range (quadratic
            envelopes only) or the output is not finite.
        """
        u_arr = np.asarray(u, dtype=float)
        if self.envelope == "quadratic" and u_arr.ndim == 1 and u_arr.size \
                and np.all(np.isfinite(u_arr)):
            tb, _ = self._batch_theta(theta, batched=False)
            if not self._monotone(tb, u_arr)[0]:
                raise SimulationError(
                    f"{self.name}: quadratic envelope not monotone: slope 1 + 2 b x < 0 "
                    f"for b_l={float(tb['b_l'][0]):.4g} or b_r={float(tb['b_r'][0]):.4g} "
                    f"on the range u in [{min(u_arr.min(), tb['u_c'][0] - tb['u_h'][0]):.4g}, "
                    f"{max(u_arr.max(), tb['u_c'][0] + tb['u_h'][0]):.4g}]; "
                    "this theta is outside the model's support")
        return super().run(u, t, theta, state0=state0, covariates=covariates)


@register
@dataclass(frozen=True)
class AsymmetricPrandtlIshlinskii(LinearInWeights, HysteresisModel):
    r"""Prandtl–Ishlinskii model with asymmetric unilateral play operators (review Eq. 27).

    .. math::  y_k = p_0 u_k + \sum_{i=1}^{n} w_i v_{i,k}, \quad
               v_{i,k} = \max(u_k - r_i,\ \min(m u_k,\ v_{i,k-1}))

    This is Eq. 27 as written in the review and in MODELS.md: the classical play's
    upper boundary ``u + r`` is replaced by the line ``m u`` through the origin, so rising
    branches follow ``u - r_i`` and all falling branches follow ``m u``. The band's width
    ``(m - 1) u + r_i`` changes along the input, which makes the loop asymmetric
    (ref. [61]). It is *not* the right/left play of ref. [56] (review Eq. 23–26), whose
    boundaries ``κ v + λ`` are fitted per half-cycle from the data's extrema.

    Where the sources are ambiguous, this implementation chooses:

    * the output: the review's Eq. 27 has ``y = sum w_i v_i``; we add ``p0 u`` as in
      Eq. 20 (``p0 = 0`` gives the review's form);
    * one slope ``m`` for all operators ("the asymmetric correction coefficient");
      ``per_operator_slope=True`` gives each operator its own ``m_i``;
    * crossing boundaries: where ``m u < u - r_i`` the outer ``max`` wins and the
      operator follows ``u - r_i`` both ways (no memory there), as the nesting says;
    * the origin: ``m u`` is not shift-invariant; ``u = 0`` is the zero of the input as
      recorded (0 V for a piezo driver), not the centre of the data;
    * reduction to the classical play: no value of ``m`` gives ``F_r``; with ``m = 1``
      the operator is a play of threshold ``r/2`` shifted down by ``r/2``,
      ``v = F_{r/2}[u] - r/2``. That is why the fixed thresholds are twice
      ``pi_play``'s: with ``m = 1`` this model is ``pi_play`` minus the constant
      ``sum_i w_i r_i / 2``.

    Parameters
    ----------
    n_operators : int
        Number of unilateral play operators ``n``.
    per_operator_slope : bool
        Whether each operator has its own slope ``m_i`` (``m`` of shape (n,)) instead
        of one shared ``m``.

    Notes
    -----
    Parameters: ``p0``, ``w`` (n,) (output unit/V); ``m`` (dimensionless, > 0; prior
    log-normal around 1 with a spread that lets ``(m - 1) max|u|`` reach about a quarter
    of the input span); fixed ``r`` (n,) (V) at ``i * span / (n + 1)``. Initial state:
    the middle of the band at ``u_0``, ``((1 + m) u_0 - r_i) / 2`` (or ``u_0 - r_i`` where
    the band is closed). Walkers with ``m <= 0`` are reported failed.
    """

    name: ClassVar[str] = "pi_asymmetric"
    equation: ClassVar[str] = "review Eq. 27, 20"
    n_operators: int = 10
    per_operator_slope: bool = False

    def __post_init__(self) -> None:
        check_count(self.n_operators)
        if not isinstance(self.per_operator_slope, bool | np.bool_):
            raise ModelError(f"per_operator_slope must be a bool, got {self.per_operator_slope!r}")

    def param_space(self, data: Any = None) -> ParamSpace:
        """The shared operator parameters plus the falling-boundary slope ``m``.

        The thresholds are twice ``pi_play``'s: ``r`` is fixed at ``i * span / (n + 1)``.
        ``m`` (scalar, or (n,) with ``per_operator_slope``) is log-normal around 1 with a
        log-scale spread ``min(0.5, span / (4 max|u|))``.
        """
        sc = data_scales(data)
        n = self.n_operators
        base = operator_space(n, sc, linear=_LINEAR)
        r = 2.0 * default_thresholds(n, sc)
        base = base.free("r").fix("r", r).replace(
            "r", description="operator thresholds (fixed at i span / (n + 1))")
        u_abs = max(abs(sc.u_min), abs(sc.u_max))
        sd = min(0.5, 0.25 * sc.u_span / u_abs)
        shape = (n,) if self.per_operator_slope else ()
        return _extended(base, (Param(
            "m", LogNormal(0.0, sd), shape=shape, unit="1",
            description="slope of the falling boundary m u (1: band of constant width)"),))

    def _slopes(self, theta: Mapping[str, np.ndarray]) -> np.ndarray:
        width = theta["w"].shape[0]
        m = np.asarray(theta["m"], dtype=float).reshape(width, -1)
        return np.ascontiguousarray(np.broadcast_to(m, (width, self.n_operators)))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        lo = u0 - theta["r"]
        hi = self._slopes(theta) * u0
        return np.ascontiguousarray(np.maximum(lo, np.minimum(hi, 0.5 * (lo + hi))))

    def _run(self, u, t, theta, state0):
        y, state, _ = kernel_buffers(state0, u.shape[0])
        m = self._slopes(theta)
        pi_asymmetric_batch(u, theta["p0"], theta["w"], theta["r"], m, state, y)
        failed = ~np.all(m > 0, axis=1) | _not_finite(y, state)
        return y, state, failed


@register
@dataclass(frozen=True)
class RateDependentPrandtlIshlinskii(LinearInWeights, HysteresisModel):
    r"""Play Prandtl–Ishlinskii model with rate-dependent thresholds (review Eq. 28–30).

    .. math::  y_k = p_0 u_k + \sum_{i=1}^{n} w_i v_{i,k}, \quad
               v_{i,k} = \max(u_k - \bar r_{i,k},\ \min(u_k + \bar r_{i,k},\ v_{i,k-1})),

    .. math::  \bar r_{i,k} = r_i \left(1 + c \ln(1 + |\dot u_k| / \dot u_0)\right),
               \quad \dot u_k = \frac{u_k - u_{k-1}}{t_k - t_{k-1}}

    The threshold law is MODELS.md §1's one-term form of ref. [53]'s
    ``α sum_l ln(β_l + λ_l |u̇|^ε)`` (review Eq. 28), written so that ``c = 0`` is the
    classical ``pi_play`` exactly and ``r_i`` keeps its meaning as the quasi-static
    threshold. The weights stay constant (the review's rate-dependent weights ``w_k``,
    ``g_k`` of Eq. 30 are not included). Faster input widens every operator, so loops
    widen with excitation frequency for ``c > 0``.

    Parameters
    ----------
    n_operators : int
        Number of play operators ``n``.

    Notes
    -----
    Discretisation: ``u̇_k`` is the backward difference of the review's Eq. 30, causal
    and exactly what a sampled controller sees; ``t`` must increase strictly. The state
    holds the operator outputs and the previous sample ``(u_{k-1}, t_{k-1})``, so a
    record simulated in pieces (even of one sample) gives the same output as in one
    piece. First sample: with the default initial state there is no previous sample, so
    ``u̇_0 := 0`` (thresholds ``r_i``); as the operators start relaxed at ``u_0`` (inside
    every band) the first output is ``(p0 + sum w_i) u_0`` whatever the rate. Turning
    points: the backward difference at the sample nearest a reversal is about
    ``π u̇_max / n_per`` (``n_per`` samples per period), not 0, so on coarsely sampled
    fast input the thresholds do not fall back to ``r_i`` there and the widest
    (saturated) operators turn a little early; the loop width then stops growing with
    frequency once ``π u̇_max / n_per`` approaches ``u̇_0``. Resolve reversals finely
    (hundreds of samples per period) when ``c`` is to be identified.

    Parameters: ``p0``, ``w`` (n,) (output unit/V); ``c`` (dimensionless, >= 0);
    ``udot0`` (V/s, > 0; log-normal prior with the median at :func:`typical_rate` of the
    data); fixed ``r`` (n,) (V) as in ``pi_play``. Walkers with ``c < 0`` or
    ``udot0 <= 0`` are reported failed.
    """

    name: ClassVar[str] = "pi_rate"
    equation: ClassVar[str] = "review Eq. 28-30, 20"
    rate_dependent: ClassVar[bool] = True
    # the thresholds follow the rate into the sample: the one-step map is not monotone
    monotone_in_input: ClassVar[bool] = False
    n_operators: int = 10

    def __post_init__(self) -> None:
        check_count(self.n_operators)

    def param_space(self, data: Any = None) -> ParamSpace:
        """The shared operator parameters plus ``c`` and ``udot0`` (V/s).

        ``c ~ HalfNormal(0.5)``; ``udot0`` log-normal with the median at
        :func:`typical_rate` of ``data`` and a decade either way at one sd.
        """
        sc = data_scales(data)
        return _extended(operator_space(self.n_operators, sc, linear=_LINEAR), (
            # c = 0.5 widens thresholds by half at |u̇| = (e^1 - 1) u̇_0
            Param("c", HalfNormal(0.5), unit="1",
                  description="rate sensitivity of the thresholds (0: rate-independent)"),
            # a decade either way around the data's typical rate at one sd
            Param("udot0", LogNormal.from_median(typical_rate(data), 2.3),
                  unit=sc.rate_unit, description="reference input rate of the thresholds"),
        ))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s = np.zeros((theta["w"].shape[0], self.n_operators + 3))
        s[:, : self.n_operators + 1] = u0  # operators relaxed at u0; u_prev = u0
        return s  # t_prev = 0 and flag 0: no previous sample yet

    def _run(self, u, t, theta, state0):
        n = self.n_operators
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ParameterError(f"{self.name}: t must be strictly increasing (the input "
                                 "rate is a backward difference in time)")
        has_prev = state0[:, n + 2] != 0.0
        if np.any(has_prev & ~(t[0] > state0[:, n + 1])):
            raise ParameterError(f"{self.name}: t[0] = {t[0]} is not after the time of the "
                                 "state's previous sample; continue with later times")
        y, state, _ = kernel_buffers(state0, u.shape[0])
        c, ud0 = theta["c"], theta["udot0"]
        pi_rate_batch(u, t, theta["p0"], theta["w"], theta["r"], c, ud0, state, y)
        failed = ~((c >= 0) & (ud0 > 0)) | _not_finite(y, state)
        return y, state, failed
