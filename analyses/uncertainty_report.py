"""Uncertainty-analysis report of one hysteresis model of a nanopositioner.

Answers the questions an engineer's uncertainty report has to answer beyond "the fit":
*how sure are we of each parameter* (90 % highest-density intervals), *how wide is the
band the model predicts the displacement in* (the 90 % posterior-predictive band --
parameter draws from the posterior plus the likelihood's noise -- in % of the stroke,
per excitation frequency) and *does that band hold what was measured* (its coverage:
the fraction of measured samples inside it, ideally about 0.9). A band that covers far
less than 90 % says that the model misses structure its noise model does not absorb;
a sampler that did not converge makes every number provisional, and the report says
so at its top.

The fit is :func:`bayeshyst.inference.fit.fit_model`; ``fit/`` holds what ``bayeshyst
fit`` writes (:func:`bayeshyst.outputs.write_fit_outputs`: ``summary.json``,
``posterior.nc``, figures). The band and its coverage are computed from the
``posterior_predictive`` group of ``fit/posterior.nc`` (scored samples only: warm-up
excluded), so anyone can recompute them from that file. The parameter-only (credible)
band of the noise-free prediction is given next to it, which splits the width into
parameter uncertainty and noise.

Outputs in ``--out``: ``coverage.csv`` (one row per frequency and an ``all`` row),
``parameters.csv`` (mean, sd, 90 % HDI per parameter), ``uncertainty.txt`` (the report),
``bands.png`` and ``summary.json`` (written last).

Run (from the repository root)::

    python -m analyses.uncertainty_report                  # full: bouc_wen, bundled data,
                                                           # all 5 frequencies, <= 20 000 steps
    python -m analyses.uncertainty_report --quick          # seconds: 2 frequencies, 200 steps
    python -m analyses.uncertainty_report --data my.csv --model "pi_play+second_order" \\
        --likelihood ar1 --out report-pi

Full mode samples to convergence (or 20 000 steps per ensemble, checkpointed in
``fit/checkpoint.h5`` so that an interrupted run resumes); quick mode (``--quick``)
fits the lowest and highest frequency with 200 steps and no fit figures -- its numbers
are NOT converged and its outputs say so.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from analyses._common import (
    DEFAULT_DATA,
    EXIT_OK,
    Progress,
    base_parser,
    budget,
    float_list,
    new_figure,
    positive_int,
    run,
    save_figure,
    select_frequencies,
    write_csv,
    write_text,
)
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.files import write_json

PROG = "uncertainty_report"
#: Central probability of the predictive band and of the parameter intervals.
BAND = 0.9
#: Coverage within this distance of BAND counts as "near nominal".
COVERAGE_TOLERANCE = 0.05
#: Posterior draws of the parameter-only (noise-free) credible band.
N_CREDIBLE_DRAWS = 200

COVERAGE_COLUMNS = ("frequency_hz", "n_scored", "stroke", "coverage", "band_width_mean",
                    "band_width_percent", "credible_width_percent", "nrmse_percent",
                    "max_error_percent", "verdict")
PARAMETER_COLUMNS = ("parameter", "unit", "mean", "sd", "hdi_low", "hdi_high",
                     "hdi_width_percent_of_mean")

FULL = {"sampler": SamplerSettings(max_steps=20_000)}
QUICK = {"sampler": SamplerSettings(max_steps=200, first_chunk=200)}


def build_parser() -> argparse.ArgumentParser:
    """Options of the uncertainty report."""
    p = base_parser(PROG, __doc__)
    p.add_argument("--data", default=str(DEFAULT_DATA),
                   help="data file (.csv/.npz/.mat, JSON sidecar optional; default the "
                        "bundled data/virtual_multifreq.csv)")
    p.add_argument("--model", default="bouc_wen",
                   help="model name or spec string (default bouc_wen)")
    p.add_argument("--likelihood", default="gaussian",
                   help="gaussian (default), student_t or ar1")
    p.add_argument("--frequencies", type=float_list, default=None, metavar="F1,F2,...",
                   help="only the records at these frequencies [Hz] (default all; with "
                        "--quick the lowest and the highest)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="step budget per ensemble (default 20000; --quick 200)")
    p.add_argument("--walkers", type=positive_int, default=None,
                   help="walkers per ensemble (default: from the number of parameters)")
    p.add_argument("--no-checkpoint", action="store_true",
                   help="do not checkpoint the sampler to OUT/fit/checkpoint.h5")
    return p


# ------------------------------------------------------------------------- numbers
def predictive_band(idata: Any, prob: float = BAND) -> dict[str, np.ndarray]:
    """The central ``prob`` posterior-predictive band of every observation.

    Parameters
    ----------
    idata : arviz.InferenceData
        As written to ``posterior.nc`` (:func:`bayeshyst.diagnostics.to_inference_data`).
    prob : float

    Returns
    -------
    dict
        ``lo``, ``hi`` (quantiles ``(1 -+ prob) / 2`` over the predictive draws without
        a failed simulation), ``y`` (observed), ``record`` (index), ``scored`` (bool),
        all shape (n_obs,), and ``n_draws``.
    """
    pp = np.asarray(idata.posterior_predictive["y"].values, dtype=float)
    draws = pp.reshape(-1, pp.shape[-1])
    draws = draws[np.all(np.isfinite(draws), axis=1)]
    if draws.shape[0] < 2:
        raise ValueError("fewer than two posterior-predictive draws without a failed "
                         "simulation: no band can be computed")
    lo, hi = np.quantile(draws, [(1 - prob) / 2, (1 + prob) / 2], axis=0)
    const = idata.constant_data
    return {"lo": lo, "hi": hi, "y": np.asarray(idata.observed_data["y"].values, dtype=float),
            "record": np.asarray(const["record"].values, dtype=int),
            "scored": np.asarray(const["scored"].values, dtype=bool),
            "n_draws": int(draws.shape[0])}


def _label(f: Any) -> str:
    """A row's frequency for reading: ``"10 Hz"``, ``"all"`` or ``"unknown"``."""
    if f == "all":
        return "all"
    return "unknown" if f is None else f"{f:g} Hz"


def _verdict(coverage: float) -> str:
    if not math.isfinite(coverage):
        return "no scored samples"
    if coverage < BAND - COVERAGE_TOLERANCE:
        return "band too narrow"
    if coverage > BAND + COVERAGE_TOLERANCE:
        return "band conservative"
    return "near nominal"


def coverage_rows(fit: Any, band: dict[str, np.ndarray], credible: list[np.ndarray]
                  ) -> list[dict[str, Any]]:
    """One row per frequency (records grouped by ``frequency_hz``) and an ``all`` row."""
    data = fit.posterior.data
    rec_freq = [r.frequency_hz for r in data]
    errors = {e.frequency_hz: e for e in fit.per_frequency}
    keys = sorted({f for f in rec_freq if f is not None})
    keys += [None] if any(f is None for f in rec_freq) else []
    if band["y"].size != data.n_samples:
        raise RuntimeError(f"posterior.nc holds {band['y'].size} observations, the fitted "
                           f"data {data.n_samples}: not the same fit")
    cred_lo = np.concatenate([c[0] for c in credible])
    cred_hi = np.concatenate([c[1] for c in credible])
    rows = []
    for key in [*keys, "all"]:
        if key == "all":
            idx = list(range(len(data)))
        else:
            idx = [i for i, f in enumerate(rec_freq) if f == key]
        mask = band["scored"] & np.isin(band["record"], idx)
        y, lo, hi = band["y"][mask], band["lo"][mask], band["hi"][mask]
        stroke = float(np.ptp(y)) if y.size else math.nan
        inside = (y >= lo) & (y <= hi)
        coverage = float(np.mean(inside)) if y.size else math.nan
        width = float(np.mean(hi - lo)) if y.size else math.nan
        cwidth = float(np.mean(cred_hi[mask] - cred_lo[mask])) if y.size else math.nan
        err = fit.overall if key == "all" else errors.get(key)
        rows.append({
            "frequency_hz": "all" if key == "all" else key,
            "n_scored": int(y.size), "stroke": stroke, "coverage": coverage,
            "band_width_mean": width,
            "band_width_percent": 100 * width / stroke if stroke else math.nan,
            "credible_width_percent": 100 * cwidth / stroke if stroke else math.nan,
            "nrmse_percent": err.nrmse_percent if err is not None else math.nan,
            "max_error_percent": err.max_error_percent if err is not None else math.nan,
            "verdict": _verdict(coverage),
        })
    return rows


def credible_band(fit: Any, seed: int, prob: float = BAND) -> list[np.ndarray]:
    """Per record, ``(2, n)``: the central ``prob`` band of the noise-free prediction over
    posterior draws (parameter uncertainty alone)."""
    z = fit.sampling.draws(N_CREDIBLE_DRAWS, seed=seed)
    out = []
    for pred in fit.posterior.predict(z):
        ok = pred[np.all(np.isfinite(pred), axis=1)]
        if ok.shape[0] < 2:
            out.append(np.full((2, pred.shape[1]), np.nan))
        else:
            out.append(np.quantile(ok, [(1 - prob) / 2, (1 + prob) / 2], axis=0))
    return out


def parameter_rows(fit: Any) -> list[dict[str, Any]]:
    """Mean, sd and the 90 % HDI of every free scalar parameter (physical units); the
    HDI's width in % of |mean| is left empty when the HDI contains 0 (no relative
    precision to speak of)."""
    rows = []
    for p in fit.sampling.summary(BAND):
        straddles = p.hdi_lo <= 0.0 <= p.hdi_hi
        rel = math.nan if straddles or not p.mean else 100 * (p.hdi_hi - p.hdi_lo) / abs(p.mean)
        rows.append({"parameter": p.label, "unit": p.unit, "mean": p.mean, "sd": p.sd,
                     "hdi_low": p.hdi_lo, "hdi_high": p.hdi_hi,
                     "hdi_width_percent_of_mean": rel})
    return rows


# -------------------------------------------------------------------------- report
def _num(x: Any, spec: str = ".4g") -> str:
    return format(x, spec) if isinstance(x, int | float) and math.isfinite(x) else "n/a"


def report_text(fit: Any, rows: list[dict[str, Any]], params: list[dict[str, Any]],
                data_path: str, quick: bool) -> str:
    """The plain-text report (``uncertainty.txt``)."""
    s = fit.sampling
    c = s.convergence
    data = fit.posterior.data
    unit = data[0].units.get("y", "")
    freqs = ", ".join(f"{f:g}" for f in data.frequencies) or "none given"
    lines = [f"UNCERTAINTY REPORT: {s.model} / {s.likelihood} on {data.name} "
             f"({len(data)} record(s); frequencies [Hz]: {freqs})", f"data: {data_path}"]
    if not c.converged:
        lines += ["", "*" * 78,
                  "*** NOT converged: " + "; ".join(c.reasons),
                  "*** Every band, coverage and interval below is provisional: rerun "
                  + ("without --quick." if quick else "with a larger --steps."),
                  "*" * 78]
    else:
        lines += ["", "sampler converged (R-hat, ESS and 50 tau criteria all hold)"]
    lines += [f"R-hat max {_num(c.rhat_max)}, bulk ESS min {_num(c.ess_bulk_min, '.0f')}, "
              f"tail ESS min {_num(c.ess_tail_min, '.0f')}, {c.n_steps} steps per ensemble, "
              f"{s.counts.failed} failed simulations, {s.runtime_s:.1f} s", ""]
    lines.append(f"Per frequency: the {BAND:.0%} posterior-predictive band (parameter draws "
                 "plus noise) and the fraction of measured samples inside it (coverage, "
                 f"nominal {BAND:g}); widths in % of the measured stroke; 'param only' is the "
                 "band of the noise-free prediction.")
    lines.append(f"{'f':>8} {'coverage':>9} {'width %':>8} {'param only %':>13} "
                 f"{'NRMSE %':>8} {'max %':>7}  verdict")
    for r in rows:
        lines.append(f"{_label(r['frequency_hz']):>8} {_num(r['coverage'], '.3f'):>9} "
                     f"{_num(r['band_width_percent'], '.3f'):>8} "
                     f"{_num(r['credible_width_percent'], '.3f'):>13} "
                     f"{_num(r['nrmse_percent'], '.3f'):>8} "
                     f"{_num(r['max_error_percent'], '.3f'):>7}  {r['verdict']}")
    narrow = [r for r in rows if r["frequency_hz"] != "all" and r["verdict"] == "band too narrow"]
    if narrow:
        lines.append("The band covers less than nominal at "
                     + ", ".join(_label(r["frequency_hz"]) for r in narrow)
                     + ": the model's error there is larger or more structured than its "
                       "noise model allows; `bayeshyst diagnose` tests what it misses.")
    lines += ["", f"Parameters: posterior mean, sd and {BAND:.0%} highest-density interval",
              f"{'parameter':<22} {'mean':>12} {'sd':>11}  {'90 % HDI':<28} {'width/|mean|':>12}"]
    for p in params:
        hdi = f"[{_num(p['hdi_low'], '.5g')}, {_num(p['hdi_high'], '.5g')}] {p['unit']}"
        lines.append(f"{p['parameter']:<22} {_num(p['mean'], '12.5g')} {_num(p['sd'], '11.4g')}"
                     f"  {hdi:<28} {_num(p['hdi_width_percent_of_mean'], '11.1f')}%")
    lines += ["", f"output unit: {unit}; the fit's own outputs (posterior.nc, summary.json, "
              "figures) are in fit/"]
    return "\n".join(lines)


def plot_bands(fit: Any, band: dict[str, np.ndarray], credible: list[np.ndarray],
               rows: list[dict[str, Any]], path: Path) -> Path:
    """Per record (frequency): the measured output, the 90 % predictive band and the
    parameter-only band, each minus the posterior-mean prediction, over the scored
    samples."""
    data = fit.posterior.data
    fig = new_figure(8.0, 1.9 * len(data) + 0.6)
    axes = fig.subplots(len(data), 1, squeeze=False)[:, 0]
    offsets = np.cumsum([0] + [r.n for r in data])
    by_f = {r["frequency_hz"]: r for r in rows}
    unit = data[0].units.get("y", "")
    for i, (ax, rec) in enumerate(zip(axes, data, strict=True)):
        sl = slice(offsets[i] + rec.warmup, offsets[i + 1])
        t = rec.t[rec.warmup:] - rec.t[rec.warmup]
        mid = fit.mean_prediction[i][rec.warmup:]
        ax.fill_between(t, band["lo"][sl] - mid, band["hi"][sl] - mid, color="#9ecae1",
                        label=f"{BAND:.0%} predictive band")
        c = credible[i][:, rec.warmup:]
        ax.fill_between(t, c[0] - mid, c[1] - mid, color="#3182bd", alpha=0.7,
                        label="parameter-only band")
        ax.plot(t, band["y"][sl] - mid, color="k", lw=0.6, label="measured")
        row = by_f.get(rec.frequency_hz)
        title = rec.name if row is None else (
            f"{rec.name} ({_label(rec.frequency_hz)}): coverage "
            f"{_num(row['coverage'], '.2f')}, band {_num(row['band_width_percent'], '.2f')} % "
            "of stroke")
        ax.set_title(title, fontsize=9)
        ax.set_ylabel(f"minus mean [{unit}]", fontsize=8)
    axes[-1].set_xlabel("time after warm-up [s]")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=8)
    conv = fit.sampling.converged
    fig.suptitle(f"{fit.sampling.model}: predictive bands"
                 + ("" if conv else " (NOT converged)"),
                 color="k" if conv else "#c0392b", fontsize=10)
    return save_figure(fig, path)


# ---------------------------------------------------------------------------- main
def _analyse(args: argparse.Namespace) -> int:
    from bayeshyst import diagnostics
    from bayeshyst.data import load
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.likelihoods import get_likelihood
    from bayeshyst.models import get as get_model
    from bayeshyst.outputs import write_fit_outputs
    from bayeshyst.outputs.assemble import fit_figures

    log = Progress(PROG, args.quiet)
    settings = budget(args, QUICK, FULL)
    sampler = settings["sampler"]
    # validate everything cheap before anything is written
    data = load(args.data)
    frequencies = args.frequencies
    if frequencies is None and args.quick and len(data.frequencies) >= 2:
        frequencies = (data.frequencies[0], data.frequencies[-1])
    data = select_frequencies(data, frequencies)
    model = get_model(args.model)
    likelihood = get_likelihood(args.likelihood)
    out = Path(args.out)
    fit_dir = out / "fit"
    log(f"{model.name} / {likelihood.name} on {data.name}: {len(data)} record(s), "
        f"{data.n_samples} samples, frequencies [Hz] "
        f"{', '.join(f'{f:g}' for f in data.frequencies) or 'none'}; budget "
        f"{sampler.max_steps} steps{' (quick)' if args.quick else ''}")
    fit = fit_model(data, model, likelihood, sampler=sampler.replace(
        checkpoint=None if args.no_checkpoint else fit_dir / "checkpoint.h5"))
    conv = "converged" if fit.converged else "NOT converged"
    log(f"fit done ({conv}, {fit.sampling.runtime_s:.1f} s); writing fit/")
    fit_summary = write_fit_outputs(
        fit, fit_dir, data_path=str(args.data),
        idata=diagnostics.to_inference_data(fit.posterior, fit.sampling, seed=args.seed),
        figures=None if args.no_figures or args.quick else fit_figures(fit, seed=args.seed))
    idata = diagnostics.load_netcdf(fit_dir / "posterior.nc")
    band = predictive_band(idata)
    credible = credible_band(fit, args.seed)
    rows = coverage_rows(fit, band, credible)
    params = parameter_rows(fit)
    for r in rows:
        log(f"{_label(r['frequency_hz'])}: coverage {_num(r['coverage'], '.3f')} of the "
            f"{BAND:.0%} predictive band, width {_num(r['band_width_percent'], '.3f')} % of "
            f"stroke ({r['verdict']})")
    write_csv(out / "coverage.csv", COVERAGE_COLUMNS, rows)
    write_csv(out / "parameters.csv", PARAMETER_COLUMNS, params)
    text = report_text(fit, rows, params, str(args.data), args.quick)
    write_text(out / "uncertainty.txt", text)
    figures = []
    if not args.no_figures:
        figures.append(plot_bands(fit, band, credible, rows, out / "bands.png").name)
    warnings = list(fit_summary.get("warnings", []))
    summary = {
        "command": PROG,
        "quick": bool(args.quick),
        "model": fit.sampling.model,
        "likelihood": fit.sampling.likelihood,
        "data": {"path": str(args.data), "name": data.name,
                 "frequencies_hz": list(data.frequencies),
                 "records": [r.name for r in data]},
        "converged": bool(fit.converged),
        "convergence_reasons": list(fit.sampling.convergence.reasons),
        "status": "converged" if fit.converged else "NOT converged",
        "band_probability": BAND,
        "band": ("central posterior-predictive interval (quantiles "
                 f"{(1 - BAND) / 2:g}, {(1 + BAND) / 2:g}) of fit/posterior.nc's "
                 "posterior_predictive draws (parameters plus the likelihood's noise), "
                 "scored samples only"),
        "n_predictive_draws": band["n_draws"],
        "per_frequency": [r for r in rows if r["frequency_hz"] != "all"],
        "overall": next(r for r in rows if r["frequency_hz"] == "all"),
        "parameters": params,
        "settings": {"sampler": sampler.to_dict(), "seed": sampler.seed,
                     "checkpoint": not args.no_checkpoint},
        "files": {"coverage": "coverage.csv", "parameters": "parameters.csv",
                  "report": "uncertainty.txt", "figures": figures,
                  "fit": "fit/summary.json", "posterior": "fit/posterior.nc"},
        "warnings": warnings,
        "runtime_s": round(log.elapsed, 2),
    }
    write_json(out / "summary.json", summary)
    print(text)
    print(f"outputs in {out}/: summary.json, uncertainty.txt, coverage.csv, parameters.csv"
          + "".join(f", {f}" for f in figures) + ", fit/")
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the uncertainty report; return the exit status (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    return run(PROG, _analyse, args)


if __name__ == "__main__":
    sys.exit(main())
