"""Preisach models: a discrete relay grid and a parametric Preisach density.

Both are evaluated the same way (review Eq. 7–8, MODELS.md §3): the input history is
reduced to its staircase of alternating dominant extrema (wiping-out property) and the
output is a short sum of Everett-function differences, so one sample costs O(1)
amortised instead of a loop over every relay. :class:`EverettTable` holds the Everett
function ``Y(a, b)``, the mass of the Preisach density over the triangle
``{b < beta <= alpha <= a}``; :func:`everett_response` runs the staircase on any table,
including one measured on an actuator (review ref. [40]).

Conventions shared by both models
---------------------------------
* Relay ``gamma_{alpha beta}`` (review Eq. 1–2): switches up when ``u >= alpha`` and
  down when ``u < beta``, otherwise keeps its value; ``alpha >= beta``. The strict
  down-switch makes a relay with ``alpha == beta`` a plain step, on exactly when
  ``u >= alpha``.
* Initial state at ``u0``: negative saturation followed by a monotone rise to ``u0``
  (every relay with ``alpha <= u0`` on, every other off). A piezo actuator is poled and
  driven from its lowest voltage, so its last large excursion was downwards; the state
  depends on ``u0`` only through the relays below it, consistent with starting at ``u0``.
* Memory: at most ``max_memory`` extrema are stored. When a reversal finds the memory
  full, the innermost pair of stored extrema (the smallest remembered minor loop) is
  forgotten, as if the input had wiped it out. This is an approximation, so it is never
  silent: the number of such merges is kept in the state (:func:`memory_merges`).
  The default 256 is reached only by more than 128 strictly nested reversals.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.preisach import (
    density_everett_tables,
    everett_eval,
    memory_valid,
    relay_everett_tables,
    staircase_batch,
)
from bayeshyst.models.base import (
    DataScales,
    HysteresisModel,
    LinearInParams,
    check_count,
    data_scales,
)
from bayeshyst.models.registry import register
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = [
    "EverettTable",
    "Preisach",
    "PreisachDensity",
    "default_levels",
    "everett_response",
    "memory_merges",
]

_STATE_HEAD = 3  # n, merges, tip: see bayeshyst.models._kernels.preisach


def default_levels(n_levels: int, scales: DataScales) -> np.ndarray:
    """Relay thresholds at the centres of ``n_levels`` equal bins of the input range (V).

    ``q_i = u_min + (i - 1/2) (u_max - u_min) / L``, ``i = 1..L``: half a bin inside
    each end, so a full-range cycle switches every relay up at ``u_max`` and down at
    ``u_min``, and relay ``(q_i, q_j)`` stands for the cell of the Preisach plane around
    it (what a density integrated over the cells gives).
    """
    check_count(n_levels, "n_levels")
    width = scales.u_span / n_levels
    return scales.u_min + (np.arange(n_levels) + 0.5) * width


def memory_merges(state: Any) -> np.ndarray:
    """How many times the memory of each state overflowed (see module docstring).

    Parameters
    ----------
    state : array_like, shape (S,) or (W, S)
        A Preisach state (``Trajectory.state``).
    """
    return np.asarray(state, dtype=float)[..., 1].astype(int)


def _check_memory_setting(max_memory: Any) -> None:
    check_count(max_memory, "max_memory")
    if max_memory < 2:
        raise ModelError(f"max_memory must be >= 2 (extrema are dropped in pairs), "
                         f"got {max_memory}")


def _initial_memory(width: int, max_memory: int, u0: float) -> np.ndarray:
    state = np.zeros((width, _STATE_HEAD + max_memory))
    state[:, 2] = u0
    return state


@dataclass(frozen=True, eq=False)
class EverettTable:
    """The Everett function ``Y(a, b)`` on nodes (review Eq. 7–8, ref. [40]).

    Parameters
    ----------
    nodes : ndarray, shape (K,)
        Strictly increasing input values (V).
    values : ndarray
        With ``bilinear=False``, shape (K+1, K+1): ``values[I, J]`` is ``Y`` for ``a``
        between nodes ``I-1`` and ``I`` and ``b`` between ``J-1`` and ``J`` (a step
        function: exact for relays switching at the nodes). With ``bilinear=True``,
        shape (K, K): ``Y(nodes[i], nodes[j])``, interpolated bilinearly in between and
        clamped to the end nodes outside (the Preisach plane is bounded).
        ``Y`` vanishes for ``b >= a``. Unit: output unit (or 1 when normalised).
    bilinear : bool
        Interpolation between nodes.
    """

    nodes: np.ndarray
    values: np.ndarray
    bilinear: bool

    def __post_init__(self) -> None:
        # writable copies: the table does not alias the caller's arrays, and numba sees
        # one array type
        nodes = np.array(self.nodes, dtype=float)
        values = np.array(self.values, dtype=float)
        k = nodes.size
        want = (k, k) if self.bilinear else (k + 1, k + 1)
        if nodes.ndim != 1 or k < (2 if self.bilinear else 1):
            raise ParameterError(f"Everett nodes must be 1-D with at least "
                                 f"{2 if self.bilinear else 1} entries, got {nodes.shape}")
        if values.shape != want:
            raise ParameterError(f"Everett values must have shape {want}, got {values.shape}")
        if not (np.all(np.isfinite(nodes)) and np.all(np.isfinite(values))):
            raise ParameterError("Everett nodes and values must be finite")
        if np.any(np.diff(nodes) <= 0):
            raise ParameterError("Everett nodes must be strictly increasing")
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "bilinear", bool(self.bilinear))

    @property
    def total(self) -> float:
        """``Y`` of the whole plane: the output span from negative to positive saturation."""
        return float(self.values[-1, 0])

    def evaluate(self, alpha: Any, beta: Any) -> np.ndarray:
        """``Y(alpha, beta)`` (broadcast arrays of input values, V)."""
        a, b = np.broadcast_arrays(np.asarray(alpha, float), np.asarray(beta, float))
        out = np.empty(a.size)
        everett_eval(self.nodes, self.values, self.bilinear, np.ascontiguousarray(a.ravel()),
                     np.ascontiguousarray(b.ravel()), out)
        return out.reshape(a.shape)


def _simulate(u, nodes, tables, bilinear, coef, skip, state0, max_memory):
    """Run the staircase kernel after validating the memory; returns ``(y, state, failed)``."""
    width = tables.shape[0]
    if state0.shape != (width, _STATE_HEAD + max_memory):
        raise ParameterError(f"Preisach state must have shape ({width}, "
                             f"{_STATE_HEAD + max_memory}) for max_memory={max_memory}, "
                             f"got {state0.shape}")
    bad = np.flatnonzero(~memory_valid(state0))
    if bad.size:
        raise ParameterError(f"Preisach state rows {bad[:10].tolist()} are not a valid "
                             "memory (count, alternating nested extrema, tip)")
    state = state0.copy()
    y = np.full((width, u.shape[0]), np.nan)
    failed = np.zeros(width, dtype=bool)
    staircase_batch(u, nodes, tables, bilinear, coef, skip, state, y, failed)
    return y, state, failed


def everett_response(u: Any, table: EverettTable, *, state0: Any = None,
                     max_memory: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Preisach output ``P`` of an Everett table for input ``u`` (review Eq. 7–8).

    Parameters
    ----------
    u : array_like, shape (N,)
        Input (V).
    table : EverettTable
        ``Y`` on nodes, e.g. measured first-order reversal curves (review ref. [40]).
    state0 : array_like, shape (3 + max_memory,), optional
        Memory before ``u[0]``; default negative saturation then a rise to ``u[0]``.
    max_memory : int
        Number of stored extrema.

    Returns
    -------
    P : ndarray, shape (N,)
        The 1-0 relay sum (unit of ``Y``).
    state : ndarray, shape (3 + max_memory,)
        Memory after the last sample.
    """
    _check_memory_setting(max_memory)
    u = np.ascontiguousarray(u, dtype=float)
    if u.ndim != 1 or u.size == 0 or not np.all(np.isfinite(u)):
        raise ParameterError(f"u must be a non-empty finite 1-D array, got shape {u.shape}")
    s0 = (_initial_memory(1, max_memory, float(u[0])) if state0 is None
          else np.asarray(state0, dtype=float).reshape(1, -1))
    y, state, failed = _simulate(u, table.nodes[None, :], table.values[None, :, :],
                                 table.bilinear, np.array([[0.0, 0.0, 1.0]]),
                                 np.zeros(1, dtype=bool), s0, max_memory)
    if failed[0]:
        raise ParameterError("Everett table gave a non-finite output")
    return y[0], state[0]


class _Staircase:
    """Shared state handling; subclasses give ``max_memory`` and ``_tables``."""

    max_memory: int
    _bilinear: ClassVar[bool]

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return _initial_memory(theta["offset"].shape[0], self.max_memory, u0)

    def _run(self, u, t, theta, state0):
        nodes, tables, coef, skip = self._tables(theta)
        return _simulate(u, nodes, tables, self._bilinear, coef, skip, state0,
                         self.max_memory)

    def _tables(self, theta):  # pragma: no cover - abstract
        raise NotImplementedError


@register
@dataclass(frozen=True)
class Preisach(LinearInParams, _Staircase, HysteresisModel):
    r"""Discrete Preisach model: a triangular grid of weighted relays.

    .. math::  y_k = c + \sum_{i \ge j} \mu_{ij} \gamma_{q_i q_j}[u]_k

    (review Eq. 1–4; the 1-0 relay of ref. [38] or the ±1 relay), evaluated through the
    Everett form Eq. 7–8 with a step-function Everett table.

    Parameters
    ----------
    n_levels : int
        Number ``L`` of threshold levels ``q_1 < ... < q_L``. Cells are the relays
        ``(alpha, beta) = (q_i, q_j)`` with ``i >= j``: ``L (L + 1) / 2`` of them; the
        ``L`` diagonal ones are non-hysteretic steps that carry the reversible part.
    relay : {"01", "pm1"}
        Relay values ``{0, 1}`` (ref. [38], the piezo convention) or ``{-1, +1}``.
    max_memory : int
        Stored extrema (module docstring: overflow merges the innermost pair).

    Notes
    -----
    Parameters: ``offset`` ``c`` (output unit): the output at negative saturation for
    1-0 relays; with ±1 relays the output there is ``c - sum(mu)``, so ``c`` sits
    mid-stroke. ``mu`` (L(L+1)/2,) cell weights (output unit), cell ``(i, j)`` at flat
    index ``i (i + 1) / 2 + j`` (0-based). ``levels`` (L,) (V), fixed at
    :func:`default_levels`; freed, they must stay strictly increasing (a walker that
    breaks the order fails). Stroke (negative to positive saturation): ``sum(mu)``,
    twice that for ±1 relays. Default prior of every weight: Normal with mean
    ``y_span / n_cells`` (a uniform density reproducing the data's stroke) and standard
    deviation ``y_span / sqrt(n_cells)``, halved for ±1 relays: the prior stroke then has
    a spread of one data span, and a single cell can carry ``~ y_span / L``, what a
    density concentrated on the diagonal (a mostly reversible response) needs.
    Linear in ``(c, mu)`` for fixed levels: :meth:`regressors`.
    """

    name: ClassVar[str] = "preisach"
    has_output_offset: ClassVar[bool] = True
    # for fixed levels, y = [1, relay outputs] @ [offset, mu] (regressors: Eq. 3)
    linear_params: ClassVar[tuple[str, ...]] = ("offset", "mu")
    equation: ClassVar[str] = "review Eq. 1-4, 7-8"
    _bilinear: ClassVar[bool] = False
    n_levels: int = 12
    relay: str = "01"
    max_memory: int = 256

    def __post_init__(self) -> None:
        check_count(self.n_levels, "n_levels")
        if self.relay not in ("01", "pm1"):
            raise ModelError(f"relay must be '01' or 'pm1', got {self.relay!r}")
        _check_memory_setting(self.max_memory)

    @property
    def n_cells(self) -> int:
        """Number of relays ``L (L + 1) / 2``."""
        return self.n_levels * (self.n_levels + 1) // 2

    def param_space(self, data: Any = None) -> ParamSpace:
        """``offset``, cell weights ``mu`` (n_cells,) and the fixed ``levels`` (n_levels,).

        Priors as in the class Notes, scaled from ``data``; ``levels`` at
        :func:`default_levels`. ``data`` as in :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        nc = self.n_cells
        half = 2.0 if self.relay == "pm1" else 1.0
        base = sc.y_min if self.relay == "01" else 0.5 * (sc.y_min + sc.y_max)
        return ParamSpace(
            (
                Param("offset", Normal(base, sc.y_span), unit=sc.y_unit,
                      description="output offset (at negative saturation for 1-0 relays)"),
                Param("mu", Normal(sc.y_span / (nc * half), sc.y_span / (math.sqrt(nc) * half)),
                      shape=(nc,), unit=sc.y_unit, description="relay weights, cell (i>=j)"),
            ),
            fixed={"levels": default_levels(self.n_levels, sc)},
            fixed_params=(
                Param("levels", Uniform(sc.u_min - sc.u_span, sc.u_max + sc.u_span),
                      shape=(self.n_levels,), unit=sc.u_unit,
                      description="relay threshold levels (fixed over the input range)"),
            ),
        )

    def _tables(self, theta):
        # a copy: fixed levels arrive read-only, which numba would compile separately for
        mu, levels, offset = theta["mu"], np.array(theta["levels"], dtype=float), theta["offset"]
        skip = ~(np.all(np.isfinite(mu), axis=1) & np.all(np.isfinite(levels), axis=1)
                 & np.all(np.diff(levels, axis=1) > 0, axis=1) & np.isfinite(offset))
        tables = np.empty((mu.shape[0], self.n_levels + 1, self.n_levels + 1))
        relay_everett_tables(mu, tables)
        coef = np.zeros((mu.shape[0], 3))
        if self.relay == "01":
            coef[:, 0] = offset
            coef[:, 2] = 1.0
        else:
            # gamma = 2 * gamma01 - 1: y = c - sum(mu) + 2 P
            coef[:, 0] = offset - tables[:, self.n_levels, 0]
            coef[:, 2] = 2.0
        return levels, tables, coef, skip

    def everett_table(self, theta: Mapping[str, Any]) -> EverettTable:
        """Step Everett table of the weights (1-0 relay sum; nodes = ``levels``)."""
        tb, _ = self._batch_theta(theta, batched=False)
        levels, tables, _, skip = self._tables(tb)
        if skip[0]:
            raise ParameterError("Preisach weights/levels must be finite, levels increasing")
        return EverettTable(levels[0], tables[0], bilinear=False)

    def cell_thresholds(self, theta: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """``(alpha, beta)`` of every cell, each shape (n_cells,), in ``mu`` order (V)."""
        q = np.asarray(theta["levels"], dtype=float)
        i, j = np.tril_indices(self.n_levels)
        return q[i], q[j]


@register
@dataclass(frozen=True)
class PreisachDensity(_Staircase, HysteresisModel):
    r"""Preisach model with a parametric density, plus a reversible linear part.

    .. math::  y = c + k_{rev} u + s \frac{\int\!\!\int_{T_+} \mu(\alpha, \beta)}
               {\int\!\!\int_{T} \mu(\alpha, \beta)}

    (review Eq. 3–4 with 1-0 relays, ref. [38]; evaluated by Eq. 7–8 with a bilinearly
    interpolated Everett function, ref. [40]). ``T`` is the bounded plane
    ``lo <= beta <= alpha <= hi``, ``T_+`` its switched-on part. In ``c = (alpha+beta)/2``
    and ``r = (alpha-beta)/2`` the density is a bivariate Gaussian of ``(c, log r)``
    (``shape="lognormal"``) or of ``(c, r)`` truncated to ``r > 0`` (``"gaussian"``),
    with correlation ``rho``. Normalising over ``T`` makes ``s`` the hysteretic stroke.

    Parameters
    ----------
    n_grid : int
        Intervals of the uniform grid on which the Everett function is integrated
        (2×2 Gauss per cell) and interpolated; cost ``~ n_grid^2`` per parameter vector.
    shape : {"lognormal", "gaussian"}
        Distribution of the half-width ``r``.
    max_memory : int
        Stored extrema (module docstring).

    Notes
    -----
    Parameters: ``offset`` ``c`` (output unit), ``k_rev`` (output unit/V), ``scale``
    ``s`` (output unit), ``centre`` and ``sd_centre`` (V) of ``c``, ``halfwidth`` (V; the
    median of ``r`` for log-normal, the mean before truncation for Gaussian),
    ``sd_log_halfwidth`` (1) or ``sd_halfwidth`` (V), ``rho`` (1), and the fixed
    ``bounds`` ``(lo, hi)`` (V) of the plane: the data's input range widened by 5 % of
    the span on each side. ``rho != 0`` or a ``centre`` off the middle of the range give
    asymmetric loops. A density whose mass inside ``T`` underflows fails the walker.
    """

    name: ClassVar[str] = "preisach_density"
    has_output_offset: ClassVar[bool] = True
    equation: ClassVar[str] = "review Eq. 3-4, 7-8"
    _bilinear: ClassVar[bool] = True
    n_grid: int = 64
    shape: str = "lognormal"
    max_memory: int = 256

    def __post_init__(self) -> None:
        check_count(self.n_grid, "n_grid")
        if self.n_grid < 2:
            raise ModelError(f"n_grid must be >= 2, got {self.n_grid}")
        if self.shape not in ("lognormal", "gaussian"):
            raise ModelError(f"shape must be 'lognormal' or 'gaussian', got {self.shape!r}")
        _check_memory_setting(self.max_memory)

    @property
    def _spread(self) -> str:
        return "sd_log_halfwidth" if self.shape == "lognormal" else "sd_halfwidth"

    def param_space(self, data: Any = None) -> ParamSpace:
        """The density, stroke and offset parameters of the class Notes, and the fixed ``bounds``.

        Prior means split the data's stroke 30 % reversible, 70 % hysteretic; ``bounds`` is
        the input range widened by 5 % of the span on each side. ``data`` as in
        :meth:`HysteresisModel.param_space`.
        """
        sc = data_scales(data)
        g, span = sc.gain, sc.u_span
        gu = sc.gain_unit
        if self.shape == "lognormal":
            spread = Param(self._spread, LogNormal.from_median(0.5, 0.5), unit="1",
                           description="standard deviation of log half-width")
        else:
            spread = Param(self._spread, LogNormal.from_median(0.1 * span, 0.7), unit=sc.u_unit,
                           description="standard deviation of the half-width")
        margin = 0.05 * span
        return ParamSpace(
            (
                # prior means split the data's stroke 30 % reversible, 70 % hysteretic
                Param("offset", Normal(sc.y_min - 0.3 * g * sc.u_min, sc.y_span),
                      unit=sc.y_unit, description="output at u = 0, negative saturation"),
                Param("k_rev", Normal(0.3 * g, 0.3 * g), unit=gu,
                      description="reversible (linear) slope"),
                Param("scale", LogNormal.from_median(0.7 * sc.y_span, 0.5), unit=sc.y_unit,
                      description="hysteretic stroke (output span of the relays)"),
                Param("centre", Normal(0.5 * (sc.u_min + sc.u_max), 0.25 * span),
                      unit=sc.u_unit, description="mean relay centre (alpha+beta)/2"),
                Param("sd_centre", LogNormal.from_median(0.2 * span, 0.5), unit=sc.u_unit,
                      description="standard deviation of relay centres"),
                Param("halfwidth", LogNormal.from_median(0.1 * span, 0.7), unit=sc.u_unit,
                      description="typical relay half-width (alpha-beta)/2"),
                spread,
                Param("rho", Uniform(-0.9, 0.9), unit="1",
                      description="correlation of centre and half-width (asymmetry)"),
            ),
            fixed={"bounds": np.array([sc.u_min - margin, sc.u_max + margin])},
            fixed_params=(
                Param("bounds", Uniform(sc.u_min - span, sc.u_max + span), shape=(2,),
                      unit=sc.u_unit, description="input range (lo, hi) of the Preisach plane"),
            ),
        )

    def _tables(self, theta):
        width = theta["offset"].shape[0]
        bounds = theta["bounds"]
        lognormal = self.shape == "lognormal"
        hw = theta["halfwidth"]
        dens = np.stack([theta["centre"], theta["sd_centre"],
                         np.log(np.where(hw > 0, hw, 1.0)) if lognormal else hw,
                         theta[self._spread], theta["rho"]], axis=1)
        coef = np.stack([theta["offset"], theta["k_rev"], theta["scale"]], axis=1)
        skip = ~(np.all(np.isfinite(dens), axis=1) & np.all(np.isfinite(coef), axis=1)
                 & np.all(np.isfinite(bounds), axis=1) & (bounds[:, 1] > bounds[:, 0])
                 & (dens[:, 1] > 0) & (dens[:, 3] > 0) & (np.abs(dens[:, 4]) < 1)
                 & (hw > 0))
        frac = np.linspace(0.0, 1.0, self.n_grid + 1)
        nodes = bounds[:, :1] + (bounds[:, 1:] - bounds[:, :1]) * frac
        nodes[:, -1] = bounds[:, 1]
        # invalid walkers get harmless stand-ins so that the kernel never divides by 0
        nodes[skip] = frac
        dens[skip] = (0.5, 1.0, 0.0, 1.0, 0.0)
        tables = np.empty((width, self.n_grid + 1, self.n_grid + 1))
        ok = np.zeros(width, dtype=bool)
        dens = np.ascontiguousarray(dens)
        density_everett_tables(nodes, dens, lognormal, tables, ok)
        return nodes, tables, np.ascontiguousarray(coef), skip | ~ok

    def everett_table(self, theta: Mapping[str, Any]) -> EverettTable:
        """Bilinear Everett table of the normalised density (``Y`` rises 0 -> 1)."""
        tb, _ = self._batch_theta(theta, batched=False)
        nodes, tables, _, skip = self._tables(tb)
        if skip[0]:
            raise ParameterError("density parameters are invalid or give no mass in the plane")
        return EverettTable(nodes[0], tables[0], bilinear=True)
