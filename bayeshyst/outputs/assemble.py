"""What the writers write but do not compute: figures, and the posteriors the report reads.

Each ``*_outputs`` module of :mod:`bayeshyst.outputs` only writes: it is handed the
InferenceData of a fit and the figures, as a mapping from file name (relative to the
writer's folder) to :class:`matplotlib.figure.Figure`. The functions here build those
mappings with :mod:`bayeshyst.plotting` (the only part of bayeshyst that imports
matplotlib); the command line calls them, then the writer::

    figures = fit_figures(fit, seed=seed)
    idata = diagnostics.to_inference_data(fit.posterior, fit.sampling, seed=seed)
    summary = write_fit_outputs(fit, out, idata=idata, figures=figures)

Nothing here writes a file.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # only for the annotations: `bayeshyst fit` need not load the others
    from bayeshyst.diagnosis import DiagnosisResult
    from bayeshyst.inference.fit import FitResult
    from bayeshyst.inference.predict import PredictionResult
    from bayeshyst.inverse.compensate import CompensationResult
    from bayeshyst.selection import ComparisonResult
    from bayeshyst.workflow import ReportResult

__all__ = ["BOUC_WEN_CORNER", "CORNER_MAX", "comparison_figures", "compensation_figures",
           "corner_figure_name", "diagnosis_figures", "fit_figures", "joint_tasks",
           "prediction_figures", "report_figures", "report_posteriors", "study_output_figures"]

#: Parameters of the Bouc–Wen corner plots, drawn whenever a fitted model has them all.
BOUC_WEN_CORNER = ("alpha", "beta", "gamma", "n")
#: Parameters in the report's corner plot of the final model (k (k + 1) / 2 panels).
CORNER_MAX = 6


#: records drawn by ``bayeshyst predict`` at most (the scores cover every record)
PREDICTION_FIGURES_MAX = 24


# ------------------------------------------------------------------- one command each
def prediction_figures(result: PredictionResult) -> dict[str, Any]:
    """The figures ``bayeshyst predict`` writes: ``figures/predict_<k>_<record>.png``.

    One per record (:func:`bayeshyst.plotting.predict.prediction_figure`), the first
    :data:`PREDICTION_FIGURES_MAX` records at most; the file names carry the record's
    index and its name with characters outside ``[A-Za-z0-9._-]`` replaced.
    """
    import re

    from bayeshyst.plotting.predict import prediction_figure

    out = {}
    for k, rec in enumerate(result.records[:PREDICTION_FIGURES_MAX]):
        safe = re.sub(r"[^A-Za-z0-9._-]+", "_", rec.name)[:60]
        out[f"figures/predict_{k}_{safe}.png"] = prediction_figure(result, rec.name)
    return out


def fit_figures(fit: FitResult, *, seed: int = 0) -> dict[str, Any]:
    """The figures ``bayeshyst fit`` writes.

    Parameters
    ----------
    fit : FitResult
    seed : int
        Selects the posterior draws the loops are predicted from.

    Returns
    -------
    dict of str to Figure
        ``loops.png``, ``trace.png``, ``corner.png`` (Bouc–Wen's α, β, γ, n when the model
        has them, else every free element) and ``residuals.png``, in that order.
    """
    from bayeshyst import plotting

    names = fit.sampling.space.names
    corner = list(BOUC_WEN_CORNER) if all(n in names for n in BOUC_WEN_CORNER) else None
    return {
        "loops.png": plotting.loops_figure(fit.posterior, fit.sampling, seed=seed),
        "trace.png": plotting.trace_figure(fit.sampling),
        "corner.png": plotting.corner_figure(fit.sampling, params=corner),
        "residuals.png": plotting.residuals_figure(fit.posterior, fit.sampling),
    }


def comparison_figures(result: ComparisonResult) -> dict[str, Any]:
    """The figure ``bayeshyst compare`` writes.

    Parameters
    ----------
    result : ComparisonResult

    Returns
    -------
    dict of str to Figure
        ``compare.png`` (:func:`bayeshyst.plotting.model_comparison_figure`); empty when
        no record has an excitation frequency to plot against.
    """
    if not any(fc.frequency_hz is not None for fc in result.per_frequency):
        return {}
    from bayeshyst.plotting import model_comparison_figure

    return {"compare.png": model_comparison_figure(result)}


def diagnosis_figures(result: DiagnosisResult) -> dict[str, Any]:
    """The figures ``bayeshyst diagnose`` writes.

    Parameters
    ----------
    result : DiagnosisResult

    Returns
    -------
    dict of str to Figure
        ``residuals.png`` (before/after,
        :func:`bayeshyst.plotting.diagnosis_residuals_figure`), then the evidence
        figures named by :func:`~bayeshyst.outputs.diagnose_outputs.evidence_figures`
        (:func:`bayeshyst.plotting.effect_evidence_figure`).
    """
    from bayeshyst.outputs.diagnose_outputs import evidence_figures
    from bayeshyst.plotting import diagnosis_residuals_figure, effect_evidence_figure

    data = result.base.posterior.data
    y_unit = data[0].units.get("y", "") if len(data) else ""
    out = {"residuals.png": diagnosis_residuals_figure(result)}
    for name, test in evidence_figures(result):
        out[name] = effect_evidence_figure(test, y_unit=y_unit)
    return out


def compensation_figures(result: CompensationResult, *,
                         fit: FitResult | None = None) -> dict[str, Any]:
    """The figure ``bayeshyst compensate`` writes.

    Parameters
    ----------
    result : CompensationResult
    fit : FitResult, optional
        The fit the commands were designed from: its output unit labels the axes.

    Returns
    -------
    dict of str to Figure
        ``compensate.png`` (:func:`bayeshyst.plotting.compensation_figure`); empty when
        the result has no rows.
    """
    if not result.rows:
        return {}
    from bayeshyst.plotting import compensation_figure

    y_unit = fit.posterior.data[0].units.get("y", "") if fit is not None else ""
    return {"compensate.png": compensation_figure(result, y_unit=y_unit)}


def study_output_figures(result: Any) -> dict[str, Any]:
    """The figures ``bayeshyst study`` writes.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult

    Returns
    -------
    dict of str to Figure
        ``figures/best_model.png`` and ``figures/scores_vs_frequency.png``
        (:func:`bayeshyst.plotting.study_figures`), each left out when the study has
        nothing to draw in it.
    """
    from bayeshyst.plotting import study_figures

    return {f"figures/{name}.png": fig for name, fig in study_figures(result).items()}


# ----------------------------------------------------------------------------- report
def joint_tasks(result: ReportResult) -> list[Any]:
    """The comparison's joint fits that saved a posterior, in the comparison's order.

    A joint fit is one of a model to all frequencies jointly.

    Parameters
    ----------
    result : ReportResult

    Returns
    -------
    list of TaskResult
    """
    return [task for task in result.comparison.tasks
            if task.spec.scope == "joint" and task.ok and task.netcdf]


def corner_figure_name(task: Any) -> str:
    """File name, relative to the report's folder, of a joint fit's Bouc–Wen corner plot.

    Parameters
    ----------
    task : TaskResult
        One of :func:`joint_tasks`.

    Returns
    -------
    str
        ``figures/corner_<model>.png``.
    """
    return f"figures/corner_{task.spec.key.split('__')[0]}.png"


def report_posteriors(result: ReportResult) -> dict[str, Any]:
    """The posteriors the report summarises, read from the comparison's netCDF files.

    Parameters
    ----------
    result : ReportResult

    Returns
    -------
    dict of str to arviz.InferenceData
        Task key -> the saved posterior of each of :func:`joint_tasks`.
    """
    from bayeshyst import diagnostics

    return {task.spec.key: diagnostics.load_netcdf(task.netcdf) for task in joint_tasks(result)}


def report_figures(result: ReportResult, posteriors: Mapping[str, Any]) -> dict[str, Any]:
    """Every figure of ``bayeshyst report`` (and ``bayeshyst demo``).

    Parameters
    ----------
    result : ReportResult
    posteriors : mapping of str to arviz.InferenceData
        From :func:`report_posteriors`.

    Returns
    -------
    dict of str to Figure
        File name relative to the report's folder -> figure: ``figures/data_loops.png``,
        ``figures/model_loops.png`` (every compared model's predicted loop per frequency,
        :func:`~bayeshyst.selection.predictions.predicted_loops`),
        ``figures/corner_<model>.png`` (:func:`corner_figure_name`, for each joint fit
        with the Bouc–Wen shape parameters), ``figures/trace_final.png`` and
        ``figures/corner_final.png`` (the diagnosis' final fit), ``figures/uncertainty.png``
        (its uncertainty budget and calibration check), and each stage's own
        figures under ``compare/``, ``diagnose/`` and ``compensate/``.
    """
    from bayeshyst import diagnostics, plotting
    from bayeshyst.selection.predictions import predicted_loops

    out: dict[str, Any] = {"figures/data_loops.png": plotting.data_overview_figure(result.data)}
    loops = predicted_loops(result.comparison, result.data, seed=result.seed)
    if loops:
        units = dict(result.data[0].units)
        out["figures/model_loops.png"] = plotting.model_loops_figure(
            loops, u_unit=str(units.get("u", "")), y_unit=str(units.get("y", "")))
    for task in joint_tasks(result):
        idata = posteriors[task.spec.key]
        if not set(BOUC_WEN_CORNER) <= set(idata.posterior.data_vars):
            continue
        draws = {k: np.asarray(idata.posterior[k].values).ravel() for k in BOUC_WEN_CORNER}
        units = {k: str(idata.posterior[k].attrs.get("unit", "")) for k in BOUC_WEN_CORNER}
        converged = diagnostics.sampling_report(idata)["converged"]
        title = (f"{task.spec.model}, all frequencies: posterior of α, β, γ, n "
                 f"({draws['alpha'].size} saved draws; "
                 f"{'converged' if converged else 'NOT CONVERGED'})")
        out[corner_figure_name(task)] = plotting.draws_corner_figure(draws, units=units,
                                                                      title=title)
    if result.final_fit is not None and result.final_fit.budget:
        y_unit = str(dict(result.data[0].units).get("y", ""))
        out["figures/uncertainty.png"] = plotting.uncertainty_figure(
            result.final_fit.budget, result.calibration, y_unit=y_unit)
    if result.diagnosis is not None:
        fit = result.diagnosis.final
        out["figures/trace_final.png"] = plotting.trace_figure(fit.sampling)
        out["figures/corner_final.png"] = plotting.corner_figure(fit.sampling,
                                                                 max_params=CORNER_MAX)
    stages = [("compare", comparison_figures(result.comparison))]
    if result.diagnosis is not None:
        stages.append(("diagnose", diagnosis_figures(result.diagnosis)))
    if result.compensation is not None:
        stages.append(("compensate", compensation_figures(result.compensation,
                                                          fit=result.final_fit)))
    for folder, figs in stages:
        out.update({f"{folder}/{name}": fig for name, fig in figs.items()})
    return out
