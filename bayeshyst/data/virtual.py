"""The virtual actuator: a documented piezo-stack simulator richer than any single model.

Every test that needs ground truth (posterior coverage, model selection per frequency,
residual diagnosis that must name a hidden effect, feedforward) simulates data here,
switching effects on and off. The implementation is independent of
:mod:`bayeshyst.models` (its effects live in :mod:`bayeshyst.data._virtual_effects`,
their kernels in :mod:`bayeshyst.data._virtual_kernels`), so a model test compares two
different codes.

Signal chain (each block switchable; defaults are typical of a 150 V piezo stack with
:data:`STROKE_UM` = 40 um quasi-static stroke)::

    u(t) --delay--> static: g u + P[u] --> creep lag bank --> 2nd order --> drift --> + AR(1)

* **static** -- reversible linear part ``g u`` plus a Preisach operator ``P`` of 0/1
  relays with a smooth, skewed density (:class:`PreisachHysteresis`); hysteresis
  ~12 % of the stroke (:func:`hysteresis_percent` measures it);
* **creep** -- ``z = w + sum_j c_j x_j``, ``tau_j x_j' = w - x_j``: log-spaced lags
  (10 ms ... 1000 s) giving ~1.5 % of the step per decade of time (:class:`LogCreep`);
* **dynamics** -- ``G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)``, 1.5 kHz, zeta 0.07
  (:class:`SecondOrder`), integrated exactly (first-order hold) on an internal grid;
* **drift** -- ``y -> (1 + g_t s) y + o_t s``, ``s = t - t[0]`` (:class:`ThermalDrift`);
* **delay** -- the sensor reports the displacement ``d`` seconds old (50 us,
  :class:`SensorDelay`); the chain before drift is time-invariant, so the delay is
  applied exactly by running it on the input at ``t - d`` (linear interpolation);
* **noise** -- stationary AR(1) per record sample, 0.1 % of the stroke RMS, phi 0.8
  (:class:`AR1Noise`).

The internal grid is uniform with step ``<= 1 / internal_rate_hz`` (50 kHz: >= 20
samples per resonance period is enforced); for uniformly sampled records it contains
every record sample, the input is linear between record samples, and each record
sample is also fed to the hysteretic memory so that no reversal is lost between grid
points. (Non-uniform records: the output is interpolated linearly between grid
points.) Same ``rng`` seed -> bit-identical output.

Measured magnitudes of the default actuator (``tests/test_virtual.py`` checks them):
hysteresis 12.0 % of the 40.0 um stroke for the static map (1 Hz sine 0-150 V, last
of 3 cycles), 13.3 % with every effect on (creep widens the loop); creep 1.46 % of the
step per decade over 0.1-10 s after a 0 -> 100 V step (drift and noise off);
resonance peak 1493 Hz, gain 7.1; drift 0.02 um/s (0.05 % of the stroke per second)
plus 0.02 %/s sensitivity; delay 50 us; noise 0.040 um RMS (0.1 %), lag-1
correlation 0.8 per sample.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data import _virtual_kernels as kern
from bayeshyst.data import excitation
from bayeshyst.data._virtual_effects import (
    STROKE_UM,
    AR1Noise,
    LogCreep,
    PreisachHysteresis,
    SecondOrder,
    SensorDelay,
    ThermalDrift,
    _check,
    preisach_offset,
)
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.data.writers import write_csv
from bayeshyst.errors import DataError, ParameterError

__all__ = [
    "BUNDLE_FREQUENCIES_HZ",
    "BUNDLE_SEED",
    "EFFECTS",
    "STROKE_UM",
    "AR1Noise",
    "LogCreep",
    "PreisachHysteresis",
    "SecondOrder",
    "SensorDelay",
    "ThermalDrift",
    "VirtualActuator",
    "bundle",
    "creep_per_decade",
    "hysteresis_only",
    "hysteresis_percent",
    "loop_width",
]

_SIMULATOR = "bayeshyst.data.virtual.VirtualActuator"

#: Names of the switchable effects, in signal-chain order.
EFFECTS = ("hysteresis", "creep", "dynamics", "drift", "delay", "noise")

#: Seed of the datasets shipped in ``data/`` (``python data/make_bundle.py``).
BUNDLE_SEED = 20240611

#: Excitation frequencies of ``virtual_multifreq.csv`` [Hz].
BUNDLE_FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0, 200.0)

#: Bundle sampling: samples per cycle of the periodic files, and the rate of the steps.
_SAMPLES_PER_CYCLE = 200
_STEPS_FS_HZ = 100.0
_DECIMALS = 6  # u [V] and y [um] are stored rounded to 1e-6: far below the noise

# placeholder Everett table when hysteresis is off; read-only like the real ones, so
# that numba compiles one specialisation of the kernel, not two
_NO_TABLE = np.zeros((2, 2))
_NO_TABLE.flags.writeable = False


@dataclass(frozen=True)
class VirtualActuator:
    """A simulated piezo stack whose every effect is known and switchable.

    Fields are the true effects; ``None`` switches one off (see :data:`EFFECTS`;
    :meth:`without` and :meth:`with_effects` derive variants). With the defaults the
    0 -> 150 V quasi-static major loop spans ~:data:`STROKE_UM` = 40 um with ~12 %
    hysteresis.

    Parameters
    ----------
    gain_um_per_v : float, default 0.1708
        Reversible linear part of the static map [um/V]; stays when hysteresis is off.
    hysteresis : PreisachHysteresis or None
        The Preisach part.
    creep : LogCreep or None
        Creep lag bank, fed by the static output.
    dynamics : SecondOrder or None
        Mechanical resonance, fed by the creep output.
    drift : ThermalDrift or None
        Slow offset and gain drift.
    delay : SensorDelay or None
        Sensor delay.
    noise : AR1Noise or None
        Coloured sensor noise.
    internal_rate_hz : float, default 50000
        Minimum rate of the internal integration grid [Hz]; with dynamics on it must
        be at least 20 times ``dynamics.resonance_hz``.
    """

    gain_um_per_v: float = 0.1708
    hysteresis: PreisachHysteresis | None = field(default_factory=PreisachHysteresis)
    creep: LogCreep | None = field(default_factory=LogCreep)
    dynamics: SecondOrder | None = field(default_factory=SecondOrder)
    drift: ThermalDrift | None = field(default_factory=ThermalDrift)
    delay: SensorDelay | None = field(default_factory=SensorDelay)
    noise: AR1Noise | None = field(default_factory=AR1Noise)
    internal_rate_hz: float = 50_000.0

    def __post_init__(self) -> None:
        me = type(self).__name__
        _check(me, "gain_um_per_v", self.gain_um_per_v, -math.inf)
        _check(me, "internal_rate_hz", self.internal_rate_hz)
        kinds = (PreisachHysteresis, LogCreep, SecondOrder, ThermalDrift, SensorDelay,
                 AR1Noise)
        for name, kind in zip(EFFECTS, kinds, strict=True):
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise ParameterError(f"{me}.{name}: expected {kind.__name__} or None, "
                                     f"got {type(value).__name__}")
        if self.dynamics is not None and self.internal_rate_hz < 20 * self.dynamics.resonance_hz:
            raise ParameterError(
                f"{me}.internal_rate_hz: expected >= 20 samples per resonance period "
                f"({20 * self.dynamics.resonance_hz!r} Hz), got {self.internal_rate_hz!r}"
            )

    @classmethod
    def from_truth(cls, truth: Any) -> VirtualActuator:
        """The actuator whose :meth:`truth` is ``truth`` (as stored in a record's metadata).

        Lets a record simulated here, and saved with its sidecar, name its own plant:
        ``bayeshyst compensate`` evaluates feedforward on it.

        Parameters
        ----------
        truth : mapping
            The dict :meth:`truth` returned (derived entries such as ``tau_s`` or the
            density formula are ignored; they follow from the parameters).

        Raises
        ------
        ParameterError
            If ``truth`` is not such a dict or a value is invalid.
        """
        if not (isinstance(truth, Mapping) and truth.get("simulator") == _SIMULATOR):
            raise ParameterError(f"not a virtual-actuator truth record (expected "
                                 f"simulator {_SIMULATOR!r}): {str(truth)[:120]}")
        kinds = dict(zip(EFFECTS, (PreisachHysteresis, LogCreep, SecondOrder, ThermalDrift,
                                   SensorDelay, AR1Noise), strict=True))
        values: dict[str, Any] = {}
        for name, kind in kinds.items():
            entry = truth.get(name)
            if entry is None:
                values[name] = None
                continue
            names = {f.name for f in dataclasses.fields(kind)}
            values[name] = kind(**{k: tuple(v) if isinstance(v, list | tuple) else v
                                   for k, v in entry.items() if k in names})
        return cls(gain_um_per_v=float(truth["gain_um_per_v"]),
                   internal_rate_hz=float(truth["internal_rate_hz"]), **values)

    # -- variants ----------------------------------------------------------------
    @property
    def effects(self) -> tuple[str, ...]:
        """Names of the effects switched on, in chain order."""
        return tuple(e for e in EFFECTS if getattr(self, e) is not None)

    def without(self, *names: str) -> VirtualActuator:
        """Copy with the named effects switched off.

        Parameters
        ----------
        *names : str
            Effect names from :data:`EFFECTS`, e.g. ``without("creep", "noise")``.

        Returns
        -------
        VirtualActuator
        """
        unknown = [n for n in names if n not in EFFECTS]
        if unknown:
            raise ParameterError(f"unknown effect(s) {unknown}; expected names from {EFFECTS}")
        return dataclasses.replace(self, **dict.fromkeys(names))

    def with_effects(self, *names: str, **effects: Any) -> VirtualActuator:
        """Copy with effects switched on: by name (default settings) or by value.

        Parameters
        ----------
        *names : str
            Effects from :data:`EFFECTS` to switch on with their default settings.
        **effects
            Fields to set, e.g. ``noise=AR1Noise(rms_um=0.1)``; also
            ``gain_um_per_v`` [um/V] and ``internal_rate_hz`` [Hz].

        Returns
        -------
        VirtualActuator
            E.g. ``with_effects("drift", noise=AR1Noise(rms_um=0.1))``.
        """
        defaults = VirtualActuator()
        unknown = [n for n in names if n not in EFFECTS]
        unknown += [k for k in effects if k not in {f.name for f in dataclasses.fields(self)}]
        if unknown:
            raise ParameterError(f"unknown effect(s) {unknown}; expected names from {EFFECTS}")
        changes = {n: getattr(defaults, n) for n in names}
        return dataclasses.replace(self, **{**changes, **effects})

    # -- simulation --------------------------------------------------------------
    def static(self, u: np.ndarray) -> np.ndarray:
        """Quasi-static displacement (linear + Preisach) along an input path [um].

        Rate-independent: only the sequence of values matters, no times. The memory
        starts from the virgin state.

        Parameters
        ----------
        u : array_like of float, shape (n,)
            Input path [V].

        Returns
        -------
        ndarray, shape (n,)
        """
        u = _vector(u, "u")
        y = self.gain_um_per_v * u
        if self.hysteresis is not None:
            table, lo, step = self.hysteresis.everett()
            y = y + kern.static_path(u, table, lo, step) - preisach_offset(self.hysteresis)
        return y

    def simulate(self, t: np.ndarray, u: np.ndarray, *,
                 rng: np.random.Generator | int | None = None) -> np.ndarray:
        """Measured displacement for the drive ``u`` sampled at times ``t``.

        Parameters
        ----------
        t : array_like of float, shape (n,)
            Sample times [s], strictly increasing, ``n >= 2``.
        u : array_like of float, shape (n,)
            Drive voltage [V]; linear between samples, held at ``u[0]`` before ``t[0]``
            (the actuator rests there, relaxed).
        rng : numpy.random.Generator or int, optional
            Noise source; required when noise is on, ignored otherwise.

        Returns
        -------
        ndarray, shape (n,)
            Displacement [um].

        Raises
        ------
        DataError
            Bad ``t`` or ``u``.
        ParameterError
            Noise on and no ``rng``.
        """
        t = _vector(t, "t")
        u = _vector(u, "u")
        if u.size != t.size or t.size < 2:
            raise DataError(f"virtual actuator: expected t and u of equal length >= 2, "
                            f"got {t.size} and {u.size}")
        if not (np.diff(t) > 0).all():
            i = int(np.argmax(np.diff(t) <= 0)) + 1
            raise DataError(f"virtual actuator: t must increase strictly; sample {i} "
                            f"({t[i]!r}) follows {t[i - 1]!r}")
        if self.noise is not None and rng is None:
            raise ParameterError("rng: noise is on; pass a numpy Generator or an int seed")
        y = self._deterministic(t, u)
        if self.drift is not None:
            s = t - t[0]
            y = (1.0 + self.drift.gain_per_s * s) * y + self.drift.offset_um_per_s * s
        if self.noise is not None:
            y = y + self.noise.sample(t.size, rng)
        return y

    def _deterministic(self, t: np.ndarray, u: np.ndarray) -> np.ndarray:
        span = t[-1] - t[0]
        n = t.size
        dt = span / (n - 1)
        rate = self.internal_rate_hz
        if np.all(np.abs(t - (t[0] + dt * np.arange(n))) <= 1e-6 * dt):
            # uniform record (to rounding of the time stamps): the grid contains every
            # record sample, so outputs need no interpolation
            n_sub = max(1, math.ceil(dt * rate * (1 - 1e-12)))
            q = np.arange(n, dtype=float) * n_sub
            h = span / (n_sub * (n - 1))
        else:
            steps = max(1, math.ceil(span * rate))
            h = span / steps
            q = (t - t[0]) / h
            near = np.rint(q)
            q = np.where(np.abs(q - near) < 1e-6, near, q)
        n_grid = round(q[-1]) + 1
        if self.hysteresis is not None:
            table, lo, step = self.hysteresis.everett()
            offset = preisach_offset(self.hysteresis)
        else:
            table, lo, step, offset = _NO_TABLE, 0.0, 1.0, 0.0
        if self.creep is not None:
            taus = self.creep.taus_s
            lag_a = np.exp(-h / taus)
            lag_b = 1.0 - taus * (1.0 - lag_a) / h
            lag_c = self.creep.weights
        else:
            lag_a = lag_b = lag_c = np.zeros(0)
        if self.dynamics is not None:
            phi, gam0, gam1 = self.dynamics.discretise(h)
        else:
            phi, gam0, gam1 = np.eye(2), np.zeros(2), np.zeros(2)
        d = 0.0 if self.delay is None else self.delay.delay_s
        return kern.run_chain(t, u, q, t[0] - d, h, n_grid, table, lo, step, offset,
                              float(self.gain_um_per_v), self.hysteresis is not None,
                              lag_a, lag_b, lag_c, self.dynamics is not None,
                              phi, gam0, gam1)

    def record(self, t: np.ndarray, u: np.ndarray, *,
               rng: np.random.Generator | int | None = None, name: str = "virtual",
               warmup: int = 0, frequency_hz: float | None = None,
               metadata: dict[str, Any] | None = None) -> Record:
        """Simulate and wrap as a :class:`~bayeshyst.data.record.Record`.

        Parameters
        ----------
        t, u, rng
            As in :meth:`simulate` (s, V).
        name : str, default "virtual"
            Record name.
        warmup : int, default 0
            Leading samples not scored by likelihoods.
        frequency_hz : float, optional
            Excitation frequency [Hz], stored in the metadata.
        metadata : dict, optional
            Extra metadata, merged over ``source`` and ``truth``.

        Returns
        -------
        Record
            ``metadata`` holds ``source="virtual actuator"``, ``truth`` (:meth:`truth`)
            and ``frequency_hz`` when given; units s, V, um.
        """
        y = self.simulate(t, u, rng=rng)
        meta: dict[str, Any] = {"source": "virtual actuator", "truth": self.truth()}
        if frequency_hz is not None:
            meta["frequency_hz"] = float(frequency_hz)
        meta.update(metadata or {})
        return Record(t=t, u=u, y=y, warmup=warmup, metadata=meta, name=name,
                      units={"t": "s", "u": "V", "y": "um"})

    def truth(self) -> dict[str, Any]:
        """Every effect's parameters and which are on, as a JSON-serialisable dict."""
        return {
            "simulator": _SIMULATOR,
            "chain": "u(t-delay) -> gain*u + Preisach -> creep -> second order -> drift "
                     "-> + AR(1) noise",
            "stroke_um_nominal": STROKE_UM,
            "effects_on": list(self.effects),
            "gain_um_per_v": self.gain_um_per_v,
            "internal_rate_hz": self.internal_rate_hz,
            **{e: (None if (v := getattr(self, e)) is None else v.truth()) for e in EFFECTS},
        }


def hysteresis_only() -> VirtualActuator:
    """Default static map (linear + Preisach) with every other effect off."""
    return VirtualActuator().without("creep", "dynamics", "drift", "delay", "noise")


def _vector(values: Any, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise DataError(f"virtual actuator: {name}: expected a non-empty 1-D array, "
                        f"got shape {arr.shape}")
    if not np.isfinite(arr).all():
        i = int(np.argmax(~np.isfinite(arr)))
        raise DataError(f"virtual actuator: {name}, sample {i}: expected a finite value, "
                        f"got {arr[i]!r}")
    return np.ascontiguousarray(arr)


# ---------------------------------------------------------------------- measurements
def loop_width(u: np.ndarray, y: np.ndarray, *, n_grid: int = 512) -> tuple[float, float]:
    """Maximum vertical width and stroke of one closed loop.

    The samples are split into the rising (``u`` increasing) and falling branches,
    each interpolated on a common input grid; the width is the largest falling-minus-
    rising difference (positive for a counter-clockwise piezo loop).

    Parameters
    ----------
    u, y : array_like of float, shape (n,)
        One cycle of input [V] and output [um] (e.g. the last cycle of a record).
    n_grid : int, default 512
        Points of the common input grid.

    Returns
    -------
    width : float
        Max loop width [units of y].
    stroke : float
        ``max(y) - min(y)`` [units of y].
    """
    u = _vector(u, "u")
    y = _vector(y, "y")
    if u.size != y.size or u.size < 4:
        raise DataError("loop_width: expected u and y of equal length >= 4")
    du = np.diff(u)
    branches = []
    for mask in (du > 0, du < 0):
        idx = np.unique(np.concatenate([np.flatnonzero(mask), np.flatnonzero(mask) + 1]))
        if idx.size < 2:
            raise DataError("loop_width: the input has no rising or no falling branch")
        order = np.argsort(u[idx], kind="stable")
        branches.append((u[idx][order], y[idx][order]))
    (ur, yr), (uf, yf) = branches
    grid = np.linspace(max(ur[0], uf[0]), min(ur[-1], uf[-1]), n_grid)
    width = float(np.max(np.interp(grid, uf, yf) - np.interp(grid, ur, yr)))
    return width, float(np.ptp(y))


def hysteresis_percent(u: np.ndarray, y: np.ndarray) -> float:
    """Hysteresis in % of the stroke: ``100 * max loop width / stroke`` (:func:`loop_width`).

    Parameters
    ----------
    u, y : array_like of float, shape (n,)
        One closed cycle of input [V] and output.

    Returns
    -------
    float
        Percent of the stroke.
    """
    width, stroke = loop_width(u, y)
    return 100.0 * width / stroke


def creep_per_decade(t: np.ndarray, y: np.ndarray, t_step: float, *,
                     window_s: tuple[float, float] = (0.1, 10.0)) -> float:
    """Creep after a step, as a fraction of the step per decade of time.

    Least-squares slope of ``y`` against ``log10(t - t_step)`` over ``window_s``,
    divided by the step ``y(t_step + window_s[0]) - y(before the step)`` (the last
    sample before ``t_step``).

    Parameters
    ----------
    t, y : array_like of float, shape (n,)
        Times [s] and output of a step-and-hold record.
    t_step : float
        Time of the step [s].
    window_s : (float, float), default (0.1, 10)
        Fit window after the step [s].

    Returns
    -------
    float
        Creep per decade [fraction of the step], e.g. 0.015.
    """
    t = _vector(t, "t")
    y = _vector(y, "y")
    s = t - t_step
    fit = (s >= window_s[0]) & (s <= window_s[1])
    before = np.flatnonzero(s < 0)
    if fit.sum() < 3 or before.size == 0:
        raise DataError("creep_per_decade: need samples before the step and >= 3 in the "
                        f"window {window_s} s after it")
    slope, start = np.polyfit(np.log10(s[fit]), y[fit], 1)
    step = slope * math.log10(window_s[0]) + start - y[before[-1]]
    return float(slope / step)


# ---------------------------------------------------------------------------- bundle
def _bundle_record(act: VirtualActuator, t: np.ndarray, u: np.ndarray, rng_key: list[int],
                   name: str, warmup: int, frequency_hz: float | None,
                   excitation_info: dict[str, Any]) -> Record:
    u = np.round(u, _DECIMALS)
    meta = {"seed": rng_key[0], "rng": f"numpy.random.default_rng({rng_key})",
            "excitation": excitation_info,
            "rounding": f"u and y rounded to {_DECIMALS} decimals"}
    rec = act.record(t, u, rng=np.random.default_rng(rng_key), name=name, warmup=warmup,
                     frequency_hz=frequency_hz, metadata=meta)
    return rec.with_(y=np.round(rec.y, _DECIMALS))


def bundle(out_dir: str | os.PathLike[str], seed: int = BUNDLE_SEED) -> list[Path]:
    """Write the virtual-actuator datasets shipped in ``data/`` (CSV + JSON sidecars).

    The default :class:`VirtualActuator` (every effect on) drives:

    1. ``virtual_multifreq.csv`` -- sines 0-150 V at :data:`BUNDLE_FREQUENCIES_HZ`,
       one record per frequency, 4 cycles at 200 samples per cycle (``fs = 200 f``),
       the first cycle as warm-up;
    2. ``virtual_steps.csv`` -- steps 0 -> 100 -> 0 -> 150 -> 75 V, 1 s then 10 s
       holds, at 100 Hz (creep visible), the first second as warm-up;
    3. ``virtual_minor_loops.csv`` -- a 1 Hz sine about 75 V decaying from 75 V to
       7.5 V amplitude over 8 cycles (nested minor loops), 200 samples per cycle, the
       first cycle as warm-up.

    Record ``k`` of file ``i`` draws its noise from ``default_rng([seed, i, k])``;
    the same seed rewrites the same bytes.

    Parameters
    ----------
    out_dir : path-like
        Existing directory to write into.
    seed : int, default BUNDLE_SEED
        Root seed.

    Returns
    -------
    list of Path
        The CSV files written (each with its ``.json`` sidecar).
    """
    out = Path(out_dir)
    if not out.is_dir():
        raise DataError(f"{out}: expected an existing directory")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ParameterError(f"seed: expected a non-negative int, got {seed!r}")
    seed = int(seed)
    act = VirtualActuator()
    spc = _SAMPLES_PER_CYCLE
    records = []
    for k, f in enumerate(BUNDLE_FREQUENCIES_HZ):
        t, u = excitation.sine(f, spc * f, cycles=4)
        info = {"kind": "sine", "frequency_hz": f, "fs_hz": spc * f, "cycles": 4,
                "offset_v": 75.0, "amplitude_v": 75.0}
        records.append(_bundle_record(act, t, u, [seed, 0, k], f"virtual_multifreq@{f:g}Hz",
                                      spc, f, info))
    levels, holds = (0.0, 100.0, 0.0, 150.0, 75.0), (1.0, 10.0, 10.0, 10.0, 10.0)
    t, u = excitation.steps(levels, holds, _STEPS_FS_HZ)
    info = {"kind": "steps", "levels_v": list(levels), "hold_s": list(holds),
            "fs_hz": _STEPS_FS_HZ}
    steps = _bundle_record(act, t, u, [seed, 1, 0], "virtual_steps",
                           round(holds[0] * _STEPS_FS_HZ), None, info)
    t, u = excitation.decaying_sine(1.0, spc, cycles=8, center_v=75.0, amplitude_v=75.0,
                                    final_amplitude_v=7.5)
    info = {"kind": "decaying_sine", "frequency_hz": 1.0, "fs_hz": float(spc), "cycles": 8,
            "center_v": 75.0, "amplitude_v": 75.0, "final_amplitude_v": 7.5}
    minor = _bundle_record(act, t, u, [seed, 2, 0], "virtual_minor_loops", spc, 1.0, info)
    return [
        write_csv(Dataset(records, name="virtual_multifreq"), out / "virtual_multifreq.csv"),
        write_csv(Dataset([steps], name="virtual_steps"), out / "virtual_steps.csv"),
        write_csv(Dataset([minor], name="virtual_minor_loops"),
                  out / "virtual_minor_loops.csv"),
    ]
