"""The virtual actuator's effects: parameters, their checks, numerics and ``truth()``.

Public through :mod:`bayeshyst.data.virtual`, which assembles them into the actuator;
their time loops are in :mod:`bayeshyst.data._virtual_kernels` (an implementation
independent of :mod:`bayeshyst.models`, so that tests of the models compare two codes).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from bayeshyst.data._virtual_kernels import ar1, static_path
from bayeshyst.errors import ParameterError

__all__ = [
    "STROKE_UM",
    "AR1Noise",
    "LogCreep",
    "PreisachHysteresis",
    "SecondOrder",
    "SensorDelay",
    "ThermalDrift",
    "preisach_offset",
]


#: Nominal quasi-static stroke of the default actuator, 0 -> 150 V major loop [um].
STROKE_UM = 40.0


def _check(owner: str, name: str, value: float, lo: float = 0.0, *, strict: bool = True,
           hi: float = math.inf) -> None:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < lo or (strict and value == lo) or value >= hi:
        bound = f"> {lo}" if strict else f">= {lo}"
        upper = "" if hi == math.inf else f" and < {hi}"
        raise ParameterError(f"{owner}.{name}: expected a finite number {bound}{upper}, "
                             f"got {value!r}")


def _asdict(obj: Any) -> dict[str, Any]:
    return {f.name: (list(v) if isinstance(v := getattr(obj, f.name), tuple) else v)
            for f in dataclasses.fields(obj)}


@dataclass(frozen=True)
class PreisachHysteresis:
    """Preisach operator of 0/1 relays with a smooth, skewed density.

    In the mean/half-width coordinates ``m = (alpha + beta) / 2``, ``r = (alpha - beta)/2``
    the relay density is ``mass_um * N(m; center_v, center_sd_v) * LN(r | m)``, where
    ``LN`` is a log-normal in ``r`` with median
    ``halfwidth_v * exp(halfwidth_slope * (m - center_v) / center_sd_v)`` and log-sd
    ``halfwidth_log_sd``. The centre below mid-range and the half-width growing with
    ``m`` make the loop asymmetric (not point-symmetric). In ``(alpha, beta)`` the
    density is half of that (Jacobian 2). It is truncated to the triangle
    ``plane_v[0] <= beta <= alpha <= plane_v[1]``; inputs outside are clamped (the
    Preisach part saturates). The virgin state is "input risen from below the plane",
    and the output is offset so that the virgin actuator reads 0 um at 0 V.

    Parameters
    ----------
    mass_um : float, default 18.5
        Mass of the untruncated density [um] (the default plane keeps 97.6 % of it:
        the largest possible swing of the Preisach part).
    center_v : float, default 60.0
        Mean of the relay centres ``m`` [V].
    center_sd_v : float, default 45.0
        Standard deviation of ``m`` [V].
    halfwidth_v : float, default 13.0
        Median relay half-width ``r`` at ``m = center_v`` [V].
    halfwidth_log_sd : float, default 0.6
        Standard deviation of ``ln r`` [-].
    halfwidth_slope : float, default 0.3
        Growth of ``ln(median r)`` per ``center_sd_v`` of ``m`` [-] (asymmetry).
    plane_v : (float, float), default (-50, 200)
        Input range of the Preisach plane [V].
    table_step_v : float, default 0.5
        Grid step of the tabulated Everett function [V] (cells integrated by 3x3
        Gauss-Legendre, bilinear interpolation between nodes).
    """

    mass_um: float = 18.5
    center_v: float = 60.0
    center_sd_v: float = 45.0
    halfwidth_v: float = 13.0
    halfwidth_log_sd: float = 0.6
    halfwidth_slope: float = 0.3
    plane_v: tuple[float, float] = (-50.0, 200.0)
    table_step_v: float = 0.5

    def __post_init__(self) -> None:
        me = type(self).__name__
        _check(me, "mass_um", self.mass_um, strict=False)
        _check(me, "center_v", self.center_v, -math.inf)
        for name in ("center_sd_v", "halfwidth_v", "halfwidth_log_sd", "table_step_v"):
            _check(me, name, getattr(self, name))
        _check(me, "halfwidth_slope", self.halfwidth_slope, -math.inf)
        lo, hi = (float(v) for v in self.plane_v)
        if not (math.isfinite(lo) and math.isfinite(hi) and hi - lo >= 4 * self.table_step_v):
            raise ParameterError(f"{me}.plane_v: expected finite (lo, hi) with hi - lo >= "
                                 f"4 table steps, got {self.plane_v!r}")
        object.__setattr__(self, "plane_v", (lo, hi))

    def density(self, alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """Relay density ``mu(alpha, beta)`` [um/V^2], zero off the truncated triangle.

        Parameters
        ----------
        alpha, beta : array_like of float
            Up and down switching thresholds [V] (broadcast together).

        Returns
        -------
        ndarray
        """
        a, b = np.broadcast_arrays(np.asarray(alpha, float), np.asarray(beta, float))
        m = 0.5 * (a + b)
        r = 0.5 * (a - b)
        lo, hi = self.plane_v
        inside = (r > 0) & (b >= lo) & (a <= hi)
        rs = np.where(inside, r, 1.0)
        zm = (m - self.center_v) / self.center_sd_v
        med = self.halfwidth_v * np.exp(self.halfwidth_slope * zm)
        zr = np.log(rs / med) / self.halfwidth_log_sd
        pdf = (np.exp(-0.5 * zm * zm) / (self.center_sd_v * math.sqrt(2 * math.pi))
               * np.exp(-0.5 * zr * zr) / (rs * self.halfwidth_log_sd * math.sqrt(2 * math.pi)))
        return np.where(inside, 0.5 * self.mass_um * pdf, 0.0)

    def everett(self) -> tuple[np.ndarray, float, float]:
        """Tabulated Everett function ``E(alpha_i, beta_j)`` (read-only, cached).

        Returns
        -------
        table : ndarray, shape (K+1, K+1)
            Relay mass of ``{beta_j <= b <= a <= alpha_i}`` [um].
        lo, step : float
            Node ``i`` is at ``lo + i * step`` [V].
        """
        return _everett_table(self)

    def truth(self) -> dict[str, Any]:
        """Parameters and the density formula, JSON-serialisable."""
        return {
            **_asdict(self),
            "relay": "0/1 (on at u >= alpha, off at u <= beta)",
            "density": "mass_um * N(m; center_v, center_sd_v) * LogNormal(r; median="
                       "halfwidth_v*exp(halfwidth_slope*(m-center_v)/center_sd_v), "
                       "sigma=halfwidth_log_sd), m=(alpha+beta)/2, r=(alpha-beta)/2",
            "initial_state": "input risen from below the plane; output 0 at 0 V",
            # rounded: a derived number, kept stable across platforms' last bits
            "offset_um": round(preisach_offset(self), 9),
        }


@functools.lru_cache(maxsize=8)
def _everett_table(hyst: PreisachHysteresis) -> tuple[np.ndarray, float, float]:
    lo, hi = hyst.plane_v
    k = max(4, round((hi - lo) / hyst.table_step_v))
    step = (hi - lo) / k
    nodes = lo + step * np.arange(k + 1)
    x, wts = np.polynomial.legendre.leggauss(3)
    pts = 0.5 * step * (x + 1.0)  # Gauss points inside a cell, from its lower edge
    wq = 0.25 * step * step * np.outer(wts, wts)
    cells = np.zeros((k, k))  # cells[a-cell, b-cell]
    for p in range(3):
        for s in range(3):
            a = nodes[:-1, None] + pts[p]
            b = nodes[None, :-1] + pts[s]
            cells += wq[p, s] * hyst.density(a, b)
    # diagonal cells straddle alpha = beta; the density vanishes there (log-normal in
    # r), so the masked Gauss rule above is accurate without a triangle rule
    table = np.zeros((k + 1, k + 1))
    table[1:, :k] = np.cumsum(np.cumsum(cells[:, ::-1], axis=1)[:, ::-1], axis=0)
    table.flags.writeable = False
    return table, float(lo), float(step)


@functools.lru_cache(maxsize=8)
def preisach_offset(hyst: PreisachHysteresis) -> float:
    """Preisach output of the virgin actuator at 0 V [um], subtracted from every output."""
    table, lo, step = _everett_table(hyst)
    return float(static_path(np.zeros(1), table, lo, step)[0])


@dataclass(frozen=True)
class LogCreep:
    """Creep: a bank of first-order lags that approximates ``1 + gamma log10(t)``.

    ``z = w + sum_j c_j x_j`` with ``tau_j dx_j/dt = w - x_j``, ``tau_j`` log-spaced
    from ``tau_min_s`` to ``tau_max_s`` at ``lags_per_decade`` per decade and equal
    weights ``c_j = per_decade / lags_per_decade``; between ~3 tau_min and
    ~tau_max / 3 a held step creeps by ``per_decade`` of the static step per decade.

    Parameters
    ----------
    per_decade : float, default 0.015
        Creep per decade of time, fraction of the static displacement [-].
    tau_min_s, tau_max_s : float, default 0.01, 1000
        Shortest and longest lag time constant [s].
    lags_per_decade : int, default 2
        Lag density; 2 keeps the log-time ripple below ~1 %.
    """

    per_decade: float = 0.015
    tau_min_s: float = 0.01
    tau_max_s: float = 1000.0
    lags_per_decade: int = 2

    def __post_init__(self) -> None:
        me = type(self).__name__
        _check(me, "per_decade", self.per_decade, strict=False)
        _check(me, "tau_min_s", self.tau_min_s)
        _check(me, "tau_max_s", self.tau_max_s, self.tau_min_s, strict=False)
        if not isinstance(self.lags_per_decade, int) or self.lags_per_decade < 1:
            raise ParameterError(f"{me}.lags_per_decade: expected an int >= 1, "
                                 f"got {self.lags_per_decade!r}")

    @property
    def taus_s(self) -> np.ndarray:
        """Lag time constants [s], shape (L,)."""
        decades = math.log10(self.tau_max_s / self.tau_min_s)
        n = max(1, round(decades * self.lags_per_decade) + 1)
        lo, hi = math.log10(self.tau_min_s), math.log10(self.tau_max_s)
        step = (hi - lo) / (n - 1) if n > 1 else 0.0
        # Python's float power (the C library's pow, correctly rounded here) and not
        # np.logspace: numpy's vectorised power differs in the last bit between releases
        # (10**2.5 came out as ...379 on numpy 2.4), and the bundled files must regenerate
        # bit for bit on any supported numpy
        return np.array([10.0 ** (lo + k * step) for k in range(n)])

    @property
    def weights(self) -> np.ndarray:
        """Lag weights ``c_j`` [-], shape (L,)."""
        return np.full(self.taus_s.size, self.per_decade / self.lags_per_decade)

    def truth(self) -> dict[str, Any]:
        """Parameters, time constants and weights, JSON-serialisable."""
        return {**_asdict(self), "tau_s": self.taus_s.tolist(),
                "weights": self.weights.tolist(),
                "form": "z = w + sum_j c_j x_j, tau_j x_j' = w - x_j, relaxed start"}


@dataclass(frozen=True)
class SecondOrder:
    """Second-order dynamics ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (unit DC gain).

    Parameters
    ----------
    resonance_hz : float, default 1500
        Undamped natural frequency ``wn / 2 pi`` [Hz].
    damping : float, default 0.07
        Damping ratio ``zeta`` [-], in (0, 1).
    """

    resonance_hz: float = 1500.0
    damping: float = 0.07

    def __post_init__(self) -> None:
        _check(type(self).__name__, "resonance_hz", self.resonance_hz)
        _check(type(self).__name__, "damping", self.damping, hi=1.0)

    def discretise(self, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact first-order-hold discretisation over a step ``h`` [s].

        Returns
        -------
        phi : ndarray, shape (2, 2)
            State transition (state: position [um], velocity [um/s]).
        gam0, gam1 : ndarray, shape (2,)
            Step update ``x+ = phi x + gam0 z_k + gam1 (z_{k+1} - z_k)``.
        """
        wn = 2 * math.pi * self.resonance_hz
        # augmented state [x, v, z, dz/dt] with z linear in time: one expm is exact
        aug = np.zeros((4, 4))
        aug[0, 1] = 1.0
        aug[1, 0] = -wn * wn
        aug[1, 1] = -2 * self.damping * wn
        aug[1, 2] = wn * wn
        aug[2, 3] = 1.0
        e = scipy.linalg.expm(aug * h)
        return e[:2, :2].copy(), e[:2, 2].copy(), e[:2, 3] / h

    def truth(self) -> dict[str, Any]:
        """Parameters, JSON-serialisable."""
        return {**_asdict(self), "discretisation": "exact first-order hold"}


@dataclass(frozen=True)
class ThermalDrift:
    """Slow thermal drift ``y -> (1 + gain_per_s s) y + offset_um_per_s s``, ``s = t - t[0]``.

    Parameters
    ----------
    offset_um_per_s : float, default 0.02
        Offset rate [um/s] (0.05 % of :data:`STROKE_UM` per second).
    gain_per_s : float, default 2e-4
        Relative sensitivity change per second [1/s] (0.02 %/s).
    """

    offset_um_per_s: float = 0.02
    gain_per_s: float = 2e-4

    def __post_init__(self) -> None:
        _check(type(self).__name__, "offset_um_per_s", self.offset_um_per_s, -math.inf)
        _check(type(self).__name__, "gain_per_s", self.gain_per_s, -math.inf)

    def truth(self) -> dict[str, Any]:
        """Parameters, JSON-serialisable."""
        return {**_asdict(self), "reference": "record start t[0]"}


@dataclass(frozen=True)
class SensorDelay:
    """Pure sensor delay.

    Parameters
    ----------
    delay_s : float, default 50e-6
        Delay [s] (one sample at 20 kHz), fractional samples allowed.
    """

    delay_s: float = 50e-6

    def __post_init__(self) -> None:
        _check(type(self).__name__, "delay_s", self.delay_s, strict=False)

    def truth(self) -> dict[str, Any]:
        """Parameters, JSON-serialisable."""
        return _asdict(self)


@dataclass(frozen=True)
class AR1Noise:
    """Stationary AR(1) sensor noise per record sample, ``e_k = phi e_{k-1} + s w_k``.

    Parameters
    ----------
    rms_um : float, default 0.04
        Stationary standard deviation [um] (0.1 % of :data:`STROKE_UM`).
    phi : float, default 0.8
        Lag-1 coefficient per record sample [-], ``|phi| < 1``.
    """

    rms_um: float = 0.04
    phi: float = 0.8

    def __post_init__(self) -> None:
        _check(type(self).__name__, "rms_um", self.rms_um, strict=False)
        _check(type(self).__name__, "phi", self.phi, -1.0, hi=1.0)

    def sample(self, n: int, rng: np.random.Generator | int) -> np.ndarray:
        """Draw ``n`` samples [um] from ``rng`` (a Generator or a seed)."""
        white = np.random.default_rng(rng).standard_normal(n)
        return ar1(white, float(self.phi), float(self.rms_um))

    def truth(self) -> dict[str, Any]:
        """Parameters, JSON-serialisable."""
        return {**_asdict(self), "innovation_sd_um": self.rms_um * math.sqrt(1 - self.phi**2),
                "start": "stationary"}
