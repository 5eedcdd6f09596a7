"""Creep blocks: a bank of first-order lags and fractional-order creep (MODELS.md §7)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError
from bayeshyst.models._kernels.blocks import lag_bank_batch
from bayeshyst.models.base import check_count, kernel_buffers
from bayeshyst.models.blocks.base import (
    EffectBlock,
    param_columns,
    register_block,
    time_scales,
)
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = ["Creep", "FractionalCreep"]


# ------------------------------------------------------------------------------ creep


def _lag_state(w0: np.ndarray, n: int, t0: float) -> np.ndarray:
    s = np.empty((w0.shape[0], n + 3))
    s[:, : n + 1] = np.asarray(w0, float)[:, None]
    s[:, n + 1] = t0
    s[:, n + 2] = np.nan
    return s


@register_block
@dataclass(frozen=True)
class Creep(EffectBlock):
    r"""Creep as a bank of first-order lags with fixed log-spaced time constants.

    .. math::  y = w + \sum_j c_j (x_j - w), \qquad \tau_j \dot x_j = w - x_j

    i.e. ``G(s) = 1 - sum_j c_j tau_j s / (tau_j s + 1)`` (MODELS.md §7), linear in the
    gains ``c``. Each lag is discretised exactly (ZOH on ``w``), for any sampling.

    Parameters
    ----------
    n_terms : int
        Number of lags.
    tau_min, tau_max : float, optional
        Range of the time constants (s), log-spaced. Default: ``tau_max`` the longest
        record's duration and ``tau_min = max(tau_max / 10^(n_terms - 1), 10 dt)``
        (one lag per decade, none faster than ten samples); without data
        ``dt = 1e-4 s`` and a 10 s record.

    Notes
    -----
    **Output convention.** ``y = w + sum c_j (x_j - w)`` has unit static gain: once
    settled ``x_j = w`` and ``y = w``, so the hysteresis model keeps the static gain,
    as with every other block, and the relaxed start needs no offset. A step of size
    ``S`` gives ``y = S (1 - sum_j c_j exp(-t / tau_j))``: an immediate ``(1 - sum c) S``,
    then creep upwards for ``c > 0``. With one lag per decade and equal ``c_j = gamma``
    this climbs by about ``gamma S`` per decade of time between ``tau_min`` and
    ``tau_max``, the logarithmic creep ``y(t0)(1 + gamma log10(t/t0))`` of piezo stacks.
    (The alternative ``y = w + sum c_j x_j`` keeps the instantaneous gain instead and
    puts ``1 + sum c`` into the static one, which trades off against the hysteresis gain.)
    Prior: ``c_j ~ Normal(0.015 D, 0.02 D)`` with ``D`` decades per lag (typical creep
    is 1–2 % of a step per decade). The time constants ``tau`` (n,) (s) are a fixed
    parameter. State: ``[x_1 .. x_n, w_prev, t_prev, h_ref]``.
    """

    name: ClassVar[str] = "creep"
    affine: ClassVar[bool] = True
    #: the output is linear in the gains given the input: the sampler draws them exactly
    #: when they are the composite's largest linear group (Bouc–Wen + creep: three gains
    #: against one ``k``; measured on the 150 V piezo with a discrepancy, 250 steps to
    #: converge instead of 1 483)
    linear_params: ClassVar[tuple[str, ...]] = ("c",)
    equation: ClassVar[str] = "y = w + sum c_j (x_j - w), tau_j x_j' = w - x_j"
    n_terms: int = 3
    tau_min: float | None = None
    tau_max: float | None = None

    def __post_init__(self) -> None:
        check_count(self.n_terms, "creep n_terms", minimum=1)
        for v in (self.tau_min, self.tau_max):
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ModelError(f"creep time constants must be positive and finite, got {v}")
        if None not in (self.tau_min, self.tau_max) and self.tau_min > self.tau_max:
            raise ModelError(f"creep needs tau_min <= tau_max, got {self.tau_min} > "
                             f"{self.tau_max}")

    @property
    def state_size(self) -> int:
        """``n_terms + 3``: the lags, the previous input and time, and ``h_ref``."""
        return self.n_terms + 3

    def time_constants(self, data: Any = None) -> np.ndarray:
        """The fixed time constants ``tau`` (n_terms,) (s) for ``data``."""
        ts = time_scales(data)
        hi = self.tau_max if self.tau_max is not None else ts.duration
        lo = self.tau_min
        if lo is None:
            lo = min(hi, max(hi / 10.0 ** max(self.n_terms - 1, 1), 10.0 * ts.dt))
        if lo > hi:
            raise ModelError(f"creep: tau_min {lo} exceeds tau_max {hi} for these data")
        if self.n_terms == 1:
            return np.array([math.sqrt(lo * hi)])
        return np.geomspace(lo, hi, self.n_terms)

    def param_space(self, data: Any = None) -> ParamSpace:
        """Free gains ``c`` (n_terms,) and the fixed time constants ``tau`` (n_terms,) (s).

        The prior of ``c`` is ``Normal(0.015 D, 0.02 D)`` with ``D`` decades per lag; ``tau``
        is :meth:`time_constants` for ``data`` (Record, Dataset or None).
        """
        tau = self.time_constants(data)
        n = self.n_terms
        dec = math.log10(tau[-1] / tau[0]) / (n - 1) if n > 1 and tau[-1] > tau[0] else 1.0
        return ParamSpace(
            (Param("c", Normal(0.015 * dec, 0.02 * dec), shape=(n,), unit="1",
                   description="creep gain of each lag (fraction of a step)"),),
            fixed={"tau": tau},
            fixed_params=(Param("tau", LogNormal.from_median(float(np.sqrt(tau[0] * tau[-1])),
                                                             2.0),
                                shape=(n,), unit="s",
                                description="time constants, log-spaced (fixed)"),),
        )

    def _initial_state(self, theta, w0, t0):
        return _lag_state(w0, self.n_terms, t0)

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        width = w.shape[0]
        lag_bank_batch(w, t, param_columns(theta, "c", width),
                       param_columns(theta, "tau", width), st, out, failed)
        return out, st, failed


@register_block
@dataclass(frozen=True)
class FractionalCreep(EffectBlock):
    """Fractional-order creep ``y = w + gain (x - w)``, ``x = w / ((tau s)^lam + 1)``.

    ``tau`` is a time constant (s) at every order; MODELS.md's ``1/(tau' s^lam + 1)`` is
    the same family with ``tau' = tau^lam`` (s^lam, a unit that changes with the order).
    The step response of ``1 / ((tau s)^lam + 1)`` is ``1 - E_lam(-(t/tau)^lam)`` (Mittag-
    Leffler), which is completely monotone:
    ``E_lam(-(t/tau)^lam) = int_0^inf exp(-r t / tau) K(r) dr`` with the spectral density
    ``K(r) = sin(lam pi) r^(lam-1) / (pi (r^(2 lam) + 2 r^lam cos(lam pi) + 1))``. The
    block discretises this *diffusive representation*: rates on a fixed log grid
    ``r_i = 10^(i / per_decade)`` (``r = 1`` always a node) with the exact mass of ``K``
    in each cell as weight, ``F(r) = [atan2(r^lam + cos(lam pi), sin(lam pi)) - pi/2 +
    lam pi] / (lam pi)``; the two end cells take all mass beyond the grid. Each mode is
    a first-order lag of time constant ``tau / r_i`` discretised exactly (ZOH), so
    non-uniform sampling is exact, the cost is ``n_modes`` per sample (no growing
    Grünwald–Letnikov memory), and ``lam = 1`` is exactly the first-order lag.

    Parameters
    ----------
    n_modes : int
        Number of modes (odd keeps the grid symmetric about ``tau``).
    per_decade : float
        Grid density in rate; the grid spans ``n_modes / per_decade`` decades of time
        centred on ``tau``.

    Notes
    -----
    Parameters: ``gain`` (1), Normal(0.05, 0.05): the creep fraction of a step;
    ``tau`` (s), log-normal with median a tenth of the longest record; ``lam`` (1) in
    (0, 1], uniform. Same output convention as :class:`Creep` (unit static gain).
    State: ``[x_1 .. x_n, w_prev, t_prev, h_ref]``.
    """

    name: ClassVar[str] = "creep_fractional"
    affine: ClassVar[bool] = True
    equation: ClassVar[str] = "y = w + gain (w/((tau s)^lam + 1) - w), diffusive modes"
    n_modes: int = 41
    per_decade: float = 4.0

    def __post_init__(self) -> None:
        check_count(self.n_modes, "creep_fractional n_modes", minimum=3)
        if not (math.isfinite(self.per_decade) and self.per_decade > 0):
            raise ModelError(f"per_decade must be positive, got {self.per_decade!r}")

    @property
    def state_size(self) -> int:
        """``n_modes + 3``: the modes, the previous input and time, and ``h_ref``."""
        return self.n_modes + 3

    def param_space(self, data: Any = None) -> ParamSpace:
        """``gain``, ``tau`` (s) and ``lam`` with the priors of the class Notes.

        The median of ``tau`` is a tenth of the longest record of ``data`` (Record, Dataset
        or None).
        """
        ts = time_scales(data)
        return ParamSpace((
            Param("gain", Normal(0.05, 0.05), unit="1",
                  description="creep fraction of a step (settled minus instantaneous)"),
            Param("tau", LogNormal.from_median(ts.duration / 10.0, 2.0), unit="s",
                  description="characteristic creep time"),
            Param("lam", Uniform(0.0, 1.0), unit="1", description="fractional order"),
        ))

    def modes(self, tau: Any, lam: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time constants (W, n) (s), weights (W, n) summing to 1, and validity (W,)."""
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        lam = np.atleast_1d(np.asarray(lam, dtype=float))
        ok = (tau > 0) & np.isfinite(tau) & (lam > 0) & (lam <= 1)
        lam_ok = np.where(ok, lam, 0.5)[:, None]
        k = np.arange(self.n_modes) - (self.n_modes - 1) // 2
        edges = 10.0 ** ((k[:-1] + 0.5) / self.per_decade)
        phi = np.pi * lam_ok
        cdf = (np.arctan2(edges[None, :] ** lam_ok + np.cos(phi), np.sin(phi))
               - 0.5 * np.pi + phi) / phi
        # F is increasing in [0, 1]; clip and accumulate only undo rounding (small lam)
        cdf = np.maximum.accumulate(np.clip(cdf, 0.0, 1.0), axis=1)
        weights = np.diff(cdf, prepend=0.0, append=1.0, axis=1)
        taus = np.where(ok, tau, np.nan)[:, None] / 10.0 ** (k[None, :] / self.per_decade)
        return taus, weights, ok

    def _initial_state(self, theta, w0, t0):
        return _lag_state(w0, self.n_modes, t0)

    def _apply(self, w, t, theta, state):
        out, st, failed = kernel_buffers(state, w.shape[1])
        taus, weights, _ = self.modes(theta["tau"], theta["lam"])
        c = np.ascontiguousarray(np.asarray(theta["gain"], float)[:, None] * weights)
        # invalid rows carry NaN time constants, which the kernel flags as failed
        lag_bank_batch(w, t, c, np.ascontiguousarray(taus), st, out, failed)
        return out, st, failed
