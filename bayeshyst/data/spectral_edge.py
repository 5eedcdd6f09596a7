"""Where a channel's spectrum ends: the highest frequency above its white-noise floor.

:func:`signal_edge` is the noise-floor rule of the working rate
(:mod:`bayeshyst.data.working_rate`): a record is decimated no lower than twice (times a
margin) the frequency at which its output's, and a smooth input's, content sinks into
the noise. :func:`edge_and_floor` returns the floor it used as well.

The estimate
------------
The channel (the working rate gives a record's scored part) is pre-whitened by a second
difference (which lowers a slow excitation's line by ``(2 sin(pi f/fs))^4``, -116 dB for
1 Hz at 5 kHz, so that its window leakage does not pose as signal), and its spectrum is
estimated by Welch's method with ``K`` non-overlapping Hann segments; dividing by the
difference's gain recolours it. For Gaussian white noise of any level every bin away from 0 and
Nyquist is then exactly ``floor * chi2(2K) / 2K`` (independent segments, a complex
Gaussian per bin and segment). The floor is the median of the bins in the upper half of
the band (``fs/4 .. fs/2``) over the median of ``chi2(2K) / 2K``; a bin is **signal**
when it exceeds ``floor * chi2.isf(alpha / M, 2K) / 2K`` (``M`` bins, Bonferroni: white
noise alone puts the signal edge anywhere with probability at most ``alpha``, default
0.01). The signal edge ``f_sig`` is the highest signal bin (0 when none).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ALPHA", "edge_and_floor", "signal_edge"]

#: family-wise level of the noise-floor test
ALPHA = 0.01
#: Welch segments (non-overlapping), and the fewest samples one may hold
_SEGMENTS = 16
_MIN_SEGMENT = 64


def signal_edge(x: np.ndarray, fs: float, *, alpha: float = ALPHA,
                exclude: np.ndarray | None = None,
                floor_at_least: float = 0.0) -> float | None:
    """Highest frequency [Hz] at which ``x``'s spectrum stands above its noise floor.

    Parameters
    ----------
    x : ndarray of float, shape (n,)
        A uniformly sampled channel [any unit].
    fs : float
        Its sampling rate [Hz].
    alpha : float, default :data:`ALPHA`
        Probability that white noise alone gives an edge above 0 (Bonferroni over bins).
    exclude : ndarray of bool, shape (n - 2,), optional
        Second-difference samples to zero before the spectrum (an input's jumps, which
        the filter keeps as jumps and which are no band content).
    floor_at_least : float, default 0
        Lower bound on the floor [unit of ``x`` squared per Hz, one-sided]: content
        below it does not count as signal (the input's band counts only where it would
        show in the output above the output's floor).

    Returns
    -------
    float or None
        The edge [Hz] (0.0 when nothing stands above the floor; ``fs / 2`` when the
        floor is exactly zero and anything is left); None when ``x`` is too short for
        two Welch segments of :data:`_MIN_SEGMENT` samples.
    """
    found = edge_and_floor(x, fs, alpha=alpha, exclude=exclude,
                           floor_at_least=floor_at_least)
    return None if found is None else found[0]


def edge_and_floor(x: np.ndarray, fs: float, *, alpha: float = ALPHA,
                   exclude: np.ndarray | None = None,
                   floor_at_least: float = 0.0) -> tuple[float, float] | None:
    """:func:`signal_edge` and the white-noise floor it used.

    Parameters are :func:`signal_edge`'s.

    Returns
    -------
    (float, float) or None
        The edge [Hz], as :func:`signal_edge` gives it, and the estimated white-noise
        floor [unit of ``x`` squared per Hz, one-sided; before ``floor_at_least``]; None
        when ``x`` is too short for two Welch segments of :data:`_MIN_SEGMENT` samples.
    """
    from scipy import signal, stats  # deferred: scipy.signal is slow to import

    d = np.diff(np.asarray(x, dtype=float), 2)
    if exclude is not None:
        d = np.where(exclude, 0.0, d)
    n_seg = min(_SEGMENTS, d.size // _MIN_SEGMENT)
    if n_seg < 2:
        return None
    nper = d.size // n_seg
    # no detrending: the second difference has no mean to speak of, and removing each
    # segment's mean would change the lowest bins' null distribution
    f, p = signal.welch(d[: n_seg * nper], fs=fs, window="hann", nperseg=nper,
                        noverlap=0, detrend=False)
    # the second difference's gain as the windowed periodogram sees it: for white noise
    # E[p] is proportional to 6 - 8 rho1 cos(w) + 2 rho2 cos(2 w), rho the window's
    # autocorrelation at lags 1, 2 (exact; with rho = 1 it is (2 sin(w/2))^4, which the
    # window's leakage from higher bins exceeds in the lowest ones)
    win = signal.get_window("hann", nper)
    # written without cancellation: 1 - rho1 and 1 - rho2 (about 1/nper^2) from
    # differences of the window, and 6 - 8 cos w + 2 cos 2w = (2 sin(w/2))^4, so that
    # the lowest bins of a long record (nper 125 000: a gain near 1e-18 read as 3e-15,
    # or as 0) keep their value
    energy = float(np.dot(win, win))
    a1 = (0.5 * float(np.sum(np.diff(win) ** 2)) + 0.5 * (win[0] ** 2 + win[-1] ** 2)) / energy
    a2 = (0.5 * float(np.sum((win[2:] - win[:-2]) ** 2))
          + 0.5 * float(win[0] ** 2 + win[1] ** 2 + win[-2] ** 2 + win[-1] ** 2)) / energy
    w = 2.0 * np.pi * f / fs
    # 6 - 8 (1 - a1) cos w + 2 (1 - a2) cos 2w
    gain = (16.0 * np.sin(w / 2.0) ** 4 + (8.0 * a1 - 2.0 * a2) * np.cos(2.0 * w)
            + 16.0 * a1 * np.sin(1.5 * w) * np.sin(w / 2.0))
    # DC and Nyquist bins are chi-square with one degree of freedom, not two: left out
    bins = slice(1, f.size - 1 if nper % 2 == 0 else f.size)
    f, r = f[bins], p[bins] / gain[bins]
    nu = 2 * n_seg
    upper = r[f >= fs / 4.0]
    floor = float(np.median(upper)) / (stats.chi2.median(nu) / nu) if upper.size else 0.0
    if max(floor, floor_at_least) <= 0.0:
        return (float(fs / 2.0) if np.any(r > 0) else 0.0), floor
    threshold = max(floor, floor_at_least) * stats.chi2.isf(alpha / r.size, nu) / nu
    above = np.flatnonzero(r > threshold)
    return (float(f[above[-1]]) if above.size else 0.0), floor
