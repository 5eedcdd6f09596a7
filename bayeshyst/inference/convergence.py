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
from scipy import special, stats

__all__ = [
    "ConvergenceReport",
    "ess_bulk",
    "ess_tail",
    "hdi",
    "integrated_time",
    "rhat",
]


def _split(x: np.ndarray) -> np.ndarray:
    """(chains, draws) -> (2 chains, draws // 2), dropping the middle draw if odd."""
    n = x.shape[1] // 2
    return np.concatenate([x[:, :n], x[:, x.shape[1] - n:]], axis=0)


def _z_scale(x: np.ndarray) -> np.ndarray:
    """Rank-normalise all draws jointly (average ranks, fractional offset 3/8)."""
    ranks = stats.rankdata(x, method="average").reshape(x.shape)
    return special.ndtri((ranks - 0.375) / (x.size + 0.25))


def _rhat_basic(x: np.ndarray) -> float:
    n = x.shape[1]
    if n < 2:
        return math.nan
    means = x.mean(axis=1)
    within = x.var(axis=1, ddof=1).mean()
    between = n * means.var(ddof=1)
    if within <= 0:
        return math.nan
    var_hat = (n - 1) / n * within + between / n
    return float(math.sqrt(var_hat / within))


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
    if x.ndim != 2 or x.shape[1] < 4 or not np.all(np.isfinite(x)):
        return math.nan
    if np.ptp(x) == 0:
        return math.nan
    s = _split(x)
    bulk = _rhat_basic(_z_scale(s))
    folded = np.abs(s - np.median(s))
    tail = _rhat_basic(_z_scale(folded))
    return float(max(bulk, tail))


def _autocov(x: np.ndarray) -> np.ndarray:
    """Autocovariance of each chain by FFT, shape (chains, draws)."""
    n = x.shape[1]
    size = 1 << (2 * n - 1).bit_length()
    xc = x - x.mean(axis=1, keepdims=True)
    f = np.fft.rfft(xc, n=size, axis=1)
    acov = np.fft.irfft(f * np.conjugate(f), n=size, axis=1)[:, :n] / n
    return acov


def _ess(x: np.ndarray) -> float:
    """ESS of (chains, draws) by Stan's estimator.

    Geyer's initial positive then monotone sequence of paired autocorrelations
    ``rho_2t + rho_2t+1``.
    """
    m, n = x.shape
    if n < 4:
        return math.nan
    acov = _autocov(x)
    mean_var = acov[:, 0].mean() * n / (n - 1.0)
    var_plus = mean_var * (n - 1.0) / n
    if m > 1:
        var_plus += x.mean(axis=1).var(ddof=1)
    if var_plus <= 0:
        return math.nan
    rho = 1.0 - (mean_var - acov.mean(axis=0)) / var_plus
    rho[0] = 1.0
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
    tau = max(tau, 1.0 / math.log10(m * n))
    return float(m * n / tau)


def ess_bulk(x: np.ndarray) -> float:
    """Bulk effective sample size (rank-normalised split chains)."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] < 4 or np.ptp(x) == 0:
        return math.nan
    return _ess(_z_scale(_split(x)))


def ess_tail(x: np.ndarray) -> float:
    """Tail ESS: the smaller ESS of the 5 % and 95 % quantile indicators."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] < 4 or np.ptp(x) == 0:
        return math.nan
    out = []
    for q in (0.05, 0.95):
        ind = _split((x <= np.quantile(x, q)).astype(float))
        out.append(_ess(ind) if np.ptp(ind) > 0 else math.nan)
    return float(min(out))


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
    ndim = chain.shape[2]
    out = np.empty(ndim)
    for d in range(ndim):
        acov = _autocov(chain[:, :, d].T)  # (walkers, steps)
        var = acov[:, :1]
        if np.all(var <= 0):
            out[d] = math.nan
            continue
        if np.any(var <= 0):
            out[d] = float(chain.shape[0])
            continue
        acf = (acov / var).mean(axis=0)  # each walker normalised, then averaged
        taus = 2.0 * np.cumsum(acf) - 1.0
        window = np.arange(len(taus)) < c * taus
        m = int(np.argmin(window)) if not np.all(window) else len(taus) - 1
        out[d] = taus[m]
    return out


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
    tau_all = max(float(np.nanmax(integrated_time(c))) for c in chains)
    burn = int(max(min(math.ceil(burn_factor * tau_all), steps // 2), min(min_burn, steps - 4)))
    kept = [c[burn:] for c in chains]
    tau = max(float(np.nanmax(integrated_time(c))) for c in kept)
    walkers = np.concatenate([c.transpose(1, 0, 2) for c in kept], axis=0)  # (chains, n, d)
    ensembles = np.stack([c.reshape(-1, c.shape[2]) for c in kept])  # step-major draws
    ndim = walkers.shape[2]
    # an undefined value (a parameter whose draws are constant or not finite: the
    # sampler never moved it) makes the extreme undefined, i.e. not converged, whichever
    # parameter it is (Python's max and min keep or drop a NaN by its position)
    rh = float(np.max([np.maximum(rhat(walkers[:, :, d]), rhat(ensembles[:, :, d]))
                       for d in range(ndim)]))
    eb = float(np.min([ess_bulk(walkers[:, :, d]) for d in range(ndim)]))
    et = float(np.min([ess_tail(walkers[:, :, d]) for d in range(ndim)]))
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
