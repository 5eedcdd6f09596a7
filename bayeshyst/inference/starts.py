"""Where a run's ensembles start.

Laplace draws around the start, a pool of given walkers, or each ensemble's own walkers
(an earlier run continued).

Used by :func:`~bayeshyst.inference.sampling.sample_posterior`.
"""

from __future__ import annotations

import logging

import numpy as np

from bayeshyst.inference.optimize import (
    MAPResult,
    initial_ensemble,
    spread_shared_coordinates,
)
from bayeshyst.inference.posterior import Posterior

__all__ = ["initial_positions", "unshared_walkers"]

_log = logging.getLogger(__name__)


def unshared_walkers(post: Posterior, start: MAPResult, initial: np.ndarray,
                     idx: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The given walkers, with the coordinates they all share drawn apart.

    :func:`~bayeshyst.inference.optimize.spread_shared_coordinates`; ``initial`` itself
    when none is shared (its checkpoint identity unchanged, and no evaluation spent:
    :func:`initial_positions` checks the walkers' densities once).

    Parameters
    ----------
    post : Posterior
    start : MAPResult
        The run's start (its Laplace conditional spreads a shared coordinate).
    initial : ndarray, shape (..., ndim)
        The given walkers (unconstrained coordinates).
    idx : ndarray of int
        The coordinates the ensemble moves propose (the others are drawn exactly).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (M, ndim) or ``initial``'s
    """
    pool = np.asarray(initial, dtype=float).reshape(-1, post.ndim)
    spread, shared = spread_shared_coordinates(post, start, pool, idx, rng)
    if shared.size == 0:
        return initial
    _log.info("%s: the starting walkers shared %s; drawn apart from the Laplace "
              "conditional (an ensemble cannot leave a subspace it starts in)",
              post.model.name, ", ".join(post.space.labels[i] for i in shared))
    return spread


def initial_positions(post: Posterior, start: MAPResult, initial: np.ndarray | None,
                      n_ens: int, n_walkers: int, rngs: list[np.random.Generator],
                      walkers: np.ndarray | None = None) -> list[np.ndarray]:
    """Each ensemble's starting walkers: the given ones, else Laplace draws.

    Of a pool given as ``initial``, the walkers without finite density are replaced by
    Laplace draws, and the rest resampled to the ensemble size. ``walkers`` are each
    ensemble's own, kept in place (a walker without finite density replaced).

    Parameters
    ----------
    post : Posterior
    start : MAPResult
        The Laplace draws are drawn around it.
    initial : ndarray, shape (..., ndim), or None
        A pool every ensemble draws its walkers from.
    n_ens, n_walkers : int
        Ensembles and walkers per ensemble.
    rngs : list of numpy.random.Generator
        One per ensemble.
    walkers : ndarray, shape (n_ens, n_walkers, ndim), optional
        Each ensemble's own walkers (an earlier run continued); used instead of
        ``initial``.

    Returns
    -------
    list of ndarray, each shape (n_walkers, ndim)
    """
    out = []
    for e in range(n_ens):
        rng = rngs[e]
        if walkers is not None:
            own = np.array(walkers[e], dtype=float)
            bad = ~np.isfinite(post.log_prob_batch(own))
            if bad.any():
                own[bad] = initial_ensemble(post, start, int(bad.sum()), rng)
            out.append(own)
            continue
        if initial is None:
            out.append(initial_ensemble(post, start, n_walkers, rng))
            continue
        pool = np.asarray(initial, dtype=float).reshape(-1, post.ndim)
        pool = pool[np.isfinite(post.log_prob_batch(pool))]
        if pool.shape[0] < n_walkers:
            fill = initial_ensemble(post, start, n_walkers - pool.shape[0], rng)
            pool = np.vstack([pool, fill])
        pick = rng.choice(pool.shape[0], size=n_walkers, replace=False)
        out.append(pool[np.sort(pick)])
    return out
