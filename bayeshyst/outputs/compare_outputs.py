"""What ``bayeshyst compare`` writes: the summary, the comparison table and its figure.

The files are ``summary.json``, ``comparison.csv``, ``comparison.txt`` and the figure
``compare.png``.

The posteriors of the fits (``posteriors/<model>__<scope>_<frequency>.nc``) and their
resumable sampler checkpoints (``checkpoints/``) are written by the fits themselves; the
figure is built by the caller (:func:`~bayeshyst.outputs.assemble.comparison_figures`).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bayeshyst.files import atomic_path
from bayeshyst.outputs.files import jsonable, write_figures, write_json
from bayeshyst.selection import ComparisonResult, FrequencyComparison

__all__ = ["CSV_COLUMNS", "comparison_summary", "error_spectrum_entry",
           "write_comparison_outputs"]

CSV_COLUMNS = ("frequency_hz", "rank", "model", "elpd_loo", "se", "delta_elpd", "delta_se",
               "weight", "p_loo", "elpd_waic", "waic_se", "elpd_lofo", "lofo_se",
               "lofo_nrmse_percent", "elpd_joint", "bic", "nrmse_percent",
               "max_error_percent", "n_params", "converged", "max_pareto_k", "n_refits",
               "n_cycles", "error")


def _statement(fc: FrequencyComparison) -> str:
    """One sentence a reader can quote: who wins here, and how clearly."""
    ok = [s for s in fc.scores if not s.error]
    if not ok:
        return f"{fc.label}: every fit failed."
    best = ok[0]
    text = f"{fc.label}: {best.model} ranks first"
    if len(ok) > 1:
        second = ok[1]
        d, se = -second.delta_elpd, second.delta_se
        if math.isfinite(se) and se > 0:
            clear = "clearly" if d > 2 * se else "not significantly"
            text += (f", {clear} ahead of {second.model} (Δelpd {d:.1f} ± {se:.1f})")
        else:
            text += f", ahead of {second.model} (Δelpd {d:.1f})"
    if fc.best_lofo and fc.best_lofo != best.model:
        text += f"; fitted to the other frequencies, {fc.best_lofo} predicts it best"
    if not all(s.converged for s in ok):
        text += "; some fits did not converge (see warnings)"
    return text + "."


def error_spectrum_entry(result: ComparisonResult, fc: FrequencyComparison,
                         model: str | None) -> dict[str, Any] | None:
    """The error spectrum of ``model`` in the band group ``fc``, as ``summary.json`` holds it.

    ``{"model", "bands": [{lo_hz, hi_hz, error_rms, input_rms, n_samples}, ...]}`` from
    the fit behind the group's ranking (:meth:`ComparisonResult.fit_of`); None for a
    frequency group, or when that fit failed or scored no octave.
    """
    if fc.band is None or model is None:
        return None
    task = result.fit_of(model, fc.key)
    rows = None if task is None else dict(task.error_spectra).get(fc.band)
    if not rows:
        return None
    return {"model": model, "bands": [r.to_dict() for r in rows]}


def comparison_summary(result: ComparisonResult, *, data_path: str | None = None,
                       files: dict[str, Any] | None = None,
                       working_rate: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The machine-readable summary of a comparison.

    Keys: ``models``, ``per_frequency`` (each ``frequency_hz``, ``group`` (its label),
    ``band_hz``, ``best``, ``best_lofo``, ``ranking`` — a list of ``{model, elpd_loo,
    se, weight, nrmse_percent, ...}`` best first — ``statement`` and, for a band
    group, ``error_spectrum`` of its best model, :func:`error_spectrum_entry`), ``overall`` (all
    frequencies jointly), ``winners``, ``statements``, ``failed_fits``, ``fits``,
    ``settings``, ``runtime_s``, ``data``, ``files``, ``warnings``, and
    ``working_rate`` when one is given (as :func:`write_comparison_outputs` takes it).
    """
    out = result.to_dict()
    for entry, fc in zip(out["per_frequency"], result.per_frequency, strict=True):
        entry["statement"] = _statement(fc)
        if fc.band is not None:
            entry["error_spectrum"] = error_spectrum_entry(result, fc, fc.best)
    out["overall"]["statement"] = _statement(result.overall)
    out["statements"] = [_statement(fc) for fc in (*result.per_frequency, result.overall)]
    warnings = []
    bad = sorted({t.spec.key for t in result.tasks if t.ok and not t.converged})
    if bad:
        warnings.append(f"{len(bad)} fits did not converge: {', '.join(bad)}; their scores "
                        f"are not reliable (raise --steps)")
    warnings += [f"fit failed: {t.error}" for t in result.failed]
    out["warnings"] = warnings
    out["data"] = data_path
    out["files"] = files or {}
    if working_rate is not None:
        out["working_rate"] = jsonable(dict(working_rate))
    return out


def _csv_text(result: ComparisonResult) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for fc in (*result.per_frequency, result.overall):
        # a band group by its label, as the frequency column names "all" the joint rows
        freq = ("all" if fc.joint else fc.label if fc.band is not None
                else "" if fc.frequency_hz is None else fc.frequency_hz)
        for rank, s in enumerate(fc.scores, start=1):
            d = s.to_dict()
            row = [freq, rank] + ["" if d[c] is None else d[c] for c in CSV_COLUMNS[2:]]
            writer.writerow(row)
    return buf.getvalue()


def write_comparison_outputs(result: ComparisonResult, out_dir: str | Path, *,
                             figures: Mapping[str, Any] | None = None,
                             data_path: str | None = None,
                             working_rate: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write the comparison's files into ``out_dir`` (each atomically, ``summary.json`` last).

    Parameters
    ----------
    result : ComparisonResult
    out_dir : path-like
        Created if needed.
    figures : mapping of str to Figure, optional
        PNG file name -> figure
        (:func:`~bayeshyst.outputs.assemble.comparison_figures`); none by default.
    data_path : str, optional
        The data file, recorded in the summary.
    working_rate : mapping, optional
        The rate the records were fitted at
        (:meth:`bayeshyst.data.working_rate.WorkingRate.to_dict`), recorded under the
        summary's ``working_rate``; left out of it by default.

    Returns
    -------
    dict
        The summary written to ``summary.json`` (:func:`comparison_summary`), before JSON
        encoding (print it with :func:`bayeshyst.files.json_text`).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Any] = {"table": "comparison.csv", "text": "comparison.txt",
                             "posteriors": sorted(Path(t.netcdf).name for t in result.tasks
                                                  if t.netcdf)}
    with atomic_path(out / "comparison.csv") as tmp:
        tmp.write_text(_csv_text(result))
    statements = "\n".join(_statement(fc) for fc in (*result.per_frequency, result.overall))
    with atomic_path(out / "comparison.txt") as tmp:
        tmp.write_text(str(result) + "\n\n" + statements + "\n")
    files["figures"] = write_figures(out, figures)
    summary = comparison_summary(result, data_path=data_path, files=files,
                                 working_rate=working_rate)
    write_json(out / "summary.json", summary)
    return summary
