"""The weighted-polynomial modified Bouc–Wen model, WPMBW (review Eq. 52–53, 55; ref. [99]).

Review §9.3; MODELS.md §6. Integrated in the input like the classical model in
:mod:`bayeshyst.models.bouc_wen` (rate-independent); its output map is a polynomial in
the hysteretic state, so the polynomial weights are a linear group the sampler draws
exactly. Kernel: :func:`bayeshyst.models._kernels.bouc_wen.mbw_batch`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.bouc_wen import mbw_batch
from bayeshyst.models.base import (
    HysteresisModel,
    LinearInParams,
    _factor,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.bouc_wen import _check_scale, _first
from bayeshyst.models.registry import register
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["ModifiedBoucWen"]

@register
@dataclass(frozen=True)
class ModifiedBoucWen(LinearInParams, HysteresisModel):
    r"""Weighted-polynomial modified Bouc–Wen model, WPMBW (review Eq. 52–53, 55; ref. [99]).

    .. math::  \dot w = \frac{\rho\, \dot u}
                              {1 - \mathrm{sgn}(\dot u)\, \rho (\lambda u - \mu w)},
               \qquad y = v = \sum_{i=1}^{L} c_i w^i

    (Eq. 52 gives the two branches ``u̇ >= 0``: ``ρ/(1 - ρλu + ρμw)`` and ``u̇ <= 0``:
    ``ρ/(1 + ρλu - ρμw)``; its minus signs are lost in the review's text and restored
    here from the inverse, Eq. 55, which is their reciprocal.) ``w`` is the MBW
    operator's output; Eq. 53 maps it through the weighted polynomial. Integrated in the
    input with RK4 sub-steps (smooth right-hand side: no power, no kink).

    Parameters
    ----------
    order : int
        Polynomial order ``L`` (default 2, as in ref. [99]).
    step_scale : float
        Largest RK4 step times ``λ`` (default 0.05: error < 1e-9 of the loop width).

    Notes
    -----
    Gauge: ``(ρ, λ, μ, c_i) -> (sρ, λ/s, μ/s², c_i / s^i)`` leaves ``v`` unchanged for
    any ``s > 0`` (an exact non-identifiability). We fix ``μ = λ``, which makes ``w``
    follow the input with unit slope (``w`` is in volts; ``c_1`` is then a gain):
    ``dw/du = ρ / (1 - sgn(u̇) ρ λ (u - w))``. The branches are ``u - w = ±(1/ρ - 1)/λ``;
    ``1/λ`` (V) is the relaxation length. ``0 < ρ < 1`` gives counter-clockwise loops
    (the prior's support); the kernel flags ``ρ`` outside ``(0, 2)`` or a state leaving
    the band ``|λ (u - w)| < 1/ρ`` where Eq. 52 is singular.

    Parameters ``rho`` (1), ``lam`` (1/V), ``c1..cL`` (output unit/V^i). Priors:
    ``rho ~ Uniform(0, 1)``; ``lam ~ LogNormal(median 4/u_span, 1)`` (rounded loops,
    relaxing over a quarter of the span); ``c1 ~ Normal(g, g)``; ``c_i ~ Normal(0,
    g / u_ref^(i-1))`` for ``i >= 2`` (at 1 sd a term moves the output by a gain times
    ``u_ref`` at the end of the range). State ``[w, u_prev]``; relaxed initial state
    ``w = u_0`` (on the centre line ``u = w`` between the branches).

    For fixed ``rho, lam`` the output is linear in ``c1..cL`` (:meth:`regressors`,
    columns ``w^i``), so the weights admit the conjugate Gaussian posterior.
    """

    name: ClassVar[str] = "mbw"
    equation: ClassVar[str] = "review Eq. 52-53, inverse Eq. 55"
    has_inverse: ClassVar[bool] = True
    order: int = 2
    step_scale: float = 0.05

    def __post_init__(self) -> None:
        if isinstance(self.order, bool) or not isinstance(self.order, int | np.integer) \
                or self.order < 1:
            raise ModelError(f"order must be an integer >= 1, got {self.order!r}")
        _check_scale(self.step_scale, "step_scale", 0.5)

    @property
    def linear_params(self) -> tuple[str, ...]:  # type: ignore[override]
        """Names of the output weights ``c1..cL`` (the output is linear in them)."""
        return tuple(f"c{i}" for i in range(1, self.order + 1))

    def param_space(self, data: Any = None) -> ParamSpace:
        """``rho``, ``lam`` (1/V) and the weights ``c1..cL`` with priors scaled from ``data``.

        The priors are those of the class Notes; ``data`` as in
        :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        g = abs(sc.gain)
        u_ref = max(abs(sc.u_min), abs(sc.u_max))
        coeffs = [
            Param(f"c{i}", Normal(sc.gain if i == 1 else 0.0, g / u_ref ** (i - 1)),
                  unit=sc.gain_unit + (f"^{i}" if i > 1 else ""),
                  description=f"weight of w^{i} in the output polynomial (Eq. 53)")
            for i in range(1, self.order + 1)
        ]
        return ParamSpace((
            Param("rho", Uniform(0.0, 1.0), unit="1",
                  description="MBW shape: branches at u - w = ±(1/rho - 1)/lam"),
            Param("lam", LogNormal.from_median(4.0 / sc.u_span, 1.0),
                  unit=f"1/{_factor(sc.u_unit)}",
                  description="inverse relaxation length of w (mu = lam by gauge)"),
            *coeffs,
        ))

    def _coeffs(self, theta: Mapping[str, Any]) -> np.ndarray:
        return np.ascontiguousarray(
            np.stack([np.asarray(theta[f"c{i}"], float) for i in range(1, self.order + 1)],
                     axis=-1))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        s = np.empty((theta["rho"].shape[0], 2))
        s[:] = u0
        return s

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0], size=2, owner=self.name)
        mbw_batch(u, theta["rho"], theta["lam"], self._coeffs(theta), float(self.step_scale),
                  state, y, failed)
        return y, state, failed

    def theta_from_review(self, rho: float, lam: float, mu: float,
                          c: Any) -> dict[str, float]:
        """The model's ``theta`` for Eq. 52–53 written with a free ``μ`` (e.g. published values).

        With ``s = μ/λ`` the gauge map gives ``rho = ρ μ/λ``, ``lam = λ²/μ``,
        ``c_i -> c_i (λ/μ)^i``; the output ``v(u)`` is unchanged.

        Parameters
        ----------
        rho, lam, mu : float
            The review's positive shape constants (1, 1/V, 1/output-unit of ``w``).
        c : array_like, shape (order,)
            Output weights ``c_1..c_L`` of Eq. 53 (for the review's ``w``).
        """
        c = np.asarray(c, dtype=float).ravel()
        if c.size != self.order:
            raise ParameterError(f"expected {self.order} weights c, got {c.size}")
        if not (rho > 0 and lam > 0 and mu > 0):
            raise ParameterError(f"rho, lam, mu must be positive, got {rho}, {lam}, {mu}")
        r = lam / mu  # = 1/s
        out = {"rho": rho / r, "lam": lam * r}
        out.update({f"c{i}": float(ci) * r**i for i, ci in enumerate(c, start=1)})
        return out

    def output_inverse(self, v: Any, theta: Mapping[str, Any]) -> np.ndarray:
        """Invert the static output polynomial, ``w`` from ``v`` (review Eq. 55, L <= 2).

        For ``L = 2`` this is ``w = (-c1 + sqrt(c1² + 4 c2 v)) / (2 c2)``, evaluated as
        ``2 v / (c1 + sqrt(c1² + 4 c2 v))`` (same value, no cancellation as ``c2 -> 0``):
        the root on the branch where ``dv/dw = c1 + 2 c2 w > 0``. It inverts only Eq. 53;
        the hysteresis is undone by :meth:`inverse`, which feeds this ``w`` into the
        inverse MBW operator (Eq. 55). A preceding linear dynamic block (Eq. 54) would be
        inverted before this step.

        Parameters
        ----------
        v : array_like
            Desired output (output unit).
        theta : mapping
            Model parameters (``c1``, ``c2``).

        Raises
        ------
        ModelError
            If ``order > 2`` (no closed-form root).
        ParameterError
            If ``c1 <= 0`` or some ``v`` is out of reach (``c1² + 4 c2 v < 0``).
        """
        if self.order > 2:
            raise ModelError(f"output_inverse is analytic for order <= 2, not {self.order}")
        v = np.asarray(v, dtype=float)
        c1 = _first(theta, "c1")
        c2 = _first(theta, "c2") if self.order == 2 else 0.0
        if not c1 > 0:
            raise ParameterError(f"output_inverse needs c1 > 0 (increasing output), got {c1}")
        disc = c1 * c1 + 4.0 * c2 * v
        if np.any(disc < 0):
            raise ParameterError(f"output {v[disc < 0].ravel()[0]:.6g} is beyond the "
                                 f"polynomial's extremum (c1={c1:.6g}, c2={c2:.6g})")
        return 2.0 * v / (c1 + np.sqrt(disc))

    def inverse(self, y: Any, t: Any, theta: Mapping[str, Any], *,
                state0: np.ndarray | None = None) -> np.ndarray:
        """Feedforward input ``u`` (N,) that drives the model to output ``y`` (N,).

        ``w_d`` = :meth:`output_inverse` of ``y``; then the inverse MBW operator, Eq. 55
        (``du/dw = (1 - sgn(ẇ) ρ λ (u - w)) / ρ``), which is linear in ``u`` and solved
        exactly on every monotone step of ``w``:
        ``u - w = A + (u_prev - w_prev - A) exp(-λ |Δw|)``, ``A = sgn(Δw)(1/ρ - 1)/λ``.
        No algebraic loop (the point of ref. [99]).

        Parameters
        ----------
        y : array_like, shape (N,)
            Desired output.
        t : array_like, shape (N,)
            Times (s), unused (rate-independent).
        theta : mapping
            Forward parameters.
        state0 : ndarray, shape (2,), optional
            The forward state ``[w, u_prev]`` before the first sample; default relaxed
            at ``w_d[0]`` (``u = w``).
        """
        wd = self.output_inverse(np.asarray(y, float).ravel(), theta)
        rho, lam = _first(theta, "rho"), _first(theta, "lam")
        if not (0 < rho < 2 and lam > 0):
            raise ParameterError(f"inverse needs 0 < rho < 2 and lam > 0, got {rho}, {lam}")
        wp, up = (wd[0], wd[0]) if state0 is None else (float(state0[0]), float(state0[1]))
        u = np.empty_like(wd)
        half = (1.0 / rho - 1.0) / lam
        for i, wi in enumerate(wd):
            dw = wi - wp
            if dw != 0.0:
                a = math.copysign(half, dw)
                up = wi + a + (up - wp - a) * math.exp(-lam * abs(dw))
            u[i] = up
            wp = wi
        return u
