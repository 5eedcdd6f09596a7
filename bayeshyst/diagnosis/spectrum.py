"""Lines in the residual's spectrum that the excitation does not explain.

A periodic disturbance at a frequency that is not a harmonic of the excitation (mains
pickup, a pump, a floor mode) depends on none of the drivers the driver scan
(:mod:`bayeshyst.diagnosis.drivers`) looks at -- it is a function of absolute time at a
frequency of its own -- so it is looked for where it shows: as a line in the
residual's periodogram, against the smooth spectrum of the noise around it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import f as f_dist

from bayeshyst.data.dataset import Dataset
from bayeshyst.tables import TableRecord, frame

__all__ = ["SpectralLine", "spectral_lines"]

#: Half-width (bins) of the neighbourhood that estimates the residual's smooth spectrum.
_LOCAL_HALF = 64
#: Bins on each side of a tested bin left out of its neighbourhood (Hann main lobe).
_SELF_GUARD = 2
#: Bins on each side of an excitation harmonic left out (Hann main lobe is 2 bins).
_HARMONIC_GUARD = 3
#: Equivalent noise bandwidth of the Hann window (bins): neighbouring bins share it.
_HANN_ENBW = 1.5


@dataclass(frozen=True)
class SpectralLine(TableRecord):
    """A narrow line in the residual's spectrum that the excitation does not explain.

    Attributes
    ----------
    record : str
    frequency_hz : float
        Where the line is (interpolated between bins).
    amplitude : float
        Its amplitude (output unit).
    share_percent : float
        Share of the record's residual variance in the line.
    p_value : float
        Bonferroni-adjusted over the bins and records tested.
    harmonic_of : float or None
        Excitation frequency the line is *not* a harmonic of (None if unknown).
    """

    record: str
    frequency_hz: float
    amplitude: float
    share_percent: float
    p_value: float
    harmonic_of: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"record": self.record, "frequency_hz": self.frequency_hz,
                "amplitude": self.amplitude, "share_percent": self.share_percent,
                "p_value": self.p_value, "excitation_hz": self.harmonic_of}

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])

    def __str__(self) -> str:
        return (f"line at {self.frequency_hz:.4g} Hz in {self.record}: amplitude "
                f"{self.amplitude:.3g}, {self.share_percent:.1f} % of the residual variance "
                f"(p = {self.p_value:.2g}); not a harmonic of the excitation")


def _local_mean(p: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the kept bins near every bin (its own main lobe left out) and their count."""
    kernel = np.ones(2 * _LOCAL_HALF + 1)
    kernel[_LOCAL_HALF - _SELF_GUARD:_LOCAL_HALF + _SELF_GUARD + 1] = 0.0
    total = np.convolve(np.where(keep, p, 0.0), kernel, mode="same")
    count = np.convolve(keep.astype(float), kernel, mode="same")
    return total / np.maximum(count, 1.0), count


def _refine(r: np.ndarray, win: np.ndarray, f: float, df: float, dt: float) -> float:
    """The frequency within a bin of ``f`` where the windowed DTFT of ``r`` peaks."""
    grid = f + df * np.linspace(-1.0, 1.0, 81)
    k = np.arange(r.size) * dt
    mag = np.abs(np.exp(-2j * math.pi * grid[:, None] * k[None, :]) @ ((r - r.mean()) * win))
    return float(grid[int(np.argmax(mag))])


def spectral_lines(data: Dataset, residual: Sequence[np.ndarray], *,
                   alpha: float = 0.01) -> tuple[SpectralLine, ...]:
    """Lines in the residual's spectrum away from every harmonic of the excitation.

    Per record: Hann-windowed periodogram of the (mean-removed) residual; each bin is
    compared with the mean of its neighbours (+-64 bins, its own main lobe left out),
    the local spectrum of coloured noise. Under the null of a smooth spectrum the ratio
    is F-distributed with 2 and ``2 m / 1.5`` degrees of freedom (``m`` neighbours, the
    Hann window's noise bandwidth of 1.5 bins), which accounts for the noise in the
    local estimate itself; a bin is a line when its p-value times the number of bins
    tested over all records (Bonferroni) is below ``alpha``. Bins within a few of a
    harmonic of the record's frequency, and below its fundamental (or, frequency
    unknown, where the input has power) are not tested: structure there is the loop's
    or slow, which the driver scan looks at.

    Parameters
    ----------
    data : Dataset
    residual : sequence of ndarray
        Residual per record on its scored samples.
    alpha : float
        Family-wise level over all bins and records.
    """
    tests = []
    for rec, r in zip(data, residual, strict=True):
        r = np.asarray(r, float)
        n = r.size
        if n < 4 * _LOCAL_HALF:
            continue
        s0 = rec.scored.start or 0
        dt = float(np.median(np.diff(rec.t[s0:])))
        win = np.hanning(n)
        spec = np.abs(np.fft.rfft((r - r.mean()) * win)) ** 2
        freqs = np.fft.rfftfreq(n, dt)
        df = freqs[1]
        keep = freqs > 2 * df
        f0 = rec.frequency_hz
        if f0:
            # below the fundamental the residual's structure is slow (drift, a driver):
            # the driver scan's; around the harmonics it is the loop's
            k = np.round(freqs / f0)
            keep &= freqs > f0 + _HARMONIC_GUARD * df
            keep &= ~((k >= 1) & (np.abs(freqs - k * f0) <= _HARMONIC_GUARD * df))
        else:
            u = np.asarray(rec.u[s0:], float)
            pu = np.abs(np.fft.rfft((u - u.mean()) * win)) ** 2
            keep &= pu < 1e-6 * pu.max()
        mean, count = _local_mean(spec, keep)
        keep &= count >= 8
        ratio = np.where(keep & (mean > 0), spec / np.where(mean > 0, mean, 1.0), 0.0)
        p_bin = f_dist.sf(ratio, 2, 2.0 * count / _HANN_ENBW)
        tests.append((rec, r, freqs, spec, p_bin, keep, f0, win, dt))
    n_tested = sum(int(np.sum(t[5])) for t in tests)
    lines = []
    for rec, r, freqs, spec, p_bin, keep, f0, win, dt in tests:
        p = np.minimum(1.0, n_tested * p_bin)
        hits = np.flatnonzero(keep & (p < alpha))
        # one line per run of adjacent significant bins, at its peak
        for run in np.split(hits, np.flatnonzero(np.diff(hits) > 2) + 1) if hits.size else []:
            j = int(run[np.argmax(spec[run])])
            lo, hi = max(j - 2, 1), min(j + 3, spec.size)
            # Parseval for the Hann window: sum(win^2) / 2 per unit sine amplitude^2
            power = float(np.sum(spec[lo:hi]) * 2.0 / (np.sum(win ** 2) * r.size))
            var = float(np.var(r)) or 1.0
            lines.append(SpectralLine(rec.name, _refine(r, win, float(freqs[j]), freqs[1], dt),
                                      math.sqrt(2.0 * power), 100.0 * min(power / var, 1.0),
                                      float(p[j]), f0))
    return tuple(sorted(lines, key=lambda x: -x.share_percent))
