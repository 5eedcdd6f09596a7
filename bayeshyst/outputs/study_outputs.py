"""What ``bayeshyst study`` writes at the end of a study.

- ``table.csv`` / ``table.json`` — one row per fit (columns
  :data:`bayeshyst.study.rows.TABLE_COLUMNS`), in plan order;
- ``by_frequency.csv`` / ``.json`` — model selection per frequency across datasets
  (:class:`bayeshyst.study.summary.FrequencySummary`);
- ``best_by_dataset.csv`` / ``.json`` — the ranking at every dataset and frequency;
- ``figures/best_model.png`` (best model per frequency and dataset) and
  ``figures/scores_vs_frequency.png`` (elpd per cycle and NRMSE against frequency);
- ``study.html`` when asked for; ``summary.json`` last (what ran, where, the files).

Each file is written to a temporary name and renamed, so none is ever half-written. The
figures are built by the caller (:func:`bayeshyst.outputs.assemble.study_output_figures`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bayeshyst._version import __version__
from bayeshyst.files import atomic_path
from bayeshyst.outputs.files import write_figures, write_json, write_rows_csv
from bayeshyst.study.rows import TABLE_COLUMNS

__all__ = ["BY_FREQUENCY_COLUMNS", "RANKING_COLUMNS", "write_study_outputs"]

BY_FREQUENCY_COLUMNS = ("likelihood", "frequency_hz", "rank", "model", "wins", "n_datasets",
                        "elpd_loo", "se", "delta_elpd", "delta_se", "mean_nrmse_percent",
                        "max_nrmse_percent", "converged_fraction")
RANKING_COLUMNS = ("likelihood", "dataset", "frequency_hz", "rank", "model", "elpd_loo", "se",
                   "delta_elpd", "delta_se", "nrmse_percent", "seed_sd", "n_seeds",
                   "converged")


def _by_frequency_rows(result: Any) -> list[dict[str, Any]]:
    out = []
    for s in result.by_frequency:
        for i, m in enumerate(s.models, 1):
            out.append({"likelihood": s.likelihood, "frequency_hz": s.frequency_hz,
                        "rank": i, **m.__dict__})
    return out


def _ranking_rows(result: Any) -> list[dict[str, Any]]:
    out = []
    for d in result.rankings:
        for i, m in enumerate(d.ranking, 1):
            out.append({"likelihood": d.likelihood, "dataset": d.dataset,
                        "frequency_hz": d.frequency_hz, "rank": i, **m.__dict__})
        for m in d.failed:
            out.append({"likelihood": d.likelihood, "dataset": d.dataset,
                        "frequency_hz": d.frequency_hz, "rank": None, "model": m,
                        "elpd_loo": math.nan})
    return out


def write_study_outputs(result: Any, out: str | Path, *,
                        figures: Mapping[str, Any] | None = None,
                        html: bool = False) -> dict[str, Any]:
    """Write the study's tables, figures, optional HTML report and ``summary.json``.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult
    out : path-like
        The study's output folder.
    figures : mapping of str to Figure, optional
        File name relative to ``out`` -> figure
        (:func:`~bayeshyst.outputs.assemble.study_output_figures`: ``figures/*.png``, which
        the HTML report embeds); none by default.
    html : bool
        Write ``study.html``.

    Returns
    -------
    dict
        The summary written to ``summary.json``, before JSON encoding (print it with
        :func:`bayeshyst.files.json_text`).
    """
    out = Path(out)
    rows = [dict(r) for r in result.rows]
    write_rows_csv(out / "table.csv", TABLE_COLUMNS, rows)
    write_json(out / "table.json", {"columns": list(TABLE_COLUMNS), "rows": rows})
    write_rows_csv(out / "by_frequency.csv", BY_FREQUENCY_COLUMNS, _by_frequency_rows(result))
    write_json(out / "by_frequency.json", [s.to_dict() for s in result.by_frequency])
    write_rows_csv(out / "best_by_dataset.csv", RANKING_COLUMNS, _ranking_rows(result))
    write_json(out / "best_by_dataset.json", [d.to_dict() for d in result.rankings])
    files: dict[str, Any] = {"table": ["table.csv", "table.json"],
                             "by_frequency": ["by_frequency.csv", "by_frequency.json"],
                             "best_by_dataset": ["best_by_dataset.csv",
                                                 "best_by_dataset.json"],
                             "fits": "fits/", "figures": []}
    # figures of an earlier run of this folder would not match the new table
    for name in ("best_model", "scores_vs_frequency"):
        (out / "figures" / f"{name}.png").unlink(missing_ok=True)
    files["figures"] = write_figures(out, figures)
    figs = {Path(name).stem: out / name for name in files["figures"]}
    if html:
        from bayeshyst.outputs.study_html import study_html

        with atomic_path(out / "study.html") as tmp:
            tmp.write_text(study_html(result, figs), encoding="utf-8")
        files["html"] = "study.html"
    n_fail = len(result.failed)
    summary = {
        "study": result.study.to_dict(),
        "n_fits": len(result.rows), "n_failed": n_fail, "n_run": result.n_run,
        "n_reused": result.n_reused, "cluster": result.cluster,
        "runtime_s": round(result.runtime_s, 2),
        "best_per_frequency": [{"likelihood": s.likelihood, "frequency_hz": s.frequency_hz,
                                "best": s.best, "n_datasets": len(s.datasets),
                                "incomplete_datasets": list(s.incomplete)}
                               for s in result.by_frequency],
        "failed_fits": [{k: r[k] for k in ("dataset", "model", "likelihood", "seed",
                                           "frequency_hz", "error")}
                        for r in result.failed],
        "versions": {"bayeshyst": __version__},
        "files": files,
    }
    write_json(out / "summary.json", summary)
    return summary
