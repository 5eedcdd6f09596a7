"""Stable inversion of the linear dynamic blocks (delay, ARX, second order) on a known signal.

A sampled second-order system has relative degree two: with a first-order hold its
output at ``t_k`` responds to ``w_k`` with a weight of order ``(w_n h)^2`` and its
discrete numerator has a *sampling zero* outside the unit circle (``-2 - sqrt(3)`` as
``h -> 0``). Solving ``y_k = y_d,k`` for ``w_k`` sample by sample is the recursion of
``1 / G(z)``, which grows like ``3.7^k``; with a zero-order hold there is no
feedthrough at all. A fractional delay has a zero outside the circle when its fraction
exceeds a half. The exact inverse of such a block is not causal, but a feedforward
knows its reference in advance, so the inverse may look ahead: this module computes the
**stable, non-causal inverse** ``w = G^{-1}[v]`` (Devasia, Chen & Paden 1996; here in
the frequency domain) as a circular deconvolution over the signal:

* the discrete impulse response ``g`` of the block is measured by running the block
  itself on a unit sample (so the inverse matches the forward kernel, its hold and its
  discretisation exactly), for every posterior draw at once;
* a periodic signal (whole periods) is deconvolved exactly on its period;
* any other signal is extended at both ends by its end values held and closed by a
  smooth ramp, long enough for the inverse filter's causal and anti-causal tails to
  have decayed to rounding, deconvolved circularly, and cut back: the command then
  contains the *pre-actuation* that an inverse of non-minimum-phase dynamics needs,
  inside the signal's own lead-in.

The division is regularised at ``1e-12`` of the peak gain only to keep a zero on the unit
circle (a delay of exactly half a sample at Nyquist) finite; the forward check below
reports what the inverse achieves.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from bayeshyst.errors import ParameterError, SimulationError
from bayeshyst.models.blocks import EffectBlock
from bayeshyst.models.blocks.base import DEFAULT_DT

__all__ = ["LTIInverse", "deconvolve", "impulse_responses", "uniform_step"]

#: Relative size below which an impulse-response tail or inverse-filter tail counts as decayed.
TAIL_RTOL = 1e-13
#: Relative size below which the inverse filter's tails count as decayed.
INVERSE_TAIL_RTOL = 1e-11
#: Longest impulse response measured (samples); slower blocks are refused.
MAX_RESPONSE = 2 ** 21
#: Regularisation of the spectral division, relative to the peak gain.
GAIN_FLOOR = 1e-12


@dataclass(frozen=True)
class LTIInverse:
    """Input of a linear block that makes it output a given signal.

    Attributes
    ----------
    w : ndarray, shape (W, N)
        Block input, one row per parameter vector (unit of the signal).
    response_length : int
        Samples of impulse response measured (where the slowest draw had decayed).
    padding : int
        Samples added before and after a non-periodic signal (0 when periodic).
    min_gain : float
        Smallest ``|G|`` over the frequencies the signal occupies, relative to the peak:
        how ill-conditioned the inversion was.
    """

    w: np.ndarray
    response_length: int
    padding: int
    min_gain: float

    def __str__(self) -> str:
        return (f"LTIInverse({self.w.shape[0]} draws x {self.w.shape[1]} samples, impulse "
                f"response {self.response_length}, padding {self.padding}, min gain "
                f"{self.min_gain:.3g})")


def uniform_step(t: np.ndarray) -> float:
    """The sampling step (s) of ``t``; ParameterError unless the sampling is uniform.

    Deconvolution needs a time-invariant discrete system, which a block is only on a
    uniform grid (its discretisation depends on the step).
    """
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return DEFAULT_DT
    steps = np.diff(t)
    dt = float(np.median(steps))
    worst = int(np.argmax(np.abs(steps - dt)))
    if not (dt > 0 and abs(steps[worst] - dt) <= 1e-6 * dt):
        raise ParameterError(f"inverting linear dynamics needs uniform sampling: step "
                             f"{worst + 1} of t is {steps[worst]:.9g} s, the median "
                             f"{dt:.9g} s")
    return dt


def impulse_responses(block: EffectBlock, theta: Mapping[str, np.ndarray], dt: float,
                      width: int) -> np.ndarray:
    """Discrete impulse responses ``g`` (W, L) of ``W`` parameter vectors of ``block``.

    ``g[:, n]`` is the output ``n`` samples after a unit input sample at rest (the
    block's own hold between samples included), measured by running the block; the
    length doubles until the tail of every row is below :data:`TAIL_RTOL` of its peak.

    Parameters
    ----------
    block : EffectBlock
        A linear, time-invariant block.
    theta : mapping
        Its batched parameters (arrays with a leading ``W`` axis).
    dt : float
        Sampling step (s).
    width : int
        ``W``.

    Raises
    ------
    SimulationError
        If a draw fails or its response has not decayed within :data:`MAX_RESPONSE`.
    """
    length = 256
    while True:
        w = np.zeros((width, length + 1))
        w[:, 1] = 1.0  # rest at 0 for the first sample, then the unit sample
        t = dt * np.arange(length + 1)
        s0 = block._initial_state(theta, np.zeros(width), math.nan)
        out, _, failed = block._apply(w, t, theta, s0)
        if failed.any():
            raise SimulationError(f"{block.name}: the impulse response of draw "
                                  f"{int(np.flatnonzero(failed)[0])} failed")
        g = out[:, 1:]
        peak = np.max(np.abs(g), axis=1, keepdims=True)
        tail = np.max(np.abs(g[:, -(length // 8):]), axis=1, keepdims=True)
        if np.all(tail <= TAIL_RTOL * peak):
            return g
        if length >= MAX_RESPONSE:
            raise SimulationError(f"{block.name}: impulse response has not decayed after "
                                  f"{length} samples (a pole on the unit circle?); its "
                                  "inverse cannot be computed")
        length *= 2


def _folded_spectrum(g: np.ndarray, n: int) -> np.ndarray:
    """``rfft`` over ``n`` samples of ``g`` wrapped modulo ``n`` (periodic response)."""
    reps = -(-g.shape[1] // n)
    padded = np.zeros((g.shape[0], reps * n))
    padded[:, :g.shape[1]] = g
    return np.fft.rfft(padded.reshape(g.shape[0], reps, n).sum(axis=1), axis=1)


def _divide(v_hat: np.ndarray, g_hat: np.ndarray) -> tuple[np.ndarray, float]:
    peak = np.max(np.abs(g_hat), axis=1, keepdims=True)
    floor = GAIN_FLOOR * peak
    w_hat = v_hat * np.conj(g_hat) / (np.abs(g_hat) ** 2 + floor ** 2)
    # conditioning over the bins the signal occupies (above rounding of its spectrum)
    occupied = np.abs(v_hat) > 1e-12 * np.max(np.abs(v_hat), axis=1, keepdims=True)
    rel = np.where(occupied, np.abs(g_hat) / peak, np.inf)
    return w_hat, float(np.min(rel)) if np.isfinite(rel).any() else 1.0


def deconvolve(block: EffectBlock, theta: Mapping[str, np.ndarray], v: np.ndarray,
               t: np.ndarray, *, periodic: bool = False) -> LTIInverse:
    """Input ``w`` (W, N) with ``block[w] = v``: the stable, non-causal inverse.

    Parameters
    ----------
    block : EffectBlock
        A linear time-invariant block with unit DC gain (``needs_preview``).
    theta : mapping
        Batched parameters, leading axis ``W``.
    v : ndarray, shape (W, N) or (N,)
        Desired block output, per draw or shared.
    t : ndarray, shape (N,)
        Uniform sample times (s).
    periodic : bool
        ``v`` holds whole periods of a periodic signal: the inverse is the periodic
        steady state, exact on the period. Otherwise ``v`` should start and end at rest
        for long enough to hold the pre- and post-actuation (it is extended by its end
        values; what falls outside is lost, and the forward check shows it).

    Returns
    -------
    LTIInverse
    """
    tb, width = block._batch_theta(theta, batched=True)
    v = np.asarray(v, dtype=float)
    width = width or (v.shape[0] if v.ndim == 2 else 1)
    v = np.broadcast_to(v, (width, t.size))
    dt = uniform_step(t)
    g = impulse_responses(block, tb, dt, width)
    n = t.size
    if periodic:
        w_hat, min_gain = _divide(np.fft.rfft(v, axis=1), _folded_spectrum(g, n))
        return LTIInverse(np.fft.irfft(w_hat, n, axis=1), g.shape[1], 0, min_gain)
    pad = max(64, g.shape[1])
    while True:
        ramp = 0.5 * (1.0 - np.cos(np.pi * np.arange(1, pad + 1) / (pad + 1)))
        first, last = v[:, :1], v[:, -1:]
        ext = np.concatenate([np.repeat(first, pad, axis=1), v, np.repeat(last, pad, axis=1),
                              last + (first - last) * ramp[None, :]], axis=1)
        m = ext.shape[1]
        g_hat = _folded_spectrum(g, m)
        w_hat, min_gain = _divide(np.fft.rfft(ext, axis=1), g_hat)
        # the inverse filter's impulse response must have decayed within the padding,
        # both forwards (causal part) and backwards (pre-actuation): else double it
        inv = np.fft.irfft(_divide(np.ones_like(g_hat), g_hat)[0], m, axis=1)
        inner = np.max(np.abs(inv[:, pad:m - pad]), axis=1)
        if np.all(inner <= INVERSE_TAIL_RTOL * np.max(np.abs(inv), axis=1)) \
                or pad >= MAX_RESPONSE:
            w = np.fft.irfft(w_hat, m, axis=1)[:, pad:pad + n]
            return LTIInverse(np.ascontiguousarray(w), g.shape[1], pad, min_gain)
        pad *= 2
