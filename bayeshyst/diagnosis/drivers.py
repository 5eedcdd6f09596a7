"""Does the residual still depend on anything observable? The open-world driver scan.

The score tests of :mod:`bayeshyst.diagnosis.residual` ask about the effects of a
closed list. This module asks the open question behind them: after the fit, is the
residual a function of *anything* the data record — where on the loop a sample is,
how fast the input moves, how long since it last turned or held, the time, the
predicted output, the excitation frequency, or any other channel of the file (a
temperature, a load, a second sensor) — and if so, of which?

Method
------
Every candidate driver ``x`` becomes a small additive block of smooth functions: the
driver rank-scaled to ``[-1, 1]`` (robust to its units and distribution) expanded in a
linear term and ``m`` sines of the Laplacian eigenbasis on ``[-L, L]`` (the basis of
:mod:`bayeshyst.discrepancy`). Slow drivers (time, frequency, covariates) also enter
as a *gain*: the same functions times the standardised predicted output, because a
temperature that changes the actuator's gain leaves a residual ``w g(T)`` that has no
mean in ``T`` at all. The loop position enters as ``g_c(u) + b g_b(u) + d g_d(u)`` with
``b`` the branch coordinate (:func:`~bayeshyst.discrepancy.branch_coordinate`) and ``d``
the direction of travel: a shape error common to both branches and width errors that
change sign at a reversal, gradually or at once -- any function of where on the loop a
sample is.

**The model's own misfit first.** Under one periodic excitation, where on the loop a
sample is and how long ago the input turned are the same coordinate, so a branch-shape
error and creep, a lag or a delay explain the residual equally well. When the best
driver of a step adds nothing significant beyond a loop-position driver that is itself
significant, the loop position is kept instead (and the two reported as tied): the
hysteresis model's shape is named before a time-domain effect is credited with it.

Each block is scored by its **held-out gain**: ridge regressions fitted on all but one
fold of *units* (cycles, or parts of cycles) predict the held-out fold's residual; the
gain is the share of the held-out residual's sum of squares they remove, ``1 -
SSE / SSE_0``. A block that only fits noise predicts held-out units worse than zero.

The threshold is **calibrated by randomisation**, not chosen: under the null (the
residual is noise, independent between units, symmetric, unrelated to every driver)
flipping the sign of every unit's residual at random leaves its distribution
unchanged, while any systematic dependence on a driver is destroyed (the fitted
function now has a random sign in every unit, and held-out units are not predicted).
The maximum gain over all candidate blocks is compared with its distribution over
random sign patterns (``n_permutations``; exact enumeration when there are few
units): the family-wise error over all drivers is the nominal ``alpha``. Drivers are
then added greedily: the best is kept while its gain *given the ones kept* beats the
same randomisation of the residual left after them (Freedman & Lane 1983). Two drivers
that each explain the residual and neither adds to the other are **tied**: the data
cannot tell them apart (temperature that rises with time, or time itself).

The held-out sums are exact functions of per-unit Gram matrices, so a thousand
randomisations of a dozen blocks cost a few matrix products.

Units: the posterior's cycles (:func:`~bayeshyst.inference.posterior.cycle_units`),
split into equal parts until there are at least :data:`MIN_UNITS_TARGET` (never shorter
than a quarter of a cycle); a record without cycles is cut into equal blocks. The
randomisation assumes the noise is correlated over less than a unit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.diagnosis._heldout import _Grams, correlation_length, sign_patterns
from bayeshyst.discrepancy import branch_coordinate
from bayeshyst.inference.posterior import cycle_units
from bayeshyst.tables import TableRecord, frame

__all__ = ["DriverRelevance", "DriverScan", "driver_blocks", "loop_position_basis", "scan_drivers",
           "scan_units"]

#: Aim for at least this many units (cycles are split into parts to get there).
MIN_UNITS_TARGET = 24
#: Fewest units with which a randomisation test can reach a small level at all.
MIN_UNITS = 8
#: Sines per driver (plus the linear term) and the basis half-width.
_N_SINES, _L = 6, 1.25
#: Sines of the loop-position basis that stands in for a branch-shape error (measured: a
#: 2-operator PI's misfit of a 4-operator one under one sine leaves rate and delay
#: regressors significant beyond 6 sines, not beyond 12 or 20).
SHAPE_SINES = 16

#: What a driver's dependence means, for the report.
READINGS: Mapping[str, str] = {
    "loop position": "the hysteresis model's branch shape is wrong (more operators, free "
                     "thresholds or another family)",
    "predicted output": "an output nonlinearity the model lacks (sensor or asymmetry)",
    "input rate": "rate dependence (dynamics, a lag)",
    "input acceleration": "dynamics (inertia, a resonance)",
    "time since reversal or hold": "creep, relaxation or a lag after each reversal",
    "time": "drift or an unrecorded slow change",
    "excitation frequency": "the loop changes with frequency (rate dependence)",
}


@dataclass(frozen=True)
class DriverBlock:
    """One candidate driver: its name, kind and design columns on the stacked samples."""

    name: str
    kind: str
    columns: np.ndarray = field(repr=False)


def _rank_scale(x: np.ndarray) -> np.ndarray:
    """``x`` mapped to ``[-1, 1]`` by its ranks (ties share the mean rank)."""
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(x.size)
    ranks[order] = np.arange(x.size, dtype=float)
    # ties: the mean rank of each group of equal values
    xs = x[order]
    edges = np.flatnonzero(np.r_[True, xs[1:] != xs[:-1], True])
    for a, b in pairwise(edges):
        if b - a > 1:
            ranks[order[a:b]] = 0.5 * (a + b - 1)
    return 2.0 * ranks / max(x.size - 1, 1) - 1.0


def _smooth_basis(x: np.ndarray, n_sines: int = _N_SINES) -> np.ndarray:
    """``x`` itself (standardised) and sines of the rank-scaled ``x``, (N, 1 + m).

    The linear term in ``x`` keeps a linear law (a gain of so many %/K) exact; the sines
    of the ranks follow any smooth shape whatever the driver's distribution.
    """
    x = np.asarray(x, float)
    s = _rank_scale(x)
    j = np.arange(1, n_sines + 1)
    sines = np.sin(math.pi * j[None, :] * (s[:, None] + _L) / (2.0 * _L))
    return np.column_stack([(x - x.mean()) / (x.std() or 1.0), sines])


def _direction(u: np.ndarray) -> np.ndarray:
    """Direction of travel (+1 rising, -1 falling), held through holds, (N,)."""
    du = np.diff(u, prepend=u[0])
    d = np.sign(du)
    idx = np.where(d != 0, np.arange(u.size), 0)
    np.maximum.accumulate(idx, out=idx)
    held = d[idx]
    first = np.flatnonzero(d)
    return np.where(held == 0, d[first[0]] if first.size else 1.0, held)


def _unit_rms(cols: np.ndarray) -> np.ndarray:
    """Columns scaled to unit RMS (zero columns left as they are): one ridge fits all."""
    rms = np.sqrt(np.mean(cols ** 2, axis=0))
    return cols / np.where(rms > 0, rms, 1.0)


def _loop_columns(u: np.ndarray, b: np.ndarray, d: np.ndarray, n_sines: int) -> np.ndarray:
    """``g_c(u) + b g_b(u) + d g_d(u)``: smooth functions of where on the loop, (N, 3 (1 + m))."""
    bu = _smooth_basis(u, n_sines)
    return np.column_stack([bu, b[:, None] * bu, d[:, None] * bu])


def _time_since_event(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Seconds since the last reversal of the input, or start or end of a hold or step."""
    du = np.diff(u, prepend=u[0])
    scale = np.max(np.abs(du)) or 1.0
    moving = np.abs(du) > 1e-3 * scale
    direction = np.where(moving, np.sign(du), 0.0)
    step = np.abs(du) > 10.0 * max(float(np.median(np.abs(du[moving]))) if moving.any()
                                   else 0.0, 1e-12)
    # an event where the direction changes (a reversal, a hold starting or ending) or
    # the input steps; every sample looks back to the last one
    previous = np.r_[0.0, direction[:-1]]
    event = ((direction != 0) & (direction != previous)) | ((direction == 0) & (previous != 0))
    event |= step
    events = np.where(event, np.arange(u.size), 0)
    np.maximum.accumulate(events, out=events)
    return t - t[events]


def driver_blocks(data: Dataset, w: Sequence[np.ndarray], starts: Sequence[int]
                  ) -> list[DriverBlock]:
    """The candidate drivers' design columns on the stacked scored samples.

    Parameters
    ----------
    data : Dataset
        The records (their inputs, times, frequencies and covariates).
    w : sequence of ndarray, each shape (n_r,)
        Predicted model output per record, whole record (output unit).
    starts : sequence of int
        First scored sample of each record.
    """
    cols: dict[str, list[np.ndarray]] = {}
    u_all = np.concatenate([np.asarray(r.u, float) for r in data])
    half = 0.5 * float(np.ptp(u_all)) or 1.0
    for rec, wr, s0 in zip(data, w, starts, strict=True):
        t, u = np.asarray(rec.t, float), np.asarray(rec.u, float)
        du = np.gradient(u, t)
        feats = {
            "u": u, "b": branch_coordinate(u, half), "d": _direction(u),
            "w": np.asarray(wr, float),
            "input rate": du, "input acceleration": np.gradient(du, t),
            "time since reversal or hold": np.log(_time_since_event(t, u) + np.median(np.diff(t))),
            "time": t - t[0],
            "f": np.full(t.size, math.log(rec.frequency_hz) if rec.frequency_hz else 0.0),
        }
        feats.update({f"covariate:{k}": np.asarray(v, float) for k, v in rec.covariates.items()})
        for k, v in feats.items():
            cols.setdefault(k, []).append(v[s0:])
    n_rec = len(data)
    stacked = {k: np.concatenate(v) for k, v in cols.items() if len(v) == n_rec}
    w_all = stacked["w"]
    gain = (w_all - w_all.mean()) / (w_all.std() or 1.0)
    b = stacked["b"]
    blocks = [DriverBlock("loop position", "loop",
                          _loop_columns(stacked["u"], b, stacked["d"], _N_SINES)),
              DriverBlock("predicted output", "loop", _smooth_basis(w_all))]
    for name in ("input rate", "input acceleration", "time since reversal or hold"):
        if np.ptp(stacked[name]) > 0:
            blocks.append(DriverBlock(name, "time", _smooth_basis(stacked[name])))
    slow = [("time", stacked["time"])]
    if len({r.frequency_hz for r in data}) > 1:
        slow.append(("excitation frequency", stacked["f"]))
    slow += [(k.removeprefix("covariate:"), v) for k, v in stacked.items()
             if k.startswith("covariate:")]
    for name, x in slow:
        if np.ptp(x) > 0:
            bx = _smooth_basis(x)
            extra = [b[:, None] * bx] if name == "excitation frequency" else []
            kind = "external" if name not in ("time", "excitation frequency") else "slow"
            blocks.append(DriverBlock(name, kind, np.column_stack([bx, gain[:, None] * bx,
                                                                   *extra])))
    for blk in blocks:
        blk.columns[:] = _unit_rms(blk.columns)
    return blocks


def loop_position_basis(data: Dataset, starts: Sequence[int],
                        n_sines: int = SHAPE_SINES) -> np.ndarray:
    """Smooth functions of where on the loop a sample is, on the stacked scored samples.

    ``g_c(u) + b g_b(u) + d g_d(u)`` (see module notes) with ``n_sines`` sines each,
    (N, 3 (1 + n_sines)): what a branch-shape error of the model looks like. Richer than
    the scan's block by default, because it stands in for *any* shape error when a
    time-domain effect is asked what it explains beyond one.
    """
    u = np.concatenate([np.asarray(r.u, float)[s0:] for r, s0 in zip(data, starts, strict=True)])
    u_all = np.concatenate([np.asarray(r.u, float) for r in data])
    half = 0.5 * float(np.ptp(u_all)) or 1.0
    b = np.concatenate([branch_coordinate(np.asarray(r.u, float), half)[s0:]
                        for r, s0 in zip(data, starts, strict=True)])
    d = np.concatenate([_direction(np.asarray(r.u, float))[s0:]
                        for r, s0 in zip(data, starts, strict=True)])
    return _unit_rms(_loop_columns(u, b, d, n_sines))


def scan_units(data: Dataset) -> list[tuple[int, int]]:
    """Units of the scan as ranges of the stacked scored samples (see module notes)."""
    per_rec = []
    offset = 0
    for rec in data:
        s0 = rec.scored.start or 0
        units = [(a - s0 + offset, b - s0 + offset) for a, b in cycle_units(rec)]
        per_rec.append((units, len(units) > 1))
        offset += rec.n - s0
    n_cycles = sum(len(u) for u, _ in per_rec)
    out = []
    for units, periodic in per_rec:
        if periodic:
            parts = min(4, max(1, math.ceil(MIN_UNITS_TARGET / n_cycles)))
        else:
            parts = max(1, math.ceil(MIN_UNITS_TARGET / len(per_rec)))
        for a, b in units:
            edges = np.linspace(a, b, parts + 1).round().astype(int)
            out += [(int(p), int(q)) for p, q in pairwise(edges)
                    if q - p >= 2]
    return out


@dataclass(frozen=True)
class DriverRelevance(TableRecord):
    """How much of the held-out residual one candidate driver explains.

    Attributes
    ----------
    driver : str
        ``"loop position"``, ``"input rate"``, ``"time"``, a covariate's column name, ...
    kind : str
        ``"loop"`` (where on the loop), ``"time"`` (rates and times since events),
        ``"slow"`` (time, frequency) or ``"external"`` (a column of the file).
    gain_percent : float
        Held-out share of the residual's sum of squares it removes alone (per cent;
        negative: it predicts held-out units worse than zero).
    p_value : float
        Randomisation p-value of the step that examined it last (family-wise over the
        candidates of that step).
    conditional_percent : float
        Its held-out gain given the drivers kept before it (or, if not kept, given all
        drivers kept).
    selected : bool
        Kept: the residual depends on it beyond the drivers kept before.
    tied_with : tuple of str
        Kept drivers it cannot be told apart from on these data.
    reading : str
        What a dependence on it means physically.
    """

    driver: str
    kind: str
    gain_percent: float
    p_value: float
    conditional_percent: float
    selected: bool
    tied_with: tuple[str, ...] = ()
    reading: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"driver": self.driver, "kind": self.kind, "gain_percent": self.gain_percent,
                "p_value": self.p_value, "conditional_percent": self.conditional_percent,
                "selected": self.selected, "tied_with": list(self.tied_with),
                "reading": self.reading}

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])

    def __str__(self) -> str:
        flag = "RELEVANT" if self.selected else "        "
        tie = f"; tied with {', '.join(self.tied_with)}" if self.tied_with else ""
        return (f"{self.driver:>28}: {flag} held-out gain {self.gain_percent:6.2f} % alone, "
                f"{self.conditional_percent:6.2f} % given the kept ones, p = "
                f"{self.p_value:.3g}{tie}")


@dataclass(frozen=True)
class DriverScan(TableRecord):
    """What the residual still depends on (see module notes).

    Attributes
    ----------
    drivers : tuple of DriverRelevance
        Every candidate, kept ones first in the order kept, then by gain (empty when the
        scan could not decide: see :attr:`decidable`).
    explained_percent : float
        Held-out share of the residual's sum of squares the kept drivers remove together.
    n_units : int
        Units the residual was cut into (held-out folds and randomisation blocks).
    n_permutations : int
        Sign patterns the threshold was calibrated with (``exact``: all of them).
    exact : bool
    alpha : float
        Family-wise level of every step.
    decidable : bool
        False when there are too few units for a randomisation test to reach ``alpha``:
        then nothing is kept and :attr:`note` says so.
    note : str
    """

    drivers: tuple[DriverRelevance, ...]
    explained_percent: float
    n_units: int
    n_permutations: int
    exact: bool
    alpha: float
    decidable: bool = True
    note: str = ""

    @property
    def selected(self) -> tuple[DriverRelevance, ...]:
        """The drivers kept, in the order kept."""
        return tuple(d for d in self.drivers if d.selected)

    @property
    def found(self) -> bool:
        """Whether the residual depends on any observed driver."""
        return bool(self.selected)

    def driver(self, name: str) -> DriverRelevance:
        """The relevance of driver ``name``."""
        for d in self.drivers:
            if d.driver == name:
                return d
        raise KeyError(name)

    def summary(self) -> str:
        """One sentence: what the residual depends on, or that it depends on nothing seen."""
        if not self.decidable:
            return self.note
        if not self.found:
            return ("the residual depends on no observed driver (held-out randomisation "
                    f"test at family-wise level {self.alpha:g})")
        parts = []
        for d in self.selected:
            tie = f" (cannot tell from {', '.join(d.tied_with)})" if d.tied_with else ""
            parts.append(f"{d.driver}{tie}")
        return (f"the residual depends on {', '.join(parts)}: together "
                f"{self.explained_percent:.1f} % of its held-out variance")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"summary": self.summary(), "drivers": [d.to_dict() for d in self.drivers],
                "selected": [d.driver for d in self.selected],
                "explained_percent": self.explained_percent, "n_units": self.n_units,
                "n_permutations": self.n_permutations, "exact": self.exact,
                "alpha": self.alpha, "decidable": self.decidable, "note": self.note}

    def to_dataframe(self) -> Any:
        """One row per candidate driver."""
        return frame([d.to_dict() for d in self.drivers])

    def __str__(self) -> str:
        head = (f"driver scan ({self.n_units} units, {self.n_permutations} "
                f"{'sign patterns (all)' if self.exact else 'random sign patterns'}): "
                f"{self.summary()}")
        return "\n".join([head, *(str(d) for d in self.drivers)])


def _fail_safe(value: float) -> float:
    return float(value) if math.isfinite(value) else 0.0


def scan_drivers(
    data: Dataset,
    residual: Sequence[np.ndarray],
    w: Sequence[np.ndarray],
    *,
    alpha: float = 0.01,
    n_permutations: int = 999,
    max_drivers: int = 4,
    seed: int = 0,
    blocks: Sequence[DriverBlock] | None = None,
) -> DriverScan:
    """Which observed drivers the residual depends on, with a calibrated threshold.

    Parameters
    ----------
    data : Dataset
        The fitted records.
    residual : sequence of ndarray, each shape (n_r - s0_r,)
        Residual per record on its scored samples (output unit).
    w : sequence of ndarray, each shape (n_r,)
        Predicted model output per record, whole record (output unit).
    alpha : float
        Family-wise level of each step of the greedy selection.
    n_permutations : int
        Random sign patterns (all of them when ``2**n_units`` is not larger).
    max_drivers : int
        Most drivers kept.
    seed : int
        Seed of the sign patterns: same seed, same result.
    blocks : sequence of DriverBlock, optional
        ``driver_blocks(data, w, starts)`` when the caller has built them already (it
        needs the kept columns' design afterwards).

    Returns
    -------
    DriverScan
    """
    starts = [int(rec.scored.start or 0) for rec in data]
    r = np.concatenate([np.asarray(x, float) for x in residual])
    if blocks is None:
        blocks = driver_blocks(data, w, starts)
    units = scan_units(data)
    n_units = len(units)
    rng = np.random.default_rng(seed)
    signs, exact = sign_patterns(n_units, int(n_permutations), rng)
    readings = dict(READINGS)
    for blk in blocks:
        readings.setdefault(blk.name, f"a gain or offset that follows the column "
                                      f"{blk.name!r}")
    min_p = (1.0 / signs.shape[0]) if exact else 1.0 / (signs.shape[0] + 1)
    if n_units < MIN_UNITS or min_p > alpha:
        # No per-driver rows: a gain or p-value that was never computed is not a number
        # to report; the note names the drivers that went untested.
        note = (f"cannot decide on these data: {n_units} units of the residual are too few "
                f"for a randomisation test at level {alpha:g}; record more cycles "
                f"(untested: {', '.join(b.name for b in blocks)})")
        return DriverScan((), 0.0, n_units, signs.shape[0], exact, float(alpha), False, note)

    x = np.column_stack([b.columns for b in blocks])
    edges = np.cumsum([0] + [b.columns.shape[1] for b in blocks])
    idx = {b.name: np.arange(edges[i], edges[i + 1]) for i, b in enumerate(blocks)}
    grams = _Grams(x, r, units, correlation_length(r, units))
    ones = np.ones((1, n_units))

    def gains(base: np.ndarray, names: Sequence[str], s: np.ndarray) -> np.ndarray:
        """Held-out gain of each candidate beyond ``base`` (P, len(names)), share of SSE0."""
        v_tr, v_te, rr = grams.versions(base, s)
        sse0 = rr.sum(axis=1)
        sse_base = grams.sse(base, v_tr, v_te, rr)
        out = [(sse_base - grams.sse(np.r_[base, idx[n]].astype(int), v_tr, v_te, rr)) / sse0
               for n in names]
        return np.column_stack(out)

    def step(kept: Sequence[str], names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        base = (np.concatenate([idx[k] for k in kept]) if kept
                else np.zeros(0, dtype=int))
        obs = gains(base, names, ones)[0]
        null_max = gains(base, names, signs).max(axis=1)
        if exact:
            p = np.array([np.mean(null_max >= o - 1e-12) for o in obs])
        else:
            p = np.array([(1 + np.sum(null_max >= o - 1e-12)) / (1 + signs.shape[0])
                          for o in obs])
        return obs, p

    names = [b.name for b in blocks]
    kinds = {b.name: b.kind for b in blocks}
    marginal, p_marginal = step([], names)
    kept: list[str] = []
    cond: dict[str, float] = {}
    pval: dict[str, float] = dict(zip(names, p_marginal, strict=True))
    obs, p = marginal, p_marginal
    rest = list(names)
    while rest and len(kept) < max_drivers:
        best = int(np.argmax(obs))
        for n, o, q in zip(rest, obs, p, strict=True):
            cond[n], pval[n] = float(o), float(q)
        if p[best] >= alpha or obs[best] <= 0:
            break
        if kinds[rest[best]] != "loop":
            for i, n in enumerate(rest):
                if kinds[n] == "loop" and p[i] < alpha and step([*kept, n],
                                                                [rest[best]])[1][0] >= alpha:
                    best = i  # the model's own shape explains it as well: name that
                    break
        kept.append(rest.pop(best))
        if rest:
            obs, p = step(kept, rest)
    # ties: a candidate that explains the residual alone, adds nothing to the kept ones,
    # and leaves a kept one adding nothing beyond itself
    ties: dict[str, list[str]] = {n: [] for n in names}
    for h, ph in zip(names, p_marginal, strict=True):
        if h in kept or ph >= alpha or pval[h] < alpha:
            continue
        for g in kept:
            others = [k for k in kept if k != g]
            # h stands in for g (significant without g) and leaves g nothing to add
            if step(others, [h])[1][0] < alpha and step([*others, h], [g])[1][0] >= alpha:
                ties[h].append(g)
                ties[g].append(h)
    base = (np.concatenate([idx[k] for k in kept]) if kept else np.zeros(0, dtype=int))
    total = 0.0
    if kept:
        v_tr, v_te, rr = grams.versions(np.zeros(0, dtype=int), ones)
        total = float(1.0 - grams.sse(base, v_tr, v_te, rr)[0] / rr.sum())
    order = kept + sorted((n for n in names if n not in kept),
                          key=lambda n: -marginal[names.index(n)])
    rel = tuple(DriverRelevance(
        n, kinds[n], 100.0 * _fail_safe(marginal[names.index(n)]), float(pval[n]),
        100.0 * _fail_safe(cond.get(n, math.nan)), n in kept, tuple(ties[n]), readings[n])
        for n in order)
    return DriverScan(rel, 100.0 * total, n_units, int(signs.shape[0]), exact, float(alpha))
