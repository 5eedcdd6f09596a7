"""Preisach variants of review §5: rate-weighted relays and the diagonally weighted grid.

References: rate weight refs. [39] [44], diagonal weights ref. [42].

* :class:`PreisachRate`, :class:`PreisachDensityRate`: the ``preisach`` grid and the
  ``preisach_density`` model with every relay weight multiplied by a factor of the
  current input rate, ``mu(alpha, beta) (1 + c ln(1 + |u̇| / u̇_0))``. The relay states
  and the memory are those of the parent (rate-independent, Eq. 7–8); ``c = 0`` is the
  parent bit for bit.
* :class:`DiagonalPreisach`: each cell of the relay grid carries its weight uniformly
  along its diagonal instead of at its centre, which makes the discrete model's output
  continuous (piecewise linear in the input) and agrees with ``preisach`` whenever the
  input stands on a cell edge.

Kernels: :mod:`bayeshyst.models._kernels.preisach_variants`. Relay conventions, the
initial state and the memory are those of :mod:`bayeshyst.models.preisach`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.preisach import memory_valid
from bayeshyst.models._kernels.preisach_variants import (
    diagonal_preisach_batch,
    rate_staircase_batch,
)
from bayeshyst.models.base import (
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
    kernel_buffers,
)
from bayeshyst.models.pi_variants import typical_rate
from bayeshyst.models.preisach import Preisach, PreisachDensity
from bayeshyst.models.registry import register
from bayeshyst.params import HalfNormal, LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["DiagonalPreisach", "PreisachDensityRate", "PreisachRate"]

_RATE_TAIL = 3  # u_prev, t_prev, has_prev after the staircase memory

_RATE_NOTES = """
    The form, and why: the review says of ref. [39] that it "introduced the derivative of
    voltage with respect to time into the weight of the double integral", and of ref.
    [44] that it "added a frequency weight to the classical Preisach model formula"; it
    gives neither function. Both read as a density ``mu(alpha, beta) w(u̇)``; the weight
    is taken from the instantaneous rate (defined for any input, where a "frequency" is
    not) with the one-parameter law of ``pi_rate`` (MODELS.md §1),
    ``w = 1 + c ln(1 + |u̇| / u̇_0)``, so that ``c = 0`` is the rate-independent model
    exactly and faster input widens the loop (review §3, Fig. 7b). The network of
    [39] and the HOFODE operator of [43] are not part of the model. Only the relays are
    weighted: the output offset (and ``k_rev`` of the density model) is not part of the
    double integral. The relay states, and so the wiping-out property and the memory,
    are rate-independent; at constant ``|u̇|`` the model is its parent with every weight
    scaled by one constant. Where ``|u̇|`` changes the output moves with the weight
    while the relays hold: at the turning points of a sine (``u̇ = 0``) it is back on
    the rate-independent loop, in between it is pushed away from ``c0`` in proportion
    to the weight, which widens the loop mid-stroke.

    Discretisation: ``u̇_k`` is the backward difference ``(u_k - u_{k-1}) / (t_k -
    t_{k-1})`` (causal; ``t`` must increase strictly). The state is the staircase
    memory followed by ``(u_{k-1}, t_{k-1}, flag)``, so a record simulated in pieces
    gives the same output as in one piece; with the default initial state there is no
    previous sample and the first sample has ``u̇ := 0``.

    Rate parameters: ``c`` (1, >= 0, HalfNormal(0.5) prior) and ``udot0`` (V/s, > 0,
    log-normal prior with the median at :func:`~bayeshyst.models.pi_variants.typical_rate`
    of the data, a decade either way at one sd), as in ``pi_rate``. Walkers with
    ``c < 0`` or ``udot0 <= 0`` are reported failed.

    Inverse: for ``c > 0`` the one-step map ``u_k -> y_k`` is not monotone. On a fall
    the weight grows as ``u_k`` moves away from ``u_{k-1}`` while the relays hold, so
    the output first rises; the sample-by-sample numerical inverse
    (:mod:`bayeshyst.inverse.numerical`) then has no unique root and counts such samples
    in ``n_nonmonotone`` (tested in ``tests/test_inverse.py``).
"""


class _RateWeighted:
    """Rate weight on top of a staircase model: subclasses also derive from the parent."""

    rate_dependent: ClassVar[bool] = True
    # the relay weights follow the rate into the sample: the one-step map is not monotone
    monotone_in_input: ClassVar[bool] = False
    name: ClassVar[str]
    max_memory: int

    def param_space(self, data: Any = None) -> ParamSpace:
        """The parent's parameters plus ``c`` (1) and ``udot0`` (V/s)."""
        space = super().param_space(data)  # type: ignore[misc]
        sc = data_scales(data)
        rate = (
            # c = 0.5 adds half of every weight at |u̇| = (e - 1) u̇_0
            Param("c", HalfNormal(0.5), unit="1",
                  description="rate sensitivity of the relay weights (0: rate-independent)"),
            # a decade either way around the data's typical rate at one sd
            Param("udot0", LogNormal.from_median(typical_rate(data), 2.3),
                  unit=sc.rate_unit, description="reference input rate of the weights"),
        )
        return ParamSpace((*space.params, *rate), space.fixed, space.fixed_params)

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        memory = super()._initial_state(theta, u0)  # type: ignore[misc]
        tail = np.zeros((memory.shape[0], _RATE_TAIL))
        tail[:, 0] = u0  # t_prev = 0 and flag 0: no previous sample yet
        return np.concatenate([memory, tail], axis=1)

    def _weighted_constant(self, theta: Mapping[str, np.ndarray],
                           tables: np.ndarray) -> np.ndarray:
        """``b0``: the weighted output with every relay off (W,); 0 for 1-0 relays."""
        return np.zeros(theta["offset"].shape[0])

    def _run(self, u, t, theta, state0):
        mem_len = 3 + self.max_memory
        width = theta["offset"].shape[0]
        if state0.shape != (width, mem_len + _RATE_TAIL):
            raise ParameterError(f"{self.name} state must have shape ({width}, "
                                 f"{mem_len + _RATE_TAIL}) for max_memory={self.max_memory}, "
                                 f"got {state0.shape}")
        bad = np.flatnonzero(~memory_valid(np.ascontiguousarray(state0[:, :mem_len])))
        if bad.size:
            raise ParameterError(f"{self.name} state rows {bad[:10].tolist()} are not a valid "
                                 "memory (count, alternating nested extrema, tip)")
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ParameterError(f"{self.name}: t must be strictly increasing (the input "
                                 "rate is a backward difference in time)")
        has_prev = state0[:, mem_len + 2] != 0.0
        if np.any(has_prev & ~(t[0] > state0[:, mem_len + 1])):
            raise ParameterError(f"{self.name}: t[0] = {t[0]} is not after the time of the "
                                 "state's previous sample; continue with later times")
        nodes, tables, coef3, skip = self._tables(theta)  # type: ignore[attr-defined]
        coef = np.ascontiguousarray(np.column_stack(
            [coef3, self._weighted_constant(theta, tables)]))
        c, ud0 = theta["c"], theta["udot0"]
        skip = skip | ~((c >= 0) & (ud0 > 0))
        rate = np.ascontiguousarray(np.column_stack([np.where(skip, 0.0, c),
                                                     np.where(skip, 1.0, ud0)]))
        y, state, failed = kernel_buffers(state0, u.shape[0])
        rate_staircase_batch(u, t, nodes, tables, self._bilinear,  # type: ignore[attr-defined]
                             coef, rate, skip, state, y, failed)
        return y, state, failed | ~np.all(np.isfinite(state), axis=1)


@register
@dataclass(frozen=True)
class PreisachRate(_RateWeighted, Preisach):
    r"""Rate-dependent discrete Preisach model: relay weights scaled by the input rate.

    .. math::  y_k = c_0 + \left(1 + c \ln(1 + |\dot u_k| / \dot u_0)\right)
               \sum_{i \ge j} \mu_{ij} \gamma_{q_i q_j}[u]_k

    (review §5, refs. [39] [44], on the grid of review Eq. 1–4 evaluated by Eq. 7–8).
    With ±1 relays the sum includes the ``-mu`` of the relays that are off. Settings
    (``n_levels``, ``relay``, ``max_memory``), the cell parameters ``offset``, ``mu``,
    the fixed ``levels`` and their priors are those of
    :class:`~bayeshyst.models.preisach.Preisach`; ``c = 0`` is ``preisach`` exactly.
    Linear in ``(offset, mu)`` for fixed ``c``, ``udot0`` and levels.

    Notes
    -----
    The rate weight (shared with :class:`PreisachDensityRate`) follows.
    """

    name: ClassVar[str] = "preisach_rate"
    equation: ClassVar[str] = ("review Eq. 1-4, 7-8, refs. [39] [44] "
                               "(weights mu*(1+c*ln(1+abs(du/dt)/udot0)))")

    def _weighted_constant(self, theta, tables):
        if self.relay == "01":
            return np.zeros(tables.shape[0])
        # a ±1 relay that is off carries -mu, which the rate weight scales too
        return -tables[:, self.n_levels, 0]


@register
@dataclass(frozen=True)
class PreisachDensityRate(_RateWeighted, PreisachDensity):
    r"""Preisach model with a parametric density whose weight depends on the input rate.

    .. math::  y_k = c + k_{rev} u_k + s \left(1 + c_r \ln(1 + |\dot u_k| / \dot u_0)\right)
               \frac{\int\!\!\int_{T_+} \mu}{\int\!\!\int_T \mu}

    (review §5, refs. [39] [44], on the density model of review Eq. 3–4, 7–8; the rate
    sensitivity ``c_r`` is the parameter named ``c``). Settings, density parameters,
    the fixed ``bounds`` and their priors are those of
    :class:`~bayeshyst.models.preisach.PreisachDensity`; ``c = 0`` is
    ``preisach_density`` exactly. The reversible slope ``k_rev`` is not weighted.

    Notes
    -----
    The rate weight (shared with :class:`PreisachRate`) follows.
    """

    name: ClassVar[str] = "preisach_density_rate"
    equation: ClassVar[str] = ("review Eq. 3-4, 7-8, refs. [39] [44] "
                               "(density times 1+c*ln(1+abs(du/dt)/udot0))")


# the shared Notes (a class docstring must be a literal, so they are appended here)
PreisachRate.__doc__ = (PreisachRate.__doc__ or "") + _RATE_NOTES
PreisachDensityRate.__doc__ = (PreisachDensityRate.__doc__ or "") + _RATE_NOTES


@register
@dataclass(frozen=True)
class DiagonalPreisach(LinearInParams, HysteresisModel):
    r"""Diagonally weighted discrete Preisach model (review §5, ref. [42]).

    .. math::  y = c_0 + \sum_{i \ge j} \mu_{ij} \frac{1}{|D_{ij}|}
               \int_{D_{ij}} \gamma_{\alpha \beta}[u] \, ds

    The Preisach plane ``lo <= beta <= alpha <= hi`` is cut into the ``L (L + 1) / 2``
    cells of a uniform grid (edges ``e_m = lo + m h``, ``h = (hi - lo) / L``); cell
    ``(i, j)`` is ``[e_i, e_{i+1}] x [e_j, e_{j+1}]`` (a half-square on the line
    ``alpha = beta`` for ``i = j``) and its weight ``mu_ij`` is spread uniformly along
    its diagonal ``D_ij``, the segment from ``(e_i, e_j)`` to ``(e_{i+1}, e_{j+1})``,
    with 1-0 relays (ref. [38]).

    The form, and why: the review says ref. [42] "proposed a diagonally weighted
    Preisach model for the problem that linear interpolation cannot obtain accurate
    ``Y(alpha, beta)`` values, in which the basic elements constituting the Preisach
    triangle are considered to have weights along their diagonal lines. The continuity
    of the discrete Preisach model is improved." Read literally, each element's weight
    lies on the element's own diagonal: a relay grid's output is then continuous
    (piecewise linear in the input; a point weight per cell gives steps), which is the
    improvement named, and its Everett function is exact where bilinear interpolation
    of a table is not. The sentence can also be read as one weight per whole diagonal
    line ``alpha - beta = d h`` of the triangle: ``weights="diagonal"`` ties the cells
    of each such line to one weight, ``L`` parameters instead of ``L (L + 1) / 2``. That
    adds no continuity of its own, and inside the plane it is a play-operator
    Prandtl–Ishlinskii model with thresholds ``d h / 2`` (saturating at the plane's
    bounds), so it is offered as the reduced parameterisation, not as the default.

    Evaluation: the cells with ``i - j = d`` lie on the line ``alpha - beta = d h``;
    a relay on it is on exactly when the play operator of half-width ``d h / 2`` is at
    or above the relay's centre, so each diagonal is a piecewise-linear function of one
    play (kernel module docstring): ``O(L)`` per sample and no memory limit.

    Parameters
    ----------
    n_levels : int
        Number ``L`` of cells along each side of the plane.
    weights : {"cell", "diagonal"}
        One weight per cell, or one per diagonal line ``i - j = d`` (shared by its
        ``L - d`` cells).

    Notes
    -----
    Parameters: ``offset`` ``c_0`` (output unit), the output at negative saturation;
    ``mu`` (L(L+1)/2,) cell weights (output unit), cell ``(i, j)`` at flat index
    ``i (i + 1) / 2 + j`` as in ``preisach``, with the same priors (with
    ``weights="diagonal"``: ``mu`` (L,), entry ``d`` the weight of each cell with
    ``i - j = d``; prior mean ``y_span / n_cells`` as for a cell, standard deviation
    ``y_span / sqrt(sum_d (L - d)^2)``, a spread of one data span in the stroke);
    the fixed ``bounds``
    ``(lo, hi)`` (V), the data's input range, so that the cell centres are the
    ``levels`` of ``preisach`` and the two models agree whenever the input stands on a
    cell edge ``e_m`` (every relay of a cell is then on or off together). Outside
    ``[lo, hi]`` the output saturates. Stroke: the sum of the cell weights. Initial state: negative
    saturation then a rise to ``u0`` (plays at ``u0 - d h / 2``), as in ``preisach``.
    Rate-independent. Linear in ``(offset, mu)`` for fixed bounds.
    """

    name: ClassVar[str] = "preisach_diagonal"
    has_output_offset: ClassVar[bool] = True
    linear_params: ClassVar[tuple[str, ...]] = ("offset", "mu")
    equation: ClassVar[str] = ("review Eq. 1-4, ref. [42] "
                               "(each cell's weight spread along its diagonal)")
    n_levels: int = 12
    weights: str = "cell"

    def __post_init__(self) -> None:
        check_count(self.n_levels, "n_levels")
        if self.weights not in ("cell", "diagonal"):
            raise ModelError(f"weights must be 'cell' or 'diagonal', got {self.weights!r}")

    @property
    def n_cells(self) -> int:
        """Number of cells ``L (L + 1) / 2``."""
        return self.n_levels * (self.n_levels + 1) // 2

    def param_space(self, data: Any = None) -> ParamSpace:
        """``offset`` and ``mu`` with the priors of ``preisach``; fixed ``bounds`` (2,).

        ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        grid = Preisach(n_levels=self.n_levels).param_space(data)
        mu = grid["mu"]
        if self.weights == "diagonal":
            cells_per_line = self.n_levels - np.arange(self.n_levels)
            mu = Param("mu", Normal(sc.y_span / self.n_cells,
                                    sc.y_span / math.sqrt(float(np.sum(cells_per_line**2)))),
                       shape=(self.n_levels,), unit=sc.y_unit,
                       description="relay weight of every cell on diagonal i - j = d")
        return ParamSpace(
            (grid["offset"], mu),
            fixed={"bounds": np.array([sc.u_min, sc.u_max])},
            fixed_params=(
                Param("bounds", Uniform(sc.u_min - sc.u_span, sc.u_max + sc.u_span),
                      shape=(2,), unit=sc.u_unit,
                      description="input range (lo, hi) of the Preisach plane"),
            ),
        )

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        bounds = np.asarray(theta["bounds"], dtype=float)
        h = (bounds[:, 1] - bounds[:, 0]) / self.n_levels
        # negative saturation, then a rise to u0: every play is pushed by its upper edge
        return u0 - 0.5 * np.arange(self.n_levels)[None, :] * h[:, None]

    def _run(self, u, t, theta, state0):
        width = theta["offset"].shape[0]
        if state0.shape != (width, self.n_levels):
            raise ParameterError(f"{self.name} state must have shape ({width}, "
                                 f"{self.n_levels}), got {state0.shape}")
        bounds = np.array(theta["bounds"], dtype=float)
        mu, offset = self.cell_weights(theta["mu"]), theta["offset"]
        skip = ~(np.all(np.isfinite(bounds), axis=1) & (bounds[:, 1] > bounds[:, 0])
                 & np.all(np.isfinite(mu), axis=1) & np.isfinite(offset)
                 & np.all(np.isfinite(state0), axis=1))
        bounds[skip] = (0.0, 1.0)  # harmless stand-ins: the kernel never divides by 0
        y, state, failed = kernel_buffers(state0, u.shape[0])
        diagonal_preisach_batch(u, offset, mu, bounds, skip, state, y, failed)
        return y, state, failed | ~np.all(np.isfinite(state), axis=1)

    def cell_weights(self, mu: Any) -> np.ndarray:
        """Weights of the cells (..., n_cells) in ``preisach`` order, from ``mu``.

        With ``weights="diagonal"`` entry ``d`` of ``mu`` is copied to every cell
        ``(i, j)`` with ``i - j = d``; otherwise ``mu`` is returned as an array.
        """
        mu = np.asarray(mu, dtype=float)
        if self.weights == "cell":
            return mu
        i, j = np.tril_indices(self.n_levels)
        return np.ascontiguousarray(mu[..., i - j])

    def cell_segments(self, theta: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """Start ``(alpha, beta)`` of every cell's diagonal, each (n_cells,), in ``mu`` order.

        The segment runs from there to ``(alpha + h, beta + h)`` (V).
        """
        lo, hi = np.asarray(theta["bounds"], dtype=float)
        if not hi > lo:
            raise ParameterError(f"bounds must satisfy lo < hi, got ({lo}, {hi})")
        edges = lo + (hi - lo) / self.n_levels * np.arange(self.n_levels)
        i, j = np.tril_indices(self.n_levels)
        return edges[i], edges[j]
