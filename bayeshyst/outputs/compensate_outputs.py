"""What ``bayeshyst compensate`` writes: summary, tables, curves, figure and posterior.

The files are ``summary.json``, ``compensation.csv``, ``compensation.txt``,
``curves.npz``, the figure ``compensate.png`` and, given the fit behind the design, its
posterior ``posterior.nc``.

Every file is written atomically, and ``summary.json`` last: a run that fails half-way
leaves no summary that claims outputs which do not exist. The resumable sampler
checkpoint (``checkpoint.h5``) is written by the fit itself. The writer only writes: the
fit's InferenceData and the figure
(:func:`~bayeshyst.outputs.assemble.compensation_figures`) come from the caller.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.inference.fit import FitResult
from bayeshyst.inverse.compensate import CompensationResult, CompensationRow
from bayeshyst.outputs.files import csv_cell, write_figures, write_json

__all__ = ["COMMANDS", "CSV_COLUMNS", "compensation_summary", "curve_prefix",
           "write_compensation_outputs", "written_files"]

#: The four commands of every row, in the order they are reported.
COMMANDS = ("uncompensated", "nominal", "posterior", "robust")

CSV_COLUMNS = ("frequency_hz", "reference",
               *(f"{c}_{m}_percent" for c in COMMANDS for m in ("nrmse", "max")),
               "band_lo_percent", "band_hi_percent", "nominal_band_lo_percent",
               "nominal_band_hi_percent", "parameter_band_lo_percent",
               "parameter_band_hi_percent", "model_band_lo_percent", "model_band_hi_percent",
               "residual_rms_percent", "realised_inside_band", "output_coverage",
               "plants_inside_band",
               *(f"mean_over_plants_{c}_nrmse_percent" for c in COMMANDS),
               "n_saturated", "model_error_percent")


def curve_prefix(row: CompensationRow) -> str:
    """Key prefix of a row's arrays in ``curves.npz``: ``f10Hz`` or ``reference``."""
    if row.frequency_hz is None:
        return "reference"
    return re.sub(r"[^0-9A-Za-z.+-]", "_", f"f{row.frequency_hz:g}Hz")


def _warnings(result: CompensationResult, fit: FitResult | None) -> list[str]:
    out = []
    if not result.converged:
        reasons = ""
        if fit is not None and fit.sampling.convergence.reasons:
            reasons = ": " + "; ".join(fit.sampling.convergence.reasons)
        out.append(f"the fit behind the design did NOT converge{reasons}. The commands and "
                   "the predicted bands are not reliable (raise --steps)")
    if result.plant_kind != "virtual actuator":
        out.append("no ground truth in the data: the commands were run on held-out posterior "
                   "draws, which measures how the model's uncertainty propagates, not how "
                   "well the model fits the actuator")
    return out


def compensation_summary(result: CompensationResult, *, fit: FitResult | None = None,
                         data_path: str | None = None,
                         files: dict[str, Any] | None = None) -> dict[str, Any]:
    """The machine-readable summary of a compensation run.

    Keys: ``command`` (``"compensate"``), ``model``, ``plant``, ``plant_kind``,
    ``converged``, ``per_frequency`` (each ``frequency_hz``, ``reference``,
    ``<command>_nrmse_percent`` and ``<command>_max_percent`` for the commands
    uncompensated / nominal / posterior / robust, ``predicted_band_percent``
    ``[lo, hi]``, ``realised_inside_band``, ``output_coverage``, ...), ``statements``,
    ``settings``, ``output_unit``, ``fit`` (the posterior's convergence, when given),
    ``data``, ``files``, ``warnings``. Non-finite numbers are written as ``null``.
    """
    out: dict[str, Any] = {"command": "compensate", **result.to_dict()}
    out["output_unit"] = fit.posterior.data[0].units.get("y", "") if fit is not None else None
    if fit is not None:
        s = fit.sampling
        c = s.convergence
        out["fit"] = {"likelihood": s.likelihood, "converged": c.converged,
                      "convergence_reasons": list(c.reasons), "rhat_max": c.rhat_max,
                      "ess_min": c.ess_bulk_min, "n_steps": c.n_steps,
                      "move_acceptance": dict(s.move_acceptance),
                      "nrmse_percent": fit.overall.nrmse_percent, "runtime_s": s.runtime_s,
                      "seed": s.seed}
    else:
        out["fit"] = None
    out["data"] = data_path
    out["files"] = files or {}
    out["warnings"] = _warnings(result, fit)
    return out


def _csv_text(result: CompensationResult) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in result.rows:
        d = row.to_dict()
        d["band_lo_percent"], d["band_hi_percent"] = row.predicted_band_percent
        d["nominal_band_lo_percent"], d["nominal_band_hi_percent"] = (
            row.nominal_predicted_band_percent)
        d["parameter_band_lo_percent"], d["parameter_band_hi_percent"] = (
            row.parameter_band_percent)
        d["model_band_lo_percent"], d["model_band_hi_percent"] = row.model_band_percent
        for c in COMMANDS:
            d[f"mean_over_plants_{c}_nrmse_percent"] = (
                None if row.mean_over_plants is None else row.mean_over_plants.get(c))
        writer.writerow([csv_cell(d[c]) for c in CSV_COLUMNS])
    return buf.getvalue()


def _curves(result: CompensationResult) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {}
    prefixes = []
    for row in result.rows:
        prefix = curve_prefix(row)
        prefixes.append(prefix)
        for key, value in row.curves.items():
            arrays[f"{prefix}_{key}"] = np.asarray(value)
    arrays["prefixes"] = np.array(prefixes, dtype=str)
    arrays["frequency_hz"] = np.array([np.nan if r.frequency_hz is None else r.frequency_hz
                                       for r in result.rows], dtype=float)
    return arrays


def write_compensation_outputs(result: CompensationResult, out_dir: str | Path, *,
                               fit: FitResult | None = None, idata: Any = None,
                               posterior: str | None = None,
                               figures: Mapping[str, Any] | None = None,
                               data_path: str | None = None) -> dict[str, Any]:
    """Write the compensation's files into ``out_dir`` (each atomically, ``summary.json`` last).

    The files: ``compensation.csv``, ``compensation.txt``, ``curves.npz``,
    ``posterior.nc`` when ``idata`` is given, the figures, ``summary.json``.

    Parameters
    ----------
    result : CompensationResult
    out_dir : path-like
        Created if needed.
    fit : FitResult, optional
        The posterior the commands were designed from: summarised under ``fit`` in the
        summary.
    idata : arviz.InferenceData, optional
        ``fit`` as :func:`bayeshyst.diagnostics.to_inference_data` gives it: written as
        ``posterior.nc`` (as ``bayeshyst fit`` writes it).
    posterior : str, optional
        Where ``fit``'s posterior is already saved (a path relative to ``out_dir``'s
        parent, e.g. ``"../diagnose/posterior_final.nc"``): recorded instead of writing
        it a second time. Not together with ``idata``.
    figures : mapping of str to Figure, optional
        PNG file name -> figure
        (:func:`~bayeshyst.outputs.assemble.compensation_figures`); none by default.
    data_path : str, optional
        Recorded in the summary.

    Returns
    -------
    dict
        The summary written to ``summary.json`` (:func:`compensation_summary`), before
        JSON encoding (print it with :func:`bayeshyst.files.json_text`).

    Raises
    ------
    ParameterError
        Both ``idata`` and ``posterior`` given (nothing is written).
    """
    if idata is not None and posterior is not None:
        raise ParameterError("give the posterior to write (idata) or where it is saved "
                             "(posterior), not both")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Any] = {"table": "compensation.csv", "text": "compensation.txt",
                             "curves": "curves.npz", "posterior": posterior, "figures": []}
    with atomic_path(out / "compensation.csv") as tmp:
        tmp.write_text(_csv_text(result))
    with atomic_path(out / "compensation.txt") as tmp:
        tmp.write_text(str(result) + "\n")
    # through a file handle: given a name, numpy would append ".npz" to the temporary file
    with atomic_path(out / "curves.npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **_curves(result))
    if idata is not None:
        from bayeshyst import diagnostics

        diagnostics.save_netcdf(idata, out / "posterior.nc")
        files["posterior"] = "posterior.nc"
    files["figures"] = write_figures(out, figures)
    summary = compensation_summary(result, fit=fit, data_path=data_path, files=files)
    write_json(out / "summary.json", summary)
    return summary


def written_files(summary: dict[str, Any]) -> list[str]:
    """The files :func:`write_compensation_outputs` wrote, from the summary it returned.

    In the order written (``summary.json`` last); a posterior saved elsewhere is not
    among them.
    """
    f = summary["files"]
    saved_here = f["posterior"] == "posterior.nc"
    return [f["table"], f["text"], f["curves"], *(["posterior.nc"] if saved_here else []),
            *f["figures"], "summary.json"]
