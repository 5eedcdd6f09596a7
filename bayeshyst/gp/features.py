"""Features and training subsets of the GP hysteresis model (:mod:`bayeshyst.gp`).

Kept apart from the estimator so that each can be tested alone:

* :func:`rate` -- ``ds/dt`` of one record: second-order central differences (default)
  or the causal backward difference a controller computes in real time;
* :func:`memory_indices` / :func:`memory_features` -- the reversal stack: direction,
  and the samples of the last two input reversals that survive the wiping-out
  property (see :func:`memory_indices` for the exact rule);
* :func:`stratified_subset` / :func:`farthest_subset` -- the two training-subset
  schemes;
* :func:`split_columns`, :func:`records_to_X` -- the estimator's array convention.

The memory stack walks every sample once (a compiled loop, about 10 ns per sample).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numba import njit

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.data.segment import find_reversals
from bayeshyst.errors import DataError, ParameterError

__all__ = [
    "RATE_SCHEMES",
    "WIPE_FRACTION",
    "SignalRecord",
    "as_records",
    "farthest_subset",
    "gather_memory",
    "memory_features",
    "memory_indices",
    "rate",
    "records_to_X",
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

#: Difference schemes of :func:`rate`.
RATE_SCHEMES = ("central", "backward")


def rate(t: np.ndarray, s: np.ndarray, scheme: str = "central") -> np.ndarray:
    """Time derivative of one record's signal, ``ds/dt`` [unit of s per s].

    ``"central"``: second-order central differences inside, first-order one-sided
    differences at the two ends (``numpy.gradient`` with the sample times); sample
    ``k`` reads ``s[k + 1]``, a future sample. ``"backward"``: ``(s[k] - s[k-1]) /
    (t[k] - t[k-1])``, what a controller can compute in real time (causal: no
    sample after ``k`` is read), and 0 at the first sample, which has no predecessor
    (the signal is taken to be at rest before the record). Either way the difference
    never reaches across records.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Strictly increasing times [s], ``n >= 2``.
    s : ndarray, shape (n,)
        Signal (input voltage, or output for the inverse model).
    scheme : {"central", "backward"}, default "central"

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    ParameterError
        For an unknown ``scheme``.
    """
    if scheme == "central":
        return np.gradient(s, t)
    if scheme != "backward":
        raise ParameterError(f"rate scheme: expected one of {RATE_SCHEMES}, found {scheme!r}")
    out = np.zeros(np.shape(s), dtype=float)
    out[1:] = np.diff(s) / np.diff(t)
    return out

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
    """Time-stratified random subset of (at most) ``m`` of the ``n`` candidates.

    One sample is drawn uniformly from each of ``m`` consecutive, equally long strata of
    the ``n`` candidates.

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



@dataclass(frozen=True)
class SignalRecord:
    """One record as the estimator sees it: signal ``s`` in, ``target`` out.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Times [s].
    s : ndarray, shape (n,)
        Input signal (``u``, or ``y`` for the inverse model).
    target : ndarray, shape (n,), or None
        Output to fit or score (None when only predicting).
    candidate : ndarray of bool, shape (n,)
        Samples that may be chosen for training.
    source : Record or None
        The record it came from (None for array input).
    """

    t: np.ndarray
    s: np.ndarray
    target: np.ndarray | None
    candidate: np.ndarray
    source: Record | None = None


def as_records(data: Dataset | Record) -> tuple[Record, ...]:
    """The records of ``data``.

    Raises
    ------
    DataError
        For anything but a Dataset or a Record.
    """
    if isinstance(data, Record):
        return (data,)
    if isinstance(data, Dataset):
        return data.records
    raise DataError(f"data: expected a Dataset or a Record, found {type(data).__name__}")


def records_to_X(data: Dataset | Record, *, inverse: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Stack records into the array convention of :class:`~bayeshyst.gp.GPHysteresis`.

    Parameters
    ----------
    data : Dataset or Record
    inverse : bool, default False
        Put the output in the input column and return the input as target.

    Returns
    -------
    X : ndarray, shape (N, 3)
        Columns ``t`` [s], ``u`` [V] (``y`` if ``inverse``), record id (0, 1, ...).
    y : ndarray, shape (N,)
        ``y`` (``u`` if ``inverse``), warm-up samples included.
    """
    recs = as_records(data)
    cols = [np.column_stack([r.t, r.y if inverse else r.u, np.full(r.n, float(i))])
            for i, r in enumerate(recs)]
    return np.vstack(cols), np.concatenate([r.u if inverse else r.y for r in recs])
