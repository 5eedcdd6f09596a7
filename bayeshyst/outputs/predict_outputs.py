"""What ``bayeshyst predict`` writes: ``predictions.csv``, ``scores.csv``, ``summary.json``.

``predictions.csv`` has one row per sample of every record: ``record``, ``t`` (s), ``u``
(input unit), ``y`` (measured), ``mean``, ``sd`` (the noise-free prediction over draws),
``lo90``, ``lo50``, ``hi50``, ``hi90`` (the predictive bands, noise included), ``pit``
(empty where not scored) and ``scored``. ``scores.csv`` has one row per record, per
frequency or band, and overall; ``spectrum.csv``, for band groups (multisine and
broadband records), the RMS of the error and of the input per octave. The figures are
handed in by the caller (:func:`bayeshyst.outputs.assemble.prediction_figures`). Every
file is written atomically, ``summary.json`` last.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bayeshyst.files import atomic_path
from bayeshyst.inference.predict import PredictionResult
from bayeshyst.outputs.files import (
    jsonable,
    nonfinite_fields,
    write_figures,
    write_json,
    write_rows_csv,
)

__all__ = ["write_predict_outputs"]


def write_predict_outputs(result: PredictionResult, out: str | Path, *, fit_path: str,
                          data_path: str, figures: Mapping[str, Any] | None = None
                          ) -> dict[str, Any]:
    """Write the predictions, the scores, the figures and the summary into ``out``.

    Parameters
    ----------
    result : PredictionResult
    out : path-like
        Created if needed.
    fit_path, data_path : str
        Where the fit and the records were read from (recorded in the summary).
    figures : mapping of str to Figure, optional
        PNG file name -> figure.

    Returns
    -------
    dict
        The summary written to ``summary.json``: ``command``, ``fit``, ``data``, the
        result's :meth:`~bayeshyst.inference.predict.PredictionResult.to_dict`, the
        columns' units and ``files``; a number that is not finite is ``null`` and named
        in ``warnings``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "predictions.csv") as tmp:
        result.predictions_frame().to_csv(tmp, index=False, float_format="%.10g")
    with atomic_path(out / "scores.csv") as tmp:
        result.to_dataframe().to_csv(tmp, index=False, float_format="%.6g")
    files = {"predictions": "predictions.csv", "scores": "scores.csv",
             "figures": write_figures(out, figures), "summary": "summary.json"}
    if result.spectra:
        rows = [{"group": band.label, **row.to_dict()} for band, rows in result.spectra
                for row in rows]
        write_rows_csv(out / "spectrum.csv", ("group", "lo_hz", "hi_hz", "error_rms",
                                              "input_rms", "n_samples"), rows)
        files["spectrum"] = "spectrum.csv"
    u, y = result.units.get("u", ""), result.units.get("y", "")
    body = result.to_dict()
    warnings = list(body.pop("warnings"))
    missing = nonfinite_fields(body)
    if missing:
        warnings.append("not a finite number, written as null: " + ", ".join(missing))
    summary = jsonable({"command": "predict", "fit": fit_path, "data": data_path, **body,
                        "columns": {"t": "s", "u": u, "y": y, "mean": y, "sd": y, "lo90": y,
                                    "lo50": y, "hi50": y, "hi90": y, "pit": "1"},
                        "files": files, "warnings": warnings})
    write_json(out / "summary.json", summary)
    return summary
