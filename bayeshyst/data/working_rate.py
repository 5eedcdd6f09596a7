"""An anti-aliased working rate per record, chosen from what the record carries.

Measured records are often sampled far faster than the hysteresis needs (a 1 Hz sine at
5 kHz), and every posterior evaluation simulates every sample. :func:`to_working_rate`
decimates each record by an integer factor ``k`` to the slowest rate that keeps

* **the signal**: every frequency at which the output's (and a smooth input's) spectrum
  stands above its noise floor;
* **the loops**: at least ``min_samples_per_cycle`` (default 100) samples per cycle of
  the highest excitation frequency, so that reversal points stay within 1/100 of a
  period of where they were;

and anti-aliases what it drops with a zero-phase FIR low-pass.

The rule
--------
Noise floor. The signal edge ``f_sig`` of a channel is the highest frequency at which its
spectrum stands above its white-noise floor, Bonferroni over the bins at ``alpha``
(default 0.01): :func:`bayeshyst.data.spectral_edge.signal_edge`, whose notes hold the
estimate.

Rate. ``fs_req = max(min_samples_per_cycle * f_exc, 2 margin f_sig(y), 2 margin
f_sig(u))`` with ``f_exc`` the record's frequency (else its classified excitation's:
the fundamental, or the upper edge of a multisine's or broadband input's band), and
``k = floor(fs / fs_req)``. A record is decimated only when ``k >= 2``; otherwise it is
kept whole. The band kept is ``0 .. fs_out / (2 margin)``, which holds ``f_sig`` by
construction: the low-pass passes it (ripple about 1e-4) and stops, by
:data:`STOPBAND_DB` (80 dB), everything that would fold into it,
``fs_out (1 - 1/(2 margin))`` and up. Between the two its power response is
complementary about the new Nyquist frequency, so **white noise stays white** at the
working rate (lag correlations about 0.002; see ``_design``): the noise model a record
needs is the same at either rate.

The input. A step through a low-pass rings (Gibbs: 9 % overshoot) and would drive a
hysteresis model through minor loops it never saw. The input is **piecewise constant**
when it moves only between holds: the increments beyond white input noise
(``|du| > z sqrt(2) sigma_u``, ``z`` the Bonferroni normal quantile at ``alpha`` over
the increments, ``sigma_u`` from the second difference's MAD, floored by the
quantisation step) cut it into pieces, every piece of two or more samples stays
within ``2 z sigma_u``, and those holds make up at least half of the record (a rest
before a sine is a hold, the sine is not). Such an input is subsampled exactly (the
kept values are the originals; a step moves to the kept sample at or after it, less
than one working-rate sample later; its noise, if any, is not reduced), and its
spectrum sets no rate (a staircase has no cycles; only a frequency the record states
does). Otherwise it is
**smooth** and is filtered like the output, but piece by piece between its **jumps**,
so that a jump (the 150 V record's 0 -> -87 V start) stays a jump and nothing rings. A
jump is an increment no signal in the kept band can make: by Bernstein's inequality a
signal band-limited to ``f_B`` with ``|u - mid| <= span/2`` moves at most
``pi f_B span / fs`` in one sample, plus ``z sqrt(2) sigma_u`` of noise.

Edges. Every piece is padded by odd reflection about its end sample (level and slope
kept: exact at the end sample itself up to the ripple, but not next to it, within half
the filter, about 15 working-rate samples). So samples within half the filter of the
record's end are **trimmed**, and those of its start become **warm-up**: the model is
simulated through them from the record's own beginning, where its initial state means
what it means at the full rate, but they are not scored (a start trimmed instead would
begin the model mid-record in a state nobody knows). A smooth input's jumps end pieces
inside a record: within half a filter of a jump the filtered input carries that
distortion.

Everything else is carried as ``analyses/_common.cut_record`` does: every ``k``-th
sample from the first (``t`` unchanged), segment labels subsampled, the warm-up divided
by ``k`` rounded up (at least the half filter's samples), ``excitation_start_index``
and ``virgin_branch_end_index`` divided by ``k`` (floor),
``metadata["sampling_rate_hz"]`` the new rate and ``metadata["working_rate"]`` what
was done. Measured covariate columns are filtered
like the output at the same cut-off (their spectra do not set the rate).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import MIN_SAMPLES, Record
from bayeshyst.data.segment import input_noise_sd
from bayeshyst.data.spectral_edge import ALPHA, edge_and_floor, signal_edge
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.tables import frame

__all__ = ["MARGIN", "MIN_SAMPLES_PER_CYCLE", "STOPBAND_DB", "RecordRate", "WorkingRate",
           "to_working_rate"]

#: samples per cycle of the highest excitation frequency kept at least (reversal points
#: within 1 % of a period)
MIN_SAMPLES_PER_CYCLE = 100.0
#: new Nyquist frequency over the highest frequency kept (the filter's transition band)
MARGIN = 1.5
#: stop-band attenuation of the anti-alias filter [dB]
STOPBAND_DB = 80.0
#: side lobes of the light Kaiser taper on the anti-alias filter's taps [dB] (see _design)
_WINDOW_DB = 30.0
#: relative jitter of the sampling step beyond which a record is not filtered (as
#: :attr:`Record.dt` calls a record uniform)
_JITTER = 0.01


# ----------------------------------------------------------------------- results
@dataclass(frozen=True)
class RecordRate:
    """What :func:`to_working_rate` did with one record.

    Attributes
    ----------
    record : str
        The record's name.
    fs_in_hz, fs_out_hz : float
        Sampling rate before and after [Hz] (equal when kept whole).
    factor : int
        Decimation factor ``k`` (1: kept whole).
    band_hz : tuple of (float, float)
        Band kept [Hz]: ``(0, fs_out / (2 margin))`` when decimated, ``(0, fs_in / 2)``
        when kept whole.
    reason : str
        Why this rate: which of the rules set it, in words.
    input_treatment : {"filtered", "subsampled", "unchanged"}
        How the input ``u`` was brought to the working rate (see the module notes).
    signal_edge_y_hz, signal_edge_u_hz : float or None
        Highest frequency [Hz] where the output's / input's spectrum stands above its
        noise floor (None: not estimated; the input's is not used when subsampled).
    excitation_hz : float or None
        The excitation frequency the samples-per-cycle floor applies to [Hz].
    n_in, n_out : int
        Samples before and after.
    input_jumps : int
        Increments of the input that no signal in the kept band can make.
    noise_gain : float
        Standard deviation of white noise after the low-pass over before,
        ``sqrt(sum(h**2))`` (``sqrt(1 / k)`` to 0.2 %: the filter keeps white noise
        white); 1 when kept whole.
    edge_warmup : int
        Working-rate samples at the start that are warm-up only because they lie within
        half the filter of it (beyond the record's own warm-up; simulated, not scored).
    dropped_at_end : int
        How many samples after the last one kept were left off (within half the filter
        of the end, plus fewer than ``k`` of the grid).
    """

    record: str
    fs_in_hz: float
    fs_out_hz: float
    factor: int
    band_hz: tuple[float, float]
    reason: str
    input_treatment: str
    signal_edge_y_hz: float | None
    signal_edge_u_hz: float | None
    excitation_hz: float | None
    n_in: int
    n_out: int
    input_jumps: int
    noise_gain: float
    edge_warmup: int = 0
    dropped_at_end: int = 0

    def __str__(self) -> str:
        if self.factor == 1:
            return f"{self.record}: kept whole at {self.fs_in_hz:.6g} Hz ({self.reason})"
        ends = ""
        if self.edge_warmup:
            ends += f"; the first {self.edge_warmup} samples warm-up (filter edge)"
        if self.dropped_at_end:
            ends += f"; the last {self.dropped_at_end} left off (filter edge)"
        return (f"{self.record}: {self.fs_in_hz:.6g} Hz -> {self.fs_out_hz:.6g} Hz "
                f"(every {self.factor}th sample, {self.n_in} -> {self.n_out}); band "
                f"0-{self.band_hz[1]:.4g} Hz kept ({self.reason}); input "
                f"{self.input_treatment}{ends}")

    def to_dict(self) -> dict[str, Any]:
        """The fields as JSON-ready values (``band_hz`` as a list), and ``statement``.

        ``statement`` is the record's text (``str(self)``), for a reader of the JSON.
        """
        out = dict(self.__dict__)
        out["band_hz"] = list(self.band_hz)
        out["statement"] = str(self)
        return out

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict` (the band as ``band_hz_lo``/``_hi`` columns)."""
        return frame([self.to_dict()], drop=("statement",))


@dataclass(frozen=True)
class WorkingRate:
    """The working rate of every record of a dataset (:func:`to_working_rate`).

    Attributes
    ----------
    mode : str or float
        ``"auto"``, ``"full"`` or the requested rate [Hz].
    min_samples_per_cycle, margin, alpha : float
        The rule's settings.
    records : tuple of RecordRate
        One per record, in order.
    """

    mode: str | float
    min_samples_per_cycle: float
    margin: float
    alpha: float
    records: tuple[RecordRate, ...] = field(default_factory=tuple)

    @property
    def changed(self) -> bool:
        """Whether any record was decimated."""
        return any(r.factor > 1 for r in self.records)

    def line(self) -> str:
        """One line saying what was done (for a command's stderr)."""
        mode = self.mode if isinstance(self.mode, str) else f"{self.mode:g} Hz"
        if not self.changed:
            why = "; ".join(dict.fromkeys(r.reason for r in self.records))
            return f"working rate {mode}: every record kept at full rate ({why})"
        parts = [f"{r.record} {r.fs_in_hz:.6g} -> {r.fs_out_hz:.6g} Hz"
                 + (f" (k={r.factor}, band 0-{r.band_hz[1]:.4g} Hz: {r.reason}; input "
                    f"{r.input_treatment})" if r.factor > 1 else " (kept whole)")
                 for r in self.records]
        return f"working rate {mode}: " + "; ".join(parts)

    def __str__(self) -> str:
        mode = self.mode if isinstance(self.mode, str) else f"{self.mode:g} Hz"
        head = (f"working rate {mode} (>= {self.min_samples_per_cycle:g} samples per "
                f"cycle, margin {self.margin:g}, alpha {self.alpha:g})")
        return "\n".join([head, *(f"  {r}" for r in self.records)])

    def to_dataframe(self) -> Any:
        """One row per record (:meth:`RecordRate.to_dict`)."""
        return frame([r.to_dict() for r in self.records], drop=("statement",))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the settings, one entry per record and :meth:`line`."""
        return {"mode": self.mode, "min_samples_per_cycle": self.min_samples_per_cycle,
                "margin": self.margin, "alpha": self.alpha, "changed": self.changed,
                "statement": self.line(), "records": [r.to_dict() for r in self.records]}


# ------------------------------------------------------------------------- input
def _noise_sd(u: np.ndarray) -> float:
    """White-noise sd of ``u``: second-difference MAD, floored by its quantisation step.

    The step counts only when the span holds at least 64 of them (two levels of a
    square wave are signal, not quantisation), as :mod:`bayeshyst.data.classify` does.
    """
    sigma = input_noise_sd(u)
    levels = np.unique(u)
    q = float(np.min(np.diff(levels))) if levels.size > 1 else 0.0
    if q > 0 and float(np.ptp(u)) >= 64 * q:
        sigma = max(sigma, q / math.sqrt(12.0))
    return sigma


def _z(alpha: float, m: int) -> float:
    """Two-sided Bonferroni normal quantile at level ``alpha`` over ``m`` tests."""
    from scipy import stats

    return float(stats.norm.isf(alpha / (2.0 * max(m, 1))))


def _jumps(u: np.ndarray, fs: float, f_band: float, sigma: float, alpha: float
           ) -> np.ndarray:
    """Indices ``i`` where ``u[i] -> u[i+1]`` is a jump (see the module notes)."""
    bound = (math.pi * f_band * float(np.ptp(u)) / fs
             + _z(alpha, u.size - 1) * math.sqrt(2.0) * sigma)
    return np.flatnonzero(np.abs(np.diff(u)) > bound)


def _moves(u: np.ndarray, sigma: float, alpha: float) -> np.ndarray:
    """Indices ``i`` where ``u[i] -> u[i+1]`` moves beyond white noise of sd ``sigma``."""
    return np.flatnonzero(np.abs(np.diff(u)) > _z(alpha, u.size - 1) * math.sqrt(2.0) * sigma)


def _pieces(n: int, cuts: Sequence[int]) -> list[tuple[int, int]]:
    """``[a, b)`` ranges of ``range(n)`` split before every index in ``cuts``."""
    edges = [0, *sorted({c for c in cuts if 0 < c < n}), n]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def _held(u: np.ndarray, pieces: list[tuple[int, int]], sigma: float, alpha: float
          ) -> bool:
    """Whether ``u`` is mostly held: within its noise band on every piece of 2+ samples.

    Those pieces must make up at least half of the samples.
    """
    band = 2.0 * _z(alpha, u.size) * sigma
    long = [(a, b) for a, b in pieces if b - a >= 2]
    return (2 * sum(b - a for a, b in long) >= u.size
            and all(float(np.ptp(u[a:b])) <= band for a, b in long))


# ------------------------------------------------------------------------ filter
def _step(x: np.ndarray) -> np.ndarray:
    """A smooth (C-infinity) step from 0 at ``x <= 0`` to 1 at ``x >= 1``.

    ``psi(x) / (psi(x) + psi(1 - x))`` with ``psi = exp(-1/x)``, so that
    ``step(x) + step(1 - x) = 1``.
    """
    from scipy.special import expit

    x = np.clip(x, 0.0, 1.0)
    inner = (x > 0) & (x < 1)
    out = np.where(x >= 1, 1.0, 0.0)
    xi = x[inner]
    out[inner] = expit(1.0 / (1.0 - xi) - 1.0 / xi)
    return out


def _design(k: int, margin: float) -> np.ndarray:
    """Zero-phase low-pass taps for decimation by ``k`` (odd length, unit DC gain).

    In cycles per input sample: flat pass band to ``f_lo = 1 / (2 k margin)``, stop band
    from ``f_hi = 1 / k - f_lo``, and between them the amplitude
    ``cos(pi/2 step((f - f_lo) / (f_hi - f_lo)))`` (:func:`_step`). The transition is
    power-complementary about the new Nyquist frequency ``1 / (2 k)``:
    ``|H(f)|^2 + |H(1/k - f)|^2 = 1``, so the power response folded by the decimation
    is flat and **white noise stays white** (lag correlations of the decimated noise
    about 0.002, against 0.23 for a Kaiser low-pass with its stop band at the new
    Nyquist frequency: every decimated record's white noise then read as coloured, and
    the diagnosis kept an AR(1) noise model for what was the filter). Content between
    ``f_lo`` and ``f_hi`` folds onto ``f_lo .. 1/(2k)``, outside the band kept; only
    content above ``f_hi`` folds into it, and there the response is down by about
    :data:`STOPBAND_DB`. The response is smooth, so its taps decay fast: frequency
    sampling with a light Kaiser taper (:data:`_WINDOW_DB`) over twice the length a
    Kaiser design of that attenuation and transition needs keeps the pass-band ripple
    about 1e-4.
    """
    from scipy import signal

    f_lo = 0.5 / (k * margin)
    f_hi = 1.0 / k - f_lo
    numtaps, _ = signal.kaiserord(STOPBAND_DB, f_hi - f_lo)
    numtaps |= 1  # odd: a centre tap, so the centred convolution has zero phase
    grid = np.linspace(0.0, 0.5, max(1 << 14, 4 * numtaps) + 1)
    gain = np.cos(0.5 * np.pi * _step((grid - f_lo) / (f_hi - f_lo)))
    taps = signal.firwin2(numtaps, grid, gain, window=("kaiser", signal.kaiser_beta(_WINDOW_DB)),
                          fs=1.0)
    return taps / taps.sum()


def _filtered(x: np.ndarray, taps: np.ndarray, pieces: list[tuple[int, int]],
              keep: np.ndarray) -> np.ndarray:
    """``x`` low-passed piece by piece (odd-reflection padding), at the ``keep`` indices."""
    from scipy import signal

    half = taps.size // 2
    out = np.empty(keep.size)
    for a, b in pieces:
        sel = (keep >= a) & (keep < b)
        if not sel.any():
            continue
        piece = x[a:b]
        if piece.size < 2:
            out[sel] = piece[keep[sel] - a]
            continue
        padded = np.pad(piece, half, mode="reflect", reflect_type="odd")
        smooth = signal.fftconvolve(padded, taps, mode="valid")
        out[sel] = smooth[keep[sel] - a]
    return out


# ----------------------------------------------------------------------- records
def _excitation_hz(rec: Record) -> tuple[float | None, str]:
    """The frequency the samples-per-cycle floor applies to, and what it is."""
    if rec.frequency_hz is not None:
        return rec.frequency_hz, f"{rec.frequency_hz:g} Hz"
    if rec.band_hz is not None and rec.band_hz[1] > 0:
        return rec.band_hz[1], f"the input band's top {rec.band_hz[1]:.4g} Hz"
    from bayeshyst.data.classify import classify_excitation

    exc = classify_excitation(rec)
    if exc.frequency_hz is not None:
        return float(exc.frequency_hz), f"{exc.frequency_hz:.4g} Hz ({exc.kind})"
    if exc.band_hz is not None and exc.band_hz[1] > 0:
        return float(exc.band_hz[1]), (f"the top of the {exc.kind} input's band "
                                       f"{exc.band_hz[1]:.4g} Hz")
    return None, "no excitation frequency"


def _whole(rec: Record, reason: str, treatment: str = "unchanged", *,
           edges: tuple[float | None, float | None] = (None, None),
           f_exc: float | None = None, jumps: int = 0) -> tuple[Record, RecordRate]:
    fs = rec.fs
    return rec, RecordRate(rec.name, fs, fs, 1, (0.0, fs / 2.0), reason, treatment,
                           edges[0], edges[1], f_exc, rec.n, rec.n, jumps, 1.0)


def _one(rec: Record, rate: str | float, spc: float, margin: float, alpha: float
         ) -> tuple[Record, RecordRate]:
    """One record at its working rate (see the module notes)."""
    if rate == "full":
        return _whole(rec, "full rate requested")
    steps = np.diff(rec.t)
    mean = rec.duration / (rec.n - 1)
    if np.any(np.abs(steps - mean) > _JITTER * mean):
        return _whole(rec, "non-uniform sampling: a FIR filter needs a uniform grid")
    fs = rec.fs
    scored = rec.scored
    found_y = edge_and_floor(rec.y[scored], fs, alpha=alpha) if rec.measured_output else None
    edge_y = None if found_y is None else found_y[0]
    sigma_u = _noise_sd(rec.u)
    k_asked = None if rate == "auto" else max(1, math.floor(fs / float(rate)))
    # piecewise constant: it moves (beyond its noise) only between holds
    moves = _moves(rec.u, sigma_u, alpha)
    stepped = moves.size > 0 and _held(rec.u, _pieces(rec.n, (moves + 1).tolist()),
                                       sigma_u, alpha)
    jumps = moves if stepped else np.zeros(0, dtype=int)
    needs = {}
    if stepped:
        # a staircase has no cycles: only a frequency the record states sets the floor
        f_exc = rec.frequency_hz
        exc_text = f"{f_exc:g} Hz" if f_exc is not None else ""
    else:
        f_exc, exc_text = _excitation_hz(rec)
    if f_exc is not None:
        needs[f"{spc:g} samples per cycle of {exc_text}"] = spc * f_exc
    if edge_y is not None:
        needs[f"noise floor of y above {edge_y:.4g} Hz"] = 2.0 * margin * edge_y
    edge_u = None
    if not stepped:
        # a smooth input's jumps relative to the band the output shows (its signal edge,
        # at least the excitation frequency; the asked rate's band if given)
        if k_asked is not None:
            f_band = fs / k_asked / (2.0 * margin)
        else:
            f_band = max(edge_y or 0.0, f_exc or 0.0)
        if f_band > 0:
            jumps = _jumps(rec.u, fs, f_band, sigma_u, alpha)
        lo = scored.start
        d2_jump = np.zeros(max(rec.n - 2 - lo, 0), dtype=bool)
        for i in jumps[jumps >= lo].tolist():
            d2_jump[max(i - 1 - lo, 0): i + 1 - lo] = True
        # the input's content counts where, times the loop's gain span(y) / span(u), it
        # would stand above the output's floor: a sine's quantisation pattern (1e-6 V)
        # is above the input's own floor but nowhere in the output
        span_u = float(np.ptp(rec.u[scored]))
        gain = float(np.ptp(rec.y[scored])) / span_u if span_u > 0 else 0.0
        floor_min = found_y[1] / gain**2 if found_y is not None and gain > 0 else 0.0
        edge_u = signal_edge(rec.u[scored], fs, alpha=alpha, exclude=d2_jump,
                             floor_at_least=floor_min)
        if edge_u is not None:
            needs[f"input band to {edge_u:.4g} Hz"] = 2.0 * margin * edge_u
    edges = (edge_y, edge_u)
    if k_asked is None:
        if not needs:
            return _whole(rec, "too short to estimate a noise floor and no excitation "
                          "frequency", edges=edges, f_exc=f_exc)
        why, fs_req = max(needs.items(), key=lambda kv: kv[1])
        if fs_req <= 0:
            return _whole(rec, "nothing above the noise floor and no excitation frequency",
                          edges=edges, f_exc=f_exc)
        k = math.floor(fs / fs_req)
        if k < 2:
            return _whole(rec, f"already near its working rate ({why} needs "
                          f"{fs_req:.4g} Hz)", edges=edges, f_exc=f_exc)
    else:
        k = k_asked
        why = f"{float(rate):g} Hz requested"
        if k < 2:
            return _whole(rec, f"{why}, at least the record's rate", edges=edges,
                          f_exc=f_exc)
        short = [w for w, need in needs.items() if need > fs / k]
        if short:
            why += f"; below what {' and '.join(short)} needs"
    if not stepped:
        # the final band is at least as wide as the one the jumps were found with:
        # the filter runs piece by piece between the jumps that remain
        jumps = _jumps(rec.u, fs, fs / k / (2.0 * margin), sigma_u, alpha)
    taps = _design(k, margin)
    # a sample within half the filter of an end is filtered partly against the padding
    # (exact for a sinusoid at the end sample itself, not next to it): the last ones are
    # dropped; the first ones are kept as warm-up, simulated but not scored. Dropping
    # them would start the model mid-record in a state it cannot know: a play PI
    # started at rest 15 working-rate samples up a 5 Hz record's first rise (10 kHz,
    # k = 20) missed its first cycle by 9 % of the stroke, which then decided the
    # held-out score of every candidate
    half = taps.size // 2
    keep = np.arange(0, rec.n - half, k)
    if keep.size < MIN_SAMPLES:
        return _whole(rec, f"too few samples at 1/{k} of the rate once the filter's "
                      f"half-length ({half} samples) is left off the end", edges=edges,
                      f_exc=f_exc)
    own_warmup = math.ceil(rec.warmup / k)
    warmup = min(max(own_warmup, math.ceil(half / k)), keep.size - 2)
    # one record is one contiguous measurement: its output and covariates are filtered
    # whole (segment labels mark protocol phases, not breaks in the signal)
    pieces_y = [(0, rec.n)]
    y = _filtered(rec.y, taps, pieces_y, keep) if rec.measured_output else rec.y[keep]
    u = (rec.u[keep] if stepped
         else _filtered(rec.u, taps, _pieces(rec.n, (jumps + 1).tolist()), keep))
    covariates = {c: _filtered(v, taps, pieces_y, keep) for c, v in rec.covariates.items()}
    fs_out = fs / k
    treatment = "subsampled" if stepped else "filtered"
    info = RecordRate(rec.name, fs, fs_out, k, (0.0, fs_out / (2.0 * margin)), why,
                      treatment, edge_y, edge_u, f_exc, rec.n, int(keep.size),
                      int(jumps.size), float(np.sqrt(np.sum(taps**2))),
                      max(warmup - own_warmup, 0),
                      int(rec.n - 1 - keep[-1]))
    meta = dict(rec.metadata)
    meta["sampling_rate_hz"] = fs_out
    for key in ("excitation_start_index", "virgin_branch_end_index"):
        if isinstance(meta.get(key), int):
            meta[key] //= k
    meta["working_rate"] = str(info)
    out = rec.with_(t=rec.t[keep], u=u, y=y,
                    segment=None if rec.segment is None else rec.segment[keep],
                    covariates=covariates, warmup=warmup, metadata=meta)
    return out, info


def _checked(rate: Any, spc: Any, margin: Any, alpha: Any) -> str | float:
    """Validated arguments of :func:`to_working_rate`; the rate as "auto", "full" or Hz."""
    if isinstance(rate, str):
        if rate not in ("auto", "full"):
            raise ParameterError(f"rate: expected 'auto', 'full' or a rate in Hz > 0, got "
                                 f"{rate!r}")
    elif (isinstance(rate, bool) or not isinstance(rate, int | float | np.number)
          or not math.isfinite(float(rate)) or float(rate) <= 0):
        raise ParameterError(f"rate: expected 'auto', 'full' or a finite rate in Hz > 0, "
                             f"got {rate!r}")
    for name, value, lo in (("min_samples_per_cycle", spc, 2.0), ("margin", margin, 1.0)):
        if (isinstance(value, bool) or not isinstance(value, int | float | np.number)
                or not math.isfinite(float(value)) or float(value) < lo
                or (name == "margin" and float(value) == lo)):
            bound = ">= 2" if name == "min_samples_per_cycle" else "> 1"
            raise ParameterError(f"{name}: expected a finite number {bound}, got {value!r}")
    if (isinstance(alpha, bool) or not isinstance(alpha, int | float | np.number)
            or not 0.0 < float(alpha) < 1.0):
        raise ParameterError(f"alpha: expected a number in (0, 1), got {alpha!r}")
    return rate if isinstance(rate, str) else float(rate)


def to_working_rate(data: Dataset | Record, *, rate: str | float = "auto",
                    min_samples_per_cycle: float = MIN_SAMPLES_PER_CYCLE,
                    margin: float = MARGIN, alpha: float = ALPHA
                    ) -> tuple[Dataset, WorkingRate]:
    """Each record at an anti-aliased working rate chosen from its data.

    Parameters
    ----------
    data : Dataset or Record
        Validated records, each sampled uniformly.
    rate : {"auto", "full"} or float, default "auto"
        ``"auto"``: the rule of the module notes, per record; ``"full"``: every record
        as it is (the same Dataset is returned); a number: decimate each record by
        ``k = floor(fs / rate)`` [Hz] (so at least ``rate``), anti-aliased the same way.
    min_samples_per_cycle : float, default 100
        Fewest samples per cycle of the highest excitation frequency ``auto`` keeps
        (>= 2).
    margin : float, default 1.5
        New Nyquist frequency over the highest frequency kept (> 1).
    alpha : float, default 0.01
        Family-wise level of the noise-floor and jump tests, in (0, 1).

    Returns
    -------
    (Dataset, WorkingRate)
        The records at their working rates (same names, order and dataset name), and
        what was done with each.

    Raises
    ------
    ParameterError
        For an unknown ``rate`` or a setting out of range (the message names it).
    DataError
        When ``data`` is neither a Dataset nor a Record.
    """
    mode = _checked(rate, min_samples_per_cycle, margin, alpha)
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    if not isinstance(data, Dataset):
        raise DataError(f"data: expected a Dataset or a Record, got {type(data).__name__}")
    pairs = [_one(r, mode, float(min_samples_per_cycle), float(margin), float(alpha))
             for r in data]
    info = WorkingRate(mode, float(min_samples_per_cycle), float(margin), float(alpha),
                       tuple(p[1] for p in pairs))
    if not info.changed:
        return data, info
    return Dataset(tuple(p[0] for p in pairs), name=data.name), info
