"""Segmentation of records into input cycles and frequency blocks.

Hysteresis is a property of *cycles*: a loop runs from one input minimum to the next.
The likelihood sums pointwise log-likelihood per cycle (for leave-one-cycle-out
cross-validation), and reports are made per excitation frequency. This module finds
the input turning points robustly, cuts records into whole cycles (reporting the
partial ends instead of dropping them), estimates the excitation frequency when the
metadata lacks it, and splits multi-frequency records into one Record per block.
Only records whose input repeats are cut: :func:`label_frequencies` first classifies
the excitation (:mod:`bayeshyst.data.classify`) and keeps broadband and multisine
records whole.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import MIN_SAMPLES, Record
from bayeshyst.errors import DataError

__all__ = [
    "CycleSplit",
    "cycle_labels",
    "default_prominence",
    "estimate_frequency",
    "find_reversals",
    "input_noise_sd",
    "label_frequencies",
    "split_by_frequency",
    "split_cycles",
]

_log = logging.getLogger(__name__)

#: Default prominence as a fraction of the input's peak-to-peak range.
_RANGE_FRACTION = 0.01
#: Default prominence as a multiple of the estimated input noise standard deviation.
#: Ten sigma: the zig-zag compares a running extreme (itself a noise maximum, ~+3 sigma
#: over thousands of samples) with a later sample (~-3 sigma), so 6-7 sigma swings
#: happen by chance; 10 sigma keeps false reversals practically impossible.
_NOISE_FACTOR = 10.0


def _input_vector(u: object) -> np.ndarray:
    arr = np.asarray(u, dtype=np.float64)
    if arr.ndim != 1 or arr.size < 2:
        raise DataError(f"input u: expected a 1-D array of at least 2 samples, got {arr.shape}")
    if not np.isfinite(arr).all():
        i = int(np.argmax(~np.isfinite(arr)))
        raise DataError(
            f"input u, sample index {i} (0-based): expected a finite value, got {float(arr[i])!r}"
        )
    return arr


def default_prominence(u: np.ndarray) -> float:
    """Default reversal threshold for input ``u``: ``max(1 % of p-p, 10 noise sigma)``.

    The noise standard deviation is estimated from the median absolute deviation of the
    second difference (``sigma = 1.4826 MAD / sqrt(6)``), which a smooth, well-sampled
    excitation barely affects but white measurement noise dominates.

    Parameters
    ----------
    u : array_like of float, shape (n,)
        Input signal [any unit].

    Returns
    -------
    float
        Threshold in the unit of ``u`` (0 for a constant input).
    """
    arr = _input_vector(u)
    return max(_RANGE_FRACTION * float(np.ptp(arr)), _NOISE_FACTOR * input_noise_sd(arr))


def input_noise_sd(u: np.ndarray) -> float:
    """White-noise standard deviation of input ``u``: ``1.4826 MAD(diff(u, 2)) / sqrt(6)``.

    The second difference of white noise of variance ``s2`` has variance ``6 s2``; a
    smooth, well-sampled excitation barely moves its median absolute deviation. A
    signal with power near the Nyquist frequency inflates the estimate.

    Parameters
    ----------
    u : array_like of float, shape (n,)
        Input signal [any unit].

    Returns
    -------
    float
        Standard deviation in the unit of ``u`` (0 for fewer than 3 samples).
    """
    arr = _input_vector(u)
    if arr.size < 3:
        return 0.0
    d2 = np.diff(arr, 2)
    return 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)


def _zigzag(u: np.ndarray, threshold: float) -> tuple[list[int], list[bool]]:
    """Turning points with hysteresis: an extreme counts once u retreats > threshold.

    Returns indices and a parallel list ``is_max``. The first extreme found before the
    direction is known is the record's edge, not a reversal, and is not reported.
    """
    idx: list[int] = []
    is_max: list[bool] = []
    hi = lo = u[0]
    hi_i = lo_i = 0
    direction = 0  # 0 unknown, +1 rising (tracking a maximum), -1 falling
    for i, v in enumerate(u.tolist()):
        if direction >= 0 and v > hi:
            hi, hi_i = v, i
        if direction <= 0 and v < lo:
            lo, lo_i = v, i
        if direction >= 0 and v < hi - threshold:
            if direction == 1:
                idx.append(hi_i)
                is_max.append(True)
            direction, lo, lo_i = -1, v, i
        elif direction <= 0 and v > lo + threshold:
            if direction == -1:
                idx.append(lo_i)
                is_max.append(False)
            direction, hi, hi_i = 1, v, i
    return idx, is_max


def find_reversals(
    u: np.ndarray,
    *,
    min_prominence: float | None = None,
    kind: Literal["both", "min", "max"] = "both",
) -> np.ndarray:
    """Indices of the input's turning points, robust to noise.

    A candidate extreme becomes a reversal only after the input has moved back from it
    by more than ``min_prominence`` (a zig-zag / hysteresis filter), so noise smaller
    than the threshold never creates spurious turning points. Reversals alternate
    between maxima and minima; the starting edge of the record is not a reversal.

    Parameters
    ----------
    u : array_like of float, shape (n,)
        Input signal.
    min_prominence : float, optional
        Retreat [unit of u] that confirms an extreme. Default
        :func:`default_prominence` (max of 1 % of peak-to-peak and 10 noise sigma).
    kind : {"both", "min", "max"}, default "both"
        Which turning points to return.

    Returns
    -------
    numpy.ndarray of int, shape (k,)
        Sample indices in increasing order (first occurrence of a flat extreme).
    """
    arr = _input_vector(u)
    if kind not in ("both", "min", "max"):
        raise ValueError(f"kind: expected 'both', 'min' or 'max', got {kind!r}")
    thr = default_prominence(arr) if min_prominence is None else float(min_prominence)
    if not np.isfinite(thr) or thr < 0:
        raise ValueError(f"min_prominence: expected a finite value >= 0, got {min_prominence!r}")
    if np.ptp(arr) == 0:
        return np.zeros(0, dtype=np.int64)
    idx, is_max = _zigzag(arr, thr)
    keep = [i for i, m in zip(idx, is_max, strict=True) if kind == "both" or m == (kind == "max")]
    return np.asarray(keep, dtype=np.int64)


@dataclass(frozen=True)
class CycleSplit:
    """Whole input cycles of a record and the partial pieces at its ends.

    Attributes
    ----------
    cycles : tuple of slice
        Sample ranges of whole cycles, consecutive and non-overlapping.
    head : slice or None
        Samples before the first whole cycle (includes the warm-up), None if empty.
    tail : slice or None
        Samples after the last whole cycle, None if empty.
    n : int
        Number of samples of the record.
    method : str
        ``"reversals"`` (minimum to minimum) or ``"period"`` (fixed period).
    period : float or None
        The fixed period [s] in ``"period"`` mode, None otherwise.
    """

    cycles: tuple[slice, ...]
    head: slice | None
    tail: slice | None
    n: int
    method: str
    period: float | None = None

    def __len__(self) -> int:
        return len(self.cycles)

    def __iter__(self) -> Iterator[slice]:
        return iter(self.cycles)

    def labels(self) -> np.ndarray:
        """Per-sample cycle index, shape (n,), int64; -1 outside whole cycles."""
        out = np.full(self.n, -1, dtype=np.int64)
        for k, sl in enumerate(self.cycles):
            out[sl] = k
        return out

    def __str__(self) -> str:
        def fmt(s: slice | None) -> str:
            return "none" if s is None else f"{s.start}:{s.stop}"

        extra = "" if self.period is None else f", period {self.period:g} s"
        span = f" over {self.cycles[0].start}:{self.cycles[-1].stop}" if self.cycles else ""
        return (
            f"CycleSplit: {len(self.cycles)} whole cycle(s) by {self.method}{extra}{span}; "
            f"partial head {fmt(self.head)}, tail {fmt(self.tail)} of {self.n} samples"
        )


def _make_split(bounds: list[int], n: int, method: str, period: float | None) -> CycleSplit:
    cycles = tuple(slice(a, b) for a, b in itertools.pairwise(bounds))
    first = bounds[0] if len(bounds) > 1 else n
    last = bounds[-1] if len(bounds) > 1 else n
    return CycleSplit(
        cycles=cycles,
        head=slice(0, first) if first > 0 else None,
        tail=slice(last, n) if last < n else None,
        n=n,
        method=method,
        period=period,
    )


def split_cycles(
    record: Record,
    *,
    period: float | None = None,
    by: Literal["reversals", "period"] = "reversals",
    min_prominence: float | None = None,
) -> CycleSplit:
    """Cut a record into whole input cycles after its warm-up.

    Parameters
    ----------
    record : Record
        The measurement.
    period : float, optional
        Fixed cycle length [s]. Implies ``by="period"``.
    by : {"reversals", "period"}, default "reversals"
        ``"reversals"``: each cycle runs from one input minimum (found by
        :func:`find_reversals`, at or after the warm-up) to the next.
        ``"period"``: cycles of length ``period`` (default ``1 / frequency_hz`` from
        the metadata, else :func:`estimate_frequency`) starting at the first scored
        sample; a cycle is whole when the record reaches its last sample slot.
    min_prominence : float, optional
        Passed to :func:`find_reversals`.

    Returns
    -------
    CycleSplit
        Whole cycles plus the partial ``head`` (including warm-up) and ``tail``.
    """
    n = record.n
    if period is not None or by == "period":
        if period is None:
            freq = record.frequency_hz or estimate_frequency(record)
            period = 1.0 / freq
        if not np.isfinite(period) or period <= 0:
            raise ValueError(f"period: expected a positive number of seconds, got {period!r}")
        t = record.t
        t0 = t[record.warmup]
        dt = record.dt
        # whole cycles: the record must reach the last sample slot of the cycle
        k_max = int(np.floor((t[-1] - t0 + 1.5 * dt) / period + 1e-9))
        targets = t0 + period * np.arange(k_max + 1)
        bounds = np.searchsorted(t, targets - 1e-6 * dt, side="left").tolist()
        return _make_split(bounds if k_max >= 1 else [], n, "period", float(period))
    if by != "reversals":
        raise ValueError(f"by: expected 'reversals' or 'period', got {by!r}")
    minima = find_reversals(record.u, min_prominence=min_prominence, kind="min")
    bounds = [int(i) for i in minima if i >= record.warmup]
    return _make_split(bounds if len(bounds) >= 2 else [], n, "reversals", None)


def cycle_labels(record: Record, **options: object) -> np.ndarray:
    """Per-sample cycle index, shape (n,), int64; -1 outside whole cycles.

    ``options`` are those of :func:`split_cycles`.
    """
    return split_cycles(record, **options).labels()  # type: ignore[arg-type]


def _uniform(record: Record) -> tuple[np.ndarray, float]:
    """Scored input on a uniform grid (interpolated only if timing jitter exceeds 1 %)."""
    t = record.t[record.scored]
    u = record.u[record.scored]
    dt = float(np.median(np.diff(t)))
    if np.max(np.abs(np.diff(t) - dt)) > 0.01 * dt:
        grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt)) + 1)
        u = np.interp(grid, t, u)
    return u, dt


def estimate_frequency(
    record: Record, *, method: Literal["fft", "reversals"] = "fft"
) -> float:
    """Dominant excitation frequency of the input over the scored samples [Hz].

    Parameters
    ----------
    record : Record
        The measurement; its warm-up is excluded.
    method : {"fft", "reversals"}, default "fft"
        ``"fft"``: peak of the Hann-windowed spectrum (zero-padded 4x), refined by
        parabolic interpolation and then by maximising the windowed DTFT magnitude
        within one padded bin (accurate to well below 0.1 % for a few cycles or more).
        ``"reversals"``: ``1 / median`` spacing of same-kind turning points.

    Returns
    -------
    float
        Frequency [Hz].

    Raises
    ------
    DataError
        Constant input, or too few turning points for ``"reversals"``.
    """
    if method == "reversals":
        t = record.t[record.scored]
        rev = find_reversals(record.u[record.scored])
        kinds = [find_reversals(record.u[record.scored], kind=k) for k in ("min", "max")]
        gaps = np.concatenate([np.diff(t[k]) for k in kinds if k.size >= 2] or [np.zeros(0)])
        if gaps.size == 0:
            raise DataError(
                f"record {record.name!r}: {rev.size} input reversal(s); expected at least "
                f"two minima or two maxima to estimate a frequency"
            )
        return float(1.0 / np.median(gaps))
    if method != "fft":
        raise ValueError(f"method: expected 'fft' or 'reversals', got {method!r}")
    u, dt = _uniform(record)
    x = (u - u.mean()) * np.hanning(u.size)
    if not np.any(x):
        raise DataError(f"record {record.name!r}: the input is constant; no frequency to find")
    nfft = 1 << int(np.ceil(np.log2(4 * u.size)))
    mag = np.abs(np.fft.rfft(x, nfft))
    mag[0] = 0.0  # the mean was removed; ignore the residual DC bin
    k = int(np.argmax(mag))
    shift = 0.0
    if 0 < k < mag.size - 1:
        a, b, c = np.log(mag[k - 1 : k + 2] + 1e-300)
        denom = a - 2 * b + c
        shift = 0.5 * (a - c) / denom if denom < 0 else 0.0
    df = 1.0 / (nfft * dt)
    f0 = (k + shift) * df
    tt = dt * np.arange(u.size)

    def neg_power(f: float) -> float:
        return -float(np.abs(np.dot(x, np.exp(-2j * np.pi * f * tt))) ** 2)

    from scipy.optimize import minimize_scalar  # deferred: scipy.optimize is slow to import

    lo, hi = max(f0 - df, 0.5 * df), f0 + df
    res = minimize_scalar(neg_power, bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-9 * max(f0, df)})
    return float(res.x) if -res.fun >= -neg_power(f0) else float(f0)


def split_by_frequency(
    data: Record | Dataset,
    *,
    frequency_hz: np.ndarray | None = None,
    segment_frequencies: Mapping[int, float] | None = None,
    estimate: bool = True,
    warmup: int | None = None,
) -> Dataset:
    """Split records at changes of a per-sample frequency or of their segment labels.

    Parameters
    ----------
    data : Record or Dataset
        Record(s) to split. With a Dataset, ``frequency_hz`` must be None; records
        without segment labels pass through (their frequency estimated if missing and
        ``estimate``).
    frequency_hz : array_like of float, shape (n,), optional
        Per-sample excitation frequency [Hz] of a single Record; blocks are maximal
        runs of constant value.
    segment_frequencies : mapping of int to float, optional
        Frequency [Hz] of each segment label; labels not listed are estimated from the
        block's input when ``estimate`` is True, else left unknown (None).
    estimate : bool, default True
        Estimate missing frequencies with :func:`estimate_frequency`.
    warmup : int, optional
        Warm-up of every block, counted from the block's start. Default: the parent
        record's warm-up (a block starts from an unknown hysteretic state).

    Returns
    -------
    Dataset
        One Record per block, named ``"<name>/<k>"``, with ``metadata["frequency_hz"]``
        set and ``metadata["parent"]``/``metadata["parent_slice"]`` recording the origin.

    Raises
    ------
    DataError
        A block shorter than ``MIN_SAMPLES`` or than its warm-up plus 2 samples.
    """
    if isinstance(data, Dataset):
        if frequency_hz is not None:
            raise ValueError("frequency_hz: a per-sample array needs a single Record")
        parts: list[Record] = []
        for rec in data:
            parts.extend(split_by_frequency(
                rec, segment_frequencies=segment_frequencies, estimate=estimate, warmup=warmup
            ))
        return Dataset(parts, name=data.name)
    record = data
    if frequency_hz is not None:
        labels = np.asarray(frequency_hz, dtype=np.float64)
        if labels.shape != (record.n,) or not (np.isfinite(labels) & (labels > 0)).all():
            raise DataError(
                f"record {record.name!r}: frequency_hz: expected {record.n} positive finite "
                f"values, got shape {labels.shape}"
            )
    elif record.segment is not None:
        labels = record.segment
    else:
        if record.frequency_hz is None and estimate:
            meta = {**record.metadata, "frequency_hz": estimate_frequency(record)}
            record = record.with_(metadata=meta)
        return Dataset([record], name=record.name)
    cuts = [0, *(np.flatnonzero(labels[1:] != labels[:-1]) + 1).tolist(), record.n]
    out = []
    for k, (a, b) in enumerate(itertools.pairwise(cuts)):
        w = record.warmup if warmup is None else warmup
        if b - a < max(MIN_SAMPLES, w + 2):
            raise DataError(
                f"record {record.name!r}: block {k} (samples {a}:{b}, label {float(labels[a])!r}): "
                f"expected at least {max(MIN_SAMPLES, w + 2)} samples (warm-up {w} + 2), "
                f"got {b - a}"
            )
        piece = record.slice(a, b, warmup=w, name=f"{record.name}/{k}")
        if frequency_hz is not None:
            freq: float | None = float(labels[a])
        elif segment_frequencies is not None and int(labels[a]) in segment_frequencies:
            freq = float(segment_frequencies[int(labels[a])])
        else:
            freq = estimate_frequency(piece) if estimate else None
        meta = {**record.metadata, "frequency_hz": freq, "parent": record.name,
                "parent_slice": (a, b)}
        out.append(dataclasses.replace(piece, metadata=meta))
    return Dataset(out, name=record.name)


#: consecutive cycles whose frequencies differ from their block's first cycle by less
#: than this fraction form one block (a sweep is binned into blocks this wide)
FREQUENCY_BIN = 0.05
#: significant figures of an estimated frequency label, so that records at the same
#: nominal frequency (10.0003 and 9.9998 Hz) share a group
FREQUENCY_DIGITS = 3
#: a block of at least this many cycles is labelled from its spectrum
SPECTRAL_CYCLES = 4


def _rounded(f: float) -> float:
    return float(f"{f:.{FREQUENCY_DIGITS}g}")


def _blocks_of(freqs: np.ndarray) -> list[list[int]]:
    """Cycle indices grouped into blocks of at least two cycles at one frequency.

    Consecutive cycles within :data:`FREQUENCY_BIN` of their run's first cycle form a
    run. A run of one cycle is a transition (between two steps of a stepped sine: it
    joins the block before it) or part of a fast sweep (consecutive single cycles pair
    up into blocks of two).
    """
    runs: list[list[int]] = []
    for k, f in enumerate(freqs):
        if runs and abs(np.log(f / freqs[runs[-1][0]])) <= np.log1p(FREQUENCY_BIN):
            runs[-1].append(k)
        else:
            runs.append([k])
    blocks: list[list[int]] = []
    lone: list[int] = []
    for run in runs:
        if len(run) == 1:
            lone.extend(run)
            if len(lone) == 2:
                blocks.append(lone)
                lone = []
            continue
        if lone:  # one transition cycle before a steady run: the block before takes it
            if blocks:
                blocks[-1].extend(lone)
            else:
                run[:0] = lone
            lone = []
        blocks.append(run)
    if lone:
        if blocks:
            blocks[-1].extend(lone)
        else:
            blocks.append(lone)
    return [sorted(b) for b in blocks]


def label_frequencies(data: Record | Dataset) -> Dataset:
    """Records without an excitation frequency, classified, labelled (and split).

    Each record whose metadata has no ``frequency_hz`` is classified by
    :func:`bayeshyst.data.classify.classify_excitation`; ``metadata["excitation"]`` gets
    its kind, ``metadata["band_hz"]`` its input band ``(lo, hi)`` [Hz] and
    ``metadata["excitation_note"]`` one line saying what was done:

    * **periodic**: labelled with :func:`estimate_frequency`, kept whole. One closed
      loop (a B(H) loop, one sine cycle) is labelled ``1 / duration``.
    * **stepped**: cut into whole input cycles (:func:`split_cycles`); consecutive
      cycles within :data:`FREQUENCY_BIN` of each other form a block (one per step).
      The record is split at the blocks' first cycles, each piece labelled from its
      spectrum (at least :data:`SPECTRAL_CYCLES` cycles) or its cycles' count over their
      duration, and given its first cycle as warm-up (a model starts from rest, the
      stage did not).
    * **multisine**: kept whole, ``metadata["period_s"]`` set, **no** ``frequency_hz``.
      Its fundamental ``1 / period`` usually carries no power (a 5-50 Hz multisine of
      period 1 s has no 1 Hz line), so labelling it would file it with a 1 Hz sine in
      per-frequency reports whose rates it does not share; its band says what it
      excites.
    * **broadband**: kept whole, never split, no ``frequency_hz``: the pieces between
      its input minima are not cycles of anything.

    Labels are rounded to :data:`FREQUENCY_DIGITS` significant figures.
    ``metadata["frequency_source"]`` says how a label was found; a record left without a
    label says why in ``metadata["frequency_note"]``. Labelled records pass through
    unchanged.

    Parameters
    ----------
    data : Record or Dataset
        Records [input in any unit, time in s].

    Returns
    -------
    Dataset
        The records, labelled where possible, stepped ones split into their steps.
    """
    from bayeshyst.data.classify import _labelled  # deferred: classify imports this module

    records = [data] if isinstance(data, Record) else list(data)
    name = data.name
    out: list[Record] = []
    for rec in records:
        if rec.frequency_hz is not None:
            out.append(rec)
            continue
        out.extend(_labelled(rec))
    return Dataset(out, name=name)
