"""The clockwise-relay Preisach model: a direct Preisach inverse (review §5, Eq. 9–10, [60]).

A piezo loop runs counter-clockwise in the ``(u, y)`` plane, so its inverse ``y -> u``
runs clockwise. The relay ``gamma`` of Eq. 1–2 is counter-clockwise; ref. [60] defines
the complementary **clockwise relay** (review Eq. 9–10)::

    theta[u] = u - gamma[u]  =  u - 1   (u > alpha)
                                u - eps (beta <= u <= alpha, eps the relay's last value)
                                u + 1   (u < beta)

a unit ramp with a downward jump where the ordinary relay jumps up: on a rise the
operator runs along ``u + 1`` and drops to ``u - 1`` at ``alpha``, on a fall it runs along
``u - 1`` and jumps to ``u + 1`` at ``beta`` -- clockwise. A weighted sum of clockwise relays,
identified with the actuator's displacement as its input and the voltage as its output
(:func:`~bayeshyst.inverse.analytic.swap_input_output`), is itself the compensator: fed a
desired displacement, it outputs the command (the direct inverse, review Table 1).

Exact identity used for the evaluation and tested: for weights ``mu`` the model is the
ramp ``sum(mu) u / u_scale`` *minus* the ordinary Preisach model with the same weights
(review Eq. 9 summed over the relays), so the Everett staircase of
:mod:`bayeshyst.models._kernels.preisach` evaluates it with the affine output map
``y = c0 + c1 u + c2 P`` (``c1 = sum(mu) / u_scale``, ``c2 = -1`` for 1-0 relays, ``-2``
for ±1 relays): one kernel for both orientations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.models.base import data_scales
from bayeshyst.models.preisach import Preisach, default_levels
from bayeshyst.models.registry import register
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["PreisachClockwise"]

#: Prior median of ``u_scale`` as a fraction of the input span per unit relay jump: the
#: relays' jumps then take a fifth of the ramp, a compensator loop about 10-25 % of its
#: stroke wide (the inverse of a typical piezo loop).
SCALE_FRACTION = 0.2


@register
@dataclass(frozen=True)
class PreisachClockwise(Preisach):
    r"""Preisach model of clockwise relays (review Eq. 9–10, ref. [60]): a direct inverse.

    .. math::  y_k = c + \sum_{i \ge j} \mu_{ij}\, \vartheta_{q_i q_j}[u]_k, \qquad
               \vartheta_{\alpha\beta}[u] = \frac{u}{u_s} - \gamma_{\alpha\beta}[u]

    with ``gamma`` the relay of :class:`~bayeshyst.models.preisach.Preisach` (1-0 or ±1).
    Meant to be identified on swapped data (``y`` as input, ``u`` as output) and used as
    the compensator: driven by a desired displacement it outputs the command.

    Which form: the review's Eq. 10 writes ``theta = u - gamma`` with ``gamma = ±1``, i.e.
    the input measured in units of the relay's half-jump. That fixes the ratio of the
    operator's ramp to its jump by the unit the input happens to be in (µm or nm would
    give different models), so the input is divided by a scale ``u_s``
    (parameter ``u_scale``): ``u_s = 1`` in the input's unit is the review's operator
    exactly (tested). The jump of a 1-0 relay (ref. [38], the default as for
    ``preisach``) is 1, of a ±1 relay 2; ``eps`` of Eq. 10 is the relay's last value
    (Eq. 2). Switching conventions as for ``preisach``: up when ``u >= alpha``, down
    when ``u < beta``.

    Parameters
    ----------
    n_levels : int
        Number ``L`` of threshold levels (in the input's unit, e.g. µm on swapped data).
    relay : {"01", "pm1"}
        Relay values ``{0, 1}`` or ``{-1, +1}`` inside the clockwise relay.
    max_memory : int
        Stored extrema (see :mod:`bayeshyst.models.preisach`).

    Notes
    -----
    Parameters: ``offset`` ``c`` (output unit), ``mu`` (L(L+1)/2,) cell weights (output
    unit), ``u_scale`` ``u_s`` (input unit, > 0), the fixed ``levels`` (L,) (input unit)
    at :func:`~bayeshyst.models.preisach.default_levels`. Between switchings the output
    rises with slope ``sum(mu) / u_s``; relay ``(i, j)`` takes ``mu_ij`` (1-0) or
    ``2 mu_ij`` (±1) off it where it switches up, and gives it back where it switches
    down. Initial state as for ``preisach`` (negative saturation, then a rise to
    ``u_0``). Linear in ``(offset, mu)`` for fixed ``u_scale`` and levels.

    Default priors: ``u_scale ~ LogNormal(median 0.2 u_span / h, 0.7)`` with ``h`` the
    relay jump (1 or 2): the jumps then take a fifth of the ramp over the input range;
    ``mu ~ Normal(y_span / (4 h n_cells), y_span / (h sqrt(n_cells)))`` (a uniform
    density giving the data's stroke at the median scale), ``offset ~ Normal(y_min,
    y_span)`` (1-0) or centred (±1).

    Not monotone in its input: every switching relay makes the output step *down* on a
    rise (the sawtooth of Eq. 10), so a numerical inverse of this model -- a model of a
    compensator -- reports non-monotone steps (``monotone_in_input = False``).
    """

    name: ClassVar[str] = "preisach_clockwise"
    equation: ClassVar[str] = "review Eq. 9-10, ref. [60] (u scaled by u_scale)"
    monotone_in_input: ClassVar[bool] = False

    @property
    def _jump(self) -> float:
        return 1.0 if self.relay == "01" else 2.0

    def param_space(self, data: Any = None) -> ParamSpace:
        """``offset``, cell weights ``mu``, ``u_scale`` and the fixed ``levels``.

        Priors as in the class Notes, scaled from ``data`` (on swapped data its input is
        the displacement); ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        nc = self.n_cells
        h = self._jump
        base = sc.y_min if self.relay == "01" else 0.5 * (sc.y_min + sc.y_max)
        return ParamSpace(
            (
                Param("offset", Normal(base, sc.y_span), unit=sc.y_unit,
                      description="output offset"),
                Param("mu", Normal(sc.y_span / (4.0 * h * nc), sc.y_span / (h * math.sqrt(nc))),
                      shape=(nc,), unit=sc.y_unit,
                      description="clockwise relay weights, cell (i>=j)"),
                Param("u_scale", LogNormal.from_median(SCALE_FRACTION * sc.u_span / h, 0.7),
                      unit=sc.u_unit,
                      description="input travel per unit of the relay ramp (Eq. 10: 1)"),
            ),
            fixed={"levels": default_levels(self.n_levels, sc)},
            fixed_params=(
                Param("levels", Uniform(sc.u_min - sc.u_span, sc.u_max + sc.u_span),
                      shape=(self.n_levels,), unit=sc.u_unit,
                      description="relay threshold levels (fixed over the input range)"),
            ),
        )

    def _tables(self, theta):
        levels, tables, _, skip = super()._tables(theta)
        scale = np.asarray(theta["u_scale"], dtype=float)
        skip = skip | ~(np.isfinite(scale) & (scale > 0))
        total = tables[:, self.n_levels, 0]  # sum(mu): Y over the whole plane
        coef = np.zeros((total.shape[0], 3))
        coef[:, 0] = theta["offset"]
        # sum(mu) u / u_s - sum(mu) gamma: gamma = P01 (jump 1), or 2 P01 - 1 (jump 2)
        coef[:, 1] = np.where(skip, 0.0, total / np.where(skip, 1.0, scale))
        coef[:, 2] = -self._jump
        if self.relay == "pm1":
            coef[:, 0] += total
        return levels, tables, coef, skip
