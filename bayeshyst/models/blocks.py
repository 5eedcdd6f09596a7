"""Effect blocks: linear dynamics, creep, drift, delay and output maps that follow a model.

A block maps the output ``w`` of whatever precedes it (a hysteresis model or another
block) to a new signal, sample by sample, with an explicit state (MODELS.md §7, review
Eq. 56–57). Blocks compose with any :class:`~bayeshyst.models.base.HysteresisModel` in
:class:`~bayeshyst.models.compose.Composite`.

Conventions shared by every block:

* **The hysteresis model carries gain and offset.** Every linear block passes a
  constant input unchanged once settled (ARX ``B(1) = A(1)``, second order
  ``G(0) = 1``, creep banks settle to ``w``); drift has no constant term and the output
  map has unit slope and no offset at the data's centre. So no block parameter trades
  off against the base model's gain (a ridge in the posterior otherwise).
* **Steady initial state.** ``_initial_state(theta, w0, t0)`` is the state after the
  input ``w0`` was held since forever; the first sample then outputs the steady value.
* **Exact continuation.** The state holds everything the block remembers (previous
  time, input and output histories, cached step), so applying a record in pieces,
  down to one sample at a time (the ``step`` of numerical inversion), gives the same
  output as one call.
* **Failures are flagged, not raised.** A parameter vector outside the valid set
  (unstable, non-monotone, too long a delay) or a non-finite output sets ``failed``.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models._kernels.blocks import (
    arx_batch,
    arx_polynomials,
    asym_output_batch,
    delay_batch,
    drift_batch,
    lag_bank_batch,
    second_order_batch,
)
from bayeshyst.models.base import Trajectory, data_scales
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace, Uniform

__all__ = [
    "ARX",
    "DEFAULT_DT",
    "DEFAULT_DURATION",
    "AsymmetricOutput",
    "Creep",
    "Delay",
    "Drift",
    "EffectBlock",
    "FractionalCreep",
    "SecondOrder",
    "TimeScales",
    "block_class",
    "block_names",
    "register_block",
    "time_scales",
]

#: Sampling period assumed when no data is given (s): a 10 kHz piezo rig.
DEFAULT_DT = 1e-4
#: Record duration assumed when no data is given (s).
DEFAULT_DURATION = 10.0


@dataclass(frozen=True)
class TimeScales:
    """Sampling period ``dt`` (s, the finest median step) and ``duration`` (s, longest record)."""

    dt: float = DEFAULT_DT
    duration: float = DEFAULT_DURATION

    @property
    def fs(self) -> float:
        """Sampling rate (Hz)."""
        return 1.0 / self.dt


def time_scales(data: Any = None) -> TimeScales:
    """Time scales of a Record, a Dataset or any object with ``t``; defaults for None.

    Raises
    ------
    ParameterError
        If the times do not increase.
    """
    if data is None or not (hasattr(data, "t") or hasattr(data, "records")):
        return TimeScales()
    records = list(data) if hasattr(data, "records") else [data]
    dts, durations = [], []
    for rec in records:
        t = np.asarray(rec.t, dtype=float)
        if t.size >= 2:
            dts.append(float(np.median(np.diff(t))))
            durations.append(float(t[-1] - t[0]))
    if not dts:
        return TimeScales()
    dt, duration = min(dts), max(durations)
    if not (dt > 0 and math.isfinite(duration)):
        raise ParameterError(f"sample times must increase; median step {dt}")
    return TimeScales(dt, duration)


def _check_int(value: Any, what: str, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ModelError(f"{what} must be an integer >= {minimum}, got {value!r}")


# ------------------------------------------------------------------------ base class


@dataclass(frozen=True)
class EffectBlock(ABC):
    """A causal single-input single-output block with explicit state.

    Class attributes
    ----------------
    name : str
        Name in spec strings (``"pi_play+arx"``) and the parameter namespace.
    rate_dependent : bool
        Whether the output depends on the time axis (or on the sample count).
    equation : str
        What the block implements, for docs.
    """

    name: ClassVar[str] = ""
    rate_dependent: ClassVar[bool] = True
    equation: ClassVar[str] = ""

    @property
    @abstractmethod
    def state_size(self) -> int:
        """Number of state entries ``S`` (fixed by the structural settings)."""

    @abstractmethod
    def param_space(self, data: Any = None) -> ParamSpace:
        """Declared parameters with priors scaled from ``data`` (Record, Dataset or None)."""

    @abstractmethod
    def _initial_state(self, theta: Mapping[str, np.ndarray], w0: np.ndarray,
                       t0: float) -> np.ndarray:
        """Steady state (W, S) for the input ``w0`` (W,) held since forever, at time ``t0``.

        ``t0`` may be NaN: the state is then taken to be at the first sample's time.
        """

    @abstractmethod
    def _apply(self, w: np.ndarray, t: np.ndarray, theta: Mapping[str, np.ndarray],
               state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Apply to ``w`` (W, N) at times ``t`` (N,) from ``state`` (W, S).

        Returns ``out (W, N)``, the final state ``(W, S)`` and ``failed (W,)``; the
        arguments are not modified. ``theta`` holds float64 arrays with a leading W axis.
        """

    # ------------------------------------------------------------------ conveniences
    @functools.cached_property
    def _shapes(self) -> dict[str, tuple[int, ...]]:
        space = self.param_space()
        return {n: space[n].shape for n in space.all_names}

    def _batch_theta(self, theta: Mapping[str, Any], width: int | None) -> dict:
        missing = [n for n in self._shapes if n not in theta]
        unknown = [n for n in theta if n not in self._shapes]
        if missing or unknown:
            raise ParameterError(f"{self.name}: theta is missing {missing} / has unknown "
                                 f"{unknown}; expected {list(self._shapes)}")
        out = {}
        for n, shape in self._shapes.items():
            arr = np.asarray(theta[n], dtype=np.float64)
            arr = arr[None, ...] if width is None else arr
            if arr.shape[1:] != shape or (width is not None and arr.shape[0] != width):
                raise ParameterError(f"{self.name}: theta[{n!r}] has shape {np.shape(theta[n])}"
                                     f", expected {(('W',) if width else ()) + shape}")
            out[n] = np.ascontiguousarray(arr)
        return out

    def initial_state(self, theta: Mapping[str, Any], w0: float,
                      t0: float = math.nan) -> np.ndarray:
        """Steady state (S,) of one parameter vector for the input ``w0`` held since forever."""
        tb = self._batch_theta(theta, None)
        return self._initial_state(tb, np.array([float(w0)]), float(t0))[0]

    def apply(self, w: Any, t: Any, theta: Mapping[str, Any], *,
              state0: np.ndarray | None = None) -> Trajectory:
        """Apply the block to one signal ``w`` (N,) at times ``t`` (N,) (s).

        ``state0`` (S,) defaults to the steady state at ``w[0]``. Raises
        :class:`SimulationError` if the parameter vector fails.
        """
        traj = self.apply_batch(np.asarray(w, float)[None, :], t, self._batch_theta(theta, None),
                                state0=None if state0 is None else np.asarray(state0)[None])
        if traj.failed[0]:
            raise SimulationError(f"{self.name}: block failed for theta={dict(theta)}")
        return Trajectory(traj.y[0], traj.state[0], np.asarray(False))

    def apply_batch(self, w: Any, t: Any, thetas: Mapping[str, Any], *,
                    state0: np.ndarray | None = None) -> Trajectory:
        """Apply ``W`` parameter vectors (arrays ``(W, *shape)``) to ``w`` (W, N) or (N,)."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        w = np.asarray(w, dtype=np.float64)
        if thetas:
            width = int(np.shape(next(iter(thetas.values())))[0])
        else:  # a block without parameters: the walkers are the rows of w
            width = w.shape[0] if w.ndim == 2 else 1
        if (t.ndim != 1 or t.size == 0 or w.shape[-1:] != t.shape or w.ndim > 2
                or not (np.all(np.isfinite(t)) and np.all(np.isfinite(w)))):
            raise ParameterError(f"w {w.shape} and t {t.shape} must be finite, t 1-D and "
                                 "non-empty, w (N,) or (W, N) with N = len(t)")
        w = np.ascontiguousarray(np.broadcast_to(w, (width, t.size)))
        tb = self._batch_theta(thetas, width)
        s0 = (self._initial_state(tb, w[:, 0].copy(), math.nan) if state0 is None
              else np.ascontiguousarray(state0, dtype=np.float64))
        if s0.shape != (width, self.state_size):
            raise ParameterError(f"{self.name}: state0 must have shape ({width}, "
                                 f"{self.state_size}), got {s0.shape}")
        y, state, failed = self._apply(w, t, tb, s0)
        return Trajectory(y, state, failed)

    def describe(self) -> str:
        """Name, equation and the default parameter table."""
        return f"{self.name}  ({type(self).__name__}; {self.equation})\n{self.param_space()}"


_BLOCKS: dict[str, type[EffectBlock]] = {}


def register_block(cls: type[EffectBlock]) -> type[EffectBlock]:
    """Class decorator adding an effect block under its ``name``."""
    if not cls.name or (cls.name in _BLOCKS and _BLOCKS[cls.name] is not cls):
        raise ModelError(f"block {cls.__name__}: name {cls.name!r} is empty or taken")
    _BLOCKS[cls.name] = cls
    return cls


def block_names() -> list[str]:
    """Registered effect-block names, sorted."""
    return sorted(_BLOCKS)


def block_class(name: str) -> type[EffectBlock]:
    """The block class registered under ``name``; ModelError listing the valid names."""
    try:
        return _BLOCKS[name]
    except KeyError:
        raise ModelError(f"unknown effect block {name!r}; valid blocks: "
                         f"{', '.join(block_names())}") from None


def _new(w: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (np.empty_like(w), np.array(state, dtype=np.float64, order="C"),
            np.zeros(w.shape[0], dtype=bool))


def _col(theta: Mapping[str, np.ndarray], name: str, width: int) -> np.ndarray:
    """A (W, n) parameter array, or (W, 0) when the block declares none of that name."""
    if name in theta:
        return np.ascontiguousarray(theta[name], dtype=np.float64).reshape(width, -1)
    return np.empty((width, 0))


# -------------------------------------------------------------------------------- ARX


@register_block
@dataclass(frozen=True)
class ARX(EffectBlock):
    """ARX linear dynamics ``A(q^-1) y_k = B(q^-1) w_{k-nk}`` (review Eq. 56–57).

    ``A = 1 + a_1 q^-1 + ... + a_na q^-na``, ``B = b_0 + ... + b_{nb-1} q^-(nb-1)``;
    the noise term ``e`` of Eq. 56 belongs to the likelihood, not here.

    Parameters
    ----------
    na : int
        Order of ``A`` (0 for a finite impulse response).
    nb : int
        Number of ``B`` coefficients (>= 1).
    nk : int
        Input delay in samples.

    Notes
    -----
    Parametrised so that **every draw is stable with unit DC gain**:

    * ``kappa`` (na,) in (-1, 1): reflection coefficients, mapped to ``A`` by the
      step-up recursion ``a^(m)_i = a^(m-1)_i + kappa_m a^(m-1)_(m-i)``,
      ``a^(m)_m = kappa_m``. ``A`` has all roots inside the unit circle iff every
      ``|kappa_m| < 1`` (Schur–Cohn), and every stable ``A`` has exactly one such
      ``kappa``, so no stable filter is lost and no unstable one is proposed.
    * ``beta`` (nb - 1,): shares of the static gain on the lagged inputs,
      ``b = A(1) [1 - sum(beta), beta_1, ..., beta_{nb-1}]``, so ``B(1) / A(1) = 1``.
      A free ``B`` would multiply the hysteresis gain by ``B(1)/A(1)``: only their
      product is identifiable, and the posterior would be a ridge.

    Priors: ``kappa`` uniform on (-1, 1), no preferred pole location (the logit
    transform lets the sampler approach the unit circle, where the poles of slow
    dynamics sampled fast lie); ``beta ~ Normal(0, 0.5)``. Coefficients are per sample:
    the block assumes the data's uniform rate and ignores ``t``. State: the last ``na``
    outputs and ``nk + nb - 1`` inputs, oldest first.
    """

    name: ClassVar[str] = "arx"
    equation: ClassVar[str] = "review Eq. 56-57"
    na: int = 2
    nb: int = 2
    nk: int = 0

    def __post_init__(self) -> None:
        _check_int(self.na, "ARX na", 0)
        _check_int(self.nb, "ARX nb", 1)
        _check_int(self.nk, "ARX nk", 0)

    @property
    def state_size(self) -> int:
        return self.na + self.nk + self.nb - 1

    def param_space(self, data: Any = None) -> ParamSpace:
        params = []
        if self.na:
            params.append(Param("kappa", Uniform(-1.0, 1.0), shape=(self.na,), unit="1",
                                description="reflection coefficients of A (stable iff |k|<1)"))
        if self.nb > 1:
            params.append(Param("beta", Normal(0.0, 0.5), shape=(self.nb - 1,), unit="1",
                                description="shares of the unit DC gain on lagged inputs"))
        return ParamSpace(tuple(params))

    def polynomials(self, theta: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """``(a, b)`` of one parameter vector: ``a`` (na + 1,) with ``a_0 = 1``, ``b`` (nb,).

        Raises ParameterError if a reflection coefficient is outside (-1, 1).
        """
        tb = self._batch_theta(theta, None)
        a, b = np.empty(self.na + 1), np.empty(self.nb)
        if not arx_polynomials(_col(tb, "kappa", 1)[0], _col(tb, "beta", 1)[0], a, b):
            raise ParameterError(f"ARX: reflection coefficients must lie in (-1, 1): {theta}")
        return a, b

    def _initial_state(self, theta, w0, t0):
        # unit DC gain: the settled output equals the held input
        return np.repeat(np.asarray(w0, float)[:, None], self.state_size, axis=1)

    def _apply(self, w, t, theta, state):
        out, st, failed = _new(w, state)
        width = w.shape[0]
        arx_batch(w, _col(theta, "kappa", width), _col(theta, "beta", width), self.nk,
                  st, out, failed)
        return out, st, failed


# ----------------------------------------------------------------------- second order


@register_block
@dataclass(frozen=True)
class SecondOrder(EffectBlock):
    """Second-order dynamics ``G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)``, ``wn = 2 pi f_n``.

    Discretised exactly: the input is held between samples (ZOH) and the state is
    propagated by the matrix exponential, in closed form for under-, critically and
    over-damped ``zeta`` (MODELS.md §7). Any sampling, uniform or not, is exact: the
    discretisation is cached per distinct step and recomputed when the step changes.

    Notes
    -----
    Parameters: ``f_n`` (Hz), log-normal prior with median ``fs / 20`` (a tenth of the
    data's Nyquist frequency; ``fs = 10 kHz`` without data) and a factor-e spread, so
    about 1 % of the prior lies above Nyquist; ``zeta`` (1), log-normal with median 0.3
    (piezo stages are lightly damped; 11 % prior mass is over-damped). ``G(0) = 1``.
    With ZOH the output at ``t_k`` depends on inputs up to ``w_{k-1}`` only (strictly
    proper). State: ``[y, dy/dt, w_prev, t_prev, h_ref]``.
    """

    name: ClassVar[str] = "second_order"
    equation: ClassVar[str] = "wn^2/(s^2 + 2 zeta wn s + wn^2), exact ZOH"

    @property
    def state_size(self) -> int:
        return 5

    def param_space(self, data: Any = None) -> ParamSpace:
        fs = time_scales(data).fs
        return ParamSpace((
            Param("f_n", LogNormal.from_median(fs / 20.0, 1.0), unit="Hz",
                  description="natural frequency (prior median a tenth of Nyquist)"),
            Param("zeta", LogNormal.from_median(0.3, 1.0), unit="1",
                  description="damping ratio"),
        ))

    def _initial_state(self, theta, w0, t0):
        s = np.zeros((w0.shape[0], 5))
        s[:, 0] = w0
        s[:, 2] = w0
        s[:, 3] = t0
        s[:, 4] = np.nan
        return s

    def _apply(self, w, t, theta, state):
        out, st, failed = _new(w, state)
        wn = 2.0 * np.pi * np.ascontiguousarray(theta["f_n"], dtype=np.float64)
        second_order_batch(w, t, wn, np.ascontiguousarray(theta["zeta"]), st, out, failed)
        return out, st, failed


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
    """Creep as a bank of first-order lags with fixed log-spaced time constants.

    .. math::  y = w + \\sum_j c_j (x_j - w), \\qquad \\tau_j \\dot x_j = w - x_j

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
    equation: ClassVar[str] = "y = w + sum c_j (x_j - w), tau_j x_j' = w - x_j"
    n_terms: int = 3
    tau_min: float | None = None
    tau_max: float | None = None

    def __post_init__(self) -> None:
        _check_int(self.n_terms, "creep n_terms", 1)
        for v in (self.tau_min, self.tau_max):
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ModelError(f"creep time constants must be positive and finite, got {v}")
        if None not in (self.tau_min, self.tau_max) and self.tau_min > self.tau_max:
            raise ModelError(f"creep needs tau_min <= tau_max, got {self.tau_min} > "
                             f"{self.tau_max}")

    @property
    def state_size(self) -> int:
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
        out, st, failed = _new(w, state)
        width = w.shape[0]
        lag_bank_batch(w, t, _col(theta, "c", width), _col(theta, "tau", width), st, out,
                       failed)
        return out, st, failed


@register_block
@dataclass(frozen=True)
class FractionalCreep(EffectBlock):
    """Fractional-order creep ``y = w + gain (x - w)``, ``x = w / (tau s^lam + 1)``.

    The step response of ``1 / (tau s^lam + 1)`` is ``1 - E_lam(-(t/tau)^lam)`` (Mittag-
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
    equation: ClassVar[str] = "y = w + gain (w/(tau s^lam + 1) - w), diffusive modes"
    n_modes: int = 41
    per_decade: float = 4.0

    def __post_init__(self) -> None:
        _check_int(self.n_modes, "creep_fractional n_modes", 3)
        if not (math.isfinite(self.per_decade) and self.per_decade > 0):
            raise ModelError(f"per_decade must be positive, got {self.per_decade!r}")

    @property
    def state_size(self) -> int:
        return self.n_modes + 3

    def param_space(self, data: Any = None) -> ParamSpace:
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
        out, st, failed = _new(w, state)
        taus, weights, _ = self.modes(theta["tau"], theta["lam"])
        c = np.ascontiguousarray(np.asarray(theta["gain"], float)[:, None] * weights)
        # invalid rows carry NaN time constants, which the kernel flags as failed
        lag_bank_batch(w, t, c, np.ascontiguousarray(taus), st, out, failed)
        return out, st, failed


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
    equation: ClassVar[str] = "y = (1 + g(s)) w + d(s), s = (t - t0)/T"
    order: int = 1

    def __post_init__(self) -> None:
        _check_int(self.order, "drift order", 1)

    @property
    def state_size(self) -> int:
        return 1

    def param_space(self, data: Any = None) -> ParamSpace:
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
        out, st, failed = _new(w, state)
        width = w.shape[0]
        drift_batch(w, t, _col(theta, "g", width), _col(theta, "d", width),
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
    equation: ClassVar[str] = "y(t) = w(t - d)"
    max_delay_samples: int = 10

    def __post_init__(self) -> None:
        _check_int(self.max_delay_samples, "max_delay_samples", 1)

    @property
    def state_size(self) -> int:
        return 2 * (self.max_delay_samples + 1)

    def param_space(self, data: Any = None) -> ParamSpace:
        top = self.max_delay_samples * time_scales(data).dt
        return ParamSpace((Param("d", Uniform(0.0, top), unit="s",
                                 description="time delay (fractional samples allowed)"),))

    def _initial_state(self, theta, w0, t0):
        h = self.max_delay_samples + 1
        s = np.full((w0.shape[0], 2 * h), -np.inf)
        s[:, h:] = np.asarray(w0, float)[:, None]
        return s

    def _apply(self, w, t, theta, state):
        out, st, failed = _new(w, state)
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
        _check_int(self.order, "asym_output order", 2)

    @property
    def state_size(self) -> int:
        return 0

    def param_space(self, data: Any = None) -> ParamSpace:
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
        out, st, failed = _new(w, state)
        width = w.shape[0]
        a = np.ascontiguousarray(np.column_stack(
            [np.asarray(theta[f"a{i}"], float).reshape(width) for i in range(2, self.order + 1)]))
        asym_output_batch(w, a, np.ascontiguousarray(theta["centre"], dtype=np.float64),
                          np.ascontiguousarray(theta["half_span"], dtype=np.float64),
                          out, failed)
        return out, st, failed
