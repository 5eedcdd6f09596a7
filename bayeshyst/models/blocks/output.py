"""Blocks acting on the output over time or amplitude: drift, delay, asymmetric output map."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.models._kernels.blocks import asym_output_batch, delay_batch, drift_batch
from bayeshyst.models.base import check_count, data_scales, kernel_buffers
from bayeshyst.models.blocks.base import (
    EffectBlock,
    param_columns,
    register_block,
    time_scales,
)
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, ProbitTransform, Uniform

__all__ = ["AsymmetricOutput", "Delay", "Drift"]


# ---------------------------------------------------------------------- drift, delay


@register_block
@dataclass(frozen=True)
class Drift(EffectBlock):
    """Slow drift of gain and offset: ``y = (1 + g(s)) w + d(s)``, ``s = (t - t_0) / T``.

    ``g(s) = sum_{i=1..order} g_i s^i`` and ``d(s) = sum_{i=1..order} d_i s^i`` have no
    constant term: the static model owns the gain and the offset at the start, the
    block only their variation over time (thermal or load effects, MODELS.md §7).

    Parameters
    ----------
    order : int
        Polynomial order in the normalised time.

    Notes
    -----
    ``t_0`` is the first sample's time and is kept in the state (continuation works);
    ``T`` is a fixed parameter ``t_scale`` (s), the longest record's duration, so ``s``
    runs over ``[0, 1]``. Priors: ``g_i ~ Normal(0, 0.02)`` (2 % gain change over a
    record), ``d_i ~ Normal(0, 0.02 y_span)`` (output unit).
    """

    name: ClassVar[str] = "drift"
    affine: ClassVar[bool] = True
    equation: ClassVar[str] = "y = (1 + g(s)) w + d(s), s = (t - t0)/T"
    order: int = 1

    def __post_init__(self) -> None:
        check_count(self.order, "drift order", minimum=1)

    @property
    def state_size(self) -> int:
        """1: the first sample's time ``t_0``."""
        return 1

    def param_space(self, data: Any = None) -> ParamSpace:
        """Gain drift ``g`` (order,), offset drift ``d`` (order,) and the fixed ``t_scale`` (s).

        ``t_scale`` is the longest record's duration in ``data`` (Record, Dataset or None)
        and the prior of ``d`` scales with its output span (class Notes).
        """
        sc, ts = data_scales(data), time_scales(data)
        n = self.order
        return ParamSpace(
            (Param("g", Normal(0.0, 0.02), shape=(n,), unit="1",
                   description="relative gain drift, coefficients of s^1..s^order"),
             Param("d", Normal(0.0, 0.02 * sc.y_span), shape=(n,), unit=sc.y_unit,
                   description="offset drift, coefficients of s^1..s^order")),
            fixed={"t_scale": ts.duration},
            fixed_params=(Param("t_scale", LogNormal.from_median(ts.duration, 1.0), unit="s",
                                description="time normalisation (fixed: record duration)"),),
        )

    def _initial_state(self, theta, w0, t0):
        return np.full((w0.shape[0], 1), t0)

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        width = w.shape[0]
        drift_batch(w, t, param_columns(theta, "g", width), param_columns(theta, "d", width),
                    np.ascontiguousarray(theta["t_scale"], dtype=np.float64).reshape(width),
                    st, out, failed)
        return out, st, failed


@register_block
@dataclass(frozen=True)
class Delay(EffectBlock):
    """Pure time delay ``y(t) = w(t - d)``, linear interpolation between past samples.

    Parameters
    ----------
    max_delay_samples : int
        Longest delay in samples of the data; the state keeps this many past samples
        plus one, so any ``d`` within the prior is covered.

    Notes
    -----
    ``d`` (s) ~ Uniform(0, max_delay_samples dt). Before the first sample the input is
    held at its initial value. A delay reaching further back than the stored history
    (possible only if the signal is sampled faster than the data behind the prior)
    fails the walker rather than being clipped. State: the last ``H`` times and inputs.
    """

    name: ClassVar[str] = "delay"
    affine: ClassVar[bool] = True
    needs_preview: ClassVar[bool] = True
    equation: ClassVar[str] = "y(t) = w(t - d)"
    max_delay_samples: int = 10

    def __post_init__(self) -> None:
        check_count(self.max_delay_samples, "max_delay_samples", minimum=1)

    @property
    def state_size(self) -> int:
        """``2 (max_delay_samples + 1)``: the last ``H`` times and inputs."""
        return 2 * (self.max_delay_samples + 1)

    def param_space(self, data: Any = None) -> ParamSpace:
        """The delay ``d`` (s), uniform on ``[0, max_delay_samples dt]`` for ``dt`` of ``data``."""
        top = self.max_delay_samples * time_scales(data).dt
        # probit: with no delay in the data the posterior lies against d = 0, where a
        # logit coordinate's exponential tail sends walkers on long excursions
        return ParamSpace((Param("d", Uniform(0.0, top), unit="s",
                                 transform=ProbitTransform(0.0, top),
                                 description="time delay (fractional samples allowed)"),))

    def _initial_state(self, theta, w0, t0):
        h = self.max_delay_samples + 1
        s = np.full((w0.shape[0], 2 * h), -np.inf)
        s[:, h:] = np.asarray(w0, float)[:, None]
        return s

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        delay_batch(w, t, np.ascontiguousarray(theta["d"], dtype=np.float64), st, out, failed)
        return out, st, failed


# --------------------------------------------------------------------- output map


@register_block
@dataclass(frozen=True)
class AsymmetricOutput(EffectBlock):
    """Static monotone polynomial output map ``y = c + h P((w - c) / h)``.

    ``P(x) = x + a_2 x^2 + ... + a_n x^n`` on the output normalised to the data's range
    (``c`` its centre, ``h`` its half-span, fixed parameters ``centre`` and
    ``half_span``): even terms bend the two halves of the stroke differently
    (asymmetric loops, MODELS.md §6), odd terms saturate both.

    Parameters
    ----------
    order : int
        Polynomial order ``n >= 2``.

    Notes
    -----
    The linear coefficient is 1 (the hysteresis model carries the gain) and ``P(0) = 0``.
    The map must be increasing over the data's range ``x in [-1, 1]`` (otherwise it is
    not invertible and the loop folds): a draw whose ``P'`` is not provably positive
    there (grid check with a bound on ``P''``; see the kernel) is flagged failed, i.e.
    the prior is effectively truncated to monotone maps. Priors
    ``a_i ~ Normal(0, 0.15 / i)`` leave under 1e-5 of their mass non-monotone.
    """

    name: ClassVar[str] = "asym_output"
    rate_dependent: ClassVar[bool] = False
    equation: ClassVar[str] = "y = c + h (x + a_2 x^2 + ...), x = (w - c)/h"
    order: int = 3

    def __post_init__(self) -> None:
        check_count(self.order, "asym_output order", minimum=2)

    @property
    def state_size(self) -> int:
        """0: the map is static."""
        return 0

    def param_space(self, data: Any = None) -> ParamSpace:
        """Coefficients ``a2..an`` and the fixed ``centre`` and ``half_span`` of the output.

        ``centre`` and ``half_span`` are those of the output range of ``data`` (Record,
        Dataset or None); priors as in the class Notes.
        """
        sc = data_scales(data)
        coef = tuple(Param(f"a{i}", Normal(0.0, 0.15 / i), unit="1",
                           description=f"coefficient of x^{i} (normalised output)")
                     for i in range(2, self.order + 1))
        centre, half = 0.5 * (sc.y_min + sc.y_max), 0.5 * sc.y_span
        return ParamSpace(coef, fixed={"centre": centre, "half_span": half}, fixed_params=(
            Param("centre", Normal(centre, half), unit=sc.y_unit,
                  description="centre of the data's output range (fixed)"),
            Param("half_span", LogNormal.from_median(half, 1.0), unit=sc.y_unit,
                  description="half the data's output span (fixed)"),
        ))

    def _initial_state(self, theta, w0, t0):
        return np.empty((w0.shape[0], 0))

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        width = w.shape[0]
        a = np.ascontiguousarray(np.column_stack(
            [np.asarray(theta[f"a{i}"], float).reshape(width) for i in range(2, self.order + 1)]))
        asym_output_batch(w, a, np.ascontiguousarray(theta["centre"], dtype=np.float64),
                          np.ascontiguousarray(theta["half_span"], dtype=np.float64),
                          out, failed)
        return out, st, failed
