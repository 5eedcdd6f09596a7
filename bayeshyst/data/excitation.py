"""Excitation signals for piezo actuators, and their concatenation with a smooth start.

The signals are sines, triangles, decaying sines, steps and multisines.

Every generator is a pure function that returns ``(t, u)``: sample times ``t`` [s]
starting at 0 and the drive voltage ``u`` [V], both float64 arrays of shape (n,),
uniformly sampled at ``fs_hz``. Periodic signals include the closing sample (``cycles``
whole periods give ``cycles * fs_hz / frequency_hz + 1`` samples), so that the last
loop closes. Random signals take an explicit ``rng`` (``numpy.random.Generator`` or an
integer seed); nothing here draws from global state.

Defaults follow piezo-stack practice: unipolar drive 0-150 V (``offset_v=75``,
``amplitude_v=75``), periodic signals starting at their minimum with zero slope, so
that a relaxed actuator at 0 V is not kicked.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bayeshyst.errors import ParameterError

__all__ = [
    "concatenate",
    "decaying_sine",
    "multisine",
    "sine",
    "steps",
    "triangle",
]


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        raise ParameterError(f"{name}: expected a positive finite number, got {value!r}")
    return value


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"{name}: expected a finite number, got {value!r}")
    return value


def _amplitude(value: float) -> float:
    """``amplitude_v`` as a finite float >= 0."""
    amp = _finite("amplitude_v", value)
    if amp < 0:
        raise ParameterError(f"amplitude_v: expected >= 0, got {amp!r}")
    return amp


def _periodic_axis(
    frequency_hz: float, fs_hz: float, cycles: float | None, duration_s: float | None
) -> np.ndarray:
    """Time axis of a periodic signal: whole samples covering the requested length."""
    f = _positive("frequency_hz", frequency_hz)
    fs = _positive("fs_hz", fs_hz)
    if f >= fs / 2:
        raise ParameterError(
            f"frequency_hz: {f!r} Hz is not below the Nyquist frequency fs_hz/2 = {fs / 2!r} Hz"
        )
    if (cycles is None) == (duration_s is None):
        raise ParameterError("give exactly one of cycles and duration_s")
    length = _positive("cycles", cycles) / f if cycles is not None else _positive(
        "duration_s", duration_s
    )
    n = round(length * fs) + 1
    if n < 4:
        raise ParameterError(f"signal too short: {n} samples at fs_hz={fs!r} (need >= 4)")
    return np.arange(n) / fs


def sine(
    frequency_hz: float,
    fs_hz: float,
    *,
    cycles: float | None = None,
    duration_s: float | None = None,
    offset_v: float = 75.0,
    amplitude_v: float = 75.0,
    phase_rad: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Sine ``u = offset - amplitude cos(2 pi f t + phase)``, starting at its minimum.

    Parameters
    ----------
    frequency_hz : float
        Frequency [Hz], below ``fs_hz / 2``.
    fs_hz : float
        Sampling rate [Hz].
    cycles : float, optional
        Number of periods (exactly one of ``cycles`` and ``duration_s``).
    duration_s : float, optional
        Length [s].
    offset_v : float, default 75
        Mean voltage [V].
    amplitude_v : float, default 75
        Peak amplitude [V] (>= 0); the defaults span 0-150 V.
    phase_rad : float, default 0
        Phase [rad]; 0 starts at the minimum with zero slope.

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s].
    u : ndarray, shape (n,)
        Voltage [V].
    """
    t = _periodic_axis(frequency_hz, fs_hz, cycles, duration_s)
    amp = _amplitude(amplitude_v)
    u = _finite("offset_v", offset_v) - amp * np.cos(
        2 * np.pi * float(frequency_hz) * t + _finite("phase_rad", phase_rad)
    )
    return t, u


def triangle(
    frequency_hz: float,
    fs_hz: float,
    *,
    cycles: float | None = None,
    duration_s: float | None = None,
    offset_v: float = 75.0,
    amplitude_v: float = 75.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric triangle wave, starting at its minimum ``offset - amplitude``.

    A triangle drives the actuator at constant ``|du/dt| = 4 amplitude frequency``,
    which separates rate effects from amplitude effects.

    Parameters
    ----------
    frequency_hz, fs_hz, cycles, duration_s, offset_v, amplitude_v
        As in :func:`sine` (Hz, Hz, periods, s, V, V).

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s].
    u : ndarray, shape (n,)
        Voltage [V].
    """
    t = _periodic_axis(frequency_hz, fs_hz, cycles, duration_s)
    amp = _amplitude(amplitude_v)
    x = np.mod(float(frequency_hz) * t, 1.0)
    return t, _finite("offset_v", offset_v) + amp * (1.0 - 4.0 * np.abs(x - 0.5))


def decaying_sine(
    frequency_hz: float,
    fs_hz: float,
    *,
    cycles: float,
    center_v: float = 75.0,
    amplitude_v: float = 75.0,
    final_amplitude_v: float = 7.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Sine with exponentially decaying amplitude: nested minor loops around ``center_v``.

    ``u = center - A(t) cos(2 pi f t)`` with ``A(t) = A0 (A1 / A0) ** (t / T)``, ``T``
    the duration. Every reversal is less extreme than the one before, so the
    hysteretic memory keeps all of them (a deep staircase).

    Parameters
    ----------
    frequency_hz, fs_hz : float
        Frequency and sampling rate [Hz].
    cycles : float
        Number of periods.
    center_v : float, default 75
        Centre of the loops [V].
    amplitude_v : float, default 75
        Initial amplitude ``A0`` [V] (> 0); with the defaults the signal starts at 0 V.
    final_amplitude_v : float, default 7.5
        Amplitude ``A1`` at the end [V], ``0 < A1 <= A0``.

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s].
    u : ndarray, shape (n,)
        Voltage [V].
    """
    t = _periodic_axis(frequency_hz, fs_hz, cycles, None)
    a0 = _positive("amplitude_v", amplitude_v)
    a1 = _positive("final_amplitude_v", final_amplitude_v)
    if a1 > a0:
        raise ParameterError(
            f"final_amplitude_v: expected <= amplitude_v ({a0!r} V), got {a1!r} V"
        )
    amp = a0 * (a1 / a0) ** (t / t[-1])
    return t, _finite("center_v", center_v) - amp * np.cos(2 * np.pi * float(frequency_hz) * t)


def steps(
    levels_v: Sequence[float],
    hold_s: float | Sequence[float],
    fs_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-constant voltage: each level held for its hold time (creep tests).

    Level ``k`` holds on ``[T_k, T_{k+1})`` with ``T_k`` the sum of the earlier holds,
    rounded to the sampling grid; the jump happens between two samples (a model that
    interpolates linearly sees a ramp of one sample period). The last sample, at
    ``T = sum(hold_s)``, repeats the last level.

    Parameters
    ----------
    levels_v : sequence of float, length L
        Voltages [V], e.g. ``[0, 100, 0]`` for a step up and back.
    hold_s : float or sequence of float, length L
        Hold time of each level [s] (one number: the same for all), each at least
        one sample period.
    fs_hz : float
        Sampling rate [Hz].

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s].
    u : ndarray, shape (n,)
        Voltage [V].
    """
    levels = np.asarray(levels_v, dtype=float)
    if levels.ndim != 1 or levels.size == 0 or not np.isfinite(levels).all():
        raise ParameterError(f"levels_v: expected a non-empty sequence of finite volts, "
                             f"got {levels_v!r}")
    holds = np.broadcast_to(np.asarray(hold_s, dtype=float), levels.shape)
    fs = _positive("fs_hz", fs_hz)
    if not (np.isfinite(holds).all() and (holds * fs >= 1).all()):
        raise ParameterError(
            f"hold_s: expected finite holds of at least one sample (1/fs_hz = {1 / fs!r} s), "
            f"got {hold_s!r}"
        )
    edges = np.rint(np.concatenate([[0.0], np.cumsum(holds)]) * fs).astype(np.int64)
    u = np.repeat(levels, np.diff(edges))
    u = np.append(u, levels[-1])
    n = u.size
    if n < 4:
        raise ParameterError(f"signal too short: {n} samples (need >= 4)")
    return np.arange(n) / fs, u


def multisine(
    f_min_hz: float,
    f_max_hz: float,
    fs_hz: float,
    duration_s: float,
    *,
    rng: np.random.Generator | int | None = None,
    schroeder: bool = False,
    offset_v: float = 75.0,
    amplitude_v: float = 75.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Band-limited periodic multisine with a flat amplitude spectrum.

    Tones at every multiple of ``1 / duration_s`` inside ``[f_min_hz, f_max_hz]``, so
    the signal is exactly periodic over ``duration_s`` (no leakage in an FFT of one
    period). The sum is scaled to the peak amplitude ``amplitude_v`` about ``offset_v``.

    Parameters
    ----------
    f_min_hz, f_max_hz : float
        Band edges [Hz], ``0 < f_min <= f_max < fs / 2``.
    fs_hz : float
        Sampling rate [Hz].
    duration_s : float
        Period of the multisine [s]; ``n = round(duration_s * fs_hz)`` samples (one
        period, without the closing sample).
    rng : numpy.random.Generator or int, optional
        Source of the random phases (uniform on ``[0, 2 pi)``); required unless
        ``schroeder``.
    schroeder : bool, default False
        Use Schroeder phases ``-pi k (k - 1) / K`` (low crest factor, deterministic).
    offset_v : float, default 75
        Mean voltage [V].
    amplitude_v : float, default 75
        Peak deviation from ``offset_v`` [V].

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s].
    u : ndarray, shape (n,)
        Voltage [V].
    """
    fs = _positive("fs_hz", fs_hz)
    dur = _positive("duration_s", duration_s)
    lo = _positive("f_min_hz", f_min_hz)
    hi = _positive("f_max_hz", f_max_hz)
    if not lo <= hi < fs / 2:
        raise ParameterError(
            f"band: expected 0 < f_min_hz <= f_max_hz < fs_hz/2 = {fs / 2!r}, "
            f"got [{lo!r}, {hi!r}] Hz"
        )
    n = round(dur * fs)
    k = np.arange(max(1, math.ceil(lo * dur - 1e-9)), math.floor(hi * dur + 1e-9) + 1)
    k = k[2 * k < n]  # strictly below Nyquist on the sample grid
    if k.size == 0:
        raise ParameterError(
            f"band [{lo!r}, {hi!r}] Hz holds no multiple of 1/duration_s = {1 / dur!r} Hz"
        )
    if schroeder:
        idx = np.arange(1, k.size + 1)
        phases = -np.pi * idx * (idx - 1) / k.size
    else:
        if rng is None:
            raise ParameterError("rng: random phases need a numpy Generator or an int seed")
        phases = np.random.default_rng(rng).uniform(0.0, 2 * np.pi, k.size)
    t = np.arange(n) / fs
    # sum of cos(2 pi k i / n + phase) by one inverse FFT: exact period, O(n log n)
    spectrum = np.zeros(n // 2 + 1, dtype=complex)
    spectrum[k] = np.exp(1j * phases)
    s = np.fft.irfft(spectrum, n) * (n / 2)
    amp = _finite("amplitude_v", amplitude_v)
    return t, _finite("offset_v", offset_v) + amp * s / np.max(np.abs(s))


def _bridge(a: float, b: float, n: int) -> np.ndarray:
    """``n - 1`` raised-cosine samples strictly between ``a`` and ``b`` (zero end slopes)."""
    k = np.arange(1, n)
    return a + (b - a) * 0.5 * (1.0 - np.cos(np.pi * k / n))


def concatenate(
    segments: Sequence[tuple[np.ndarray, np.ndarray]],
    fs_hz: float,
    *,
    ramp_s: float = 0.1,
    start_v: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Join signals end to end, with a smooth start from ``start_v`` and smooth joins.

    Wherever consecutive values differ (``start_v`` -> first segment, one segment's
    last sample -> the next one's first), a raised-cosine bridge of ``ramp_s`` seconds
    (zero slope at both ends) is inserted; a bridge from ``start_v`` begins with a
    sample at ``start_v`` itself, so that no step reaches the actuator unless
    a segment contains one itself.

    Parameters
    ----------
    segments : sequence of (t, u)
        Signals sampled at ``fs_hz`` (times [s], voltages [V], each shape (n_i,)); their
        time axes only serve to check the sampling rate.
    fs_hz : float
        Common sampling rate [Hz].
    ramp_s : float, default 0.1
        Length of each bridge [s]; 0 joins without bridges.
    start_v : float, default 0
        Voltage before the first segment [V] (the actuator at rest).

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s], from 0.
    u : ndarray, shape (n,)
        Voltage [V].
    """
    fs = _positive("fs_hz", fs_hz)
    ramp = _finite("ramp_s", ramp_s)
    if ramp < 0:
        raise ParameterError(f"ramp_s: expected >= 0, got {ramp!r}")
    if not segments:
        raise ParameterError("segments: expected at least one (t, u) pair")
    n_ramp = round(ramp * fs)
    parts = []
    prev = _finite("start_v", start_v)
    for i, (t_i, u_i) in enumerate(segments):
        t_i = np.asarray(t_i, dtype=float)
        u_i = np.asarray(u_i, dtype=float)
        if t_i.ndim != 1 or t_i.shape != u_i.shape or t_i.size < 2:
            raise ParameterError(f"segments[{i}]: expected t and u of equal shape (n >= 2,)")
        dt = np.diff(t_i)
        if not np.allclose(dt, 1.0 / fs, rtol=1e-6, atol=0.0):
            raise ParameterError(
                f"segments[{i}]: expected sampling at fs_hz={fs!r} Hz, "
                f"found steps {dt.min()!r}..{dt.max()!r} s"
            )
        if not np.isfinite(u_i).all():
            raise ParameterError(f"segments[{i}]: u has non-finite values")
        if n_ramp > 1 and u_i[0] != prev:
            if i == 0:  # the record starts at rest, at start_v itself
                parts.append(np.array([prev]))
            parts.append(_bridge(prev, u_i[0], n_ramp))
        parts.append(u_i)
        prev = u_i[-1]
    u = np.concatenate(parts)
    return np.arange(u.size) / fs, u
