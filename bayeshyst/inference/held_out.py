"""Leave-one-cycle-out predictive densities of the linear block, and their gradient.

With the linear block ``beta`` (a model's linear parameters, the observation offset, a
discrepancy's basis coefficients) integrated out exactly, the held-out density of cycle
``c`` given the others is a difference of two Gaussian marginals,

    log p(y_c | y_-c, z_n) = log p(y | z_n) - log p(y_-c | z_n),

each computed from the Gram matrices of ``[Phi, r]`` over its samples
(:class:`~bayeshyst.inference.linear.LinearStructure`): the cycle's Gram is taken away
from the total, no refit. These terms serve PSIS-LOO over the nonlinear draws
(:mod:`bayeshyst.diagnostics`) and the discrepancy's scale search
(:mod:`bayeshyst.inference.discrepancy_fit`), which also needs their gradient with
respect to the basis' column scales and the noise: analytic here for white noise.

For one set of samples with scaled Gram ``A`` (coefficients), ``b`` (coefficients x
residual), ``m`` (residual), prior ``N(m0, diag(s0^2))`` and noise ``sigma``, the
marginal is a function of ``P = A / sigma^2 + diag(s0^-2)`` and
``h = b / sigma^2 + h0``; with ``mu = P^-1 h`` (the posterior mean about the reference)
and ``C = P^-1`` (MacKay 1992, the evidence of a linear model; Bishop 2006, Sec. 3.5):

* d/d log c_j (a column's scale) = ``-1 + C_jj / s0_j^2 + mu_j (mu_j / s0_j^2 - h0_j)``;
* d/d log sigma = ``-n + |r - Phi mu|^2 / sigma^2 + sum_j (1 - C_jj / s0_j^2)``, where
  ``|r - Phi mu|^2 = m - 2 mu^T b + mu^T A mu``.

The test suite checks both against central differences of the values.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.linalg import lapack

from bayeshyst.inference._grams import grams, sample_rows, stacked
from bayeshyst.inference.conditional import LinearStats
from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.optimize import MAPResult, find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.profile import profile_start

__all__ = ["SCALE_STEP", "central_points", "held_out_from_units", "held_out_gradient",
           "held_out_log_predictive", "held_out_start", "unit_grams"]

#: (unit, walker) pairs whose held-out marginals are factorised in one stacked call
#: (256 Grams of 110 x 110 coefficients: 25 MB)
_HELD_OUT_STACK = 256
_TRTRI = lapack.dtrtri
#: Step of the central differences of the column scales and the noise's transform in
#: their unconstrained coordinates (cheap functions: no factorisation)
SCALE_STEP = 1e-6


def central_points(z: np.ndarray, idx: np.ndarray, step: float = SCALE_STEP) -> np.ndarray:
    """``z`` (ndim,), then ``z + step e_k`` and ``z - step e_k`` for each ``k`` of ``idx``.

    Shape (2 len(idx) + 1, ndim): one batch for central differences of a cheap function.
    """
    k = len(idx)
    zs = np.tile(z, (2 * k + 1, 1))
    zs[1 + np.arange(k), idx] += step
    zs[1 + k + np.arange(k), idx] -= step
    return zs


def held_out_log_predictive(structure: LinearStructure, z: np.ndarray, *,
                            chunk: int = 64, units: Sequence[int] | None = None
                            ) -> np.ndarray:
    """Held-out ``log p(y_c | y_-c, z_n)`` of every cycle ``c``, shape (W, n_units).

    With the linear block integrated out exactly, this is the Rao-Blackwellised
    leave-one-cycle-out term: the marginal of all scored samples minus the marginal
    without cycle ``c`` (whose Grams are the cycle's own contribution taken away; with
    AR(1) noise the sample after a held-out cycle stays conditioned on it, as in
    :meth:`Posterior.holding_out`). Importance sampling over the nonlinear draws alone
    (PSIS-LOO on these values) leaves the linear block's sensitivity to one cycle to the
    algebra, so it needs no refits.

    Parameters
    ----------
    structure : LinearStructure
        The posterior's linear block.
    z : ndarray, shape (W, ndim)
        Posterior draws.
    chunk : int
        Draws processed together (bounds the memory of the per-cycle Grams).
    units : sequence of int, optional
        Only these cycles' terms (the others' columns are ``-inf``); the marginal
        without a cycle is the costly part, one factorisation per cycle and draw.
    """
    z = np.atleast_2d(np.asarray(z, dtype=float))
    n_units = structure.post.n_units
    out = np.full((z.shape[0], n_units), -np.inf)
    for a in range(0, z.shape[0], chunk):
        zz = z[a:a + chunk]
        out[a:a + chunk] = held_out_from_units(structure, unit_grams(structure, zz, n_units),
                                               zz, units=units)
    return out


def unit_grams(structure: LinearStructure, z: np.ndarray,
               n_units: int | None = None) -> tuple:
    """Per-cycle Grams (unscaled basis) of the walkers ``z``: what the held-out terms need.

    Returns ``(first, lag0, cross, prev, n_unit, n_first, failed)``: the Grams (units,
    W, Q, Q) (``cross``/``prev`` (units, 1, 1, 1) zeros for white noise), scored and
    first samples per unit (units,), failed walkers (W,). They depend on ``z`` only
    through the design (the model's coordinates), so a search
    over the noise or the discrepancy's scales computes them once and calls
    :func:`held_out_from_units` for each candidate.
    """
    s = structure
    n_units = s.post.n_units if n_units is None else n_units
    w, q = z.shape[0], s.p + 1
    shape = (n_units, w, q, q)
    first, lag0 = np.zeros(shape), np.zeros(shape)
    cross = np.zeros(shape) if s.lagged else np.zeros((n_units, 1, 1, 1))
    prev = np.zeros(shape) if s.lagged else np.zeros((n_units, 1, 1, 1))
    n_unit = np.zeros(n_units, dtype=int)
    n_first = np.zeros(n_units, dtype=int)
    rows, failed = s.designs(z)
    for i, (rec, (phi, const)) in enumerate(zip(s._records, rows, strict=True)):
        r = s._reference_residual(rec, phi, const)
        failed |= ~np.all(np.isfinite(r), axis=1)
        x = (None if s.has_basis else
             stacked(np.broadcast_to(phi, (w, *phi.shape[1:])), r))
        keep = rec["keep"] if rec["keep"] is not None else np.ones(r.shape[1], dtype=bool)
        bounds = [*rec["unit_starts"], r.shape[1]]
        for j in range(len(bounds) - 1):
            u = rec["unit_first"] + j
            mask = np.zeros(r.shape[1], dtype=bool)
            mask[bounds[j]:bounds[j + 1]] = True
            mask &= keep
            if not mask.any():
                continue
            f, l0, c, pv = (s._grams_with_basis(i, phi, r, mask) if x is None
                            else grams(x, mask, s.lagged))
            first[u], lag0[u] = f, l0
            if s.lagged:
                cross[u], prev[u] = c, pv
            n_unit[u] = int(np.count_nonzero(mask))
            n_first[u] = int(mask[0])
    return first, lag0, cross, prev, n_unit, n_first, failed


def _scaled_units(structure: LinearStructure, grams: tuple, z: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                             np.ndarray | None, np.ndarray]:
    """The unit Grams of the scaled basis at ``z`` (white noise: first + lag0 in one)."""
    first, lag0, cross, prev, _, _, failed = grams
    w, q = z.shape[0], structure.p + 1
    if not structure.lagged:  # white noise: only first + lag0 enters, summed once
        first, lag0, cross, prev = first + lag0, None, None, None
    if structure.has_basis:  # the unit Grams are linear in the scaled columns
        outer = structure._scaled(LinearStats(np.ones((w, q, q)), None, None, None, 0, 0,
                                              failed), z)
        failed = outer.failed
        first = first * outer.first[None]
        if structure.lagged:
            lag0 = lag0 * outer.first[None]
            cross, prev = cross * outer.first[None], prev * outer.first[None]
    return first, lag0, cross, prev, failed


def _subsets(structure: LinearStructure, grams: tuple, z: np.ndarray,
             only: Sequence[int] | None = None):
    """All samples, then stacks of 'all but one unit', as (LinearStats, units) pairs.

    The first pair's units are None; each later pair covers the units ``us`` for every
    walker, unit-major ((unit, walker) stacked): each pair's factor is computed on its
    own, so the values do not depend on the grouping, and the scale search's hundreds of
    evaluations of 10-40 units each were mostly per-call overhead one unit at a time
    (measured).
    """
    first, lag0, cross, prev, failed = _scaled_units(structure, grams, z)
    n_unit, n_first = grams[4], grams[5]
    w, q = z.shape[0], structure.p + 1
    tot = LinearStats(first.sum(axis=0), None if lag0 is None else lag0.sum(axis=0),
                      None if cross is None else cross.sum(axis=0),
                      None if prev is None else prev.sum(axis=0),
                      int(n_unit.sum()), int(n_first.sum()), failed)
    yield tot, None
    units = np.flatnonzero(n_unit > 0)  # the others are held out already
    if only is not None:
        units = np.intersect1d(units, np.asarray(only, dtype=int))
    step = max(1, _HELD_OUT_STACK // w)
    for a in range(0, units.size, step):
        us = units[a:a + step]
        rows = sample_rows(us)  # a view when the units are a contiguous run

        def rest(total: np.ndarray | None, parts: np.ndarray | None,
                 rows: np.ndarray | slice = rows, k: int = us.size) -> np.ndarray | None:
            if total is None or parts is None:
                return None
            return (total[None] - parts[rows]).reshape(k * w, q, q)

        yield LinearStats(rest(tot.first, first), rest(tot.lag0, lag0),
                          rest(tot.cross, cross), rest(tot.prev, prev),
                          np.repeat(tot.n - n_unit[us], w),
                          np.repeat(tot.n_first - n_first[us], w),
                          np.tile(failed, us.size)), us


def held_out_from_units(structure: LinearStructure, grams: tuple,
                        z: np.ndarray, *, units: Sequence[int] | None = None) -> np.ndarray:
    """Held-out ``log p(y_c | y_-c, z_n)`` (W, n_units) from :func:`unit_grams`.

    ``units``: only these cycles' columns are computed (the others are ``-inf``).
    """
    w = z.shape[0]
    out = np.full((w, grams[4].size), -np.inf)
    lm_all = None
    for st, us in _subsets(structure, grams, z, units):
        if us is None:
            lm_all = structure.log_marginal(st, z)
            continue
        with np.errstate(invalid="ignore"):
            out[:, us] = lm_all[:, None] - structure.log_marginal(
                st, np.tile(z, (us.size, 1))).reshape(us.size, w).T
    return np.where(np.isfinite(out), out, -np.inf)


def _log_scale_gradient(structure: LinearStructure, st: LinearStats, z: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """The marginal log p(y_S | z) (K,) and its gradient in (log c_j, log sigma) (K, P + 1).

    White noise only; ``z`` (K, ndim) the walkers of the stacked sets.
    """
    p = structure.p
    sigma, _ = structure.noise(z)
    value, cond = structure.log_marginal(st, z, conditional=True)
    mu = cond.mean - structure.beta_ref
    # C = P^-1 = L^-T L^-1: its diagonal is the column sums of squares of L^-1
    # (LAPACK's triangular inverse, a third of a general inverse's work: measured 6x
    # faster on 106 coefficients)
    c_diag = np.empty(mu.shape)
    for k in range(mu.shape[0]):
        inv_chol, info = _TRTRI(cond.chol[k], lower=1)
        c_diag[k] = np.sum(inv_chol**2, axis=0) if info == 0 else np.nan
    prec0 = 1.0 / structure.s0**2
    h0 = (structure.m0 - structure.beta_ref) * prec0
    d_scale = -1.0 + c_diag * prec0 + mu * (mu * prec0 - h0)
    m = st.first if st.lag0 is None else st.first + st.lag0
    a, b = m[:, :p, :p], m[:, :p, p]
    rss = m[:, p, p] - 2.0 * np.einsum("kj,kj->k", mu, b) + np.einsum("ki,kij,kj->k", mu, a, mu)
    d_sigma = -st.n + rss / sigma**2 + np.sum(1.0 - c_diag * prec0, axis=1)
    return value, np.concatenate([d_scale, d_sigma[:, None]], axis=1)


def held_out_gradient(structure: LinearStructure, grams: tuple, z: np.ndarray,
                      idx: np.ndarray) -> tuple[float, np.ndarray]:
    """Summed held-out log density at one point ``z`` and its gradient in ``z[idx]``.

    Parameters
    ----------
    structure : LinearStructure
        White noise (Gaussian likelihood); the coordinates ``idx`` are the discrepancy's
        scale coordinates and the noise's ``sigma``.
    grams : tuple
        :func:`unit_grams` at ``z``.
    z : ndarray, shape (ndim,)
    idx : ndarray of int
        The coordinates to differentiate (unconstrained, as the search sees them).

    Returns
    -------
    value : float
        ``sum_c log p(y_c | y_-c, z)`` (-inf where undefined).
    gradient : ndarray, shape (len(idx),)
        Zeros where the value is undefined.
    """
    if structure.lagged:
        raise ValueError("held_out_gradient: white noise only (an AR(1) likelihood's phi "
                         "whitens the Grams nonlinearly)")
    z1 = z[None]
    value, total = 0.0, None
    grad = np.zeros(structure.p + 1)
    for st, us in _subsets(structure, grams, z1):
        zz = z1 if us is None else np.tile(z1, (us.size, 1))
        lm, g = _log_scale_gradient(structure, st, zz)
        if us is None:
            total, g_total = float(lm[0]), g[0]
            continue
        value += us.size * total - float(np.sum(lm))
        grad += us.size * g_total - g.sum(axis=0)
    if not np.isfinite(value) or not np.all(np.isfinite(grad)):
        return -np.inf, np.zeros(len(idx))
    # chain rule to the unconstrained coordinates: d log c_j / d z_k and d log sigma /
    # d z_k by central differences of the (cheap) scale functions
    k = len(idx)
    zs = central_points(z, idx)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        c, sig = structure.column_scale(zs), structure.noise(zs)[0]
        dc = (c[1:k + 1] - c[k + 1:]) / (2.0 * SCALE_STEP)
        # a column scaled to zero carries no data and has no gradient
        dlog_c = np.where(c[0] > 0, dc / c[0], 0.0)
        dlog_s = (sig[1:k + 1] - sig[k + 1:]) / (2.0 * SCALE_STEP * sig[0])
    out = dlog_c @ grad[:-1] + dlog_s * grad[-1]
    if not np.all(np.isfinite(out)):
        return -np.inf, np.zeros(len(idx))
    return value, out


def held_out_start(held: Posterior, start: MAPResult, seed: int) -> MAPResult:
    """Where a posterior with cycles held out (``held``) starts, from the full one's MAP.

    Its own MAP, searched from the full fit's: by least squares and a small screen,
    without a global search (one cycle moves the optimum locally). With a discrepancy
    the linear block is ~100 coordinates a search would differentiate one by one (a
    branch-shape fit on the bundled record: its exact refit ran 5 000 steps, 13 min,
    unconverged); there the search runs over the other coordinates with the block at its
    conditional mean (:func:`~bayeshyst.inference.profile.profile_start`), as the
    calibration check's refit does. The exact refits of leave-one-cycle-out start here,
    and so do the screen's held-out Laplace approximations.

    Parameters
    ----------
    held : Posterior
        The posterior without the held-out cycles (:meth:`Posterior.holding_out`).
    start : MAPResult
        The full posterior's MAP (same coordinates).
    seed : int
        Randomness of the search's screen.
    """
    if held.discrepancy is not None:
        structure = LinearStructure.of(held, reference=start.z)
        if structure is not None:
            return profile_start(held, structure, start)
    return find_map(held, seed=np.random.default_rng(seed), x0=start.z, n_screen=32,
                    global_search=False)

