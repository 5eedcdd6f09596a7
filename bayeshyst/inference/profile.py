"""The posterior's mode searched over the coordinates outside its linear block.

A posterior with a linear block (a model's gains and offsets, a discrepancy's hundred
basis coefficients) is maximised over the other coordinates with the block at its
conditional mean at every point (variable projection): the joint mode, searched in the
handful of coordinates that need a simulation. :func:`profile_mode` is the search,
:func:`profile_start` the sampler's start built from it; they start fits with a
discrepancy, their restarts, held-out refits and the calibration check's refit.
:func:`at_conditional_mean` completes points with their block;
:func:`conditional_mode` moves only the noise, the block following it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from scipy import optimize

from bayeshyst.inference.optimize import _BIG, MAPResult, _polish
from bayeshyst.inference.posterior import NOISE, Posterior

__all__ = ["MAX_PROFILE_PASSES", "at_conditional_mean", "conditional_mode", "profile_mode",
           "profile_start"]


#: most restarts of :func:`profile_mode`'s polish after its first pass
MAX_PROFILE_PASSES = 5


def at_conditional_mean(structure: Any, z: np.ndarray) -> tuple[np.ndarray, Any]:
    """Points ``z`` (n, ndim) with their linear block at its conditional mean, and their Grams.

    The Grams of ``[design, reference residual]`` depend on the coordinates outside the
    block only: one computation serves the conditional and the likelihood. A point whose
    conditional is undefined (failed design, noise outside its support) keeps its block.
    """
    z = np.array(z, dtype=float)
    st = structure.stats(z)
    cond = structure.conditional(st, z)
    zb, _ = structure.z_of(cond.mean)
    good = cond.ok & np.all(np.isfinite(zb), axis=1)
    z[np.ix_(good, structure.lin_idx)] = zb[good]
    return z, st


class _Profiled:
    """The log posterior as a function of the coordinates outside the linear block.

    Each point's block is set to its conditional mean (the block's conditional mode), so
    the maximum over the other coordinates is the joint maximum. ``log_prob`` takes
    points of the other coordinates only, as :func:`_polish`'s target.
    """

    def __init__(self, post: Posterior, structure: Any, z: np.ndarray) -> None:
        from bayeshyst.inference.structured_target import StructuredTarget

        self.structure = structure
        self.base = np.asarray(z, dtype=float)
        self.target = StructuredTarget(post, structure)

    def full(self, x: np.ndarray) -> tuple[np.ndarray, Any]:
        """Complete points (n, ndim) for ``x`` (n, n_other), with their Grams."""
        z = np.repeat(self.base[None, :], x.shape[0], axis=0)
        z[:, self.structure.other_idx] = x
        return at_conditional_mean(self.structure, z)

    def log_prob(self, x: np.ndarray) -> np.ndarray:
        z, st = self.full(np.atleast_2d(x))
        return self.target.log_prob(z, st)


def profile_mode(post: Posterior, structure: Any, z: np.ndarray) -> tuple[float, np.ndarray]:
    """The posterior's mode from ``z``, searched over the coordinates outside the block.

    A quasi-Newton search (:func:`_polish`) over the nonlinear and noise coordinates,
    the linear block at its conditional mean at every point (variable projection), so a
    posterior with a hundred linear coefficients (a discrepancy's basis) is searched in
    the handful of coordinates that need a simulation. A start built from a smaller
    model's MAP can lie hundreds of nats below this mode: on the measured 150 V piezo
    (Bouc–Wen with creep, drift and the shape correction) the sampler's walkers took
    6 000 steps to climb 550 nats from such a start.

    Parameters
    ----------
    post : Posterior
    structure : LinearStructure
        Its linear block.
    z : ndarray, shape (ndim,)
        Where the search starts (finite density).

    Returns
    -------
    log_prob : float
        Log posterior at the point returned (``-inf`` if none with finite density).
    z : ndarray, shape (ndim,)
        The mode found, its block at the conditional mean; ``z`` itself (block
        completed) when the search found nothing better.
    """
    from bayeshyst.inference.least_squares import least_squares_point

    z = np.asarray(z, dtype=float)
    prof = _Profiled(post, structure, z)
    x0 = z[structure.other_idx]
    if x0.size == 0:
        zz, st = prof.full(x0[None, :])
        return float(prof.target.log_prob(zz, st)[0]), zz[0]
    # Gauss-Newton steps first (variable projection: a ridge such as Bouc-Wen's (alpha,
    # beta, n) is what they follow and a gradient method crawls along), then the polish
    # of the exact profile (the priors the least squares does not see). Not with a
    # discrepancy's basis in the block: there the least squares ended thousands of nats
    # below its start after a minute (measured on the 150 V piezo with creep and drift),
    # and the polish's passes alone climbed
    if structure.m_basis == 0:
        f = -float(prof.log_prob(x0[None, :])[0])
        z_lsq, _ = least_squares_point(post, structure, z)
        f_lsq = -float(prof.log_prob(z_lsq[structure.other_idx][None, :])[0])
        if f_lsq < f:
            x0 = z_lsq[structure.other_idx]
    f, x = _polish(post, x0, prof)
    # the polish scales its coordinates by the curvature where it starts; from far below
    # the mode those scales are wrong near it, so it starts again from where it stopped
    # (with the curvature there) until a pass gains less than a thousandth of a nat
    for _ in range(MAX_PROFILE_PASSES):
        f_next, x_next = _polish(post, x, prof)
        gained = f - f_next
        f, x = f_next, x_next
        if not gained > 1e-3:
            break
    zz, _ = prof.full(x[None, :])
    return (-f if f < _BIG else -math.inf), zz[0]


def profile_start(post: Posterior, structure: Any, start: MAPResult,
                  z: np.ndarray | None = None) -> MAPResult:
    """``start`` moved to :func:`profile_mode` of ``post`` from ``z`` (default ``start.z``).

    Its covariance is kept (the walkers' spread around the new point), its notes are not
    (they were about the old point).
    """
    lp, z0 = profile_mode(post, structure, start.z if z is None else z)
    return replace(start, z=z0, theta=post.space.unpack(z0), log_prob=lp, notes=())


def conditional_mode(post: Posterior, structure: Any, z: np.ndarray) -> np.ndarray:
    """``z`` with its noise re-optimised and its linear block at the conditional mean.

    A start for a posterior that is close to one whose MAP is known (the same model with
    a discrepancy added, or with cycles held out): the model's nonlinear coordinates
    stay, the noise (1-2 coordinates) is re-optimised by Nelder-Mead on the log
    posterior with the whole linear block following it exactly. A full
    :func:`~bayeshyst.inference.optimize.find_map` would differentiate every linear
    coordinate too (minutes with a hundred of them).

    Parameters
    ----------
    post : Posterior
    structure : LinearStructure
        Its linear block.
    z : ndarray, shape (ndim,)
    """
    space = post.space
    noise = [n for n in space.names if n.startswith(NOISE + ".")]
    noise_idx = space.indices(noise)

    def with_block(x: np.ndarray) -> np.ndarray:
        zz = np.asarray(z, dtype=float).copy()
        zz[noise_idx] = x
        return at_conditional_mean(structure, zz[None])[0][0]

    def neg(x: np.ndarray) -> float:
        val = -post.log_prob(with_block(x))
        return val if math.isfinite(val) else _BIG

    if noise_idx.size == 0:
        return with_block(np.zeros(0))
    res = optimize.minimize(neg, np.asarray(z, float)[noise_idx], method="Nelder-Mead",
                            options={"xatol": 1e-5, "fatol": 1e-4})
    return with_block(res.x)
