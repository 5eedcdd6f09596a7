"""Convergence diagnostics of MCMC draws: rank-normalised R-hat, bulk/tail ESS, tau.

Written with NumPy so that the sampler can decide when to stop without importing arviz
(which stays in :mod:`bayeshyst.diagnostics`); the tests check these functions against
arviz on the same draws. Definitions follow Vehtari, Gelman, Simpson, Carpenter and
Bürkner (2021), "Rank-normalization, folding, and localization: an improved R-hat",
Bayesian Analysis 16(2): split chains, rank-normalised bulk R-hat and folded tail R-hat,
ESS by Geyer's initial monotone sequence on the FFT autocorrelation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

__all__ = [
    "ConvergenceReport",
    "ess_bulk",
    "ess_tail",
    "hdi",
    "integrated_time",
    "rhat",
]


def _split(x: np.ndarray) -> np.ndarray:
    """(..., chains, draws) -> (..., 2 chains, draws // 2), dropping the middle draw if odd."""
    n = x.shape[-1] // 2
    return np.concatenate([x[..., :n], x[..., x.shape[-1] - n:]], axis=-2)


#: Draws per batch of quantities processed together: the batched FFTs and sorts are
#: faster than one quantity at a time, but a 10 000-step, 100-parameter run would need
#: gigabytes at once
_BATCH_DRAWS = 1 << 21


def _batched(fn, x: np.ndarray) -> np.ndarray:
    """``fn`` over batches of the leading axis of ``x`` (P, ...), results concatenated."""
    per = max(1, _BATCH_DRAWS // max(1, x[0].size))
    return np.concatenate([fn(x[i:i + per]) for i in range(0, x.shape[0], per)]) \
        if x.shape[0] else fn(x)


def _average_ranks(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranks 1..N along the last axis of ``flat`` (P, N), ties given their average rank.

    Returns the ranks and the sorted rows.

    One unstable sort per row: tied values share their group's average rank whatever
    order the sort leaves them in (the sampler repeats a value at every rejected
    proposal, so ties are common).
    """
    n = flat.shape[1]
    order = np.argsort(flat, axis=1)
    ordered = np.take_along_axis(flat, order, axis=1)
    avg = np.broadcast_to(np.arange(1.0, n + 1.0), flat.shape)
    first = np.ones(flat.shape, dtype=bool)
    first[:, 1:] = ordered[:, 1:] != ordered[:, :-1]
    tied = ~np.all(first, axis=1)
    if tied.any():  # only rows with ties need their groups' bounds
        avg = avg.copy()
        f = first[tied]
        pos = np.broadcast_to(np.arange(n), f.shape)
        last = np.ones(f.shape, dtype=bool)
        last[:, :-1] = f[:, 1:]
        lo = np.maximum.accumulate(np.where(f, pos, 0), axis=1)
        hi = np.minimum.accumulate(np.where(last, pos, n - 1)[:, ::-1], axis=1)[:, ::-1]
        avg[tied] = (lo + hi) / 2.0 + 1.0
    ranks = np.empty(flat.shape)
    np.put_along_axis(ranks, order, avg, axis=1)
    return ranks, ordered


def _z_scale(x: np.ndarray) -> np.ndarray:
    """Rank-normalise the draws of each quantity jointly (average ranks, offset 3/8).

    ``x`` is (..., chains, draws); the leading axes index quantities, each ranked over
    all its chains and draws together.
    """
    return _z_scale_sorted(x)[0]


def _z_scale_sorted(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_z_scale` and each quantity's sorted draws (..., chains * draws)."""
    size = x.shape[-2] * x.shape[-1]
    ranks, ordered = _average_ranks(x.reshape(-1, size))
    return (special.ndtri((ranks.reshape(x.shape) - 0.375) / (size + 0.25)),
            ordered.reshape(*x.shape[:-2], size))


def _sorted_quantile(ordered: np.ndarray, q: float) -> np.ndarray:
    """``np.quantile(row, q)`` (its default, linear method) of each sorted row (P, N).

    The same arithmetic as numpy's, so an indicator ``x <= quantile`` is the same.
    """
    n = ordered.shape[1]
    h = (n - 1) * q
    lo = math.floor(h)
    t = h - lo
    a, b = ordered[:, lo], ordered[:, min(lo + 1, n - 1)]
    d = b - a
    return b - d * (1 - t) if t >= 0.5 else a + d * t


def _sorted_median(ordered: np.ndarray) -> np.ndarray:
    """``np.median`` of each sorted row (P, N)."""
    n = ordered.shape[1]
    mid = n // 2
    return ordered[:, mid] if n % 2 else (ordered[:, mid - 1] + ordered[:, mid]) / 2.0


def _bulk_and_folded(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rank-normalised draws, the same of their distance to the median, the sorted draws.

    ``x`` is (P, chains, draws); the sorted draws are (P, chains * draws).
    """
    bulk, ordered = _z_scale_sorted(x)
    return bulk, _z_scale(np.abs(x - _sorted_median(ordered)[:, None, None])), ordered


def _rhat_basic(x: np.ndarray) -> np.ndarray:
    """Split-free R-hat of each quantity of ``x`` (..., chains, draws); NaN where undefined."""
    n = x.shape[-1]
    if n < 2:
        return np.full(x.shape[:-2], math.nan)
    within = x.var(axis=-1, ddof=1).mean(axis=-1)
    between = n * x.mean(axis=-1).var(axis=-1, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        var_hat = (n - 1) / n * within + between / n
        out = np.sqrt(var_hat / within)
    return np.where(within > 0, out, math.nan)


def _defined(x: np.ndarray) -> np.ndarray:
    """Which quantities of ``x`` (..., chains, draws) have finite, non-constant draws."""
    flat = x.reshape(*x.shape[:-2], -1)
    finite = np.all(np.isfinite(flat), axis=-1)
    with np.errstate(invalid="ignore"):
        return finite & (np.ptp(flat, axis=-1) > 0)


def _rhat_many(x: np.ndarray) -> np.ndarray:
    """Rank-normalised split R-hat of each quantity of ``x`` (P, chains, draws)."""
    out = np.full(x.shape[0], math.nan)
    ok = _defined(x)
    if x.shape[-1] < 4 or not ok.any():
        return out
    bulk, folded, _ = _bulk_and_folded(_split(x[ok]))
    # np.maximum propagates NaN: undefined in either is undefined
    out[ok] = np.maximum(_rhat_basic(bulk), _rhat_basic(folded))
    return out


def rhat(x: np.ndarray) -> float:
    """Rank-normalised split R-hat: the max of the bulk and folded (tail) versions.

    Parameters
    ----------
    x : ndarray, shape (chains, draws)
        Draws of one scalar quantity.

    Returns
    -------
    float
        R-hat (1 at convergence); NaN when undefined (constant draws, < 4 draws).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 2:
        return math.nan
    return float(_rhat_many(x[None])[0])


def _autocov(x: np.ndarray) -> np.ndarray:
    """Autocovariance of each chain by FFT along the last axis, shape of ``x``."""
    n = x.shape[-1]
    size = 1 << (2 * n - 1).bit_length()
    # C order: the transforms run along contiguous rows (a transposed chain's strided
    # rows made the batched FFT 3x slower, measured)
    xc = np.ascontiguousarray(x - x.mean(axis=-1, keepdims=True))
    f = np.fft.rfft(xc, n=size, axis=-1)
    acov = np.fft.irfft(f * np.conjugate(f), n=size, axis=-1)[..., :n] / n
    return acov


def _geyer_tau(rho: np.ndarray, m: int, n: int) -> float:
    """Stan's integrated time from the combined autocorrelation ``rho`` (n,).

    Geyer's initial positive then monotone sequence of paired autocorrelations
    ``rho_2t + rho_2t+1``.
    """
    # initial positive sequence: keep pairs (rho_t, rho_t+1), t even, while their sum > 0
    kept = np.zeros(n)
    kept[:2] = rho[:2]
    t = 1
    even, odd = rho[0], rho[1]
    while t < n - 3 and even + odd > 0.0:
        even, odd = rho[t + 1], rho[t + 2]
        if even + odd >= 0:
            kept[t + 1], kept[t + 2] = even, odd
        t += 2
    max_t = t - 2
    if even > 0:
        kept[max_t + 1] = even
    # initial monotone sequence: pair sums may not increase
    t = 1
    while t <= max_t - 2:
        if kept[t + 1] + kept[t + 2] > kept[t - 1] + kept[t]:
            kept[t + 1] = kept[t + 2] = (kept[t - 1] + kept[t]) / 2.0
        t += 2
    tau = -1.0 + 2.0 * kept[: max_t + 1].sum() + kept[max_t + 1: max_t + 2].sum()
    return max(tau, 1.0 / math.log10(m * n))


def _ess_many(x: np.ndarray) -> np.ndarray:
    """ESS of each quantity of ``x`` (P, chains, draws) by Stan's estimator."""
    p, m, n = x.shape
    out = np.full(p, math.nan)
    if n < 4 or p == 0:
        return out
    acov = _autocov(x)
    mean_var = acov[:, :, 0].mean(axis=1) * n / (n - 1.0)
    var_plus = mean_var * (n - 1.0) / n
    if m > 1:
        var_plus = var_plus + x.mean(axis=2).var(axis=1, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = 1.0 - (mean_var[:, None] - acov.mean(axis=1)) / var_plus[:, None]
    for i in np.flatnonzero(var_plus > 0):
        r = rho[i].copy()
        r[0] = 1.0
        out[i] = m * n / _geyer_tau(r, m, n)
    return out


def _ess_bulk_many(x: np.ndarray) -> np.ndarray:
    """Bulk ESS of each quantity of ``x`` (P, chains, draws)."""
    out = np.full(x.shape[0], math.nan)
    ok = _defined(x)
    if x.shape[-1] < 4 or not ok.any():
        return out
    out[ok] = _ess_many(_z_scale(_split(x[ok])))
    return out


def _ess_tail_many(x: np.ndarray, ordered: np.ndarray | None = None) -> np.ndarray:
    """Tail ESS of each quantity of ``x`` (P, chains, draws): the 5 % / 95 % indicators'.

    ``ordered`` (P, chains * draws): the quantities' sorted draws when known.
    """
    out = np.full(x.shape[0], math.nan)
    ok = _defined(x)
    if x.shape[-1] < 4 or not ok.any():
        return out
    xs = x[ok]
    ordered = np.sort(xs.reshape(xs.shape[0], -1), axis=1) if ordered is None else ordered[ok]
    ess = []
    for q in (0.05, 0.95):
        ind = _split((xs <= _sorted_quantile(ordered, q)[:, None, None]).astype(float))
        e = _ess_many(ind)
        ess.append(np.where(np.ptp(ind.reshape(ind.shape[0], -1), axis=1) > 0, e, math.nan))
    out[ok] = np.minimum(ess[0], ess[1])  # NaN in either stays NaN
    return out


def _diagnostics_many(walkers: np.ndarray, n_ensembles: int) -> np.ndarray:
    """R-hat (walkers and ensembles as chains, the larger), bulk and tail ESS (P, 3).

    ``walkers`` is (P, ensembles * walkers, n) with ``n`` even, ensemble-major; as
    :func:`rhat`, :func:`ess_bulk` and :func:`ess_tail` on the two arrangements, but
    each quantity's draws sorted once for its ranks, median and quantiles (both
    arrangements' split chains hold the same draws).
    """
    p, c, n = walkers.shape
    out = np.full((p, 3), math.nan)
    ok = _defined(walkers)
    if n < 4 or not ok.any():
        return out
    x = walkers[ok]
    k = x.shape[0]
    bulk, folded, ordered = _bulk_and_folded(x)

    def as_ensembles(z: np.ndarray) -> np.ndarray:  # each ensemble's draws step-major
        w = c // n_ensembles
        return z.reshape(k, n_ensembles, w, n).transpose(0, 1, 3, 2).reshape(
            k, n_ensembles, n * w)

    parts = [_rhat_basic(_split(z)) for z in (bulk, folded, as_ensembles(bulk),
                                               as_ensembles(folded))]
    out[ok, 0] = np.stack(parts).max(axis=0)  # NaN in any part stays NaN
    out[ok, 1] = _ess_many(_split(bulk))
    out[ok, 2] = _ess_tail_many(x, ordered)
    return out


def ess_bulk(x: np.ndarray) -> float:
    """Bulk effective sample size (rank-normalised split chains)."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2:
        return math.nan
    return float(_ess_bulk_many(x[None])[0])


def ess_tail(x: np.ndarray) -> float:
    """Tail ESS: the smaller ESS of the 5 % and 95 % quantile indicators."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2:
        return math.nan
    return float(_ess_tail_many(x[None])[0])


def integrated_time(chain: np.ndarray, c: float = 5.0) -> np.ndarray:
    """Integrated autocorrelation time per parameter of an ensemble chain.

    The estimator of Goodman & Weare / emcee (``emcee.autocorr.integrated_time`` with
    ``tol=0``): the autocorrelation averaged over walkers, Sokal's automatic window
    ``M >= c tau``.

    Parameters
    ----------
    chain : ndarray, shape (steps, walkers, ndim)

    Returns
    -------
    ndarray, shape (ndim,)
        NaN for a parameter no walker moves in; the number of steps when some walkers
        move and others never do (a walker stuck for the whole window has an
        autocorrelation time of at least the window: an independence proposal can
        leave one stuck at a point of high posterior-to-proposal ratio, and averaging
        it away would hide exactly that).
    """
    chain = np.asarray(chain, dtype=float)
    return _batched(lambda x: _integrated_time_many(x, c), chain.transpose(2, 1, 0))


def _integrated_time_many(x: np.ndarray, c: float) -> np.ndarray:
    """:func:`integrated_time` of each quantity of ``x`` (ndim, walkers, steps)."""
    acov = _autocov(x)
    var = acov[:, :, :1]
    # a walker is stuck when its draws are all equal, tested exactly: the variance of a
    # constant series is not always 0 (its mean rounds), and dividing by the rounding
    # would turn the walker into white noise
    stuck = np.ptp(x, axis=2) == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        acf = (acov / var).mean(axis=1)  # each walker normalised, then averaged
    taus = 2.0 * np.cumsum(acf, axis=1) - 1.0
    window = np.arange(taus.shape[1]) < c * taus
    m = np.where(np.all(window, axis=1), taus.shape[1] - 1, np.argmin(window, axis=1))
    out = taus[np.arange(taus.shape[0]), m]
    out = np.where(np.any(stuck, axis=1), float(x.shape[2]), out)
    return np.where(np.all(stuck, axis=1), math.nan, out)


def hdi(x: np.ndarray, prob: float = 0.9) -> tuple[float, float]:
    """Highest-density interval: the shortest interval holding ``prob`` of the draws."""
    x = np.sort(np.asarray(x, dtype=float).ravel())
    n = x.size
    k = math.floor(prob * n)
    if n == 0 or k < 1:
        return (math.nan, math.nan)
    widths = x[k:] - x[: n - k]
    i = int(np.argmin(widths))
    return (float(x[i]), float(x[i + k]))


@dataclass(frozen=True)
class ConvergenceReport:
    """Convergence of a multi-ensemble run.

    Attributes
    ----------
    rhat_max : float
        Largest rank-normalised split R-hat over parameters, computed with every walker
        of every ensemble as a chain and with each ensemble as one chain (so a
        disagreement *between* independent ensembles shows); the larger is reported.
    ess_bulk_min, ess_tail_min : float
        Smallest bulk / tail ESS over parameters (walkers as chains).
    tau_max : float
        Largest integrated autocorrelation time (steps) over parameters and ensembles.
    n_steps : int
        Steps per ensemble so far; ``burn`` of them discarded.
    burn : int
    converged : bool
        R-hat below its threshold, both ESS above theirs, and ``n_steps - burn >= 50
        tau_max``.
    reasons : tuple of str
        Why not converged (empty when converged), in plain words.
    """

    rhat_max: float
    ess_bulk_min: float
    ess_tail_min: float
    tau_max: float
    n_steps: int
    burn: int
    converged: bool
    reasons: tuple[str, ...] = ()

    def __str__(self) -> str:
        state = "converged" if self.converged else "NOT converged: " + "; ".join(self.reasons)
        def num(v: float, fmt: str) -> str:
            return format(v, fmt) if math.isfinite(v) else "undefined"

        return (f"{state} (R-hat max {num(self.rhat_max, '.4f')}, ESS bulk min "
                f"{num(self.ess_bulk_min, '.0f')}, tail min {num(self.ess_tail_min, '.0f')}, "
                f"tau max {num(self.tau_max, '.1f')} steps, {self.n_steps} steps, "
                f"burn {self.burn})")


def _longest_time(chains: list[np.ndarray]) -> float:
    """The longest autocorrelation time of any parameter in any ensemble, in steps.

    A parameter that no walker of an ensemble moved (NaN from :func:`integrated_time`)
    counts as the ensemble's whole length: its autocorrelation time is at least the
    window, as for a single stuck walker. Dropping it instead would let a frozen
    ensemble pass the length criterion unseen, or, with only frozen ensembles, leave no
    time at all.
    """
    return max(float(np.max(np.where(np.isnan(t), float(c.shape[0]), t)))
               for c in chains for t in [integrated_time(c)])


def assess(
    chains: list[np.ndarray],
    *,
    rhat_threshold: float = 1.01,
    min_ess: float = 400.0,
    tau_factor: float = 50.0,
    burn_factor: float = 5.0,
    min_burn: int = 0,
) -> ConvergenceReport:
    """Convergence of equally long ensemble chains.

    Parameters
    ----------
    chains : list of ndarray, each (steps, walkers, ndim)
        One chain per independent ensemble (all steps, burn-in included).
    rhat_threshold, min_ess, tau_factor : float
        The criteria (R-hat < 1.01, ESS >= 400 bulk and tail, 50 tau).
    burn_factor : float
        Burn-in is ``burn_factor * tau`` of the whole chain, at most half of it.
    min_burn : int
        Steps always discarded (an adaptive proposal's warm-up: only the steps after
        it form a Markov chain with a fixed kernel).
    """
    steps = min(c.shape[0] for c in chains)
    chains = [c[:steps] for c in chains]
    tau_all = _longest_time(chains)
    burn = int(max(min(math.ceil(burn_factor * tau_all), steps // 2), min(min_burn, steps - 4)))
    # an even number of kept steps: every split chain then holds all the draws, in both
    # arrangements below, so one rank-normalisation serves R-hat (walkers and ensembles
    # as chains) and the bulk ESS
    burn += (steps - burn) % 2
    kept = [c[burn:] for c in chains]
    tau = _longest_time(kept)
    # (d, chains, n): every walker of every ensemble a chain
    walkers = np.concatenate([c.transpose(2, 1, 0) for c in kept], axis=1)
    # an undefined value (a parameter whose draws are constant or not finite: the
    # sampler never moved it) makes the extreme undefined, i.e. not converged, whichever
    # parameter it is (np.max and np.min propagate NaN)
    diag = _batched(lambda x: _diagnostics_many(x, len(kept)), walkers)
    rh, eb, et = float(np.max(diag[:, 0])), float(np.min(diag[:, 1])), float(np.min(diag[:, 2]))
    reasons = []
    undefined = "undefined (a parameter's draws are constant or not finite)"
    if not rh < rhat_threshold:
        reasons.append(f"R-hat {rh:.3f} >= {rhat_threshold}" if math.isfinite(rh)
                       else f"R-hat {undefined}")
    if not eb >= min_ess:
        reasons.append(f"bulk ESS {eb:.0f} < {min_ess:.0f}" if math.isfinite(eb)
                       else f"bulk ESS {undefined}")
    if not et >= min_ess:
        reasons.append(f"tail ESS {et:.0f} < {min_ess:.0f}" if math.isfinite(et)
                       else f"tail ESS {undefined}")
    n_kept = steps - burn
    if not n_kept >= tau_factor * tau:
        reasons.append(f"{n_kept} kept steps < {tau_factor:.0f} tau = {tau_factor * tau:.0f}")
    return ConvergenceReport(float(rh), float(eb), float(et), float(tau), int(steps), burn,
                             not reasons, tuple(reasons))
