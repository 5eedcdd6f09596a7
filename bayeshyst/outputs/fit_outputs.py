"""What ``bayeshyst fit`` writes: ``summary.json``, ``posterior.nc`` and the figures.

The writer only writes: the caller hands it the fit's InferenceData (from
:func:`bayeshyst.diagnostics.to_inference_data`, which simulates every kept draw) and
the figures (:func:`bayeshyst.outputs.assemble.fit_figures`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.inference.cv_units import unit_kind
from bayeshyst.inference.fit import FitResult
from bayeshyst.outputs.files import nonfinite_fields, write_figures, write_json

__all__ = ["fit_summary", "write_fit_outputs"]

# |r| above which a posterior correlation is listed: strong enough that the two
# parameters cannot be read separately (Bouc-Wen's alpha/beta/gamma/n ridge)
CORRELATION_REPORT = 0.5


def _correlations(fit: FitResult) -> list[dict[str, Any]]:
    z = fit.sampling.flat_z
    labels = fit.sampling.space.labels
    if z.shape[0] < 3 or z.shape[1] < 2:
        return []
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.corrcoef(z.T)
    out = []
    for i in range(len(labels)):
        for j in range(i + 1, len(labels)):
            if np.isfinite(c[i, j]) and abs(c[i, j]) >= CORRELATION_REPORT:
                out.append({"a": labels[i], "b": labels[j], "r": float(c[i, j])})
    return sorted(out, key=lambda d: -abs(d["r"]))


def fit_summary(fit: FitResult, *, data_path: str | None = None,
                files: dict[str, Any] | None = None) -> dict[str, Any]:
    """The machine-readable summary of a fit (what the report shows, as numbers).

    Keys: ``model``, ``likelihood``, ``converged`` (+ ``convergence_reasons``),
    ``rhat_max``, ``ess_min`` (bulk), ``ess_tail_min``, ``tau_max``, ``n_steps``,
    ``burn``, ``n_evals``, ``n_failed_evals``, ``n_prior_rejected``, ``params`` (label
    -> mean, sd, hdi_5, hdi_95, unit: a 90 % HDI), ``map``, ``correlations``
    (|r| >= 0.5, in the sampler's unconstrained coordinates), ``rmse``,
    ``nrmse_percent``, ``max_error``, ``max_error_percent``, ``per_frequency``,
    ``runtime_s``, ``seed``, ``settings``, ``data`` (each record with its group, its
    excitation and what its leave-one-out units are: ``loo_units``, e.g. "8 time
    blocks"), ``files``, ``warnings``.

    A number that is not finite (an overflow, a statistic the chains cannot give) is
    ``inf``/``nan`` here, ``null`` in ``summary.json``, and named in ``warnings``.
    """
    s = fit.sampling
    c = s.convergence
    params = {p.label: {"mean": p.mean, "sd": p.sd, "hdi_5": p.hdi_lo, "hdi_95": p.hdi_hi,
                        "unit": p.unit} for p in s.summary(0.9)}
    map_theta = {}
    for name, value in s.start.theta.items():
        arr = np.asarray(value, dtype=float)
        labels = s.space[name].labels()
        for lab, v in zip(labels, arr.ravel(), strict=True):
            map_theta[lab] = float(v)
    warnings = []
    if not c.converged:
        warnings.append("the sampler did NOT converge: " + "; ".join(c.reasons)
                        + ". Intervals and errors below are not reliable.")
    if s.counts.failed:
        warnings.append(f"{s.counts.failed} of {s.counts.evaluations} posterior evaluations "
                        "had failed simulations (given zero density)")
    if not s.start.laplace_ok:
        warnings.append("the Hessian at the MAP was not positive definite: the posterior is "
                        "flat or ridge-shaped in some direction")
    warnings.extend(fit.warnings)
    per_f = [{"frequency_hz": e.frequency_hz, "rmse": e.rmse, "nrmse_percent": e.nrmse_percent,
              "max_error": e.max_error, "max_error_percent": e.max_error_percent,
              "n_samples": e.n_samples} for e in fit.per_frequency]
    post = fit.posterior
    summary = {
        "command": "fit",
        "model": s.model,
        "likelihood": s.likelihood,
        "converged": c.converged,
        "convergence_reasons": list(c.reasons),
        "rhat_max": c.rhat_max,
        "ess_min": c.ess_bulk_min,
        "ess_tail_min": c.ess_tail_min,
        "tau_max": c.tau_max,
        "n_steps": c.n_steps,
        "burn": c.burn,
        "n_evals": s.counts.evaluations,
        "n_failed_evals": s.counts.failed,
        "n_prior_rejected": s.counts.prior_rejected,
        "acceptance_mean": float(np.mean(s.acceptance)),
        "move_acceptance": dict(s.move_acceptance),
        "linear_block": list(s.linear_block),
        "params": params,
        "map": map_theta,
        # how the MAP was found: global searches, disagreeing starts, sampler restarts
        "map_notes": list(s.start.notes),
        "correlations": _correlations(fit),
        "rmse": fit.overall.rmse,
        "nrmse_percent": fit.overall.nrmse_percent,
        "max_error": fit.overall.max_error,
        "max_error_percent": fit.overall.max_error_percent,
        "output_unit": post.data[0].units.get("y", ""),
        "per_frequency": per_f,
        "runtime_s": s.runtime_s,
        "seed": s.seed,
        "settings": s.settings,
        "data": {"path": data_path, "name": post.data.name, "records": [
            {"name": r.name, "n": r.n, "fs_hz": r.fs, "frequency_hz": r.frequency_hz,
             "group": r.group, "excitation": r.metadata.get("excitation"),
             "warmup": r.warmup, "units": dict(r.units),
             # what a leave-one-out unit of this record is: cycles, periods, time blocks
             "loo_units": unit_kind(r)} for r in post.data]},
        "files": files or {},
        "discrepancy": (None if post.discrepancy is None else
                        {**post.discrepancy.to_dict(),
                         **({} if fit.discrepancy_scales is None
                            else fit.discrepancy_scales.to_dict())}),
        "uncertainty_budget": [b.to_dict() for b in fit.budget],
        "calibration": None if fit.calibration is None else fit.calibration.to_dict(),
        "warnings": warnings,
    }
    # JSON has no inf or NaN: such a number is written as null, and said so here
    missing = nonfinite_fields({k: v for k, v in summary.items() if k != "warnings"})
    if missing:
        warnings.append("not a finite number, written as null: " + ", ".join(missing))
    return summary


def write_fit_outputs(fit: FitResult, out: str | Path, *, idata: Any,
                      figures: Mapping[str, Any] | None = None,
                      data_path: str | None = None) -> dict[str, Any]:
    """Write ``posterior.nc``, the figures and ``summary.json`` into ``out``.

    Every file is written atomically, and ``summary.json`` last: a run that fails
    half-way leaves no summary that claims outputs which do not exist.

    Parameters
    ----------
    fit : FitResult
    out : path-like
        Created if needed.
    idata : arviz.InferenceData
        The fit as :func:`bayeshyst.diagnostics.to_inference_data` gives it; written as
        ``posterior.nc``.
    figures : mapping of str to Figure, optional
        PNG file name -> figure (:func:`~bayeshyst.outputs.assemble.fit_figures`); none
        by default.
    data_path : str, optional
        The data file, recorded in the summary.

    Returns
    -------
    dict
        The summary written to ``summary.json`` (:func:`fit_summary`), before JSON
        encoding (print it with :func:`bayeshyst.files.json_text`).
    """
    from bayeshyst import diagnostics

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    diagnostics.save_netcdf(idata, out / "posterior.nc")
    files: dict[str, Any] = {"posterior": "posterior.nc",
                             "figures": write_figures(out, figures)}
    summary = fit_summary(fit, data_path=data_path, files=files)
    write_json(out / "summary.json", summary)
    return summary
