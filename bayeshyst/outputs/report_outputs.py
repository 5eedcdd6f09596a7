"""What ``bayeshyst report`` (and ``bayeshyst demo``) writes.

One self-contained HTML report, ``summary.json`` and every posterior as netCDF.

Layout of ``out``::

    report.html          the report (figures embedded: one file to send or archive)
    summary.json         every number the report shows, by section (written last)
    figures/             the report's own figures as PNG (data overview, corners, trace)
    compare/             what ``bayeshyst compare`` writes (table, figure, posteriors/*.nc)
    diagnose/            what ``bayeshyst diagnose`` writes (posterior_base/final.nc, ...)
    compensate/          what ``bayeshyst compensate`` writes (curves, table, figure; its
                         posterior is the diagnosis' final one, not written twice)

The page is rendered from the summary by :mod:`bayeshyst.outputs.report_html`; every
user-provided string (data and record names, file paths, metadata) reaches it through
:mod:`bayeshyst.outputs.html`, which escapes it.

The writer only writes: the caller loads the comparison's joint posteriors
(:func:`~bayeshyst.outputs.assemble.report_posteriors`) and builds every figure
(:func:`~bayeshyst.outputs.assemble.report_figures`).
"""

from __future__ import annotations

import json
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst._version import __version__
from bayeshyst.data.dataset import Dataset
from bayeshyst.files import atomic_path, json_text
from bayeshyst.outputs.assemble import corner_figure_name, joint_tasks
from bayeshyst.outputs.compare_outputs import error_spectrum_entry, write_comparison_outputs
from bayeshyst.outputs.compensate_outputs import write_compensation_outputs
from bayeshyst.outputs.diagnose_outputs import evidence_figures, write_diagnosis_outputs
from bayeshyst.outputs.files import jsonable, write_figures, write_json
from bayeshyst.outputs.report_html import convergence_words, report_html
from bayeshyst.workflow import ReportResult

__all__ = ["SECTIONS", "data_overview", "write_report_outputs"]

#: Sections of ``summary.json`` (and of the HTML report), in order.
SECTIONS = ("data", "posteriors", "model_selection", "diagnosis", "uncertainty",
            "compensation", "model_averaged_feedforward")


# ----------------------------------------------------------------------------- data
def data_overview(data: Dataset, data_path: str | None) -> dict[str, Any]:
    """The ``data`` section of ``summary.json``: the file and one entry per record."""
    recs = []
    for r in data:
        meta = {k: v for k, v in r.metadata.items()}
        recs.append({
            "name": r.name, "frequency_hz": r.frequency_hz, "n": r.n, "fs_hz": r.fs,
            "duration_s": r.duration, "warmup": r.warmup, "n_scored": r.n_scored,
            "units": dict(r.units), "u_range": [float(np.min(r.u)), float(np.max(r.u))],
            "y_range": [float(np.min(r.y)), float(np.max(r.y))], "stroke": r.stroke,
            "metadata": jsonable(meta),
        })
    return {"path": data_path, "name": data.name, "n_records": len(data),
            "n_samples": data.n_samples, "frequencies_hz": list(data.frequencies),
            "records": recs}


# ------------------------------------------------------------------ model selection
def _band_spectra(result: ReportResult, sel: dict[str, Any]) -> None:
    """Each band group's error spectrum, of the chosen model, into the section ``sel``.

    A band group has no excitation frequency to give a per-frequency error; the report
    shows where in frequency the chosen model's error lies instead (the comparison's
    own summary shows the group's best model's).
    """
    units = dict(result.data[0].units)
    for entry, fc in zip(sel["per_frequency"], result.comparison.per_frequency, strict=True):
        if fc.band is None:
            continue
        spectrum = error_spectrum_entry(result.comparison, fc, result.chosen_model)
        if spectrum is not None:
            spectrum.update(y_unit=units.get("y", ""), u_unit=units.get("u", ""))
        entry["error_spectrum"] = spectrum


# ----------------------------------------------------------------------- posteriors


def _under(figures: Mapping[str, Any], folder: str) -> dict[str, Any]:
    """The figures of one stage, named relative to its folder."""
    prefix = f"{folder}/"
    return {k[len(prefix):]: v for k, v in figures.items() if k.startswith(prefix)}


def _posteriors(result: ReportResult, out: Path, posteriors: Mapping[str, Any],
                figures: Mapping[str, Any]) -> dict[str, Any]:
    """Per parametric model: its joint fit's posterior (from the comparison's netCDF)."""
    from bayeshyst import diagnostics

    entries = []
    for task in joint_tasks(result):
        idata = posteriors[task.spec.key]
        rep = diagnostics.sampling_report(idata)
        params = [{"label": p.label, "unit": p.unit, "mean": p.mean, "sd": p.sd,
                   "hdi_5": p.hdi_lo, "hdi_95": p.hdi_hi}
                  for p in diagnostics.posterior_summary(idata, 0.9)]
        corner = corner_figure_name(task)
        entries.append({"model": task.spec.model, "scope": "all frequencies jointly",
                        "posterior": str(Path(task.netcdf).relative_to(out)),
                        "sampling": rep, "params": params,
                        "verdict": convergence_words(rep),
                        "corner": corner if corner in figures else None})
    section: dict[str, Any] = {"models": entries, "chosen": None, "base_converged": None}
    if result.diagnosis is not None:
        section["base_converged"] = bool(result.diagnosis.base.sampling.converged)
        fit = result.diagnosis.final
        c = fit.sampling.convergence
        section["chosen"] = {
            "model": fit.label, "converged": c.converged,
            "convergence_reasons": list(c.reasons), "rhat_max": c.rhat_max,
            "ess_bulk_min": c.ess_bulk_min, "n_steps": c.n_steps,
            "failed_simulations": fit.sampling.counts.failed,
            "move_acceptance": dict(fit.sampling.move_acceptance),
            "params": [{"label": p.label, "unit": p.unit, "mean": p.mean, "sd": p.sd,
                        "hdi_5": p.hdi_lo, "hdi_95": p.hdi_hi}
                       for p in fit.sampling.summary(0.9)],
            "trace": None, "corner": None}
        for key in ("trace", "corner"):
            name = f"figures/{key}_final.png"
            section["chosen"][key] = name if name in figures else None
    return section


# ---------------------------------------------------------------------- uncertainty
def _uncertainty(result: ReportResult, comp: dict[str, Any] | None) -> dict[str, Any] | None:
    """The uncertainty-analysis section: calibration, budget, tracking band per frequency."""
    fit = result.final_fit
    if fit is None:
        return None
    cal = result.calibration
    y_unit = str(dict(result.data[0].units).get("y", ""))
    calib = {} if cal is None else {c.frequency_hz: c.to_dict() for c in cal.per_frequency}
    rows = []
    for b in fit.budget:
        row = {**b.to_dict(), "calibration": calib.get(b.frequency_hz)}
        rows.append(row)
    tracking = []
    for r in (comp or {}).get("per_frequency", []):
        tracking.append({"frequency_hz": r.get("frequency_hz"),
                         "band_percent": r.get("predicted_band_percent"),
                         "parameter_band_percent": r.get("parameter_band_percent"),
                         "model_band_percent": r.get("model_band_percent"),
                         "residual_rms_percent": r.get("residual_rms_percent"),
                         "realised_percent": r.get("posterior_nrmse_percent"),
                         "inside": r.get("realised_inside_band")})
    return {"model": result.diagnosis.final.label, "y_unit": y_unit,
            "discrepancy": fit.posterior.discrepancy is not None,
            "checked": cal is not None,
            "calibrated": None if cal is None else cal.calibrated,
            "refit_converged": None if cal is None else cal.refit_converged,
            "held_out": [] if cal is None else list(cal.held_out),
            "per_frequency": rows, "tracking_band": tracking}


# --------------------------------------------------------------------------- writer
def _warnings(result: ReportResult, sel: dict[str, Any], dg: dict[str, Any] | None,
              comp: dict[str, Any] | None) -> list[str]:
    out = list(result.warnings)
    out += sel.get("warnings", [])
    if dg is not None:
        if not dg.get("converged", True):
            out.append("a fit of the residual diagnosis did NOT converge: its decisions rest "
                       "on unreliable posteriors")
        out += dg.get("warnings", [])
    if comp is not None:
        out += comp.get("warnings", [])
    return list(dict.fromkeys(out))


def _as_written(summary: dict[str, Any]) -> dict[str, Any]:
    """A stage's summary as its ``summary.json`` holds it.

    Plain types, ``null`` for non-finite numbers: what the report's own summary and HTML
    are built from.
    """
    return json.loads(json_text(summary))


def write_report_outputs(result: ReportResult, out_dir: str | Path, *,
                         posteriors: Mapping[str, Any],
                         figures: Mapping[str, Any] | None = None,
                         data_path: str | None = None,
                         title: str | None = None,
                         working_rate: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write ``report.html``, ``summary.json`` and each stage's files into ``out_dir``.

    Parameters
    ----------
    result : ReportResult
    out_dir : path-like
        Created if needed; the comparison's posteriors must already be under
        ``out_dir/compare`` (pass the same folder to :func:`~bayeshyst.workflow.run_report`).
    posteriors : mapping of str to arviz.InferenceData
        The comparison's joint posteriors
        (:func:`~bayeshyst.outputs.assemble.report_posteriors`).
    figures : mapping of str to Figure, optional
        File name relative to ``out_dir`` -> figure
        (:func:`~bayeshyst.outputs.assemble.report_figures`); each stage's are handed to
        its writer, the rest written under ``figures/`` and embedded. None by default.
    data_path : str, optional
        The data file, shown in the report and recorded in the summary.
    title : str, optional
        Report title (default: "bayeshyst report: <data name>").
    working_rate : mapping, optional
        The rate the records were fitted at
        (:meth:`bayeshyst.data.working_rate.WorkingRate.to_dict`): recorded under the
        summary's ``working_rate`` (once, not again in the stages' summaries) and said in
        the report's Data section; left out by default.

    Returns
    -------
    dict
        The summary written (sections :data:`SECTIONS` plus ``command``, ``chosen_model``,
        ``warnings``, ``settings``, ``seed``, ``runtime_s``, ``versions``, ``files`` and,
        when given, ``working_rate``).
    """
    if not isinstance(result, ReportResult):
        raise TypeError(f"result must be a ReportResult, got {type(result).__name__}")
    figures = figures or {}
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    # the report's own figures (the stages' go to their writers below)
    write_figures(out, {k: v for k, v in figures.items() if k.startswith("figures/")})
    data_sec = data_overview(result.data, data_path)
    overview = out / "figures" / "data_loops.png"
    overview = overview if "figures/data_loops.png" in figures else None
    sel = write_comparison_outputs(result.comparison, out / "compare", data_path=data_path,
                                   figures=_under(figures, "compare"))
    _band_spectra(result, sel)
    dg = comp = None
    evidence: list[str] = []
    if result.diagnosis is not None:
        dg = _as_written(write_diagnosis_outputs(result.diagnosis, out / "diagnose",
                                                 data_name=data_path,
                                                 figures=_under(figures, "diagnose")))
        kept = {s.effect for s in result.diagnosis.steps}
        evidence = [n for n, t in evidence_figures(result.diagnosis)
                    if (t.effect in kept or t.significant) and f"diagnose/{n}" in figures]
    if result.compensation is not None:
        # the design's posterior is the diagnosis' final fit, already saved there
        saved = "posterior_final.nc" if (result.diagnosis.final is not result.diagnosis.base
                                         ) else "posterior_base.nc"
        comp = _as_written(write_compensation_outputs(
            result.compensation, out / "compensate", fit=result.final_fit,
            posterior=f"../diagnose/{saved}", figures=_under(figures, "compensate"),
            data_path=data_path))
    post_sec = _posteriors(result, out, posteriors, figures)
    unc = _uncertainty(result, comp)
    summary: dict[str, Any] = {
        "command": "report",
        "title": title or f"bayeshyst report: {result.data.name}",
        "chosen_model": result.chosen_model,
        "data": data_sec,
        "posteriors": post_sec,
        "model_selection": sel,
        "diagnosis": dg,
        "uncertainty": unc,
        "compensation": comp,
        "model_averaged_feedforward": (None if result.averaged is None
                                       else result.averaged.to_dict()),
        "warnings": _warnings(result, sel, dg, comp),
        "settings": result.settings.to_dict(),
        "seed": result.seed,
        "runtime_s": {k: round(v, 2) for k, v in result.runtime_s.items()},
        "versions": {"bayeshyst": __version__, "python": platform.python_version(),
                     "numpy": np.__version__},
        "files": {"report": "report.html", "summary": "summary.json",
                  "figures": sorted(str(p.relative_to(out))
                                    for p in (out / "figures").glob("*.png"))},
    }
    if working_rate is not None:
        summary["working_rate"] = dict(working_rate)
    summary = jsonable(summary)
    subtitle = (f"data: {data_path or result.data.name} · models: "
                f"{', '.join(result.comparison.models)} · seed {result.seed}")
    document = report_html(summary, out, subtitle=subtitle, overview=overview,
                           evidence=evidence)
    with atomic_path(out / "report.html") as tmp:
        tmp.write_text(document, encoding="utf-8")
    write_json(out / "summary.json", summary)
    return summary

