"""Generalised Maxwell-slip model: elasto-slide elements in parallel (review Eq. 36–37)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.models._kernels.operators import maxwell_slip_batch
from bayeshyst.models.base import (
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.pi import default_thresholds
from bayeshyst.models.registry import register
from bayeshyst.params import Normal, Param, ParamSpace, Uniform

__all__ = ["MaxwellSlip"]


@register
@dataclass(frozen=True)
class MaxwellSlip(LinearInParams, HysteresisModel):
    """Generalised Maxwell-slip model (review Eq. 36–37, MODELS.md §1, §4).

    Element ``i`` is a spring of stiffness ``k_i`` and a slider with breakaway force
    ``f_i``: its force is ``F_i = k_i (x - x_i)`` while ``|x - x_i| < delta_i`` with the
    slip deflection ``delta_i = f_i / |k_i|``; beyond it the slider moves
    (``x_i = x - delta_i sgn(dx)``). The output is ``y = k0 x + sum_i F_i``: a linear
    spring ``k0`` in parallel with ``n`` elements.

    Parameters
    ----------
    n_elements : int
        Number of elasto-slide elements.

    Notes
    -----
    Each element is a stop operator of threshold ``delta_i`` scaled by ``k_i``
    (review ref. [70]), so with fixed ``delta`` the model is linear in ``k0, k``.
    Physical springs have ``k_i > 0`` and give clockwise loops; a piezo loop is
    counter-clockwise, which the model reaches with ``k0 > 0`` and negative ``k_i``
    (ref. [70]: play-PI = elements of negative stiffness in parallel). The default
    prior therefore lets ``k_i`` take either sign. Parameters: ``k0``, ``k`` (n,) in
    output unit per input unit; ``delta`` (n,) (input unit), fixed like the PI
    thresholds; the breakaway forces are ``f_i = |k_i| delta_i``.
    Initial state: sliders at the first input, ``x_i = x_0`` (unloaded springs).
    """

    name: ClassVar[str] = "maxwell_slip"
    linear_params: ClassVar[tuple[str, ...]] = ("k0", "k")
    equation: ClassVar[str] = "review Eq. 36-37"
    n_elements: int = 10

    def __post_init__(self) -> None:
        check_count(self.n_elements, "n_elements")

    def param_space(self, data: Any = None) -> ParamSpace:
        """``k0``, ``k`` (n,) and the fixed slip deflections ``delta`` (n,), scaled from ``data``.

        ``k0 ~ Normal(g, |g|)`` and ``k_i ~ Normal(0, |g|)`` (either sign) for the secant
        gain ``g``; ``delta`` at :func:`~bayeshyst.models.pi.default_thresholds` over the
        input span. ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        g = abs(sc.gain)
        gu = sc.gain_unit
        n = self.n_elements
        return ParamSpace(
            (
                Param("k0", Normal(sc.gain, g), unit=gu, description="parallel linear spring"),
                Param("k", Normal(0.0, g), shape=(n,), unit=gu,
                      description="element stiffnesses (negative for counter-clockwise loops)"),
            ),
            fixed={"delta": default_thresholds(n, sc)},
            fixed_params=(
                Param("delta", Uniform(0.0, sc.u_span), shape=(n,), unit=sc.u_unit,
                      description="slip deflections f_i/|k_i| (fixed over the input span)"),
            ),
        )

    def breakaway_forces(self, theta: Mapping[str, Any]) -> np.ndarray:
        """``f_i = |k_i| delta_i`` (output unit), the derived slider forces."""
        return np.abs(np.asarray(theta["k"], float)) * np.asarray(theta["delta"], float)

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return np.full((theta["k"].shape[0], self.n_elements), u0)

    def _run(self, u, t, theta, state0):
        y, state, failed = kernel_buffers(state0, u.shape[0])
        maxwell_slip_batch(u, theta["k0"], theta["k"], theta["delta"], state, y)
        return y, state, failed
