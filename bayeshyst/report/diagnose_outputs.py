"""What ``bayeshyst diagnose`` writes: the summary, the steps table, the posteriors of the
base and final models, and the figures."""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path
from typing import Any

from bayeshyst.diagnosis import DiagnosisFit, DiagnosisResult, EffectTest
from bayeshyst.files import atomic_path
from bayeshyst.report.files import csv_cell, write_json

__all__ = ["STEP_COLUMNS", "diagnosis_summary", "evidence_figures", "write_diagnosis_outputs"]

#: Columns of ``steps.csv``, one row per augmentation tried.
STEP_COLUMNS = ("round", "effect", "accepted", "statistic", "statistic_value", "p_value",
                "p_adjusted", "bayes_factor_log", "rmse_before", "rmse_after",
                "max_error_before", "max_error_after", "delta_elpd", "delta_elpd_se",
                "model_before", "model_after")


def _steps_csv(result: DiagnosisResult) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(STEP_COLUMNS)
    for step in result.steps:
        d = step.to_dict()
        writer.writerow([csv_cell(d[c]) for c in STEP_COLUMNS])
    return buf.getvalue()


def _slug(name: str) -> str:
    return re.sub(r"[^0-9A-Za-z_.-]", "_", name)


def evidence_figures(result: DiagnosisResult) -> list[tuple[str, EffectTest]]:
    """``(file name, test)`` of every evidence figure :func:`write_diagnosis_outputs`
    draws: ``evidence_<effect>.png`` for every effect tested on the base model's residual,
    and ``evidence_round<k>_<effect>.png`` for the test behind each step accepted in a
    later round ``k``. Skipped tests have no evidence and no figure."""
    out = [(f"evidence_{_slug(t.effect)}.png", t) for t in result.base.analysis.tests
           if t.skipped is None]
    for step in result.steps:
        if step.accepted and step.index > 1 and step.test.skipped is None:
            out.append((f"evidence_round{step.index}_{_slug(step.effect)}.png", step.test))
    return out


def _y_unit(result: DiagnosisResult) -> str:
    data = result.base.posterior.data
    return data[0].units.get("y", "") if len(data) else ""


def diagnosis_summary(result: DiagnosisResult, *, data_name: str | None = None,
                      outputs: list[str] | None = None) -> dict[str, Any]:
    """The machine-readable summary of a diagnosis.

    :meth:`DiagnosisResult.to_dict` (``base_model``, ``final_model``, ``effects_found``,
    ``steps`` — each with ``effect``, ``statistic``, ``p_value``, ``p_adjusted``,
    ``bayes_factor_log``, ``rmse_before``/``after``, ``max_error_before``/``after``,
    ``delta_elpd``, ``delta_elpd_se``, ... —, ``before``, ``after``, ``per_frequency``,
    ``rounds``, ``cycles``, ``converged``, ``warnings``, ``settings``) plus ``command``
    (``"diagnose"``), ``output_unit``, ``data`` and ``outputs`` (the files written).
    Non-finite numbers become ``null`` when written (:func:`~bayeshyst.report.files.jsonable`).
    """
    out: dict[str, Any] = {"command": "diagnose", **result.to_dict()}
    out["output_unit"] = _y_unit(result)
    out["data"] = data_name
    out["outputs"] = list(outputs or [])
    return out


def _idata(fit: DiagnosisFit, seed: int) -> Any:
    if fit.idata is not None:
        return fit.idata
    from bayeshyst import diagnostics

    return diagnostics.to_inference_data(fit.posterior, fit.sampling, seed=seed)


def write_diagnosis_outputs(result: DiagnosisResult, out_dir: str | Path, *,
                            data_name: str | None = None, figures: bool = True) -> list[Path]:
    """Write the diagnosis's files into ``out_dir`` (each atomically, ``summary.json`` last).

    Files: ``diagnosis.txt`` (the text report), ``steps.csv`` (one row per augmentation
    tried, columns :data:`STEP_COLUMNS`; non-finite numbers empty), ``posterior_base.nc``
    and — when the loop kept an effect — ``posterior_final.nc`` (arviz InferenceData of
    the base and final fits), with ``figures`` ``residuals.png`` (before/after) and the
    evidence figures of :func:`evidence_figures`, then ``summary.json``
    (:func:`diagnosis_summary`).

    Parameters
    ----------
    result : DiagnosisResult
    out_dir : path-like
        Created if needed.
    data_name : str, optional
        The data the diagnosis ran on (a path or name), recorded in the summary.
    figures : bool
        Draw the PNG figures.

    Returns
    -------
    list of Path
        The files written, ``summary.json`` last.
    """
    from bayeshyst import diagnostics

    if not isinstance(result, DiagnosisResult):
        raise TypeError(f"result must be a DiagnosisResult, got {type(result).__name__}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    with atomic_path(out / "diagnosis.txt") as tmp:
        tmp.write_text(str(result) + "\n")
    written.append(out / "diagnosis.txt")
    with atomic_path(out / "steps.csv") as tmp:
        tmp.write_text(_steps_csv(result))
    written.append(out / "steps.csv")
    seed = int(result.settings.seed)
    written.append(diagnostics.save_netcdf(_idata(result.base, seed),
                                           out / "posterior_base.nc"))
    if result.final is not result.base:
        written.append(diagnostics.save_netcdf(_idata(result.final, seed),
                                               out / "posterior_final.nc"))
    if figures:
        from bayeshyst.plotting import plot_diagnosis_residuals, plot_effect_evidence

        written.append(plot_diagnosis_residuals(result, out / "residuals.png"))
        y_unit = _y_unit(result)
        for name, test in evidence_figures(result):
            written.append(plot_effect_evidence(test, out / name, y_unit=y_unit))
    names = [p.name for p in written] + ["summary.json"]
    summary = diagnosis_summary(result, data_name=data_name, outputs=names)
    written.append(write_json(out / "summary.json", summary))
    return written
