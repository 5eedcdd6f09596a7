"""Building blocks of the GP hysteresis model (:mod:`bayeshyst.gp`).

Private helpers, kept apart from the estimator so that each can be tested alone:

* :func:`rate` -- ``ds/dt`` of one record (second-order central differences);
* :func:`memory_indices` / :func:`memory_features` -- the reversal stack: direction,
  and the samples of the last two input reversals that survive the wiping-out
  property (see :func:`memory_indices` for the exact rule);
* :func:`stratified_subset` / :func:`farthest_subset` -- the two training-subset
  schemes;
* :func:`log_marginal_likelihood` -- value and analytic gradient in ``O(m^2 d)``;
  :func:`maximise_marginal_likelihood` (L-BFGS-B from several starts, every optimum
  returned) and
  :func:`sample_marginal_likelihood` (emcee);
* :func:`split_columns` -- validation of the estimator's array convention;
  :func:`make_kernel`, :data:`BOUNDS`;
* the result records :class:`GPPrediction`, :class:`UnitLogDensity`,
  :class:`HyperparameterReport` (re-exported by :mod:`bayeshyst.gp`);
* :class:`Conditioned` -- a GP conditioned on a training set (Cholesky factor), with
  chunked predictive means, variances and joint covariances.

The memory stack walks every sample once (a compiled loop, about 10 ns per sample).
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import emcee
import numpy as np
from numba import njit
from scipy import linalg, optimize
from scipy.spatial.distance import cdist
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Matern, WhiteKernel
from threadpoolctl import ThreadpoolController

from bayeshyst.data.segment import find_reversals
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.convergence import ess_bulk, rhat
from bayeshyst.inference.posterior import Unit

__all__ = [
    "BOUNDS",
    "SMALL_BLAS",
    "WIPE_FRACTION",
    "Conditioned",
    "GPPrediction",
    "HyperparameterReport",
    "UnitLogDensity",
    "blas_limit",
    "farthest_subset",
    "gather_memory",
    "log_marginal_likelihood",
    "make_kernel",
    "maximise_marginal_likelihood",
    "memory_features",
    "memory_indices",
    "rate",
    "sample_marginal_likelihood",
    "split_columns",
    "stratified_subset",
]

#: Two extrema closer than ``WIPE_FRACTION * threshold`` count as equal when the stack
#: decides whether a branch has closed a loop. Half the reversal threshold is at least
#: 5 noise sigma with the default threshold (:func:`~bayeshyst.data.segment.default_prominence`
#: takes >= 10 sigma), so the repeated extrema of a periodic input -- equal up to
#: rounding or noise -- always close their loop the same way, while loops whose
#: extrema differ by more than that stay resolved.
WIPE_FRACTION = 0.5

#: Hyperparameter bounds in standardised units (inputs and targets of unit variance):
#: they bound the optimiser and are the support of the hyperparameter prior. A
#: length-scale at its upper bound switches its feature off.
BOUNDS = {"signal_variance": (1e-3, 1e4), "length_scale": (1e-2, 1e3), "noise_level": (1e-8, 1.0)}

#: Largest training-set size whose linear algebra runs with single-threaded BLAS.
SMALL_BLAS = 1000
_CONTROLLER: ThreadpoolController | None = None


def rate(t: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Time derivative of one record's signal, ``ds/dt`` [unit of s per s].

    Second-order central differences inside, first-order one-sided differences at the
    two ends (``numpy.gradient`` with the sample times), so it never reaches across
    records.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Strictly increasing times [s], ``n >= 2``.
    s : ndarray, shape (n,)
        Signal (input voltage, or output for the inverse model).

    Returns
    -------
    ndarray, shape (n,)
    """
    return np.gradient(s, t)


@njit(cache=True)
def _walk(s: np.ndarray, rev: np.ndarray, rev_max: np.ndarray, first_dir: int,
          tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = s.size
    direction = np.empty(n, dtype=np.int64)
    ref1 = np.empty(n, dtype=np.int64)
    ref2 = np.empty(n, dtype=np.int64)
    stack = np.empty(rev.size + 1, dtype=np.int64)
    stack[0] = 0
    size = 1
    d = first_dir
    k = 0
    for i in range(n):
        if k < rev.size and i > 0 and rev[k] == i - 1:
            stack[size] = i - 1
            size += 1
            d = -1 if rev_max[k] else 1
            k += 1
        if d != 0:
            while size >= 2 and d * (s[i] - s[stack[size - 2]]) >= -tol:
                if size >= 3:
                    size -= 2
                else:
                    stack[0] = stack[1]
                    size = 1
        direction[i] = d
        ref1[i] = stack[size - 1]
        ref2[i] = stack[size - 2] if size >= 2 else stack[size - 1]
    return direction, ref1, ref2


def memory_indices(s: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Direction and reversal-stack indices of every sample of one record.

    The rule (a Preisach memory with a noise-robust zig-zag):

    1. Reversals are the turning points of ``s`` found by
       :func:`~bayeshyst.data.segment.find_reversals` with ``min_prominence=threshold``
       (an extreme counts once ``s`` has retreated from it by more than ``threshold``).
       A reversal at sample ``i`` ends its branch there; the next branch starts at
       ``i + 1``. The record's first sample is the *anchor*, the start of the first
       branch.
    2. The stack holds sample indices of alternating extrema, oldest first; it starts
       as ``[0]`` (the anchor). At sample ``i`` it is first pushed the reversal
       ``i - 1`` if there is one, then wiped: with ``d`` the direction of the branch,
       while the stack holds at least two entries and ``d * (s[i] - s[S[-2]]) >=
       -WIPE_FRACTION * threshold`` (the branch has reached the extremum before its
       own start, so the loop it opened is closed), the two top entries are popped
       (wiping-out; the branch now continues from the older reversal of the same kind,
       return-point memory), or, when only two entries are left, the bottom one is
       dropped (nothing older is remembered).
    3. Sample ``i`` is described by ``d``, the top entry ``S[-1]`` (the last surviving
       reversal, the start of the current branch) and ``S[-2]`` (the one before it; the
       top entry again when the stack holds one entry).

    ``d`` is +1 on a rising branch, -1 on a falling one: before the first reversal the
    direction towards it (+1 if it is a maximum); without any reversal the sign of
    ``s[-1] - s[0]`` (0 for a constant signal, which never wipes anything). A
    reversal's own sample belongs to the branch that ends there.

    The features are non-causal by the confirmation lag of the zig-zag: a reversal at
    ``i`` is known once the signal has retreated by ``threshold``, a few samples later.
    The *outputs* they refer to (at ``S[-1]``, ``S[-2]``) are always at samples strictly
    before ``i`` (or the anchor), which is what makes the free-run simulation a
    sequence over reversals instead of over samples.

    Parameters
    ----------
    s : ndarray, shape (n,)
        The signal whose reversals define the memory (input voltage [V]; the output for
        the inverse model), finite, ``n >= 2``.
    threshold : float
        Zig-zag threshold [unit of s], >= 0.

    Returns
    -------
    direction : ndarray of int64, shape (n,)
        -1, 0 or +1.
    ref1, ref2 : ndarray of int64, shape (n,)
        Sample indices of the last and the previous surviving reversal (0: the anchor).
        ``ref1[i] < i`` unless it is the anchor, likewise ``ref2``.
    """
    s = np.ascontiguousarray(s, dtype=np.float64)
    idx = find_reversals(s, min_prominence=threshold)
    maxima = set(find_reversals(s, min_prominence=threshold, kind="max").tolist())
    rev_max = np.array([i in maxima for i in idx.tolist()], dtype=np.bool_)
    if idx.size:
        first_dir = 1 if rev_max[0] else -1
    else:
        first_dir = int(np.sign(s[-1] - s[0]))
    return _walk(s, idx.astype(np.int64), rev_max, first_dir, WIPE_FRACTION * float(threshold))


def memory_features(s: np.ndarray, out: np.ndarray, threshold: float,
                    anchor_output: float) -> np.ndarray:
    """Memory features of one record: ``[d, s_r1, y_r1, s_r2, y_r2]`` per sample.

    Parameters
    ----------
    s : ndarray, shape (n,)
        Signal defining the memory (see :func:`memory_indices`).
    out : ndarray, shape (n,)
        Output whose values at the reversals are fed in: measured (teacher forcing,
        training) or simulated (free run). Its value at the anchor (sample 0) is not
        used.
    threshold : float
        Zig-zag threshold [unit of s].
    anchor_output : float
        Output feature of the anchor. The output at a record's first sample is not
        known in a free run, so the anchor carries the same fixed value in training
        and prediction (the estimator uses the training mean of the output).

    Returns
    -------
    ndarray, shape (n, 5)
        Direction, input and output at the last reversal, input and output at the one
        before it.
    """
    y_ref = np.array(out, dtype=np.float64, copy=True)
    y_ref[0] = anchor_output
    return gather_memory(s, y_ref, *memory_indices(s, threshold))


def gather_memory(s: np.ndarray, y_ref: np.ndarray, direction: np.ndarray, ref1: np.ndarray,
                  ref2: np.ndarray) -> np.ndarray:
    """Assemble ``[d, s_r1, y_r1, s_r2, y_r2]`` from the indices of :func:`memory_indices`.

    ``y_ref`` (n,) holds the outputs to feed in, its sample 0 already the anchor value.
    Rows may be any subset of a record as long as ``s`` and ``y_ref`` are the whole
    record and the index arrays are the rows' own.
    """
    return np.column_stack([direction.astype(np.float64), s[ref1], y_ref[ref1], s[ref2],
                            y_ref[ref2]])


def stratified_subset(n: int, m: int, rng: np.random.Generator) -> np.ndarray:
    """Time-stratified random subset: one sample drawn uniformly from each of ``m``
    consecutive, equally long strata of the ``n`` candidates.

    Every cycle and every record gets training points in proportion to its length,
    and no two points are closer than one stratum apart on average.

    Returns
    -------
    ndarray of int64, shape (min(m, n),)
        Increasing candidate positions.
    """
    if m >= n:
        return np.arange(n, dtype=np.int64)
    edges = np.floor(np.linspace(0, n, m + 1)).astype(np.int64)
    return edges[:-1] + (rng.random(m) * (edges[1:] - edges[:-1])).astype(np.int64)


def farthest_subset(z: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """Farthest-point (greedy k-centre) subset in the standardised feature space.

    The first point is drawn at random; each next one is the candidate farthest
    (Euclidean) from all points chosen so far, the first such in time on ties.
    Covers the feature space evenly, including its sparse regions (reversals, fast
    rates), at the price of under-weighting densely visited regions. ``O(n m d)``.

    Parameters
    ----------
    z : ndarray, shape (n, d)
        Standardised candidate features.
    m : int
        Subset size.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of int64, shape (min(m, n),)
        Increasing candidate positions.
    """
    n = z.shape[0]
    if m >= n:
        return np.arange(n, dtype=np.int64)
    chosen = np.empty(m, dtype=np.int64)
    chosen[0] = rng.integers(n)
    dist = np.sum((z - z[chosen[0]]) ** 2, axis=1)
    for j in range(1, m):
        chosen[j] = int(np.argmax(dist))
        np.minimum(dist, np.sum((z - z[chosen[j]]) ** 2, axis=1), out=dist)
    return np.sort(chosen)


def split_columns(X: np.ndarray, y: np.ndarray | None,
                  input_name: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
    """Validate the array convention of :class:`bayeshyst.gp.GPHysteresis` and split it.

    ``X`` (N, 2): columns ``t`` [s] and the input (named ``input_name`` in messages) of
    one record; (N, 3): plus an integer record id, each record one contiguous block of
    at least 2 rows with strictly increasing ``t``. ``y`` (N,) or None.

    Returns
    -------
    list of (t, s, y_part)
        One tuple per record, in row order.

    Raises
    ------
    DataError
        Naming the column (and its index) and the 0-based row of the first problem.
    """
    arr = np.asarray(X)
    if arr.dtype.kind not in "biuf" or arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise DataError(f"X: expected a real array of shape (N, 2) (columns t, {input_name}) or "
                        f"(N, 3) (t, {input_name}, record id), found shape {arr.shape}, "
                        f"dtype {arr.dtype}")
    arr = arr.astype(float)
    names = ("t", input_name, "record")
    bad = ~np.isfinite(arr)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise DataError(f"X: column {names[j]!r} (index {j}), row {i}: expected a finite "
                        f"value, found {arr[i, j]!r}")
    if y is not None:
        y = np.asarray(y)
        if y.dtype.kind not in "biuf" or y.shape != (arr.shape[0],):
            raise DataError(f"y: expected a real array of shape ({arr.shape[0]},) (one per "
                            f"row of X), found shape {y.shape}, dtype {y.dtype}")
        y = y.astype(float)
        if not np.isfinite(y).all():
            i = int(np.argmax(~np.isfinite(y)))
            raise DataError(f"y: row {i}: expected a finite value, found {y[i]!r}")
    ids = arr[:, 2] if arr.shape[1] == 3 else np.zeros(arr.shape[0])
    if arr.shape[1] == 3 and not np.all(ids == np.round(ids)):
        i = int(np.argmax(ids != np.round(ids)))
        raise DataError(f"X: column 'record' (index 2), row {i}: expected an integer record "
                        f"id, found {ids[i]!r}")
    cuts = [0, *(np.flatnonzero(np.diff(ids) != 0) + 1).tolist(), arr.shape[0]]
    seen: set[float] = set()
    out = []
    for a, b in itertools.pairwise(cuts):
        if ids[a] in seen:
            raise DataError(f"X: column 'record' (index 2), row {a}: record id {ids[a]:g} "
                            f"reappears; each record must be one contiguous block of rows")
        seen.add(ids[a])
        if b - a < 2:
            raise DataError(f"X: record id {ids[a]:g} (rows {a}:{b}): expected at least 2 "
                            f"samples, found {b - a}")
        t = arr[a:b, 0]
        steps = np.diff(t)
        if not (steps > 0).all():
            i = a + int(np.argmax(steps <= 0)) + 1
            raise DataError(f"X: column 't' (index 0), row {i}: expected strictly increasing "
                            f"time within record id {ids[a]:g}, found {arr[i, 0]!r} after "
                            f"{arr[i - 1, 0]!r}")
        out.append((t, arr[a:b, 1], None if y is None else y[a:b]))
    return out


@contextlib.contextmanager
def blas_limit(m: int) -> Iterator[None]:
    """Single-threaded BLAS while working with ``m x m`` matrices, ``m <= SMALL_BLAS``.

    Threads gain little at that size, and on an oversubscribed machine OpenBLAS's
    spinning threads made these calls up to 100x slower (measured: a 300 x 300 Cholesky
    took 172 ms instead of ~1 ms with another job on both cores). Larger problems keep
    the configured thread count.
    """
    global _CONTROLLER
    if m > SMALL_BLAS:
        yield
        return
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    with _CONTROLLER.limit(limits=1, user_api="blas"):
        yield


def _kernel_parts(theta: np.ndarray, kind: str, a: np.ndarray,
                  b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlation ``k`` (without the amplitude) and ``-dk/d(r^2) * 2`` between scaled
    inputs ``a`` (n, d) and ``b`` (m, d), for the gradient with respect to log
    length-scales."""
    sq = cdist(a, b, "sqeuclidean")
    if kind == "rbf":
        k = np.exp(-0.5 * sq)
        return k, k
    r = np.sqrt(5.0 * sq)
    e = np.exp(-r)
    return (1.0 + r + r * r / 3.0) * e, (5.0 / 3.0) * (1.0 + r) * e


def log_marginal_likelihood(theta: np.ndarray, kind: str, z: np.ndarray, y: np.ndarray,
                            gradient: bool = True) -> tuple[float, np.ndarray] | float:
    """Log marginal likelihood of ``c k(z/l) + s2 I`` and its gradient in ``theta``.

    ``theta = log([c, l_1..l_d, s2])`` in the order of sklearn's
    ``ConstantKernel * RBF|Matern(nu=2.5) + WhiteKernel`` (``kernel.theta``). The
    gradient uses ``dlml/dtheta_j = tr(W dK/dtheta_j) / 2``, ``W = a a^T - K^-1``; for
    the length-scales ``sum_ij G_ij (x_ik - x_jk)^2 = 2 (x_k^2)^T G 1 - 2 x_k^T G x_k``
    with ``G = c W o k'``, so no (m, m, d) tensor is formed.

    Parameters
    ----------
    theta : ndarray, shape (d + 2,)
    kind : {"rbf", "matern52"}
    z : ndarray, shape (m, d)
        Standardised training inputs.
    y : ndarray, shape (m,)
        Standardised targets.
    gradient : bool
        Also return the gradient.

    Returns
    -------
    float, or (float, ndarray of shape (d + 2,))
        ``-inf`` (and a zero gradient) when ``K`` is not numerically positive definite.
    """
    c, noise = math.exp(theta[0]), math.exp(theta[-1])
    a = z / np.exp(theta[1:-1])
    k, dk = _kernel_parts(theta, kind, a, a)
    m = y.size
    kmat = c * k
    kmat[np.diag_indices(m)] += noise
    try:
        chol = linalg.cholesky(kmat, lower=True, check_finite=False)
    except linalg.LinAlgError:
        return (-np.inf, np.zeros_like(theta)) if gradient else -np.inf
    alpha = linalg.cho_solve((chol, True), y, check_finite=False)
    lml = float(-0.5 * y @ alpha - np.log(np.diag(chol)).sum() - 0.5 * m * math.log(2 * math.pi))
    if not gradient:
        return lml
    inv, info = linalg.lapack.dpotri(chol, lower=1)
    if info != 0:
        return -np.inf, np.zeros_like(theta)
    inv = np.tril(inv) + np.tril(inv, -1).T
    w = np.outer(alpha, alpha) - inv
    grad = np.empty_like(theta)
    grad[0] = 0.5 * c * float(np.sum(w * k))
    grad[-1] = 0.5 * noise * float(np.trace(w))
    g = c * w * dk
    grad[1:-1] = (a * a).T @ g.sum(axis=1) - np.sum(a * (g @ a), axis=0)
    return lml, grad


@dataclass(frozen=True)
class HyperparameterReport:
    """emcee run over the log hyperparameters.

    Attributes
    ----------
    names : tuple of str
        Hyperparameter names (sklearn's, e.g. ``k1__k2__length_scale[0]``).
    mean, sd : ndarray, shape (p,)
        Posterior mean and standard deviation of each log hyperparameter.
    rhat, ess_bulk : ndarray, shape (p,)
        Rank-normalised split R-hat and bulk ESS, walkers as chains, after burn-in.
    acceptance : float
        Mean acceptance fraction.
    n_walkers, n_steps, burn, n_draws : int
    converged : bool
        Every R-hat below ``rhat_threshold`` and every ESS at least ``min_ess``.
    reasons : tuple of str
        Why not converged.
    """

    names: tuple[str, ...]
    mean: np.ndarray
    sd: np.ndarray
    rhat: np.ndarray
    ess_bulk: np.ndarray
    acceptance: float
    n_walkers: int
    n_steps: int
    burn: int
    n_draws: int
    converged: bool
    reasons: tuple[str, ...] = ()

    def __str__(self) -> str:
        state = "converged" if self.converged else "NOT converged: " + "; ".join(self.reasons)
        lines = [f"GP hyperparameters, {self.n_walkers} walkers x {self.n_steps} steps "
                 f"(burn {self.burn}), acceptance {self.acceptance:.2f}: {state}",
                 f"  {'log hyperparameter':<32} {'mean':>9} {'sd':>8} {'R-hat':>7} {'ESS':>7}"]
        for i, n in enumerate(self.names):
            lines.append(f"  {n:<32} {self.mean[i]:9.3f} {self.sd[i]:8.3f} "
                         f"{self.rhat[i]:7.4f} {self.ess_bulk[i]:7.0f}")
        return "\n".join(lines)


@dataclass(frozen=True)
class GPPrediction:
    """Free-run prediction of one record (warm-up included).

    Attributes
    ----------
    name : str
        Record name.
    mean, std : ndarray, shape (n,)
        Predictive mean and latent standard deviation (noise excluded) of the output
        [output unit].
    noise_std : float
        Observation noise standard deviation [output unit]; add ``noise_std**2`` to
        ``std**2`` for the predictive density of a measurement.
    """

    name: str
    mean: np.ndarray
    std: np.ndarray
    noise_std: float

    def __str__(self) -> str:
        return (f"GPPrediction {self.name!r}: {self.mean.size} samples, mean std "
                f"{float(np.mean(self.std)):.4g}, noise std {self.noise_std:.4g}")


@dataclass(frozen=True)
class UnitLogDensity:
    """Predictive log-density of each cycle (the cross-validation units of the models).

    Attributes
    ----------
    units : tuple of Unit
        From :func:`bayeshyst.inference.posterior.cycle_units`, in record order.
    values : ndarray, shape (n_units,)
        ``log p(y_unit)`` [nats], hyperparameter draws mixed per unit.
    n_samples : ndarray of int, shape (n_units,)
        Scored samples per unit.
    per_draw : ndarray, shape (n_draws, n_units)
        The same per hyperparameter draw (one row at the ML values).
    method : str
        ``"free-run"`` or ``"leave-one-cycle-out"``.
    covariance : str
        ``"pointwise"`` (sum of marginal log-densities) or ``"joint"``.
    """

    units: tuple[Unit, ...]
    values: np.ndarray
    n_samples: np.ndarray
    per_draw: np.ndarray
    method: str
    covariance: str

    @property
    def total(self) -> float:
        """Sum over units [nats]."""
        return float(np.sum(self.values))

    def __str__(self) -> str:
        return (f"UnitLogDensity ({self.method}, {self.covariance}, {self.per_draw.shape[0]} "
                f"hyperparameter draw(s)): {len(self.units)} units, total {self.total:.2f} "
                f"nats, {self.total / max(1, int(self.n_samples.sum())):.4f} per sample")


def make_kernel(kind: str, d: int, length_scale: float | np.ndarray, signal_variance: float,
                noise_level: float):
    """``ConstantKernel * RBF|Matern(nu=2.5) (ARD, d length-scales) + WhiteKernel`` with
    the initial values given and :data:`BOUNDS`.

    Raises
    ------
    ParameterError
        ``length_scale`` neither a positive number nor ``d`` positive numbers.
    """
    ls = np.asarray(length_scale, dtype=float)
    ok = ls.ndim == 0 or ls.shape == (d,)
    ls = np.broadcast_to(ls, (d,)).copy() if ok else ls
    if not (ok and np.isfinite(ls).all() and (ls > 0).all()):
        raise ParameterError(f"length_scale: expected a positive number or {d} positive "
                             f"numbers (one per feature), found {length_scale!r}")
    corr = (RBF(ls, BOUNDS["length_scale"]) if kind == "rbf"
            else Matern(ls, BOUNDS["length_scale"], nu=2.5))
    return (ConstantKernel(float(signal_variance), BOUNDS["signal_variance"]) * corr
            + WhiteKernel(float(noise_level), BOUNDS["noise_level"]))


def maximise_marginal_likelihood(starts: list[np.ndarray], bounds: np.ndarray, kind: str,
                                 z: np.ndarray, y: np.ndarray,
                                 ) -> list[tuple[np.ndarray, float, bool]]:
    """L-BFGS-B from each start (log hyperparameters within ``bounds`` (p, 2)).

    Returns
    -------
    list of (theta, lml, converged)
        One entry per start whose optimum has a finite log marginal likelihood, best
        (highest ``lml``) first, ties in the order of the starts; ``converged`` is
        whether that run reported success. The caller chooses among them
        (:class:`bayeshyst.gp.GPHysteresis` takes the best one whose free run
        reproduces the training records).

    Raises
    ------
    DataError
        If the kernel matrix was singular everywhere the optimiser went.
    """
    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        lml, grad = log_marginal_likelihood(theta, kind, z, y)
        return -lml, -grad

    runs = [optimize.minimize(objective, th, jac=True, method="L-BFGS-B", bounds=bounds)
            for th in starts]
    optima = sorted(((r.x, float(-r.fun), bool(r.success)) for r in runs if np.isfinite(r.fun)),
                    key=lambda o: -o[1])
    if not optima:
        raise DataError("GP fit: the kernel matrix is not positive definite anywhere the "
                        "optimiser went (duplicate training inputs with conflicting outputs?)")
    return optima


def sample_marginal_likelihood(theta0: np.ndarray, bounds: np.ndarray, kind: str, z: np.ndarray,
                               y: np.ndarray, names: tuple[str, ...], n_walkers: int,
                               n_steps: int, burn: int, n_draws: int, rng: np.random.Generator,
                               rhat_threshold: float, min_ess: float,
                               ) -> tuple[np.ndarray, HyperparameterReport]:
    """emcee over log hyperparameters: marginal likelihood times a uniform prior in ``bounds``.

    Walkers start from the Laplace approximation at ``theta0`` (the Hessian by central
    differences of the analytic gradient; curvatures below 1 -- standard deviations
    above 1 in log units -- are raised to 1, which only narrows an over-wide start),
    reflected into the bounds. Moves: differential evolution (80 %) and its snooker
    variant (20 %), as in :mod:`bayeshyst.inference.sampling`.

    The first ``burn`` steps are discarded; R-hat and bulk ESS take the walkers as
    chains.

    Returns
    -------
    kept : ndarray, shape ((n_steps - burn) * n_walkers, p)
        Step-major draws after burn-in.
    report : HyperparameterReport
    """
    p, h = theta0.size, 1e-4

    def log_prob(theta: np.ndarray) -> float:
        if np.any(theta < bounds[:, 0]) or np.any(theta > bounds[:, 1]):
            return -np.inf
        return float(log_marginal_likelihood(theta, kind, z, y, gradient=False))

    hess = np.array([(log_marginal_likelihood(theta0 + h * e, kind, z, y)[1]
                      - log_marginal_likelihood(theta0 - h * e, kind, z, y)[1]) / (2 * h)
                     for e in np.eye(p)])
    lam, vec = np.linalg.eigh(-0.5 * (hess + hess.T))
    start = theta0 + rng.standard_normal((n_walkers, p)) @ (vec / np.sqrt(np.maximum(lam, 1.0))).T
    width = bounds[:, 1] - bounds[:, 0]
    start = bounds[:, 0] + np.abs((start - bounds[:, 0] + width) % (2 * width) - width)
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(n_walkers, p, log_prob, moves=moves)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31 - 1))).get_state()
    sampler.run_mcmc(start, n_steps, progress=False)
    kept = sampler.get_chain()[burn:]  # (steps, walkers, p)
    r_hat = np.array([rhat(kept[:, :, i].T) for i in range(p)])
    ess = np.array([ess_bulk(kept[:, :, i].T) for i in range(p)])
    reasons = tuple(f"R-hat of {n} = {r:.4f} >= {rhat_threshold}"
                    for n, r in zip(names, r_hat, strict=True) if not r < rhat_threshold)
    reasons += tuple(f"bulk ESS of {n} = {e:.0f} < {min_ess:g}"
                     for n, e in zip(names, ess, strict=True) if not e >= min_ess)
    flat = kept.reshape(-1, p)
    return flat, HyperparameterReport(names, flat.mean(0), flat.std(0), r_hat, ess,
                                      float(np.mean(sampler.acceptance_fraction)), n_walkers,
                                      n_steps, burn, n_draws, not reasons, reasons)


class Conditioned:
    """A zero-mean GP ``c k(z/l) + s2 I`` conditioned on standardised training data.

    Parameters
    ----------
    theta : ndarray, shape (d + 2,)
        Log-hyperparameters (see :func:`log_marginal_likelihood`).
    kind : {"rbf", "matern52"}
    z : ndarray, shape (m, d)
        Standardised training inputs.
    y : ndarray, shape (m,)
        Standardised targets.
    chol, alpha : ndarray, optional
        The Cholesky factor of ``K + s2 I`` and ``(K + s2 I)^-1 y`` when already known
        (sklearn's ``L_`` and ``alpha_``); computed otherwise (Rasmussen & Williams,
        Algorithm 2.1).
    """

    #: Rows of test inputs per chunk: bounds the (rows, m) cross-kernel to ~32 MB.
    CHUNK_ELEMENTS = 1 << 22

    def __init__(self, theta: np.ndarray, kind: str, z: np.ndarray, y: np.ndarray,
                 chol: np.ndarray | None = None, alpha: np.ndarray | None = None) -> None:
        self.theta = np.asarray(theta, dtype=float)
        self.kind = kind
        self.amplitude = math.exp(self.theta[0])
        self.noise = math.exp(self.theta[-1])
        self.scale = np.exp(self.theta[1:-1])
        self.a = z / self.scale
        if chol is None:
            k, _ = _kernel_parts(self.theta, kind, self.a, self.a)
            kmat = self.amplitude * k
            kmat[np.diag_indices(y.size)] += self.noise
            chol = linalg.cholesky(kmat, lower=True, check_finite=False)
            alpha = linalg.cho_solve((chol, True), y, check_finite=False)
        self.chol, self.alpha = chol, alpha

    def cross(self, zs: np.ndarray) -> np.ndarray:
        """Signal covariance between test inputs ``zs`` (n, d) and the training inputs."""
        return self.amplitude * _kernel_parts(self.theta, self.kind, zs / self.scale, self.a)[0]

    def predict(self, zs: np.ndarray, var: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Latent mean and variance (noise excluded) at ``zs`` (n, d), standardised units."""
        n = zs.shape[0]
        step = max(1, self.CHUNK_ELEMENTS // max(1, self.alpha.size))
        mean = np.empty(n)
        out = np.empty(n) if var else None
        for lo in range(0, n, step):
            ks = self.cross(zs[lo:lo + step])
            mean[lo:lo + step] = ks @ self.alpha
            if var:
                v = linalg.solve_triangular(self.chol, ks.T, lower=True, check_finite=False)
                # k(x, x) = c for both kernels; rounding can push tiny variances below 0
                out[lo:lo + step] = np.maximum(self.amplitude - np.einsum("ij,ij->j", v, v), 0.0)
        return mean, out

    def covariance(self, zs: np.ndarray) -> np.ndarray:
        """Joint latent covariance (n, n) at ``zs`` (noise excluded), standardised units."""
        v = linalg.solve_triangular(self.chol, self.cross(zs).T, lower=True, check_finite=False)
        k, _ = _kernel_parts(self.theta, self.kind, zs / self.scale, zs / self.scale)
        return self.amplitude * k - v.T @ v

    def joint_log_density(self, zs: np.ndarray, resid: np.ndarray) -> float:
        """``log N(resid; 0, Sigma + s2 I)`` for standardised residuals at ``zs`` (n, d)."""
        cov = self.covariance(zs)
        cov[np.diag_indices(resid.size)] += self.noise
        chol = linalg.cholesky(cov, lower=True, check_finite=False)
        w = linalg.solve_triangular(chol, resid, lower=True, check_finite=False)
        return float(-0.5 * w @ w - np.log(np.diag(chol)).sum()
                     - 0.5 * resid.size * math.log(2 * math.pi))
