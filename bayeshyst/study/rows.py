"""The study table: one row per fit, and the per-fit record stored on disk.

``fits/<task name>.json`` holds a finished fit: its table row, its pointwise
leave-one-cycle-out elpd (what the cross-dataset summary pairs models on) and where it
ran. It is written after the fit's posterior (``fits/<task name>.nc``), atomically, so
a fit is done exactly when its JSON file is there.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.files import write_json
from bayeshyst.selection import total_and_se
from bayeshyst.study.tasks import FitOutcome, StudyTask, settings_fingerprint

__all__ = ["TABLE_COLUMNS", "VOLATILE_COLUMNS", "failed_row", "fit_record", "read_record"]

TABLE_COLUMNS = (
    "dataset", "source", "model", "likelihood", "seed", "frequency_hz", "status",
    "n_records", "n_cycles", "elpd_loo", "elpd_se", "p_loo", "elpd_waic", "waic_se", "bic",
    "nrmse_percent", "max_error_percent", "max_pareto_k", "n_refits", "n_params",
    "converged", "failed_simulations", "runtime_s", "worker", "posterior", "task",
    "warnings", "error",
)
"""Columns of ``table.csv`` (``table.json`` has the same keys per row)."""

VOLATILE_COLUMNS = ("runtime_s", "worker")
"""Columns that differ between two runs of the same study (timing, placement); every
other column is a function of the study file and the data."""


def _num(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def failed_row(task: StudyTask | None, *, dataset: str, source: str, model: str,
               likelihood: str, seed: int, frequency_hz: float | None, error: str,
               worker: str = "") -> dict[str, Any]:
    """A row for a fit that produced no scores (unreadable dataset, lost worker)."""
    row: dict[str, Any] = dict.fromkeys(TABLE_COLUMNS)
    row.update(dataset=dataset, source=source, model=model, likelihood=likelihood, seed=seed,
               frequency_hz=frequency_hz, status="failed", converged=False,
               task=None if task is None else task.name, warnings="", error=error,
               worker=worker)
    return row


def fit_record(outcome: FitOutcome, source: str, n_records: int,
               posterior: str | None) -> dict[str, Any]:
    """The stored record of a finished fit: ``{"row", "pointwise", "unit_labels", ...}``."""
    t, r = outcome.task, outcome.result
    warnings = list(r.warnings) + list(outcome.notes)
    if not r.ok:
        row = failed_row(t, dataset=t.dataset, source=source, model=t.model,
                         likelihood=t.likelihood, seed=t.seed, frequency_hz=t.frequency_hz,
                         error=r.error or "failed", worker=outcome.worker)
        row.update(n_records=n_records, runtime_s=round(r.runtime_s, 3),
                   warnings="; ".join(warnings))
        return {"row": row, "pointwise": [], "unit_labels": [], "failure": "fit"}
    pw = np.asarray(r.pointwise, dtype=float)
    elpd, se = total_and_se(pw)
    waic = total_and_se(np.asarray(r.waic_pointwise)) if r.waic_pointwise is not None else (
        math.nan, math.nan)
    k = np.asarray(r.pareto_k, dtype=float) if r.pareto_k is not None else np.zeros(0)
    finite_k = k[np.isfinite(k)]
    err = r.overall
    row = {
        "dataset": t.dataset, "source": source, "model": t.model, "likelihood": t.likelihood,
        "seed": t.seed, "frequency_hz": t.frequency_hz,
        "status": "ok" if np.all(np.isfinite(pw)) else "failed",
        "n_records": n_records, "n_cycles": int(pw.size), "elpd_loo": _num(elpd),
        "elpd_se": _num(se), "p_loo": _num(r.p_loo), "elpd_waic": _num(waic[0]),
        "waic_se": _num(waic[1]), "bic": _num(r.bic),
        "nrmse_percent": _num(err.nrmse_percent) if err else None,
        "max_error_percent": _num(err.max_error_percent) if err else None,
        "max_pareto_k": _num(finite_k.max()) if finite_k.size else None,
        "n_refits": int(r.n_refits), "n_params": int(r.n_params),
        "converged": bool(r.converged), "failed_simulations": int(r.failed_simulations),
        "runtime_s": round(r.runtime_s, 3), "worker": outcome.worker, "posterior": posterior,
        "task": t.name, "warnings": "; ".join(warnings), "error": None,
    }
    if row["status"] == "failed":
        row["error"] = "non-finite predictive density of some cycles (failed simulations)"
    return {"row": row, "pointwise": pw.tolist(), "unit_labels": list(r.unit_labels),
            "failure": None if row["status"] == "ok" else "fit"}


def write_record(path: Path, record: dict[str, Any], task: StudyTask) -> None:
    """Write a fit's record (atomically) with the task that made it."""
    write_json(path, {**record, "study_task": {
        "name": task.name, "digest": task.digest, "dataset": task.dataset,
        "model": task.model, "likelihood": task.likelihood,
        "frequency_hz": task.frequency_hz, "seed": task.seed, "fit_seed": task.fit_seed,
        "data_sha256": task.data_sha256, "settings": settings_fingerprint(task.settings)}})


def read_record(path: Path, task: StudyTask) -> dict[str, Any] | None:
    """The stored record of ``task``, or None when there is none or it is not this task's.

    A record is not this task's when it is unreadable or written for other inputs; then
    the fit runs again.
    """
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.get("study_task", {}).get("digest") != task.digest:
        return None
    post = rec.get("row", {}).get("posterior")
    if post and not (path.parent / Path(post).name).is_file():
        return None  # the posterior went missing: the record alone is not the result
    return rec
