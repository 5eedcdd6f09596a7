"""Model selection across the datasets of a study, per excitation frequency.

Two levels, both from the fits' pointwise leave-one-cycle-out elpd (PSIS-LOO with exact
refits; exact LOO for the GP):

- :class:`DatasetRanking` — at one dataset and frequency, the models ranked by elpd;
  ``Δelpd`` of the runner-up and its standard error are **paired over the same cycles**
  (Vehtari, Gelman & Gabry 2017, §5.2). With several seeds, a model's pointwise elpd is
  the mean over its successful seeds and ``seed_sd`` is the spread of the totals (how
  much the sampler's randomness moves the score).
- :class:`FrequencySummary` — at one frequency, pooled over the datasets where **every**
  model produced a score (a comparison on different cycles would not be paired): each
  model's total elpd, its paired difference to the best with the standard error over
  all pooled cycles, how many datasets it wins, its mean and worst NRMSE. Datasets left
  out because a model failed there are named.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.data.record import frequency_key, frequency_label
from bayeshyst.selection.ranking import rank_by_elpd
from bayeshyst.tables import TableRecord, frame

__all__ = ["DatasetRanking", "FrequencySummary", "ModelAcrossDatasets", "ModelAtDataset",
           "frequency_label", "summarise"]


@dataclass(frozen=True)
class ModelAtDataset:
    """One model at one dataset and frequency (seeds averaged)."""

    model: str
    elpd_loo: float
    se: float
    delta_elpd: float
    delta_se: float
    nrmse_percent: float
    seed_sd: float
    n_seeds: int
    converged: bool


@dataclass(frozen=True)
class DatasetRanking(TableRecord):
    """The models ranked by elpd at one dataset and frequency.

    ``failed`` names the models without a score there (their errors are in the table).
    """

    likelihood: str
    dataset: str
    frequency_hz: float | None
    ranking: tuple[ModelAtDataset, ...]
    failed: tuple[str, ...]

    @property
    def best(self) -> str | None:
        """The model with the highest elpd (None when every fit failed)."""
        return self.ranking[0].model if self.ranking else None

    def to_dataframe(self) -> Any:
        """One row per model, ranked, with the dataset and frequency."""
        return frame([{"likelihood": self.likelihood, "dataset": self.dataset,
                       "frequency_hz": self.frequency_hz, **m.__dict__}
                      for m in self.ranking])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``best_by_dataset.json``)."""
        return {"likelihood": self.likelihood, "dataset": self.dataset,
                "frequency_hz": self.frequency_hz, "best": self.best,
                "ranking": [m.__dict__ for m in self.ranking], "failed": list(self.failed)}


@dataclass(frozen=True)
class ModelAcrossDatasets:
    """One model at one frequency, pooled over the complete datasets."""

    model: str
    n_datasets: int
    wins: int
    elpd_loo: float
    se: float
    delta_elpd: float
    delta_se: float
    mean_nrmse_percent: float
    max_nrmse_percent: float
    converged_fraction: float


@dataclass(frozen=True)
class FrequencySummary(TableRecord):
    """Model selection at one frequency across datasets (see the module docstring)."""

    likelihood: str
    frequency_hz: float | None
    models: tuple[ModelAcrossDatasets, ...]
    datasets: tuple[str, ...]
    incomplete: tuple[str, ...]

    @property
    def best(self) -> str | None:
        """Highest pooled elpd (None when no dataset is complete)."""
        return self.models[0].model if self.models else None

    def to_dataframe(self) -> Any:
        """One row per model, pooled over the complete datasets at this frequency."""
        return frame([{"likelihood": self.likelihood, "frequency_hz": self.frequency_hz,
                       **m.__dict__} for m in self.models])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``by_frequency.json``)."""
        return {"likelihood": self.likelihood, "frequency_hz": self.frequency_hz,
                "best": self.best, "datasets": list(self.datasets),
                "incomplete_datasets": list(self.incomplete),
                "models": [m.__dict__ for m in self.models]}

    def __str__(self) -> str:
        def f(x: float, fmt: str = ".1f") -> str:
            return "—" if not math.isfinite(x) else format(x, fmt)

        head = (f"── {frequency_label(self.frequency_hz)} ({self.likelihood}): best {self.best} "
                f"over "
                f"{len(self.datasets)} dataset(s)"
                + (f"; left out (a model failed): {', '.join(self.incomplete)}"
                   if self.incomplete else ""))
        lines = [head, f"{'model':<26} {'wins':>4} {'elpd_loo':>10} {'se':>7} {'Δelpd':>9} "
                       f"{'Δse':>7} {'NRMSE%':>7} {'conv':>5}"]
        for m in self.models:
            lines.append(f"{m.model:<26} {m.wins:>4} {f(m.elpd_loo):>10} {f(m.se):>7} "
                         f"{f(m.delta_elpd):>9} {f(m.delta_se):>7} "
                         f"{f(m.mean_nrmse_percent, '.3f'):>7} "
                         f"{f(m.converged_fraction, '.0%'):>5}")
        return "\n".join(lines)


def _nan(x: Any) -> float:
    return math.nan if x is None else float(x)


def summarise(rows: Sequence[Mapping[str, Any]], pointwise: Mapping[str, np.ndarray],
              models: Sequence[str]) -> tuple[tuple[DatasetRanking, ...],
                                              tuple[FrequencySummary, ...]]:
    """Rank the models per dataset and frequency, then pool per frequency.

    Parameters
    ----------
    rows : sequence of dict
        The study table (:data:`~bayeshyst.study.rows.TABLE_COLUMNS`).
    pointwise : mapping of str to ndarray
        Per-cycle elpd of each successful fit, by its ``task`` name.
    models : sequence of str
        The study's models (their order breaks ties).

    Returns
    -------
    (tuple of DatasetRanking, tuple of FrequencySummary)
        Ordered by likelihood, frequency (unknown last) and dataset as in ``rows``.
    """
    cells: dict[tuple[str, str, float | None], dict[str, list[Mapping[str, Any]]]] = {}
    order_ds: list[str] = []
    order_lik: list[str] = []  # the study's order (rows come in plan order)
    for r in rows:
        if r["likelihood"] not in order_lik:
            order_lik.append(r["likelihood"])
        if r["frequency_hz"] is None and r["n_records"] in (None, 0):
            continue  # an unreadable dataset: no frequency to rank at
        key = (r["likelihood"], r["dataset"], frequency_key(r["frequency_hz"]))
        cells.setdefault(key, {}).setdefault(r["model"], []).append(r)
        if r["dataset"] not in order_ds:
            order_ds.append(r["dataset"])
    rankings: list[DatasetRanking] = []
    per_cell: dict[tuple[str, str, float | None], dict[str, tuple[np.ndarray, ModelAtDataset]]] = {}
    for key, by_model in cells.items():
        ok: dict[str, tuple[np.ndarray, list[Mapping[str, Any]]]] = {}
        failed = []
        for m in models:
            good = [r for r in by_model.get(m, []) if r["status"] == "ok"
                    and r["task"] in pointwise]
            sizes = {pointwise[r["task"]].size for r in good}
            if not good or len(sizes) != 1:
                if m in by_model:
                    failed.append(m)
                continue
            ok[m] = (np.mean([pointwise[r["task"]] for r in good], axis=0), good)
        sizes = {v[0].size for v in ok.values()}
        if len(sizes) > 1:  # cannot happen for one dataset's records; refuse to pair
            failed += list(ok)
            ok = {}
        ranked = []
        for rk in rank_by_elpd({m: pw for m, (pw, _) in ok.items()}):
            good = ok[rk.model][1]
            totals = [float(np.sum(pointwise[r["task"]])) for r in good]
            nrmse = [_nan(r["nrmse_percent"]) for r in good]
            ranked.append(ModelAtDataset(
                rk.model, rk.elpd, rk.se, rk.delta_elpd, rk.delta_se,
                float(np.nanmean(nrmse)) if np.any(np.isfinite(nrmse)) else math.nan,
                float(np.std(totals, ddof=1)) if len(totals) > 1 else math.nan,
                len(good), all(bool(r["converged"]) for r in good)))
        rankings.append(DatasetRanking(key[0], key[1], key[2], tuple(ranked), tuple(failed)))
        per_cell[key] = {s.model: (ok[s.model][0], s) for s in ranked}

    def sort_key(k: tuple[str, str, float | None]) -> tuple[int, bool, float, int]:
        return (order_lik.index(k[0]), k[2] is None, k[2] or 0.0, order_ds.index(k[1]))

    rankings.sort(key=lambda d: sort_key((d.likelihood, d.dataset, d.frequency_hz)))
    summaries = []
    groups: dict[tuple[str, float | None], list[tuple[str, str, float | None]]] = {}
    for key in sorted(per_cell, key=sort_key):
        groups.setdefault((key[0], key[2]), []).append(key)
    for (lik, f), keys in groups.items():
        complete = [k for k in keys if len(per_cell[k]) == len(models)]
        incomplete = tuple(k[1] for k in keys if k not in complete)
        if not complete:
            summaries.append(FrequencySummary(lik, f, (), (), incomplete))
            continue
        pooled = {m: np.concatenate([per_cell[k][m][0] for k in complete]) for m in models}
        best_per = [next(iter(per_cell[k])) for k in complete]  # each cell's ranking
        rows_m = []
        for rk in rank_by_elpd(pooled):
            m = rk.model
            nr = np.array([per_cell[k][m][1].nrmse_percent for k in complete])
            fin = nr[np.isfinite(nr)]
            rows_m.append(ModelAcrossDatasets(
                m, len(complete), best_per.count(m), rk.elpd, rk.se, rk.delta_elpd,
                rk.delta_se, float(fin.mean()) if fin.size else math.nan,
                float(fin.max()) if fin.size else math.nan,
                float(np.mean([per_cell[k][m][1].converged for k in complete]))))
        summaries.append(FrequencySummary(lik, f, tuple(rows_m), tuple(k[1] for k in complete),
                                          incomplete))
    return tuple(rankings), tuple(summaries)
