"""What ``bayeshyst compensate`` writes: ``summary.json``, ``compensation.csv``,
``compensation.txt``, ``curves.npz``, the figure ``compensate.png`` and, given the fit
behind the design, its posterior ``posterior.nc``.

Every file is written atomically, and ``summary.json`` last: a run that fails half-way
leaves no summary that claims outputs which do not exist. The resumable sampler
checkpoint (``checkpoint.h5``) is written by the fit itself.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.files import atomic_path
from bayeshyst.inference.fit import FitResult
from bayeshyst.inverse.compensate import CompensationResult, CompensationRow
from bayeshyst.report.files import csv_cell, write_json

__all__ = ["COMMANDS", "CSV_COLUMNS", "compensation_summary", "curve_prefix",
           "write_compensation_outputs"]

#: The four commands of every row, in the order they are reported.
COMMANDS = ("uncompensated", "nominal", "posterior", "robust")

CSV_COLUMNS = ("frequency_hz", "reference",
               *(f"{c}_{m}_percent" for c in COMMANDS for m in ("nrmse", "max")),
               "band_lo_percent", "band_hi_percent", "nominal_band_lo_percent",
               "nominal_band_hi_percent", "realised_inside_band", "output_coverage",
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
                               figures: bool = True, fit: FitResult | None = None,
                               data_path: str | None = None,
                               posterior: str | None = None) -> list[Path]:
    """Write the compensation's files into ``out_dir`` (each atomically).

    Parameters
    ----------
    result : CompensationResult
    out_dir : path-like
        Created if needed.
    figures : bool
        Draw ``compensate.png``.
    fit : FitResult, optional
        The posterior the commands were designed from: written as ``posterior.nc``
        (as ``bayeshyst fit`` writes it) and summarised under ``fit`` in the summary.
    data_path : str, optional
        Recorded in the summary.
    posterior : str, optional
        Where ``fit``'s posterior is already saved (a path relative to ``out_dir``'s
        parent, e.g. ``"../diagnose/posterior_final.nc"``): recorded instead of writing
        ``posterior.nc`` a second time.

    Returns
    -------
    list of Path
        The files written, ``summary.json`` last.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    files: dict[str, Any] = {"table": "compensation.csv", "text": "compensation.txt",
                             "curves": "curves.npz", "posterior": None, "figures": []}
    with atomic_path(out / "compensation.csv") as tmp:
        tmp.write_text(_csv_text(result))
    written.append(out / "compensation.csv")
    with atomic_path(out / "compensation.txt") as tmp:
        tmp.write_text(str(result) + "\n")
    written.append(out / "compensation.txt")
    # through a file handle: given a name, numpy would append ".npz" to the temporary file
    with atomic_path(out / "curves.npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **_curves(result))
    written.append(out / "curves.npz")
    if fit is not None and posterior is not None:
        files["posterior"] = posterior
    elif fit is not None:
        from bayeshyst import diagnostics

        idata = diagnostics.to_inference_data(fit.posterior, fit.sampling,
                                              seed=int(result.settings.get("seed", 0)))
        written.append(diagnostics.save_netcdf(idata, out / "posterior.nc"))
        files["posterior"] = "posterior.nc"
    if figures and result.rows:
        from bayeshyst.plotting import plot_compensation

        y_unit = fit.posterior.data[0].units.get("y", "") if fit is not None else ""
        written.append(plot_compensation(result, out / "compensate.png", y_unit=y_unit))
        files["figures"] = ["compensate.png"]
    summary = compensation_summary(result, fit=fit, data_path=data_path, files=files)
    written.append(write_json(out / "summary.json", summary))
    return written
