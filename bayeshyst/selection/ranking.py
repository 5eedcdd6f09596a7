"""One ranking of models by their pointwise predictive densities.

Both :func:`~bayeshyst.selection.compare_models` (one dataset, per frequency) and the
study summary (:mod:`bayeshyst.study.summary`, pooled over datasets) rank models the same
way, by :func:`rank_by_elpd`:

- the score is the summed leave-one-cycle-out elpd; its standard error is
  ``sqrt(n var(pointwise))`` over the n cycles;
- ``Δelpd`` of each model to the best and its standard error are **paired over the same
  cycles** (Vehtari, Gelman & Gabry 2017, §5.2), which is why every model must be scored
  on the same cycles;
- ties in elpd keep the order the caller gave (the user's order of models);
- stacking weights (Yao, Vehtari, Simpson & Gelman 2018) combine the pointwise densities.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import softmax

from bayeshyst.errors import ModelError, ParameterError

__all__ = ["RankedModel", "paired_difference", "rank_by_elpd", "stacking_weights",
           "total_and_se"]


def stacking_weights(pointwise: np.ndarray) -> np.ndarray:
    """Stacking weights of predictive distributions (Yao, Vehtari, Simpson & Gelman 2018).

    Maximises ``sum_i log sum_k w_k exp(lpd[i, k])`` over the simplex.

    Parameters
    ----------
    pointwise : ndarray, shape (n_units, K)
        Leave-one-out log predictive density of each unit under each model.

    Returns
    -------
    ndarray, shape (K,)
        Non-negative weights summing to 1.
    """
    lpd = np.asarray(pointwise, dtype=float)
    if lpd.ndim != 2 or lpd.shape[1] == 0:
        raise ParameterError(f"pointwise must be (n_units, K >= 1), got shape {lpd.shape}")
    k = lpd.shape[1]
    if k == 1:
        return np.ones(1)
    if not np.all(np.isfinite(lpd)):
        raise ParameterError("pointwise log densities must be finite for stacking")
    # the objective is invariant to a per-unit shift; subtracting the row max keeps the
    # exponentials in range for elpd values of thousands (long cycles)
    dens = np.exp(lpd - lpd.max(axis=1, keepdims=True))

    def objective(a: np.ndarray) -> tuple[float, np.ndarray]:
        w = softmax(np.append(a, 0.0))
        mix = dens @ w
        val = -np.sum(np.log(mix))
        g_w = -(dens / mix[:, None]).sum(axis=0)
        # d w / d a_j = w_j (delta - w); the last logit is pinned at 0
        grad = w[:-1] * (g_w[:-1] - g_w @ w)
        return float(val), grad

    best = None
    for a0 in (np.zeros(k - 1), np.log(np.maximum(dens.mean(axis=0), 1e-300))[:-1]
               - math.log(max(dens.mean(axis=0)[-1], 1e-300))):
        r = minimize(objective, a0, jac=True, method="L-BFGS-B",
                     options={"gtol": 1e-12, "ftol": 1e-15, "maxiter": 10_000})
        if best is None or r.fun < best.fun:
            best = r
    w = softmax(np.append(best.x, 0.0))
    return w / w.sum()


def total_and_se(pw: np.ndarray) -> tuple[float, float]:
    """``sum(pw)`` and its standard error ``sqrt(n var(pw))`` (NaN se for one unit)."""
    if pw.size == 0:
        return math.nan, math.nan
    return float(np.sum(pw)), float(math.sqrt(pw.size * np.var(pw))) if pw.size > 1 else math.nan


def paired_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """``sum(a - b)`` and its standard error ``sqrt(n var(a - b))`` over paired units."""
    return total_and_se(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))


@dataclass(frozen=True)
class RankedModel:
    """One model's place in a ranking (see :func:`rank_by_elpd`).

    Attributes
    ----------
    model : str
    elpd, se : float
        Summed pointwise elpd and its standard error.
    delta_elpd, delta_se : float
        ``elpd`` below the best model's (0 for the best) and the standard error of that
        paired difference (0 for the best).
    weight : float
        Stacking weight (NaN when not asked for).
    """

    model: str
    elpd: float
    se: float
    delta_elpd: float
    delta_se: float
    weight: float = math.nan


def rank_by_elpd(pointwise: Mapping[str, np.ndarray], *,
                 stacking: bool = False) -> tuple[RankedModel, ...]:
    """Rank models by summed pointwise elpd, best first.

    Parameters
    ----------
    pointwise : mapping of str to ndarray, each shape (n_cycles,)
        Each model's leave-one-cycle-out log predictive density of the **same** cycles
        (nats). The mapping's order breaks ties.
    stacking : bool
        Also compute stacking weights (needs every density finite).

    Returns
    -------
    tuple of RankedModel
        Best first; empty for an empty mapping.

    Raises
    ------
    ModelError
        The models were scored on different numbers of cycles (a paired difference
        would be meaningless).
    """
    names = list(pointwise)
    if not names:
        return ()
    pw = {m: np.asarray(pointwise[m], dtype=float).ravel() for m in names}
    sizes = {v.size for v in pw.values()}
    if len(sizes) != 1:
        raise ModelError("models scored different numbers of cycles: "
                         + ", ".join(f"{m}: {pw[m].size}" for m in names))
    totals = {m: float(np.sum(pw[m])) for m in names}
    order = sorted(names, key=lambda m: (-totals[m], names.index(m)))
    top = order[0]
    weights = (dict(zip(names, stacking_weights(np.column_stack([pw[m] for m in names])),
                        strict=True)) if stacking else {})
    out = []
    for m in order:
        elpd, se = total_and_se(pw[m])
        d, dse = (0.0, 0.0) if m == top else paired_difference(pw[m], pw[top])
        out.append(RankedModel(m, elpd, se, d, dse, float(weights.get(m, math.nan))))
    return tuple(out)
