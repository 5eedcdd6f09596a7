"""Maxwell-slip variants of review §7.2: asymmetric (ref. [67]) and distributed-parameter ([70]).

Both keep the elasto-slide elements of :class:`~bayeshyst.models.maxwell.MaxwellSlip`
(review Eq. 36–37) and run them with its kernel; the asymmetric model adds a nonlinear
spring in parallel, the distributed-parameter model draws the elements' slip deflections
from a two-parameter distribution instead of fixing ``n`` of them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from scipy.special import ndtri

from bayeshyst.errors import ModelError
from bayeshyst.models._kernels.maxwell_variants import asym_maxwell_batch
from bayeshyst.models._kernels.operators import maxwell_slip_batch
from bayeshyst.models.base import (
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.duhem import _normalisation
from bayeshyst.models.maxwell import MaxwellSlip
from bayeshyst.models.registry import register
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace

__all__ = ["MAX_SPRING_ORDER", "AsymmetricMaxwellSlip", "DistributedMaxwellSlip"]

#: Highest power of ``s`` in the nonlinear spring ``g``: beyond it the monomials on
#: ``[-1, 1]`` become too collinear to sample (as :data:`bayeshyst.models.duhem.MAX_ORDER`).
MAX_SPRING_ORDER = 6


@register
@dataclass(frozen=True)
class AsymmetricMaxwellSlip(LinearInParams, HysteresisModel):
    r"""Asymmetric Maxwell-slip model: elasto-slide elements and a nonlinear spring ``g``.

    .. math::  y = k_0 x + \sum_i k_i (x - x_i) + g(s), \qquad
               g(s) = \sum_{j=2}^{m} a_j s^j, \quad s = (x - u_{centre}) / u_{half}

    with the elements of review Eq. 36–37 (:class:`~bayeshyst.models.maxwell.MaxwellSlip`)
    and the nonlinear spring ``g(x)`` connected in parallel that review §7.2 attributes to
    ref. [67] to make the loop asymmetric.

    Parameters
    ----------
    n_elements : int
        Number of elasto-slide elements.
    spring_order : int
        Highest power ``m`` of ``s`` in ``g`` (2..6); ``g`` has ``m - 1`` coefficients.

    Notes
    -----
    **Form chosen.** The review gives no equation for ref. [67], only its structure: the
    actuator stiffness ``k_m`` and the capacitance-equivalent stiffness ``k_e`` in
    series, in parallel with the Maxwell-slip elements, and a nonlinear spring ``g(x)``
    in parallel with all of it. The series pair is a linear spring
    ``k_m k_e / (k_m + k_e)``, which cannot be told apart from ``k0`` in the output, so
    it is ``k0`` here (one identifiable parameter instead of two). ``g`` is taken as a
    polynomial (the usual choice, as in the Duhem model's ``f, g``) in the normalised
    input, without constant (an output offset) and linear term (``k0`` again): its even
    powers bend the two branches the same way, which is what makes the loop
    asymmetric. With ``a = 0`` it is ``maxwell_slip`` exactly.

    Parameters: ``k0``, ``k`` (n,) (output unit per input unit), ``a`` (m - 1,) (output
    unit, coefficients of ``s^2 .. s^m``); fixed: the slip deflections ``delta`` (n,)
    as in ``maxwell_slip`` and the normalisation ``u_centre``, ``u_half`` (input unit).
    The output is linear in ``(k0, k, a)``. Initial state: sliders at the first input.
    """

    name: ClassVar[str] = "maxwell_slip_asym"
    linear_params: ClassVar[tuple[str, ...]] = ("k0", "k", "a")
    equation: ClassVar[str] = "review Eq. 36-37 + nonlinear spring g(x), ref. [67]"
    n_elements: int = 10
    spring_order: int = 3

    def __post_init__(self) -> None:
        check_count(self.n_elements, "n_elements")
        m = self.spring_order
        if isinstance(m, bool) or not isinstance(m, int | np.integer) \
                or not 2 <= m <= MAX_SPRING_ORDER:
            raise ModelError(f"spring_order must be an integer in [2, {MAX_SPRING_ORDER}], "
                             f"got {m!r}")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``maxwell_slip``'s parameters, ``a`` (m - 1,) and the fixed normalisation.

        ``a_j ~ Normal(0, |g| u_half / 4)`` for the secant gain ``g``: a spring that
        bends the curve by a quarter of the half-stroke at 1 sd. ``data`` as in
        :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        base = MaxwellSlip(self.n_elements).param_space(data)
        norm, fixed = _normalisation(sc)
        scale = 0.25 * abs(sc.gain) * 0.5 * sc.u_span
        spring = Param("a", Normal(0.0, scale), shape=(self.spring_order - 1,),
                       unit=sc.y_unit,
                       description="nonlinear spring g(s), coefficients of s^2 .. s^m")
        return ParamSpace((*base.params, spring),
                          fixed={**base.fixed, **fixed},
                          fixed_params=tuple(base.fixed_params) + tuple(norm))

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return np.full((theta["k"].shape[0], self.n_elements), u0)

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0])
        bad = ~((theta["u_half"] > 0) & np.isfinite(theta["u_centre"]))
        asym_maxwell_batch(u, theta["k0"], theta["k"], theta["delta"], theta["a"],
                           theta["u_centre"], np.where(bad, 1.0, theta["u_half"]), state, y)
        failed |= bad
        state[failed] = np.nan
        return y, state, failed


@register
@dataclass(frozen=True)
class DistributedMaxwellSlip(LinearInParams, HysteresisModel):
    r"""Distributed-parameter Maxwell-slip model (DPMS): log-normal slip deflections.

    .. math::  y = k_0 x + K \int_0^\infty p(\delta)\, E_\delta[x]\, d\delta,
               \qquad \log \delta \sim \mathcal N(\log \delta_{med}, \sigma^2)

    where ``E_delta[x] = x - x_delta`` is the spring deflection of an elasto-slide element
    of slip deflection ``delta`` (review Eq. 36, a stop operator) and ``K`` the total
    stiffness of the continuum of elements. Review §7.2, ref. [70].

    Parameters
    ----------
    n_nodes : int
        Number of quadrature nodes (elements actually simulated).

    Notes
    -----
    **Form chosen.** The review only says that ref. [70] replaces the ``n`` elements by
    a continuous distribution so that accuracy no longer costs parameters. Here the
    elements share the stiffness equally per unit of probability and their slip
    deflections ``delta = f / k`` follow a log-normal law (positive, scale-free, two
    parameters: the median ``delta_med`` and the log-spread ``sigma``). The integral is
    evaluated by equal-weight quantile quadrature: ``n`` elements of stiffness ``K / n``
    and deflections ``delta_i = delta_med exp(sigma z_i)``, ``z_i = Phi^-1((i - 1/2) /
    n)``, so every node carries the same probability mass and ``sigma = 0`` is a single
    element of stiffness ``K`` and deflection ``delta_med`` exactly.

    Parameters: ``k0``, ``K`` (output unit per input unit; ``K < 0`` with ``k0 > 0``
    gives the counter-clockwise piezo loop as in ``maxwell_slip``), ``delta_med`` (input
    unit, > 0), ``sigma`` (1, >= 0). The output is linear in ``(k0, K)``. Rate
    independent. Initial state: sliders at the first input (unloaded springs).
    ``delta_med <= 0`` or ``sigma < 0`` is flagged as a failed simulation.
    """

    name: ClassVar[str] = "maxwell_slip_dp"
    linear_params: ClassVar[tuple[str, ...]] = ("k0", "K")
    equation: ClassVar[str] = "review Eq. 36-37, log-normal slip deflections, ref. [70]"
    n_nodes: int = 16

    def __post_init__(self) -> None:
        check_count(self.n_nodes, "n_nodes")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``k0``, ``K``, ``delta_med`` and ``sigma`` with priors scaled from ``data``.

        ``k0 ~ Normal(g, |g|)`` and ``K ~ Normal(0, |g|)`` for the secant gain ``g``;
        ``delta_med`` log-normal with median a sixth of the input span (wide: sd 1 in
        log); ``sigma ~ HalfNormal(1)``. ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        g = abs(sc.gain)
        gu = sc.gain_unit
        return ParamSpace((
            Param("k0", Normal(sc.gain, g), unit=gu, description="parallel linear spring"),
            Param("K", Normal(0.0, g), unit=gu,
                  description="total stiffness of the elements (negative: counter-clockwise)"),
            Param("delta_med", LogNormal.from_median(sc.u_span / 6.0, 1.0), unit=sc.u_unit,
                  description="median slip deflection f/k of the elements"),
            Param("sigma", HalfNormal(1.0),
                  description="log-spread of the slip deflections"),
        ))

    def nodes(self, delta_med: Any, sigma: Any) -> tuple[np.ndarray, np.ndarray]:
        """Quadrature slip deflections ``delta`` (W, n) and validity (W,).

        Parameters
        ----------
        delta_med, sigma : array_like, shape (W,)
            Median slip deflection (input unit) and log-spread.
        """
        dm = np.atleast_1d(np.asarray(delta_med, float))
        sg = np.atleast_1d(np.asarray(sigma, float))
        ok = (dm > 0) & (sg >= 0) & np.isfinite(dm) & np.isfinite(sg)
        z = ndtri((np.arange(self.n_nodes) + 0.5) / self.n_nodes)
        delta = np.where(ok, dm, 1.0)[:, None] * np.exp(np.where(ok, sg, 0.0)[:, None] * z)
        return np.ascontiguousarray(delta), ok

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return np.full((theta["K"].shape[0], self.n_nodes), u0)

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0])
        delta, ok = self.nodes(theta["delta_med"], theta["sigma"])
        k = np.repeat(theta["K"][:, None] / self.n_nodes, self.n_nodes, axis=1)
        maxwell_slip_batch(u, theta["k0"], k, delta, state, y)
        failed |= ~ok
        state[failed] = np.nan
        return y, state, failed
