"""What kind of excitation drove a record: periodic, stepped, multisine or broadband.

Cutting a record into "cycles" between input minima only makes sense when the input
repeats. A band-limited random drive, a sweep or a multisine also has minima, but the
pieces between them are not cycles of anything: labelling them with frequencies and
restarting the model from rest at each of them invents data. :func:`classify_excitation`
decides from the input alone (its scored part) which of four kinds a record is:

``periodic``
    One period repeats (at least twice) and the fundamental line holds at least half of
    the input's AC power (sine, triangle, square-ish); or the record is one closed loop
    (the input returns to its start after one maximum and one minimum, e.g. a measured
    B(H) loop), taken as one cycle at ``1 / duration``.
``stepped``
    Several blocks of cycles at different frequencies (a stepped sine), each block
    periodic by the same test.
``multisine``
    A period repeats (at least twice) but its fundamental holds less than half of the
    AC power: many lines (a multisine, a periodic arbitrary waveform).
``broadband``
    Nothing repeats within what the input noise explains: random / band-limited noise,
    sweeps, arbitrary histories, steps with holds.

Periodicity test. For a candidate period of ``L`` samples the input ``x`` (mean
removed) is compared with itself shifted by ``L`` in consecutive windows of ``L``
samples. In each window the mismatch is ``m = 1 - sign(r) r**2`` with ``r`` the
correlation of the two (window-centred) pieces: the fraction of the later piece's
variance that a scaled copy of the earlier one leaves unexplained (a decaying sine
repeats up to scale). White input noise of variance ``s2`` alone leaves
``m_noise = s2 len (1/E1 + 1/E2)`` (``E`` the pieces' energies); ``s2`` is estimated
like :func:`bayeshyst.data.segment.default_prominence` does (MAD of the second
difference), floored by the quantisation step ``q**2 / 12``. A window repeats when
``m <= NOISE_ALLOWANCE m_noise + m_grid``: the allowance (4) admits a noise standard
deviation misestimated by a factor 2 (coloured or filtered noise); ``m_grid`` is the
lag-1 mismatch of the window beyond noise, bounding what a period that is not a whole
number of samples costs (a shift by less than one sample). A record is periodic at the
smallest candidate for which at least :data:`QUORUM` of the windows repeat (a start
transient or a dropout may spoil one window in five), provided the noise allowance
stays below 1/2 (an unrelated window has ``m`` near 1; above that the noise hides any
structure). A window with ``m <= EXACT_REPEAT`` (0.01) repeats whatever the allowance:
the noise estimate is an upper bound that input content near Nyquist inflates (the
Bouc-Wen benchmark's 5-150 Hz multisine at 750 Hz), and a copy that explains 99 % of a
window's variance is no accident of noise. Candidates are the local minima of the
whole-record mismatch with ``m < 1/2`` beyond the first zero of the autocorrelation, up
to half the record (two periods needed). Nothing is tuned to particular signals.

Band. ``band_hz`` is the range where the input's power spectral density, less five
times the level of the estimated white input noise, is within
:data:`BAND_DB` (20 dB) of its peak, widened to hold the central 98 % of the AC power
(a log sweep's PSD falls as ``1/f``; its power still reaches the top of the sweep).
The spectrum is the line spectrum over whole periods for periodic
and multisine records (no leakage, so a multisine's band is its first and last line),
a Welch estimate (Hann, segments of a quarter of the record, half overlapping)
otherwise, whose resolution is ``4 / duration``.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from bayeshyst.data.record import Record
from bayeshyst.data.segment import (
    FREQUENCY_BIN,
    SPECTRAL_CYCLES,
    CycleSplit,
    _blocks_of,
    _rounded,
    _uniform,
    default_prominence,
    estimate_frequency,
    find_reversals,
    input_noise_sd,
    split_cycles,
)
from bayeshyst.tables import TableRecord, frame

__all__ = [
    "BAND_DB",
    "NOISE_ALLOWANCE",
    "QUORUM",
    "Excitation",
    "block_bounds",
    "classify_excitation",
]

_log = logging.getLogger("bayeshyst.data.segment")  # the labels' log, as before

Kind = Literal["periodic", "stepped", "multisine", "broadband"]

#: factor on the noise-explained mismatch a repeating window may reach (noise sd
#: misestimated by up to a factor 2)
NOISE_ALLOWANCE = 4.0
#: fraction of the windows that must repeat for a period to be accepted
QUORUM = 0.8
#: mismatch below which a window repeats whatever the noise estimate allows (the copy
#: explains 99 % of the window's variance: a correlation of 0.995)
EXACT_REPEAT = 0.01
#: ``band_hz``: where the input's PSD is within this many dB of its peak
BAND_DB = 20.0
#: a periodic record whose fundamental holds at least this share of the AC power has
#: one fundamental (sine, triangle, square: 100, 81, 81 %); below it, many lines
FUNDAMENTAL_SHARE = 0.5
#: candidates for the period tested, at most (smallest lags first)
_MAX_CANDIDATES = 20


@dataclass(frozen=True)
class Excitation(TableRecord):
    """How a record's input was classified.

    Attributes
    ----------
    kind : {"periodic", "stepped", "multisine", "broadband"}
        See :mod:`bayeshyst.data.classify`.
    period_s : float or None
        Detected period [s] (periodic, multisine); None otherwise.
    frequency_hz : float or None
        Fundamental excitation frequency [Hz] of a periodic record; None otherwise.
    band_hz : tuple of (float, float) or None
        ``(lo, hi)`` [Hz] where the input's PSD is within :data:`BAND_DB` of its peak;
        None for a constant input.
    n_periods : float
        Periods (periodic, multisine) or whole cycles (stepped) in the scored part; 0
        for broadband.
    evidence : str
        One line: the statistic the decision rests on.
    """

    kind: Kind
    period_s: float | None
    frequency_hz: float | None
    band_hz: tuple[float, float] | None
    n_periods: float
    evidence: str

    def __str__(self) -> str:
        parts = [self.kind]
        if self.frequency_hz is not None:
            parts.append(f"{self.frequency_hz:.4g} Hz")
        if self.period_s is not None:
            parts.append(f"period {self.period_s:.4g} s x {self.n_periods:.3g}")
        if self.band_hz is not None:
            parts.append(f"band {self.band_hz[0]:.3g}-{self.band_hz[1]:.3g} Hz")
        return ", ".join(parts) + f" ({self.evidence})"

    def to_dict(self) -> dict[str, Any]:
        """The fields as JSON-ready values (``band_hz`` as a list)."""
        out = asdict(self)
        out["band_hz"] = None if self.band_hz is None else list(self.band_hz)
        return out

    def to_dataframe(self) -> Any:
        """One row: the fields of :meth:`to_dict` (the band as ``band_hz_lo``/``_hi``)."""
        return frame([self.to_dict()])


def _noise_var(u: np.ndarray) -> float:
    """Input noise variance: MAD of the 2nd difference, floored by quantisation q^2/12.

    ``q`` is the smallest step between the input's distinct values; it counts as an ADC
    step only when the span holds at least 64 of them (a square wave's two levels are
    signal, not quantisation). A slow quantised input has a zero MAD.
    """
    sigma = input_noise_sd(u)
    levels = np.unique(u)
    q = float(np.min(np.diff(levels))) if levels.size > 1 else 0.0
    if q <= 0 or float(np.ptp(u)) < 64 * q:
        return sigma**2
    return max(sigma**2, q**2 / 12.0)


def _mismatch_curve(x: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Whole-record correlation ``r(L)`` and mismatch ``1 - sign(r) r^2`` for L <= max_lag."""
    n = x.size
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.fft.rfft(x, nfft)
    c = np.fft.irfft(spec * np.conj(spec), nfft)[: max_lag + 1]
    cs = np.concatenate([[0.0], np.cumsum(x * x)])
    lag = np.arange(max_lag + 1)
    e = np.sqrt((cs[n - lag]) * (cs[n] - cs[lag]))
    r = np.divide(c, e, out=np.zeros_like(c), where=e > 0)
    return r, 1.0 - np.sign(r) * r * r


def _window_stats(x: np.ndarray, lag: int, starts: np.ndarray, size: int,
                  noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Mismatch and noise-explained mismatch of windows ``[s, s+size)`` vs ``+lag``."""
    idx = starts[:, None] + np.arange(size)[None, :]
    a = x[idx]
    b = x[idx + lag]
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    e1, e2, c = (a * a).sum(1), (b * b).sum(1), (a * b).sum(1)
    ok = (e1 > 0) & (e2 > 0)
    r = np.where(ok, c / np.sqrt(np.where(ok, e1 * e2, 1.0)), 0.0)
    m = 1.0 - np.sign(r) * r * r
    with np.errstate(divide="ignore"):
        mn = np.where(ok, noise * size * (1.0 / e1 + 1.0 / e2), np.inf)
    return m, mn


def _repeats(x: np.ndarray, lag: int, noise: float, lo: int = 0,
             hi: int | None = None) -> tuple[float, float, float]:
    """Fraction of windows of ``x[lo:hi]`` that repeat after ``lag`` samples.

    Returns ``(fraction, median mismatch, median allowance)``; the fraction is 0 when
    the noise allowance reaches 1/2 (the noise hides any structure).
    """
    hi = x.size if hi is None else hi
    k = (hi - lo - lag) // lag
    if k < 1 or lag < 2:
        return 0.0, 1.0, 0.0
    # windows tile [lo, hi - lag); the few samples left over are not tested
    max_windows = 2000  # enough for the quorum's statistics, bounded cost
    step = max(1, k // max_windows)
    starts = lo + lag * np.arange(0, k, step)
    m, mn = _window_stats(x, lag, starts, lag, noise)
    m1, mn1 = _window_stats(x, 1, starts, lag, noise)
    grid = np.maximum(m1 - mn1, 0.0)
    allow = NOISE_ALLOWANCE * mn + grid
    # a window whose later piece a copy of the earlier one explains to EXACT_REPEAT
    # repeats whatever the noise estimate says: that estimate (second differences) is
    # an upper bound, inflated by input content near Nyquist (a 5-150 Hz multisine at
    # 750 Hz), while an unrelated window leaves m near 1
    repeats = (m <= allow) | (m <= EXACT_REPEAT)
    if np.median(NOISE_ALLOWANCE * mn) >= 0.5 and np.median(m) > EXACT_REPEAT:
        return 0.0, float(np.median(m)), float(np.median(allow))
    return float(np.mean(repeats)), float(np.median(m)), float(np.median(allow))


def _vertex(m: np.ndarray, i: int) -> float:
    """Parabolic vertex of ``m`` around its local minimum at integer ``i``."""
    if not 0 < i < m.size - 1:
        return float(i)
    a, b, c = m[i - 1], m[i], m[i + 1]
    den = a - 2 * b + c
    return i + (float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)) if den > 0 else 0.0)


def _find_period(x: np.ndarray, noise: float) -> tuple[float | None, str]:
    """Period [samples] of ``x`` (two periods at least), or None; and the evidence."""
    n = x.size
    max_lag = n // 2
    if max_lag < 3 or not np.any(x):
        return None, "too short or constant for a period"
    # one lag past half the record, so that a record of exactly two periods has its
    # dip at n / 2 tested as a local minimum
    r, m = _mismatch_curve(x, min(max_lag + 1, n - 1))
    neg = np.flatnonzero(r[1:] <= 0)
    if neg.size == 0:
        return None, "the autocorrelation stays positive up to half the record (drift)"
    first = int(neg[0]) + 1
    core = m[first : max_lag + 1]
    inner = np.arange(first + 1, min(max_lag, m.size - 2) + 1)
    is_min = (m[inner] <= m[inner - 1]) & (m[inner] <= m[inner + 1]) & (m[inner] < 0.5)
    cands = inner[is_min][:_MAX_CANDIDATES]
    best = (0.0, float(core.min()) if core.size else 1.0, 0.0, 0)
    for lag in cands.tolist():
        frac, med, allow = _repeats(x, int(lag), noise)
        if frac > best[0]:
            best = (frac, med, allow, int(lag))
        if frac >= QUORUM:
            # fractional period: the best lag near 2, 4, 8 ... periods (within half the
            # record), refined by a parabola, over the multiple; each doubling halves
            # the error (< 0.5 sample / multiple), so +-2 samples keeps the right dip
            period, k = _vertex(m, lag), 1
            while 2 * k * period <= max_lag:
                k *= 2
                c0 = round(k * period)
                lo_, hi_ = max(1, c0 - 2), min(c0 + 2, m.size - 2)
                period = _vertex(m, lo_ + int(np.argmin(m[lo_ : hi_ + 1]))) / k
            return period, (f"repeats every {period:.2f} samples in {frac:.0%} of "
                            f"{(n - lag) // lag} window(s) (median mismatch {med:.2g}, "
                            f"noise allows {allow:.2g})")
    if best[3]:
        return None, (f"no period: best candidate {best[3]} samples repeats in "
                      f"{best[0]:.0%} of windows (median mismatch {best[1]:.2g}, noise "
                      f"allows {best[2]:.2g}; {QUORUM:.0%} needed)")
    return None, (f"no period: the mismatch never falls below 0.5 after the "
                  f"autocorrelation's first zero (minimum {best[1]:.2g})")


def _band(x: np.ndarray, dt: float, period: float | None,
          noise: float) -> tuple[float, float] | None:
    """Frequencies [Hz] where the PSD is within BAND_DB of its peak (see module doc)."""
    if not np.any(x):
        return None
    if period is not None and period * 1.0 <= x.size:
        # whole periods, rectangular window: a periodic signal's lines without leakage
        k = int(np.floor(x.size / period + 1e-9))
        seg = x[: max(2, round(k * period))]
        seg = seg - seg.mean()
        psd = np.abs(np.fft.rfft(seg)) ** 2
        f = np.fft.rfftfreq(seg.size, dt)
        floor = seg.size * noise  # E|X_k|^2 of white noise of variance `noise`
    else:
        from scipy.signal import welch  # deferred: scipy.signal is slow to import

        nper = min(x.size, max(x.size // 4, min(x.size, 64)))
        f, psd = welch(x, fs=1.0 / dt, window="hann", nperseg=nper, detrend="constant")
        floor = 2.0 * noise * dt  # one-sided density of white noise
    # the input's measurement noise is not excitation: a white-noise bin exceeds five
    # times its mean with probability e^-5, so this removes it from band and power
    raw = np.asarray(psd, dtype=float)
    raw[0] = 0.0  # the mean was removed; DC is no excitation
    psd = np.maximum(raw - 5.0 * floor, 0.0)
    if float(psd.max()) <= 0:
        # nothing stands above the "noise": the noise estimate (second differences) is
        # the excitation itself, a broadband input reaching Nyquist; its own spectrum
        psd = raw
    top = float(psd.max())
    if top <= 0:
        return None
    on = np.flatnonzero(psd >= top * 10 ** (-BAND_DB / 10))
    # union with the central 98 % of the power: a log sweep's PSD falls as 1/f and
    # leaves the 20 dB range before its top frequency; its power does not
    cum = np.cumsum(psd) / np.sum(psd)
    q_lo = int(np.searchsorted(cum, 0.01))
    q_hi = min(int(np.searchsorted(cum, 0.99)), f.size - 1)
    return float(f[min(on[0], q_lo)]), float(f[max(on[-1], q_hi)])


def _fundamental_share(x: np.ndarray, period: float) -> float:
    """Share of the AC power of whole periods of ``x`` in the line at 1/period."""
    k = int(np.floor(x.size / period + 1e-9))
    n = max(2, round(k * period))
    seg = x[:n] - x[:n].mean()
    power = float(np.mean(seg * seg))
    if power <= 0:
        return 0.0
    line = np.dot(seg, np.exp(-2j * np.pi * np.arange(n) / period))
    return float(2.0 * abs(line) ** 2 / n**2 / power)


def _closed_loop(u: np.ndarray) -> bool:
    """One loop: one max and one min, back to the start, the input moving (no holds).

    A jump of more than a quarter of the range (a step test) is not a loop.
    """
    span = float(np.ptp(u))
    if span <= 0 or u.size < 4:
        return False
    rev = find_reversals(u)
    thr = default_prominence(u)
    return (1 <= rev.size <= 2 and abs(float(u[-1] - u[0])) <= thr
            and float(np.max(np.abs(np.diff(u)))) <= 0.25 * span)


def _stepped(record: Record, split: CycleSplit, noise: float,
             blocks: list[list[int]]) -> tuple[str, list[list[int]]] | None:
    """Evidence that every block of cycles repeats (a stepped sine), and the steps.

    None unless every block repeats and at least two blocks differ in frequency by more
    than :data:`FREQUENCY_BIN`; neighbouring blocks at one frequency are merged.
    """
    x = record.u - float(np.mean(record.u[record.scored]))
    freqs = []
    for b in blocks:
        lengths = np.array([split.cycles[i].stop - split.cycles[i].start for i in b])
        med = float(np.median(lengths))
        # transition cycles (joined to a block by _blocks_of) are not tested
        steady = [i for i, n in zip(b, lengths, strict=True)
                  if abs(np.log(n / med)) <= np.log1p(FREQUENCY_BIN)]
        if len(steady) < 2 or steady != list(range(steady[0], steady[-1] + 1)):
            return None
        lo, hi = split.cycles[steady[0]].start, split.cycles[steady[-1]].stop
        # the period: best lag within the bin around the mean cycle (noisy minima move
        # by several samples, the shifted block's mismatch does not)
        mean = (hi - lo) / len(steady)
        a = max(2, int(np.floor(mean / (1 + FREQUENCY_BIN))))
        b_ = min(int(np.ceil(mean * (1 + FREQUENCY_BIN))), (hi - lo) // 2)
        if b_ < a:
            return None
        m = _mismatch_curve(x[lo:hi] - np.mean(x[lo:hi]), b_)[1]
        lag = a + int(np.argmin(m[a : b_ + 1]))
        if _repeats(x, lag, noise, lo, hi)[0] < QUORUM:
            return None
        freqs.append(1.0 / (lag * record.dt))
    # neighbouring blocks at one frequency (noisy minima broke a run): one step
    merged, steps = [list(blocks[0])], [freqs[0]]
    for b, f in zip(blocks[1:], freqs[1:], strict=True):
        if abs(np.log(f / steps[-1])) <= np.log1p(FREQUENCY_BIN):
            merged[-1].extend(b)
        else:
            merged.append(list(b))
            steps.append(f)
    if len(merged) < 2:
        return None
    return (f"{len(merged)} blocks of repeating cycles at "
            f"{', '.join(f'{f:.3g}' for f in steps)} Hz"), merged


def _classify(record: Record) -> tuple[Excitation, CycleSplit | None, list[list[int]]]:
    """:func:`classify_excitation`, plus the cycles and blocks of a stepped record."""
    # the whole input, warm-up included: it is the same excitation, and a record whose
    # warm-up is one of its two periods repeats only with it
    u, dt = _uniform(record.with_(warmup=0) if record.warmup else record)
    x = u - float(np.mean(u))
    noise = _noise_var(u)
    duration = dt * (u.size - 1)
    if not np.any(x):
        return Excitation("broadband", None, None, None, 0.0, "constant input"), None, []
    split = split_cycles(record)
    blocks: list[list[int]] = []
    if len(split) >= 2:
        t = record.t
        ends = np.array([t[min(c.stop, record.n - 1)] for c in split.cycles])
        blocks = _blocks_of(1.0 / (ends - np.array([t[c.start] for c in split.cycles])))
    if len(blocks) >= 2:
        found = _stepped(record, split, noise, blocks)
        if found is not None:
            return (Excitation("stepped", None, None, _band(x, dt, None, noise), float(len(split)),
                               found[0]), split, found[1])
    period, why = _find_period(x, noise)
    if period is not None:
        n_per = u.size / period
        share = _fundamental_share(x, period)
        band = _band(x, dt, period, noise)
        why = f"{why}; fundamental holds {share:.0%} of the AC power"
        if share >= FUNDAMENTAL_SHARE:
            # few periods: the period found by repetition (the spectral peak of two
            # Hann-windowed cycles is biased by ~0.5 %); more: the refined spectral peak
            f0 = (1.0 / (period * dt) if n_per < SPECTRAL_CYCLES
                  else estimate_frequency(record))
            return (Excitation("periodic", period * dt, f0, band, n_per, why), split,
                    blocks)
        return Excitation("multisine", period * dt, None, band, n_per, why), split, blocks
    if _closed_loop(u):
        return (Excitation(
            "periodic", duration, 1.0 / duration, _band(x, dt, float(u.size), noise), 1.0,
            "one closed loop: the input returns to its start after one maximum and one "
            "minimum; one cycle of a periodic excitation at 1/duration"), split, blocks)
    return Excitation("broadband", None, None, _band(x, dt, None, noise), 0.0, why), split, blocks


def _labelled(rec: Record) -> list[Record]:
    """One unlabelled record classified and labelled, or split into its steps.

    The rules are those of :func:`bayeshyst.data.segment.label_frequencies`.
    """
    out: list[Record] = []
    exc, split, blocks = _classify(rec)
    band = exc.band_hz
    band_text = "" if band is None else f", {band[0]:.3g}-{band[1]:.3g} Hz"
    base = {**rec.metadata, "excitation": exc.kind, "band_hz": band,
            "excitation_evidence": exc.evidence}
    if exc.kind == "periodic":
        # periodic by repetition: at least two periods; fewer: one closed loop
        one_loop = exc.n_periods < 2
        f = _rounded(float(exc.frequency_hz))  # type: ignore[arg-type]
        source = ("one closed loop (1/duration)" if one_loop
                  else f"estimated ({len(split) if split else 0} cycles)")
        _log.info("%s: no frequency_hz; %g Hz, %s", rec.name, f, source)
        out.append(rec.with_(metadata={
            **base, "frequency_hz": f, "frequency_source": source,
            "excitation_note": (f"periodic, {f:g} Hz (one closed loop" if one_loop else
                                f"periodic, {f:g} Hz ({exc.n_periods:.3g} periods")
                               + f"{band_text}), kept whole"}))
        return out
    if exc.kind in ("multisine", "broadband") or split is None:
        if exc.kind == "multisine":
            base["period_s"] = exc.period_s
            note = (f"multisine, period {exc.period_s:.4g} s x {exc.n_periods:.3g}"
                    f"{band_text}, kept whole (no cycles cut, no single frequency)")
        else:
            note = f"broadband{band_text}, kept whole (no cycles cut)"
        out.append(rec.with_(metadata={
            **base, "excitation_note": note,
            "frequency_note": f"{exc.kind} input: no excitation frequency "
                              f"({exc.evidence})"}))
        return out
    _log.info("%s: no frequency_hz; %d blocks of cycles at different frequencies",
              rec.name, len(blocks))
    t = rec.t
    ends = np.array([t[min(c.stop, rec.n - 1)] for c in split.cycles])
    starts = [split.cycles[b[0]].start for b in blocks]
    bounds = [0, *starts[1:], rec.n]
    note = f"stepped{band_text}, split into {len(blocks)} records, one per step"
    for k, (a, b) in enumerate(itertools.pairwise(bounds)):
        first = split.cycles[blocks[k][0]]
        warm = rec.warmup if k == 0 else first.stop - first.start
        piece = rec.slice(a, b, warmup=min(warm, b - a - 2), name=f"{rec.name}/{k}")
        # a steady block of several cycles: its spectrum (a noisy input's minima
        # move by tens of samples, its spectral peak does not); a short block:
        # its cycles over their duration (a spectrum of two cycles is not resolved)
        if len(blocks[k]) >= SPECTRAL_CYCLES:
            f = _rounded(estimate_frequency(piece))
        else:
            span = ends[blocks[k][-1]] - t[first.start]
            f = _rounded(len(blocks[k]) / span)
        out.append(dataclasses.replace(piece, metadata={
            **base, "frequency_hz": f, "parent": rec.name,
            "parent_slice": (a, b), "excitation_note": note,
            "frequency_source": f"estimated ({len(blocks[k])} cycles)"}))
    return out


def classify_excitation(record: Record) -> Excitation:
    """Classify the excitation of a record from its scored input.

    Parameters
    ----------
    record : Record
        The measurement; its warm-up is excluded, its input ``u`` [any unit] sampled
        uniformly (interpolated if the timing jitters by more than 1 %).

    Returns
    -------
    Excitation
        Kind, period [s], fundamental [Hz], band [Hz], number of periods and evidence;
        the decision rules are in :mod:`bayeshyst.data.classify`.
    """
    return _classify(record)[0]


def block_bounds(n: int, start: int, period: int | None = None,
                 target_blocks: int = 8, min_block: int = 256) -> list[tuple[int, int]]:
    """Contiguous blocks partitioning ``[start, n)``, for records without cycles.

    Parameters
    ----------
    n : int
        Samples of the record.
    start : int
        First scored sample.
    period : int, optional
        Period [samples]: one block per whole period, the partial rest joining the last.
        Used when at least two periods fit.
    target_blocks : int, default 8
        Otherwise, this many blocks of equal length ...
    min_block : int, default 256
        ... but none shorter than this many samples (fewer blocks; one if the scored
        part is shorter than ``2 min_block``).

    Returns
    -------
    list of (int, int)
        ``[a, b)`` sample ranges, consecutive, covering ``[start, n)``.
    """
    size = n - start
    if period is not None and period >= 2 and size // period >= 2:
        k = size // period
    else:
        k = max(1, min(target_blocks, size // max(1, min_block)))
    edges = [start + (size * j) // k for j in range(k)] + [n]
    if period is not None and period >= 2 and size // period >= 2:
        edges = [start + period * j for j in range(k)] + [n]
    return list(itertools.pairwise(edges))
