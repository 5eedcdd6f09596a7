"""Maximum a posteriori point and its Laplace covariance, the start of every sampler run.

The search runs in the unconstrained space ``z`` (so bounds never bind) and uses the
batched posterior throughout: a screen of prior draws, least squares from the best
distinct ones (:mod:`bayeshyst.inference.least_squares`), a quasi-Newton polish of the
exact log posterior with central-difference gradients evaluated as one batch, and a
differential evolution over the prior when the starts disagree (hysteresis posteriors
such as Bouc–Wen's can be multimodal and ridge-shaped). The Gauss–Newton curvature at
the optimum (or, without a residual form, the finite-difference Hessian) gives the
Laplace covariance that spreads the initial walkers along the posterior's own ridges.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from bayeshyst.errors import ParameterError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.threads import with_single_threaded_blas

__all__ = ["MAPResult", "find_map", "initial_ensemble",
           "laplace_covariance", "spread_shared_coordinates"]

# stands for -log p = +inf inside the optimisers (they cannot take inf); far above any
# feasible value, yet its square stays finite (differential evolution takes the std of
# its population energies, and 1e300 overflowed there)
_BIG = 1e100


@dataclass(frozen=True)
class MAPResult:
    """The MAP estimate.

    Attributes
    ----------
    z : ndarray, shape (ndim,)
        Unconstrained MAP point.
    theta : dict
        Named physical values at ``z``.
    log_prob : float
        Log posterior density at ``z`` (up to the normalising constant).
    covariance : ndarray, shape (ndim, ndim)
        Laplace covariance of ``z`` (inverse Hessian of ``-log p``).
    laplace_ok : bool
        Whether the Hessian was positive definite; if not, negative or zero curvature
        directions were given the prior's width instead (reported, not hidden).
    n_evals : int
        Posterior evaluations spent.
    candidates : tuple of float
        Log densities of the distinct local optima found (best first): several nearly
        equal values mean a multimodal or flat posterior.
    notes : tuple of str
        What the search had to do that a user should know (starts that disagreed, a
        global search, a regularised Laplace covariance), in plain words.
    """

    z: np.ndarray
    theta: dict[str, Any]
    log_prob: float
    covariance: np.ndarray
    laplace_ok: bool
    n_evals: int
    candidates: tuple[float, ...] = field(default_factory=tuple)
    notes: tuple[str, ...] = field(default_factory=tuple)

    def __str__(self) -> str:
        lines = [f"MAP: log p = {self.log_prob:.6g} ({self.n_evals} evaluations, "
                 f"{len(self.candidates)} local optima; Laplace "
                 f"{'ok' if self.laplace_ok else 'regularised'})"]
        for k, v in self.theta.items():
            lines.append(f"  {k:<20} {np.array2string(np.asarray(v), precision=5)}")
        return "\n".join(lines)


#: largest coordinate scale of the polish (z units): a coordinate flat to the finite
#: differences is moved in unit steps, one almost flat at most 100 at a time
MAX_POLISH_SCALE = 100.0


def _neg(post: Posterior, z: np.ndarray) -> np.ndarray:
    lp = post.log_prob_batch(np.atleast_2d(z))
    return np.where(np.isfinite(lp), -lp, _BIG)


def _steps(z: np.ndarray) -> np.ndarray:
    return 1e-4 * np.maximum(1.0, np.abs(z))


def _value_and_grad(post: Posterior, z: np.ndarray) -> tuple[float, np.ndarray]:
    h = _steps(z)
    eye = np.diag(h)
    pts = np.vstack([z[None, :], z + eye, z - eye])
    f = _neg(post, pts)
    grad = (f[1:1 + z.size] - f[1 + z.size:]) / (2 * h)
    if not np.all(np.isfinite(grad)) or np.any(np.abs(f) >= _BIG):
        grad = np.where(np.isfinite(grad) & (np.abs(grad) < 1e150), grad, 0.0)
    return float(f[0]), grad


def _latin_hypercube(n: int, d: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points of a Latin hypercube in the unit cube ``[0, 1)^d``."""
    u = (np.argsort(rng.random((d, n)), axis=1).T + rng.random((n, d))) / max(n, 1)
    return u


def _hessian(post: Posterior, z: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Central-difference Hessian of ``-log p`` with steps ``h`` (one batch)."""
    n = z.size
    pts = [z]
    for i in range(n):
        for j in range(i, n):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                p = z.copy()
                p[i] += si * h[i]
                p[j] += sj * h[j]
                pts.append(p)
    f = _neg(post, np.asarray(pts))
    hess = np.empty((n, n))
    k = 1
    for i in range(n):
        for j in range(i, n):
            pp, pm, mp, mm = f[k:k + 4]
            k += 4
            hess[i, j] = hess[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
    return 0.5 * (hess + hess.T)


def laplace_covariance(post: Posterior, z: np.ndarray) -> tuple[np.ndarray, bool]:
    """Inverse Hessian of ``-log p`` at ``z`` by central differences.

    Two passes: the diagonal curvature first gives each coordinate's conditional
    scale, and the full Hessian is then taken with steps of a fifth of that scale —
    a fixed step would be far too long across a thin ridge and far too short along it.
    Returns the covariance and whether the Hessian was positive definite; directions of
    non-positive curvature (flat or numerically unresolved) get the broadest variance
    the positive directions identify, so the result is a usable covariance and
    ``False`` says it had to be regularised.
    """
    n = z.size
    h0 = 1e-3 * np.maximum(1.0, np.abs(z))
    eye = np.diag(h0)
    f = _neg(post, np.vstack([z[None, :], z + eye, z - eye]))
    diag = (f[1:n + 1] - 2 * f[0] + f[n + 1:]) / h0**2
    cond_sd = np.where(np.isfinite(diag) & (diag > 0), 1.0 / np.sqrt(np.abs(diag)), h0 * 10)
    h = np.clip(0.2 * cond_sd, 1e-8 * np.maximum(1.0, np.abs(z)), 1e-1)
    hess = _hessian(post, z, h)
    if not np.all(np.isfinite(hess)):
        return np.diag(post.space.prior_scale_z(z) ** 2), False
    vals, vecs = np.linalg.eigh(hess)
    ok = bool(np.all(vals > 0))
    if not ok:
        pos = vals[vals > 0]
        floor = float(pos.min()) if pos.size else 1.0 / float(
            np.max(post.space.prior_scale_z(z) ** 2))
        vals = np.where(vals > 0, vals, floor)
    cov = (vecs / vals) @ vecs.T
    return 0.5 * (cov + cov.T), ok


def _polish(post: Posterior, z: np.ndarray, target: Any) -> tuple[float, np.ndarray]:
    """L-BFGS-B on the exact ``-log p`` from ``z``, each coordinate in units of its scale.

    Gradients are batched central differences, evaluated from the linear block's Grams
    where there is one. The scale is the conditional sd from the diagonal curvature at
    ``z`` (1 where it is not positive, at most :data:`MAX_POLISH_SCALE`): one scalar
    curvature for all coordinates, as L-BFGS starts with, is set by the stiffest ones: a
    coordinate in its prior's flat tail (the Bouc–Wen exponent at z = -8, conditional
    sd 38) barely moved while the gains converged, and the search stopped 6 sd from the
    mode (tests/test_map.py).
    """
    def values(zz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = _steps(zz)
        eye = np.diag(h)
        pts = np.vstack([zz[None, :], zz + eye, zz - eye])
        lp = target.log_prob(pts) if target is not None else post.log_prob_batch(pts)
        return np.where(np.isfinite(lp), -lp, _BIG), h

    def value_and_grad(zz: np.ndarray) -> tuple[float, np.ndarray]:
        f, h = values(zz)
        grad = (f[1:1 + zz.size] - f[1 + zz.size:]) / (2 * h)
        grad = np.where(np.isfinite(grad) & (np.abs(grad) < 1e150), grad, 0.0)
        return float(f[0]), grad

    z = np.asarray(z, dtype=float)
    f, h = values(z)
    f0 = float(f[0])
    with np.errstate(all="ignore"):
        curv = (f[1:1 + z.size] - 2 * f0 + f[1 + z.size:]) / h**2
        scale = np.where(np.isfinite(curv) & (curv > 0) & (f[1:] < _BIG).reshape(2, -1).all(0),
                         1.0 / np.sqrt(curv), 1.0)
    scale = np.clip(scale, 1e-3 * h, MAX_POLISH_SCALE)

    def scaled(w: np.ndarray) -> tuple[float, np.ndarray]:
        val, grad = value_and_grad(z + scale * w)
        return val, grad * scale

    res = optimize.minimize(scaled, np.zeros(z.size), jac=True, method="L-BFGS-B",
                            options={"maxiter": 500, "gtol": 1e-8})
    x = z + scale * np.asarray(res.x, dtype=float)
    if res.fun <= f0 and np.all(np.isfinite(x)):
        return float(res.fun), x
    return f0, z


def _global_search(post: Posterior, rng: np.random.Generator, cand: np.ndarray,
                   f: np.ndarray, maxiter: int, structure: Any = None) -> np.ndarray:
    """Differential evolution over five prior sd either side of the prior median in ``z``.

    Its population is seeded with the best screened draws and filled with a Latin
    hypercube.

    With a linear block the search runs over the other coordinates only, the block at
    its conditional mean for each (a profile: three dimensions instead of ten for a
    five-operator PI model behind second-order dynamics).
    """
    space = post.space
    idx = np.arange(space.ndim) if structure is None else structure.other_idx
    if idx.size == 0:
        return cand[int(np.argmin(f))]
    base = cand[int(np.argmin(f))].copy()

    def complete(zz: np.ndarray) -> np.ndarray:
        z = np.repeat(base[None, :], zz.shape[0], axis=0)
        z[:, idx] = zz
        if structure is not None:
            cond = structure.conditional(structure.stats(z), z)
            zb, _ = structure.z_of(cond.mean)
            good = cond.ok & np.all(np.isfinite(zb), axis=1)
            z[np.ix_(good, structure.lin_idx)] = zb[good]
        return z

    # five prior sd either side of the prior median (robust sd from the quartiles): a
    # long record outweighs its prior by thousands of nats, and the mode it picks may
    # lie far in the prior's tail (a second-order resonance at a 5 Hz drive's own
    # frequency, 4.6 sd below a prior median of fs / 20, beat the mode inside the
    # central 99 % by 1 400 nats on 6 000 samples)
    q25, q50, q75 = np.quantile(space.sample_prior(rng, 2000)[:, idx], [0.25, 0.5, 0.75],
                                axis=0)
    half = 5.0 * (q75 - q25) / 1.349
    half = np.where(half > 0, half, 1.0)
    lo, hi = q50 - half, q50 + half
    d = idx.size
    size = max(20, 10 * d)
    sub = cand[:, idx]
    inside = np.all((sub >= lo) & (sub <= hi), axis=1)
    seeded = sub[np.argsort(np.where(inside, f, np.inf))][: size // 2]
    seeded = seeded[np.all((seeded >= lo) & (seeded <= hi), axis=1)]
    lhs = lo + (hi - lo) * _latin_hypercube(size - seeded.shape[0], d, rng)
    res = optimize.differential_evolution(
        lambda zz: _neg(post, complete(np.asarray(zz).T)), list(zip(lo, hi, strict=True)),
        maxiter=maxiter, tol=0.0, atol=0.0, init=np.vstack([seeded, lhs]),
        seed=int(rng.integers(2**31 - 1)), polish=False, vectorized=True,
        updating="deferred")
    return complete(np.asarray(res.x, dtype=float)[None, :])[0]


@with_single_threaded_blas
def find_map(
    post: Posterior,
    *,
    seed: int | np.random.Generator = 0,
    n_screen: int = 256,
    n_starts: int = 2,
    global_search: bool | str = "auto",
    de_maxiter: int = 100,
    x0: np.ndarray | None = None,
) -> MAPResult:
    """Maximum a posteriori point in ``z`` with its Laplace covariance.

    A screen of prior draws (one batch; with a linear block each draw's block is set to
    its conditional mean first, so the screen ranks the nonlinear coordinates), least
    squares from the best distinct draws (:func:`~bayeshyst.inference.least_squares.
    least_squares_point`: variable projection, batched Jacobians), an L-BFGS polish of
    the exact log posterior, and the Gauss–Newton Laplace covariance. When the starts
    end at optima more than half a nat apart — a multimodal or rugged posterior — a
    differential evolution searches the prior globally as well, and the result says so.

    Parameters
    ----------
    post : Posterior
    seed : int or Generator
        Randomness of the screen and of the differential evolution.
    n_screen : int
        Prior draws evaluated (one batch) to pick starting points.
    n_starts : int
        Distinct starting points of the least squares (two that end at the same optimum
        settle it; two that do not call the global search).
    global_search : bool or "auto"
        Run the differential evolution always (True), never (False), or when the
        starts disagree or the model declares ``multimodal_posterior`` ("auto").
    de_maxiter : int
        Generations of the differential evolution.
    x0 : ndarray, shape (ndim,), optional
        An extra starting point (e.g. an earlier fit's optimum), tried first.

    Raises
    ------
    ParameterError
        If no point with finite posterior density is found.
    """
    from bayeshyst.inference.least_squares import gauss_newton_covariance, least_squares_point
    from bayeshyst.inference.linear import LinearStructure
    from bayeshyst.inference.structured_target import StructuredTarget

    if global_search not in (True, False, "auto"):
        raise ParameterError(f"global_search must be True, False or 'auto', got {global_search!r}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    n0 = post.counts.evaluations
    space = post.space
    structure = LinearStructure.of(post) if post.beta == 1.0 else None
    target = None if structure is None else StructuredTarget(post, structure)
    cand = space.sample_prior(rng, n_screen)
    if x0 is not None:
        cand = np.vstack([np.asarray(x0, dtype=float)[None, :], cand])
    if structure is not None:
        cond = structure.conditional(structure.stats(cand), cand)
        zb, _ = structure.z_of(cond.mean)
        good = cond.ok & np.all(np.isfinite(zb), axis=1)
        if x0 is not None:
            good[0] = False  # an explicit start is kept as it is
        cand[np.ix_(good, structure.lin_idx)] = zb[good]
    f = _neg(post, cand)
    order = np.argsort(f, kind="stable")
    starts: list[np.ndarray] = []
    if x0 is not None and f[0] < _BIG:
        starts.append(cand[0])

    def more_starts(k: int) -> list[np.ndarray]:
        """The next ``k`` best screened draws, none near a start already taken.

        Near means within a tenth of a prior scale.
        """
        new: list[np.ndarray] = []
        for i in order:
            if f[i] >= _BIG or len(new) >= k:
                break
            scale = space.prior_scale_z(cand[i])
            if all(np.max(np.abs(cand[i] - st) / scale) > 0.1 for st in starts + new):
                new.append(cand[i])
        starts.extend(new)
        return new

    more_starts(n_starts - len(starts))
    if not starts:
        raise ParameterError(
            f"no parameter vector with finite posterior density among {cand.shape[0]} "
            f"prior draws of {post!r}: the data and the priors do not overlap, or every "
            "simulation failed"
        )
    lsq = post.likelihood.name in ("gaussian", "ar1", "student_t") and post.beta == 1.0

    def local(st: np.ndarray) -> tuple[float, np.ndarray]:
        z = st
        if lsq:
            z, _ = least_squares_point(post, structure, st)
            # the least squares sees the residual and the Gaussian priors, not the other
            # priors and Jacobians: where the residual is flat it can end far below its
            # start in log posterior (an MR-damper restart: 1 500 nats below the walker it
            # started from); the polish then starts from the better of the two
            if not _neg(post, z[None, :])[0] < _neg(post, st[None, :])[0]:
                z = st
        return _polish(post, z, target)

    def agree(opt: list[tuple[float, np.ndarray]]) -> bool:
        # the best optimum reached from two starts (within half a nat) settles it
        return len(opt) < 2 or not opt[1][0] < _BIG or opt[1][0] - opt[0][0] <= 0.5

    optima = sorted((local(st) for st in starts), key=lambda p: p[0])
    notes = []
    tried = len(starts)
    if global_search == "auto" and not agree(optima):
        # before searching globally, a few more starts: a rugged posterior with one
        # dominant basin is settled when a second start reaches the best optimum
        optima = sorted(optima + [local(st) for st in more_starts(4)], key=lambda p: p[0])
        tried = len(starts)
        if agree(optima):
            notes.append(f"the first least-squares starts ended at different optima; of "
                         f"{tried} starts, two reached the best")
    # a few nonlinear coordinates behind a linear block (a resonance, a delay, a creep
    # bank): their likelihood is rugged (one narrow basin per alias) and the profiled
    # search over them is cheap, so a short one always runs
    cheap = (structure is not None and 0 < structure.design_idx.size <= 3
             and structure.other_idx.size <= 4)
    disagreed = not agree(optima)
    # a family with a known minor mode: agreeing starts prove nothing (both can be in it)
    declared = global_search == "auto" and bool(post.model.multimodal_posterior)
    if global_search is True or (global_search == "auto" and (disagreed or cheap or declared)):
        full = global_search is True or disagreed or declared
        zg = _global_search(post, rng, cand, f, de_maxiter if full else min(de_maxiter, 40),
                            structure)
        found = _polish(post, zg, target)
        better = found[0] < optima[0][0] - 0.5
        optima = sorted([*optima, found], key=lambda p: p[0])
        if global_search == "auto" and disagreed:
            notes.append(
                f"{tried} least-squares starts ended at optima up to "
                f"{optima[-1][0] - optima[0][0]:.3g} nats apart (a multimodal or rugged "
                f"posterior); a differential evolution searched the prior globally")
        elif global_search == "auto" and better:
            notes.append(
                f"the least-squares starts agreed on an optimum that a short differential "
                f"evolution over the {structure.other_idx.size} nonlinear coordinates beat "
                f"by {optima[1][0] - optima[0][0]:.3g} nats (a rugged posterior: narrow "
                f"basins, e.g. of a resonance frequency)")
    best_f, best_z = optima[0]
    if best_f >= _BIG:
        raise ParameterError(f"MAP search for {post!r} found no finite posterior density")
    if structure is not None and post.likelihood.name in ("gaussian", "ar1"):
        structure.set_reference(best_z)
        cov, ok, _ = gauss_newton_covariance(post, structure, best_z)
    elif post.likelihood.name in ("gaussian", "ar1") and post.beta == 1.0:
        cov, ok, _ = gauss_newton_covariance(post, None, best_z)
    else:
        cov, ok = laplace_covariance(post, best_z)
    if not ok:
        notes.append("the Laplace covariance had directions without positive curvature; "
                     "they were given the broadest variance the others identify")
    distinct: list[float] = []
    for v, _ in optima:  # sorted best first; optima within 0.05 nats count as one
        if v < _BIG and all(abs(-v - d) > 0.05 for d in distinct):
            distinct.append(-v)
    return MAPResult(best_z, space.unpack(best_z), -best_f, cov, ok,
                     post.counts.evaluations - n0, tuple(distinct), tuple(notes))


def initial_ensemble(
    post: Posterior, start: MAPResult, n_walkers: int, rng: np.random.Generator,
    *, spread: float = 1.0, max_tries: int = 50,
) -> np.ndarray:
    """Walkers drawn from the Laplace approximation at the MAP, all with finite density.

    Parameters
    ----------
    spread : float
        Multiplier of the Laplace standard deviations.
    """
    n = post.ndim
    chol = np.linalg.cholesky(start.covariance + 1e-12 * np.eye(n))
    out = np.empty((n_walkers, n))
    filled = 0
    for _ in range(max_tries):
        need = n_walkers - filled
        draws = start.z + spread * rng.standard_normal((2 * need, n)) @ chol.T
        good = draws[np.isfinite(post.log_prob_batch(draws))][:need]
        out[filled:filled + good.shape[0]] = good
        filled += good.shape[0]
        if filled == n_walkers:
            return out
        spread *= 0.5  # the Laplace ball pokes outside the support: shrink it
    raise ParameterError(f"could not place {n_walkers} walkers with finite density around "
                         f"the MAP of {post!r} (got {filled})")


#: a coordinate whose spread over the walkers is below this fraction of its Laplace
#: standard deviation counts as shared by every walker
SHARED_SPREAD = 1e-8


def spread_shared_coordinates(
    post: Posterior, start: MAPResult, walkers: np.ndarray, idx: np.ndarray,
    rng: np.random.Generator, *, max_tries: int = 50,
) -> tuple[np.ndarray, np.ndarray]:
    """Given walkers, the coordinates every one of them shares drawn around their value.

    Differential-evolution and stretch moves move a walker along differences of
    walkers, and an independence proposal re-fitted to the ensemble has no width where
    the ensemble has none: a coordinate that starts equal in every walker stays where it
    is for the whole run. (Seen: the drift candidate on the 0.5 A MR damper started with
    ``drift.g`` and ``drift.d`` at the score test's estimate in all 40 walkers; after
    10 000 steps their R-hat was undefined and none of 342 160 independence proposals had
    been accepted.) Each shared coordinate set ``D`` is redrawn from the Laplace
    approximation's conditional given the walker's other coordinates (covariance
    ``inv(P_DD)``, ``P`` the Laplace precision) centred on the shared value; a walker
    whose draw has no finite density is drawn again at half the width, and one that
    never finds finite density is left out (the caller fills the ensemble). Nothing is
    evaluated when no coordinate is shared (the common case: a refit started from an
    earlier fit's draws).

    Parameters
    ----------
    post : Posterior
    start : MAPResult
        Its Laplace covariance sets the widths.
    walkers : ndarray, shape (M, ndim)
        Starting points; where a coordinate is shared, those without finite density are
        left out before the draw.
    idx : ndarray of int
        Coordinates the sampler's non-exact moves act on (coordinates drawn exactly from
        their conditional, the linear block of the structured moves, cannot stick).
    rng : numpy.random.Generator

    Returns
    -------
    walkers : ndarray, shape (M', ndim)
        ``walkers`` itself when no coordinate in ``idx`` is shared (so a run started from
        them keeps its identity), else the repaired walkers (``M' <= M``).
    shared : ndarray of int
        The coordinates that were shared (empty when none).
    """
    walkers = np.asarray(walkers, dtype=float)
    idx = np.asarray(idx, dtype=int)
    if walkers.shape[0] < 2 or idx.size == 0:
        return walkers, np.zeros(0, dtype=int)
    cov = start.covariance + 1e-12 * np.eye(post.ndim)
    width = np.sqrt(np.diag(cov))[idx]
    shared = idx[walkers[:, idx].std(axis=0) <= SHARED_SPREAD * width]
    if shared.size == 0:
        return walkers, shared
    walkers = walkers[np.isfinite(post.log_prob_batch(walkers))]
    precision = np.linalg.inv(cov)
    chol = np.linalg.cholesky(np.linalg.inv(precision[np.ix_(shared, shared)]))
    out = walkers.copy()
    todo = np.arange(walkers.shape[0])
    scale = 1.0
    for _ in range(max_tries):
        trial = walkers[todo].copy()
        trial[:, shared] += scale * rng.standard_normal((todo.size, shared.size)) @ chol.T
        good = np.isfinite(post.log_prob_batch(trial))
        out[todo[good]] = trial[good]
        todo = todo[~good]
        if todo.size == 0:
            return out, shared
        scale *= 0.5  # the conditional ball pokes outside the support: shrink it
    return np.delete(out, todo, axis=0), shared
