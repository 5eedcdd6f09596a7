"""Why a sampling run did not converge, said in terms of the posterior's coordinates.

A run that ends unconverged gives its criteria (R-hat, ESS, length in autocorrelation
times). What a user can act on is *why*: which coordinates mix slowest and how many steps
they would need, which pairs the data do not tell apart (a posterior correlation near
one: only a combination of the two is identified), and whether the independent
ensembles sit in separate regions that more steps will not join (then each region's
approximate weight). :func:`explain_nonconvergence` says those three things from the
kept chains; :func:`~bayeshyst.inference.sampling.sample_posterior` adds them to an
unconverged run's reasons.

Measured on the 150 V piezo's Bouc–Wen with creep and drift on its shape correction
(4 500 kept steps): ``k`` and ``alpha`` had posterior correlation 1.00 (the hysteretic
term had gone linear, ``beta`` near zero), and their autocorrelation times, 600-640
steps, grew with the chain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayeshyst.inference.convergence import integrated_time
from bayeshyst.params import ParamSpace

__all__ = ["COLLINEAR", "SEPARATED_SD", "Region", "explain_nonconvergence",
           "separate_regions"]

#: A posterior correlation at least this large (in absolute value) between two
#: coordinates is reported: the draws then move along one line of the pair, and the data
#: identify one combination of the two, not each.
COLLINEAR = 0.99

#: Two ensembles are in separate regions when some coordinate's ensemble means lie this
#: many within-ensemble sd apart and the ensembles' 1-99 % ranges of it do not overlap.
#: One ensemble's mean over a chain of ``n`` steps with autocorrelation time ``tau`` has
#: standard error ``sd sqrt(tau / (n W))``; a run stopped with tau comparable to the
#: chain still has means within a few sd, and non-overlapping ranges exclude that.
SEPARATED_SD = 4.0

#: Coordinates and pairs named at most.
SHOWN = 3


@dataclass(frozen=True)
class Region:
    """One ensemble's region of a posterior whose ensembles do not mix.

    Attributes
    ----------
    ensemble : int
    mean_log_prob : float
        Mean log density of its kept draws.
    log_mass : float
        Laplace approximation of the region's log posterior mass: its highest log density
        plus half the log determinant of ``2 pi`` times its draws' covariance (``z``).
    weight : float
        ``exp(log_mass)`` normalised over the regions.
    mean_z : ndarray, shape (ndim,)
        Mean of its kept draws in ``z``.
    """

    ensemble: int
    mean_log_prob: float
    log_mass: float
    weight: float
    mean_z: np.ndarray


def _slowest(chains: np.ndarray, labels: list[str], tau_factor: float) -> str | None:
    """The coordinates whose autocorrelation time the kept steps cannot cover."""
    n_kept = chains.shape[1]
    tau = np.max([np.where(np.isnan(t), float(n_kept), t)
                  for t in (integrated_time(c) for c in chains)], axis=0)
    slow = [i for i in np.argsort(-tau) if tau_factor * tau[i] > n_kept][:SHOWN]
    if not slow:
        return None
    names = ", ".join(f"{labels[i]} (tau {tau[i]:.0f} steps)" for i in slow)
    need = math.ceil(tau_factor * float(tau[slow[0]]))
    return (f"slowest to mix: {names}; {tau_factor:g} tau of kept steps would be at least "
            f"{need} (a lower bound: a chain shorter than about 50 tau underestimates tau)")


#: Draws per ensemble the correlations and regions are computed from (evenly thinned):
#: their errors are then far below the thresholds, at a fraction of the cost
MAX_DRAWS = 20_000


def _thinned(a: np.ndarray, chains: np.ndarray) -> np.ndarray:
    """``a`` (E, S, ...) with every k-th step of ``chains`` (E, S, W, d) kept.

    ``k`` leaves at most :data:`MAX_DRAWS` draws per ensemble.
    """
    k = max(1, math.ceil(chains.shape[1] * chains.shape[2] / MAX_DRAWS))
    return a[:, ::k]


def _collinear(chains: np.ndarray, labels: list[str]) -> str | None:
    """The coordinate pairs with posterior correlation at least :data:`COLLINEAR`."""
    flat = _thinned(chains, chains).reshape(-1, chains.shape[-1])
    sd = flat.std(axis=0)
    live = np.flatnonzero(sd > 0)
    if live.size < 2:
        return None
    with np.errstate(invalid="ignore"):
        r = np.corrcoef(flat[:, live], rowvar=False)
    iu = np.triu_indices(live.size, k=1)
    rho = r[iu]
    ok = np.isfinite(rho) & (np.abs(rho) >= COLLINEAR)
    if not np.any(ok):
        return None
    order = np.flatnonzero(ok)[np.argsort(-np.abs(rho[ok]))][:SHOWN]
    pairs = "; ".join(f"{labels[live[iu[0][j]]]} ~ {labels[live[iu[1][j]]]} "
                      f"({rho[j]:+.3f})" for j in order)
    return (f"posterior correlation of {COLLINEAR:g} or more: {pairs}: the data identify a "
            f"combination of each pair, not its members (a reparametrisation or a tighter "
            f"prior on one of them removes the ridge the sampler crawls along)")


def separate_regions(chains: np.ndarray, log_prob: np.ndarray
                     ) -> tuple[list[Region], int, float] | None:
    """The ensembles' regions when they sit apart, with their Laplace weights.

    Parameters
    ----------
    chains : ndarray, shape (E, S, W, ndim)
        Kept draws in ``z``.
    log_prob : ndarray, shape (E, S, W)

    Returns
    -------
    (regions, coordinate, separation) or None
        One :class:`Region` per ensemble, the coordinate that separates them most and by
        how many within-ensemble sd; None when no pair of ensembles is separated
        (:data:`SEPARATED_SD` and non-overlapping 1-99 % ranges).
    """
    n_ens = chains.shape[0]
    if n_ens < 2:
        return None
    chains, log_prob = _thinned(chains, chains), _thinned(log_prob, chains)
    flat = chains.reshape(n_ens, -1, chains.shape[-1])
    mean, sd = flat.mean(axis=1), flat.std(axis=1)
    lo, hi = np.percentile(flat, 1, axis=1), np.percentile(flat, 99, axis=1)
    best, where = 0.0, -1
    for a in range(n_ens):
        for b in range(a + 1, n_ens):
            pooled = np.sqrt(0.5 * (sd[a] ** 2 + sd[b] ** 2))
            with np.errstate(divide="ignore", invalid="ignore"):
                sep = np.where(pooled > 0, np.abs(mean[a] - mean[b]) / pooled, 0.0)
            apart = (hi[a] < lo[b]) | (hi[b] < lo[a])
            sep = np.where(apart & np.isfinite(sep), sep, 0.0)
            j = int(np.argmax(sep))
            if sep[j] > best:
                best, where = float(sep[j]), j
    if not best > SEPARATED_SD:
        return None
    lp = log_prob.reshape(n_ens, -1)
    log_mass = np.full(n_ens, -np.inf)
    for e in range(n_ens):
        x = flat[e][:, sd[e] > 0]
        cov = np.atleast_2d(np.cov(x, rowvar=False))
        sign, logdet = np.linalg.slogdet(2.0 * math.pi * cov)
        if sign > 0 and np.isfinite(lp[e]).any():
            log_mass[e] = float(np.max(lp[e])) + 0.5 * logdet
    top = np.max(log_mass)
    w = np.exp(log_mass - top) if np.isfinite(top) else np.full(n_ens, np.nan)
    w = w / np.sum(w) if np.isfinite(top) else w
    regions = [Region(e, float(np.mean(lp[e][np.isfinite(lp[e])])), float(log_mass[e]),
                      float(w[e]), mean[e]) for e in range(n_ens)]
    return regions, where, best


def _regions(chains: np.ndarray, log_prob: np.ndarray, space: ParamSpace) -> str | None:
    found = separate_regions(chains, log_prob)
    if found is None:
        return None
    regions, j, sep = found
    # the separating coordinate in physical units (its parameter unpacked at each mean)
    owner = space.owners[j]
    k = j - space.slice_of(owner).start
    values = [float(np.ravel(space.unpack(r.mean_z)[owner])[k]) for r in regions]
    unit = space[owner].unit
    where = ", ".join(f"{v:.4g}" for v in values) + (f" {unit}" if unit and unit != "1" else "")
    if all(math.isfinite(r.weight) for r in regions):
        weights = ", ".join(f"{r.weight:.2g}" for r in regions)
        mass = f"their Laplace weights are {weights}"
    else:
        mass = "their weights cannot be approximated (a degenerate covariance)"
    dens = ", ".join(f"{r.mean_log_prob:.1f}" for r in regions)
    return (f"the {len(regions)} ensembles sit in separate regions ({space.labels[j]}: {where}; "
            f"{sep:.1f} sd apart): {mass} (mean log density {dens}); more steps will not "
            f"join them, and the draws weigh each region by its walkers, not by its mass")


def explain_nonconvergence(chains: np.ndarray, log_prob: np.ndarray, space: ParamSpace, *,
                           tau_factor: float) -> tuple[str, ...]:
    """What held a run back, in words (empty when nothing stands out).

    Parameters
    ----------
    chains : ndarray, shape (E, S, W, ndim)
        The kept draws of ``z``: E ensembles, S steps, W walkers.
    log_prob : ndarray, shape (E, S, W)
    space : ParamSpace
        Names the coordinates and unpacks them to physical values.
    tau_factor : float
        Autocorrelation times of kept steps the convergence criteria ask for.

    Returns
    -------
    tuple of str
        Separate regions of the ensembles (with approximate weights), near-collinear
        pairs, and the slowest coordinates with the steps they would need, in that order.
    """
    chains = np.asarray(chains, dtype=float)
    if chains.ndim != 4 or chains.shape[1] < 4:
        return ()
    labels = list(space.labels)
    found = (_regions(chains, log_prob, space), _collinear(chains, labels),
             _slowest(chains, labels, tau_factor))
    return tuple(s for s in found if s is not None)
