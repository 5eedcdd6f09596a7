"""Blocks driven by something other than the input: a measured column, a moment in time.

Review §3 names temperature and mechanical load as changing a piezo loop's slope and
width; a stage's file often carries them as extra columns. :class:`AuxInput` lets the
gain and offset follow such a column (``aux(column=temperature_c)``), and
:class:`ChangePoint` lets them change once, at an unknown time (a load clamped on, a
sensor re-mounted); :class:`Disturbance` adds a periodic disturbance at a frequency the
excitation does not explain (mains pickup). All are stateless output maps, affine in
their input, so a model that is linear in some parameters stays so after them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError
from bayeshyst.models.base import check_count, data_scales
from bayeshyst.models.blocks.base import (
    EffectBlock,
    param_columns,
    register_block,
    time_scales,
)
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["AuxInput", "ChangePoint", "Disturbance", "change_step", "column_scales"]

#: Prior scale of the relative gain change per standard deviation of the column (and of
#: a change point's gain step): 5 % -- temperature coefficients of piezo stacks are
#: ~0.1-1 %/K over swings of a few kelvin (review §3).
GAIN_PRIOR = 0.05
#: Prior scale of the offset change, as a fraction of the output span.
OFFSET_PRIOR = 0.05

_COLUMN = re.compile(r"^[^\s=+(),'\"]+(?: [^=+(),'\"]+)*$")


def column_scales(data: Any, column: str) -> tuple[float, float]:
    """Mean and standard deviation of ``column`` over every record of ``data``.

    ``(0, 1)`` when ``data`` is None or a record lacks the column (the block then has
    no data to scale to; its simulations need the column anyway). A constant column
    gets scale 1.
    """
    if data is None:
        return 0.0, 1.0
    records = list(data) if hasattr(data, "records") else [data]
    cols = [getattr(r, "covariates", {}).get(column) for r in records]
    if any(c is None for c in cols):
        return 0.0, 1.0
    values = np.concatenate([np.asarray(c, float) for c in cols])
    sd = float(np.std(values))
    return float(np.mean(values)), (sd if sd > 0 else 1.0)


def _powers(z: np.ndarray, order: int) -> np.ndarray:
    """``z, z^2, ..., z^order`` stacked on a new first axis (order, ...)."""
    return np.stack([z ** (i + 1) for i in range(order)])


@register_block
@dataclass(frozen=True)
class AuxInput(EffectBlock):
    """Gain and offset as smooth functions of a measured column (temperature, load, ...).

    ``y = (1 + g(z)) w + h(z)``, ``z = (c - c_ref) / c_scale``, with
    ``g(z) = sum_{i=1..order} g_i z^i`` and ``h(z) = sum_{i=1..order} h_i z^i``: no
    constant terms, so the hysteresis model owns gain and offset at the column's
    reference value (the data's mean) and the block only their change with it. Review
    §3: temperature and mechanical load change the loop's slope.

    Parameters
    ----------
    column : str
        Name of the column in the data file (``Record.covariates``).
    order : int
        Polynomial order in the standardised column.

    Notes
    -----
    ``c_ref`` and ``c_scale`` are fixed parameters: the column's mean and standard
    deviation over the fitted data, so ``g_1`` is the relative gain change per standard
    deviation (``100 g_1 / c_scale`` per cent per unit of the column, e.g. %/K).
    Priors ``g_i ~ Normal(0, 0.05)``, ``h_i ~ Normal(0, 0.05 y_span)``. Simulated
    without the column (a feedforward command for a future run), the block holds it at
    ``c_ref``: the actuator at its nominal conditions, which is then the identity.
    """

    name: ClassVar[str] = "aux"
    affine: ClassVar[bool] = True
    rate_dependent: ClassVar[bool] = False
    equation: ClassVar[str] = "y = (1 + g(z)) w + h(z), z = (c - c_ref) / c_scale"
    example: ClassVar[Mapping[str, Any]] = MappingProxyType({"column": "temperature_c"})
    column: str = ""
    order: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.column, str) or not _COLUMN.match(self.column):
            raise ModelError(f"aux: column must name a data column (no '=', '+', "
                             f"parentheses, commas or quotes), got {self.column!r}")
        check_count(self.order, "aux order", minimum=1)

    @property
    def covariates(self) -> tuple[str, ...]:
        """The one column the block reads."""
        return (self.column,)

    @property
    def state_size(self) -> int:
        """0: the block has no memory."""
        return 0

    def param_space(self, data: Any = None) -> ParamSpace:
        """Gain ``g`` (order,), offset ``h`` (order,), fixed ``c_ref`` and ``c_scale``."""
        sc = data_scales(data)
        ref, scale = column_scales(data, self.column)
        n = self.order
        return ParamSpace(
            (Param("g", Normal(0.0, GAIN_PRIOR), shape=(n,), unit="1",
                   description=f"relative gain change per sd of {self.column}, z^1..z^order"),
             Param("h", Normal(0.0, OFFSET_PRIOR * sc.y_span), shape=(n,), unit=sc.y_unit,
                   description=f"offset change per sd of {self.column}, z^1..z^order")),
            fixed={"c_ref": ref, "c_scale": scale},
            fixed_params=(
                Param("c_ref", Normal(ref, scale), unit=self.column,
                      description="reference value of the column (fixed: its mean)"),
                Param("c_scale", LogNormal.from_median(scale, 1.0), unit=self.column,
                      description="scale of the column (fixed: its standard deviation)")),
        )

    def _initial_state(self, theta, w0, t0):
        return np.zeros((w0.shape[0], 0))

    def _apply(self, w, t, theta, state):
        # nominal conditions: the column at its reference, where g and h vanish
        return (np.array(w, dtype=np.float64), np.zeros((w.shape[0], 0)),
                ~np.all(np.isfinite(w), axis=1))

    def _apply_with(self, w, t, theta, state, covariates):
        if covariates is None:
            return self._apply(w, t, theta, state)
        width = w.shape[0]
        ref = np.asarray(theta["c_ref"], float).reshape(width, 1)
        scale = np.asarray(theta["c_scale"], float).reshape(width, 1)
        z = (np.asarray(covariates[self.column], float)[None, :] - ref) / scale
        zp = _powers(z, self.order)                                       # (order, W, N)
        g = param_columns(theta, "g", width).T[:, :, None]               # (order, W, 1)
        h = param_columns(theta, "h", width).T[:, :, None]
        with np.errstate(over="ignore", invalid="ignore"):
            out = w * (1.0 + np.sum(g * zp, axis=0)) + np.sum(h * zp, axis=0)
        failed = ~np.all(np.isfinite(out), axis=1)
        return np.ascontiguousarray(out), np.zeros((width, 0)), failed


@register_block
@dataclass(frozen=True)
class ChangePoint(EffectBlock):
    """A step in gain and offset at an unknown time (a load clamped on, a re-mounted sensor).

    ``y = (1 + g S(t)) w + h S(t)``, ``S(t) = (1 + tanh((t - t_c) / (2 width))) / 2``:
    a logistic step of ``width`` a few samples, smooth so that the change time has a
    continuous likelihood between samples.

    Notes
    -----
    ``t_c ~ Uniform`` over the data's time span (absolute times, every record on the same
    clock); ``g ~ Normal(0, 0.05)``, ``h ~ Normal(0, 0.05 y_span)``; ``width`` is fixed
    at 2 sampling periods.
    """

    name: ClassVar[str] = "change_point"
    affine: ClassVar[bool] = True
    rate_dependent: ClassVar[bool] = True
    equation: ClassVar[str] = "y = (1 + g S(t - t_c)) w + h S(t - t_c)"

    @property
    def state_size(self) -> int:
        """0: the step depends on absolute time only."""
        return 0

    def param_space(self, data: Any = None) -> ParamSpace:
        """Change time ``t_c`` (s), gain step ``g``, offset step ``h``, fixed ``width`` (s)."""
        sc, ts = data_scales(data), time_scales(data)
        if data is None:
            lo, hi = 0.0, ts.duration
        else:
            records = list(data) if hasattr(data, "records") else [data]
            lo = min(float(r.t[0]) for r in records)
            hi = max(float(r.t[-1]) for r in records)
        return ParamSpace(
            (Param("t_c", Uniform(lo, hi), unit="s", description="time of the change"),
             Param("g", Normal(0.0, GAIN_PRIOR), unit="1",
                   description="relative gain change at t_c"),
             Param("h", Normal(0.0, OFFSET_PRIOR * sc.y_span), unit=sc.y_unit,
                   description="offset change at t_c")),
            fixed={"width": 2.0 * ts.dt},
            fixed_params=(Param("width", LogNormal.from_median(2.0 * ts.dt, 1.0), unit="s",
                                description="duration of the step (fixed: 2 samples)"),),
        )

    def _initial_state(self, theta, w0, t0):
        return np.zeros((w0.shape[0], 0))

    def _apply(self, w, t, theta, state):
        width = w.shape[0]
        tc = np.asarray(theta["t_c"], float).reshape(width)
        wd = np.asarray(theta["width"], float).reshape(width)
        # the step once per distinct (t_c, width): a linear block's design pushes each of
        # its columns through with the walker's values repeated, and the tanh was most
        # of this block's cost (the same formula per row, so the same bits)
        pairs, rows = np.unique(np.stack([tc, wd], axis=1), axis=0, return_inverse=True)
        step = 0.5 * (1.0 + np.tanh((np.asarray(t, float)[None, :] - pairs[:, :1])
                                    / (2.0 * pairs[:, 1:])))[rows.reshape(width)]
        g = np.asarray(theta["g"], float).reshape(width, 1)
        h = np.asarray(theta["h"], float).reshape(width, 1)
        out = w * (1.0 + g * step) + h * step
        failed = ~np.all(np.isfinite(out), axis=1)
        return np.ascontiguousarray(out), np.zeros((width, 0)), failed


def change_step(t: np.ndarray, t_c: float, width: float) -> np.ndarray:
    """The block's step ``S(t)`` for one change time (the diagnosis' score regressor)."""
    if not (math.isfinite(t_c) and width > 0):
        raise ModelError(f"change_step: t_c must be finite and width > 0, got {t_c}, {width}")
    return 0.5 * (1.0 + np.tanh((np.asarray(t, float) - t_c) / (2.0 * width)))


@register_block
@dataclass(frozen=True)
class Disturbance(EffectBlock):
    """A periodic disturbance added to the output: mains pickup, a pump, a floor mode.

    ``y = w + a sin(2 pi f t) + b cos(2 pi f t)`` at a fixed frequency ``f`` (found in
    the residual's spectrum, :func:`~bayeshyst.diagnosis.drivers.spectral_lines`),
    absolute time. Priors ``a, b ~ Normal(0, 0.05 y_span)``. A command designed with it
    would try to cancel it, which only works for a disturbance locked to the clock of the
    record; design feedforward from the model without this block otherwise.

    Parameters
    ----------
    frequency_hz : float
        Frequency of the disturbance (Hz), > 0.
    """

    name: ClassVar[str] = "disturbance"
    affine: ClassVar[bool] = True
    rate_dependent: ClassVar[bool] = True
    equation: ClassVar[str] = "y = w + a sin(2 pi f t) + b cos(2 pi f t)"
    frequency_hz: float = 50.0

    def __post_init__(self) -> None:
        f = self.frequency_hz
        if isinstance(f, bool) or not isinstance(f, int | float) or not (
                math.isfinite(f) and f > 0):
            raise ModelError(f"disturbance: frequency_hz must be a positive number, got {f!r}")

    @property
    def state_size(self) -> int:
        """0: the disturbance depends on absolute time only."""
        return 0

    def param_space(self, data: Any = None) -> ParamSpace:
        """Sine and cosine amplitudes ``a``, ``b`` (output unit)."""
        sc = data_scales(data)
        prior = Normal(0.0, OFFSET_PRIOR * sc.y_span)
        return ParamSpace(
            (Param("a", prior, unit=sc.y_unit, description="sine amplitude"),
             Param("b", prior, unit=sc.y_unit, description="cosine amplitude")))

    def _initial_state(self, theta, w0, t0):
        return np.zeros((w0.shape[0], 0))

    def _apply(self, w, t, theta, state):
        width = w.shape[0]
        phase = 2.0 * math.pi * float(self.frequency_hz) * np.asarray(t, float)[None, :]
        a = np.asarray(theta["a"], float).reshape(width, 1)
        b = np.asarray(theta["b"], float).reshape(width, 1)
        out = w + a * np.sin(phase) + b * np.cos(phase)
        return (np.ascontiguousarray(out), np.zeros((width, 0)),
                ~np.all(np.isfinite(out), axis=1))
