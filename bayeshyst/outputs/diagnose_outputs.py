"""What ``bayeshyst diagnose`` writes: the summary, the steps table, posteriors, figures.

The posteriors are those of the base and final models.

The writer only writes: the posteriors are the InferenceData each fit of the diagnosis
carries (:attr:`DiagnosisFit.idata`, made when its leave-one-cycle-out elpd was
computed), the figures are built by the caller
(:func:`~bayeshyst.outputs.assemble.diagnosis_figures`).
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bayeshyst.diagnosis import DiagnosisFit, DiagnosisResult, EffectTest
from bayeshyst.errors import ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.outputs.files import csv_cell, jsonable, write_figures, write_json

__all__ = ["STEP_COLUMNS", "diagnosis_summary", "evidence_figures", "write_diagnosis_outputs"]

#: Columns of ``steps.csv``, one row per augmentation tried.
STEP_COLUMNS = ("round", "effect", "accepted", "statistic", "statistic_value", "p_value",
                "p_adjusted", "bayes_factor_log", "rmse_before", "rmse_after",
                "max_error_before", "max_error_after", "delta_elpd", "delta_elpd_se",
                "model_before", "model_after", "decided_by")


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
    """``(file name, test)`` of every evidence figure of the diagnosis.

    :func:`~bayeshyst.outputs.assemble.diagnosis_figures` builds these:
    ``evidence_<effect>.png`` for every effect tested on the base model's residual, and
    ``evidence_round<k>_<effect>.png`` for the test behind each step accepted in a later
    round ``k``. Tests without evidence arrays (skipped ones, and the candidates the
    driver scan or the spectrum proposed: :attr:`EffectTest.has_evidence`) have none.
    """
    out = [(f"evidence_{_slug(t.effect)}.png", t) for t in result.base.analysis.tests
           if t.has_evidence]
    for step in result.steps:
        if step.accepted and step.index > 1 and step.test.has_evidence:
            out.append((f"evidence_round{step.index}_{_slug(step.effect)}.png", step.test))
    return out


def _y_unit(result: DiagnosisResult) -> str:
    data = result.base.posterior.data
    return data[0].units.get("y", "") if len(data) else ""


def diagnosis_summary(result: DiagnosisResult, *, data_name: str | None = None,
                      outputs: list[str] | None = None,
                      working_rate: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The machine-readable summary of a diagnosis.

    :meth:`DiagnosisResult.to_dict` (``base_model``, ``final_model``, ``effects_found``,
    ``steps`` — each with ``effect``, ``statistic``, ``p_value``, ``p_adjusted``,
    ``bayes_factor_log``, ``rmse_before``/``after``, ``max_error_before``/``after``,
    ``delta_elpd``, ``delta_elpd_se``, ... —, ``before``, ``after``, ``per_frequency``,
    ``rounds``, ``cycles``, ``converged``, ``warnings``, ``settings``) plus ``command``
    (``"diagnose"``), ``output_unit``, ``data``, ``outputs`` (the files written) and
    ``working_rate`` when one is given (as :func:`write_diagnosis_outputs` takes it).
    Non-finite numbers become ``null`` when written (:func:`~bayeshyst.outputs.files.jsonable`).
    """
    out: dict[str, Any] = {"command": "diagnose", **result.to_dict()}
    out["output_unit"] = _y_unit(result)
    out["data"] = data_name
    out["outputs"] = list(outputs or [])
    if working_rate is not None:
        out["working_rate"] = jsonable(dict(working_rate))
    return out


def _idata(fit: DiagnosisFit) -> Any:
    if fit.idata is None:
        raise ParameterError(f"{fit.label}: the fit carries no InferenceData to write (a "
                             "DiagnosisFit made by bayeshyst.diagnosis.diagnose has one)")
    return fit.idata


def write_diagnosis_outputs(result: DiagnosisResult, out_dir: str | Path, *,
                            figures: Mapping[str, Any] | None = None,
                            data_name: str | None = None,
                            working_rate: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write the diagnosis's files into ``out_dir`` (each atomically, ``summary.json`` last).

    Files: ``diagnosis.txt`` (the text report), ``steps.csv`` (one row per augmentation
    tried, columns :data:`STEP_COLUMNS`; non-finite numbers empty), ``posterior_base.nc``
    and — when the loop kept an effect — ``posterior_final.nc`` (the InferenceData the
    base and final fits carry), the ``figures``, then ``summary.json``
    (:func:`diagnosis_summary`, whose ``outputs`` lists every file written).

    Parameters
    ----------
    result : DiagnosisResult
        Its base and final fits carry their InferenceData (``DiagnosisFit.idata``).
    out_dir : path-like
        Created if needed.
    figures : mapping of str to Figure, optional
        PNG file name -> figure
        (:func:`~bayeshyst.outputs.assemble.diagnosis_figures`); none by default.
    data_name : str, optional
        The data the diagnosis ran on (a path or name), recorded in the summary.
    working_rate : mapping, optional
        The rate the records were fitted at
        (:meth:`bayeshyst.data.working_rate.WorkingRate.to_dict`, with the final fit
        scored at full rate under ``full_rate_check`` when a record was decimated:
        :meth:`bayeshyst.inference.predict.FullRateCheck.to_dict`), recorded under the
        summary's ``working_rate``; left out of it by default.

    Returns
    -------
    dict
        The summary written to ``summary.json``, before JSON encoding (print it with
        :func:`bayeshyst.files.json_text`).

    Raises
    ------
    ParameterError
        A fit to be written carries no InferenceData (nothing is written).
    """
    from bayeshyst import diagnostics

    if not isinstance(result, DiagnosisResult):
        raise TypeError(f"result must be a DiagnosisResult, got {type(result).__name__}")
    posteriors = {"posterior_base.nc": _idata(result.base)}
    if result.final is not result.base:
        posteriors["posterior_final.nc"] = _idata(result.final)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "diagnosis.txt") as tmp:
        tmp.write_text(str(result) + "\n")
    with atomic_path(out / "steps.csv") as tmp:
        tmp.write_text(_steps_csv(result))
    for name, idata in posteriors.items():
        diagnostics.save_netcdf(idata, out / name)
    names = ["diagnosis.txt", "steps.csv", *posteriors, *write_figures(out, figures),
             "summary.json"]
    summary = diagnosis_summary(result, data_name=data_name, outputs=names,
                                working_rate=working_rate)
    write_json(out / "summary.json", summary)
    return summary
