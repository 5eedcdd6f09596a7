"""``report.html``: the self-contained page of ``bayeshyst report`` (and ``bayeshyst demo``).

Rendered from the report's ``summary.json`` sections only (what
:func:`~bayeshyst.outputs.report_outputs.write_report_outputs` computes and writes), with
:mod:`bayeshyst.outputs.html`, which escapes every user-provided string (data and record
names, file paths, metadata), shows a missing or non-finite number as an em dash and
embeds the figures: the page needs no network and no neighbouring file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bayeshyst.data.record import frequency_label
from bayeshyst.inverse.averaged import POSTERIOR_WORDS
from bayeshyst.outputs import html as H
from bayeshyst.outputs.assemble import CORNER_MAX
from bayeshyst.outputs.compensate_outputs import COMMANDS
from bayeshyst.outputs.files import jsonable

__all__ = ["convergence_words", "report_html"]

_METADATA_SHOWN = 6  # metadata entries listed per record (the rest are in summary.json)
_INLINE_CHARS = 40  # longer metadata values are named, not shown (they are in summary.json)


# ----------------------------------------------------------------------------- data
def _short(value: Any, limit: int = 120) -> str:
    s = value if isinstance(value, str) else json.dumps(jsonable(value), default=str)
    return s if len(s) <= limit else s[: limit - 1] + "…"


def _working_rate_html(entry: dict[str, Any]) -> H.Markup:
    """What ``--working-rate`` did (:meth:`bayeshyst.data.working_rate.WorkingRate.to_dict`).

    In the entry's own words (its ``statement`` texts), as the command printed them.
    """
    if not entry["changed"]:
        return H.paragraph(f"{entry['statement'][:1].upper()}{entry['statement'][1:]}.")
    changed = [r for r in entry["records"] if r["factor"] > 1]
    kept = len(entry["records"]) - len(changed)
    # the table below shows the records as fitted: say so before it
    return H.join([H.paragraph(
        f"{len(changed)} record(s) sampled faster than the fit needs were anti-aliased and "
        "decimated to a working rate before fitting (the rates and samples below are the "
        "working rate's)" + (f"; the other {kept} were kept whole" if kept else "") + "."),
        *(H.paragraph(f"{r['statement']}.") for r in changed)])


def _data_html(section: dict[str, Any], figure: Path | None,
               working_rate: dict[str, Any] | None = None) -> H.Markup:
    rows = []
    for r in section["records"]:
        meta = r["metadata"] or {}
        # scalars inline; structured entries (a simulator's truth, an excitation) by name
        def inline(v: Any) -> bool:
            return not isinstance(v, dict | list) and len(str(v)) <= _INLINE_CHARS

        scalars = [f"{k}: {v}" for k, v in meta.items() if inline(v)]
        nested = [k for k, v in meta.items() if not inline(v)]
        items = scalars[:_METADATA_SHOWN]
        hidden = len(scalars) - len(items)
        if nested or hidden:
            items.append(f"in summary.json: {', '.join(nested)}"
                         + (f" and {hidden} more" if hidden else ""))
        u, y = H.unit_text(r["units"].get("u", "")), H.unit_text(r["units"].get("y", ""))
        rows.append([r["name"], r["frequency_hz"], r["fs_hz"], r["n"], r["n_scored"],
                     f"{r['u_range'][0]:.4g} … {r['u_range'][1]:.4g} {u}",
                     f"{r['y_range'][0]:.4g} … {r['y_range'][1]:.4g} {y}",
                     H.Markup("<br>".join(H.text(i) for i in items)) if items else "—"])
    parts = [H.paragraph(f"{section['n_records']} record(s), {section['n_samples']} samples; "
                         "excitation frequencies [Hz]: "
                         f"{', '.join(f'{f:g}' for f in section['frequencies_hz']) or 'none'}"
                         f". File: {section['path'] or section['name']}.")]
    estimated = [r for r in section["records"] if "frequency_source" in (r["metadata"] or {})]
    if estimated:
        parts.append(H.paragraph(
            f"The file gave no excitation frequency for {len(estimated)} record(s): their "
            "frequencies were estimated from the input's cycles ("
            + ", ".join(f"{r['name']}: {r['frequency_hz']:g} Hz" for r in estimated[:8])
            + (", …" if len(estimated) > 8 else "") + "); a record holding several "
            "frequencies was split into one record per block."))
    if working_rate is not None:
        parts.append(_working_rate_html(working_rate))
    parts.append(H.table(["record", "frequency [Hz]", "fs [Hz]", "samples", "scored",
                          "input range", "output range", "metadata"], rows,
                         numeric=[False, True, True, True, True, False, False, False]))
    if figure is not None:
        parts.append(H.figure(figure, "Measured loops per excitation frequency (scored part "
                              "in colour, warm-up in grey)."))
    return H.join(parts)


# ----------------------------------------------------------------------- posteriors
def convergence_words(rep: dict[str, Any]) -> str:
    """The convergence verdict of a fit in plain words."""
    if rep.get("converged"):
        return (f"converged: R-hat {rep['rhat_max']:.3f} (≤ 1.01 needed), smallest bulk ESS "
                f"{rep['ess_bulk_min']:.0f}, after {rep['n_steps']} steps per ensemble.")
    reasons = "; ".join(rep.get("convergence_reasons") or []) or "no report saved"
    return ("NOT converged — the intervals below are not reliable; rerun with a larger "
            f"step budget (--steps). Why: {reasons}.")


def _param_table(params: list[dict[str, Any]]) -> H.Markup:
    return H.table(["parameter", "unit", "mean", "sd", "90 % HDI low", "90 % HDI high"],
                   [[p["label"], p["unit"] or "1", p["mean"], p["sd"], p["hdi_5"],
                     p["hdi_95"]] for p in params],
                   numeric=[False, False, True, True, True, True])


def _posteriors_html(section: dict[str, Any], out: Path) -> H.Markup:
    parts = [H.paragraph(
        "Every parametric model fitted to all frequencies jointly: posterior mean, standard "
        "deviation and 90 % highest-density interval of each parameter (from the draws "
        "saved with the fit), and the sampler's convergence verdict (judged on the full "
        "chains: R-hat < 1.01 across walkers and independent ensembles, ESS ≥ 400, ≥ 50 "
        "autocorrelation times).")]
    for e in section["models"]:
        ok = e["sampling"]["converged"]
        parts.append(H.Markup(f"<h3>{H.text(e['model'])} {H.badge(ok)}</h3>"))
        parts.append(H.paragraph(e["verdict"], cls=None if ok else "warn"))
        if e["sampling"].get("failed_simulations"):
            parts.append(H.paragraph(f"{e['sampling']['failed_simulations']} posterior "
                                     "evaluations had failed simulations (zero density).",
                                     cls="warn"))
        parts.append(H.details(f"parameters of {e['model']} ({len(e['params'])})",
                               _param_table(e["params"])))
        if e["corner"]:
            parts.append(H.figure(out / e["corner"], f"{e['model']}: joint posterior of the "
                                  "Bouc–Wen shape parameters α, β, γ, n (90 % HDI shaded on "
                                  "the diagonal; contours hold 50 and 90 % of the draws). "
                                  "A ridge means the data fix a combination, not each one."))
    ch = section.get("chosen")
    if ch:
        parts.append(H.Markup(f"<h3>Model the feedforward uses: {H.text(ch['model'])} "
                              f"{H.badge(ch['converged'])}</h3>"))
        parts.append(H.paragraph(
            "The model the residual diagnosis ended with, sampled on all frequencies. "
            + convergence_words({"converged": ch["converged"], "rhat_max": ch["rhat_max"],
                           "ess_bulk_min": ch["ess_bulk_min"], "n_steps": ch["n_steps"],
                           "convergence_reasons": ch["convergence_reasons"]}),
            cls=None if ch["converged"] else "warn"))
        parts.append(_param_table(ch["params"]))
        if ch["trace"]:
            parts.append(H.details("traces and rank plots of the final model", H.figure(
                out / ch["trace"], "Traces and rank plots of the final model (chains should "
                "overlap; ranks should be uniform).")))
        if ch["corner"]:
            parts.append(H.details("corner plot of the final model", H.figure(
                out / ch["corner"], "Corner plot of the final model (MAP in red; first "
                f"{CORNER_MAX} parameters).")))
    return H.join(parts)


# ------------------------------------------------------------------ model selection
def _selection_html(summary: dict[str, Any], out: Path) -> H.Markup:
    parts = [H.paragraph(
        "Each model fitted to each frequency's records and ranked by PSIS-LOO with one "
        "input cycle as the left-out unit (Δelpd and its paired standard error relative to "
        "the best; a difference under about 2 se is not a difference). elpd LOFO: the "
        "model fitted to all other frequencies, scored on this one (extrapolation across "
        "frequency). NRMSE: posterior-mean tracking error in % of the measured stroke. "
        "Multisine and broadband records are grouped by the band their input covers; "
        "for such a group the chosen model's error spectrum stands in for a "
        "per-frequency error.")]
    for fc in [*summary["per_frequency"], summary["overall"]]:
        label = ("all frequencies jointly" if fc is summary["overall"] else
                 fc["group"] if fc.get("band_hz") is not None else
                 ("unknown frequency" if fc["frequency_hz"] is None
                  else f"{fc['frequency_hz']:g} Hz"))
        rows = []
        for s in fc["ranking"]:
            if s.get("error"):
                rows.append([s["model"], None, None, None, None, None, None, None,
                             H.Markup(f'<span class="badge bad">failed</span> '
                                      f"{H.text(_short(s['error']))}")])
                continue
            rows.append([s["model"], s["elpd_loo"], s["se"], s["delta_elpd"], s["delta_se"],
                         s["weight"], s["elpd_lofo"], s["nrmse_percent"],
                         H.badge(s["converged"], "yes", "NO")])
        parts.append(H.Markup(f"<h3>{H.text(label)}</h3>"))
        parts.append(H.paragraph(fc.get("statement", "")))
        parts.append(H.table(["model", "elpd LOO", "se", "Δelpd", "Δ se", "stacking weight",
                              "elpd LOFO", "NRMSE %", "converged"], rows,
                             numeric=[False, True, True, True, True, True, True, True, False],
                             formats=[None, ".1f", ".1f", ".1f", ".1f", ".2f", ".1f", ".3f",
                                      None]))
        if fc.get("band_hz") is not None:
            parts.append(_spectrum_html(fc.get("error_spectrum")))
    fig = out / "figures" / "model_loops.png"
    if fig.is_file():
        parts.append(H.figure(fig, "Each compared model's predicted loop (posterior mean) "
                                   "over the measured one per frequency, with the 90 % "
                                   "band of the first-ranked parametric model, and their "
                                   "errors against time."))
    fig = out / "compare" / "compare.png"
    if fig.is_file():
        parts.append(H.figure(fig, "elpd and tracking error of every model against "
                                   "excitation frequency."))
    return H.join(parts)


def _spectrum_html(spectrum: dict[str, Any] | None) -> H.Markup:
    """A band group's error spectrum (its records have no frequency to tabulate by)."""
    if not spectrum:
        return H.paragraph("No error spectrum: the chosen model's fit to this band failed "
                           "or did not run.", cls="warn")
    y, u = H.unit_text(spectrum.get("y_unit", "")), H.unit_text(spectrum.get("u_unit", ""))
    rows = [[f"{b['lo_hz']:.3g}–{b['hi_hz']:.3g}", b["error_rms"], b["input_rms"]]
            for b in spectrum["bands"]]
    return H.table(["octave [Hz]", f"error RMS [{y}]", f"input RMS [{u}]"], rows,
                   numeric=[False, True, True], formats=[None, ".4g", ".4g"],
                   caption=f"Error spectrum of {spectrum['model']}: RMS of measured minus "
                           "posterior-mean prediction per octave, from the band's lower "
                           "edge to Nyquist, beside the input's (periodogram)")


# ------------------------------------------------------------------------ diagnosis
def _diagnosis_html(summary: dict[str, Any] | None, out: Path,
                    evidence: list[str]) -> H.Markup:
    if summary is None:
        return H.paragraph("No parametric model fitted, so nothing was diagnosed.", cls="warn")
    found = summary["effects_found"]
    b, a = summary["before"], summary["after"]
    unit = H.unit_text(summary.get("output_unit") or "")
    parts = [H.paragraph(
        f"The residual of {summary['base_model']} was tested for the structure each missing "
        "effect would leave (score tests on the fit's own sensitivities, AR-whitened, Holm "
        "over effects); a fired effect was added and kept only when the held-out elpd "
        "improved by more than "
        f"{summary['settings'].get('threshold', 2):g} paired standard errors.")]
    if found:
        parts.append(H.paragraph(
            f"Effects found, in the order added: {', '.join(found)}. Final model: "
            f"{summary['final_model']}. RMSE {b['rmse']:.4g} → {a['rmse']:.4g} {unit}; max "
            f"error {b['max_error']:.4g} → {a['max_error']:.4g} {unit}."))
    else:
        parts.append(H.paragraph(f"No effect was added. RMSE {b['rmse']:.4g} {unit}."))
    if summary.get("verdict"):
        parts.append(H.paragraph(f"Verdict: {summary['verdict']}."))
    parts += _remaining_html(summary.get("remaining"))
    rows = [[s["round"], s["effect"], s.get("bayes_factor_log"), s.get("p_adjusted"),
             s.get("delta_elpd"), s.get("delta_elpd_se"), s.get("rmse_before"),
             s.get("rmse_after"),
             H.badge(None if s.get("outcome") == "not decided" else s["accepted"], "kept",
                     "rejected", "not decided"),
             s.get("reason") or ""] for s in summary["steps"]]
    if rows:
        parts.append(H.table(["round", "effect", "log BF", "p (Holm)", "Δelpd", "se",
                              f"RMSE before [{unit}]", f"RMSE after [{unit}]", "decision",
                              "why"], rows,
                             numeric=[True, False, True, True, True, True, True, True, False,
                                      False]))
    parts.append(H.table(
        ["frequency [Hz]", f"RMSE before [{unit}]", f"RMSE after [{unit}]",
         "NRMSE % before", "NRMSE % after", "max % before", "max % after"],
        [[p["frequency_hz"], p["before"]["rmse"], p["after"]["rmse"],
          p["before"]["nrmse_percent"], p["after"]["nrmse_percent"],
          p["before"]["max_error_percent"], p["after"]["max_error_percent"]]
         for p in summary["per_frequency"] if p["frequency_hz"] is not None],
        caption="Tracking error of the posterior mean, before and after"))
    for w in summary.get("warnings", []):
        parts.append(H.paragraph(w, cls="warn"))
    fig = out / "diagnose" / "residuals.png"
    if fig.is_file():
        parts.append(H.figure(fig, "Residual of the base model and of the final model."))
    for name in evidence:
        parts.append(H.figure(out / "diagnose" / name,
                              f"Evidence behind the test of {name[9:-4].replace('_', ' ')}."))
    return H.join(parts)


def _remaining_html(remaining: dict[str, Any] | None) -> list[H.Markup]:
    """What the final residual still depends on: the driver scan's table and the lines."""
    if not remaining or remaining.get("drivers") is None:
        return []
    scan = remaining["drivers"]
    rows = [[d["driver"], d["gain_percent"], d["conditional_percent"], d["p_value"],
             H.badge(d["selected"], "relevant", "—"), ", ".join(d["tied_with"]),
             d["reading"]] for d in scan["drivers"][:8]]
    parts = [H.paragraph(
        "What the final residual still depends on, among everything the data record "
        "(every extra column of the file, the loop position, rates, times since reversals, "
        "time, frequency): held-out share of its variance each driver explains, with a "
        "threshold calibrated by randomly flipping the sign of whole cycles "
        f"({scan['n_permutations']} patterns, family-wise level {scan['alpha']:g}). "
        f"{scan['summary'].capitalize()}."),
        H.table(["driver", "held-out gain alone [%]", "given kept [%]", "p", "decision",
                 "tied with", "what it would mean"], rows,
                numeric=[False, True, True, True, False, False, False],
                caption="Open-world driver scan of the final residual")]
    lines = remaining.get("lines") or []
    if lines:
        parts.append(H.table(
            ["record", "frequency [Hz]", "amplitude", "share of residual variance [%]", "p"],
            [[x["record"], x["frequency_hz"], x["amplitude"], x["share_percent"],
              x["p_value"]] for x in lines],
            numeric=[False, True, True, True, True],
            caption="Lines in the final residual's spectrum that are no harmonic of the "
                    "excitation"))
    return parts


# ---------------------------------------------------------------------- uncertainty
def _uncertainty_sentence(row: dict[str, Any], y_unit: str) -> str:
    """One plain sentence per frequency: calibrated or not, the budget, what dominates."""
    where = frequency_label(row["frequency_hz"])
    sh = row["shares"]
    budget = (f"predictive sd {row['predictive_sd']:.3g} {y_unit}: noise "
              f"{100 * sh['noise']:.0f} %, parameters {100 * sh['parameters']:.0f} %, "
              f"discrepancy {100 * sh['discrepancy']:.0f} % of the variance, dominated by "
              f"{row['dominant']}")
    c = row.get("calibration")
    if c is None:
        verdict = "calibration not checked"
    else:
        lo, hi = c["expected_90"]
        verdict = (f"{'calibrated' if c['calibrated'] else 'NOT calibrated'} (the 90 % band "
                   f"held {100 * c['coverage_90']:.0f} % of the held-out samples; a "
                   f"calibrated predictive holds {100 * lo:.0f}-{100 * hi:.0f} %)")
    return f"At {where}: {verdict}; {budget}."


def _uncertainty_html(section: dict[str, Any] | None, out: Path) -> H.Markup:
    if section is None:
        return H.paragraph("No parametric model fitted, so there is no predictive to "
                           "analyse.", cls="warn")
    unit = section["y_unit"]
    parts = [H.paragraph(
        f"The predictive of {section['model']} (the diagnosis' final model"
        f"{', with a model discrepancy' if section['discrepancy'] else ''}): is it "
        "calibrated on cycles it was not fitted to (the last cycle of every record held "
        "out, the posterior re-sampled without them), and where does its uncertainty come "
        "from (sensor noise, parameters, model discrepancy)?")]
    if not section["checked"]:
        parts.append(H.paragraph("The calibration check was not run (--no-calibration).",
                                 cls="warn"))
    elif not section["refit_converged"]:
        parts.append(H.paragraph("The posterior without the held-out cycles did not converge: "
                                 "the calibration verdicts are indicative.", cls="warn"))
    for row in section["per_frequency"]:
        bad = row.get("calibration") is not None and not row["calibration"]["calibrated"]
        parts.append(H.paragraph(_uncertainty_sentence(row, unit), cls="warn" if bad else None))
    table = []
    for row in section["per_frequency"]:
        c = row.get("calibration") or {}
        sh = row["shares"]
        table.append([row["frequency_hz"],
                      H.badge(c.get("calibrated"), "yes", "no") if c else "not checked",
                      None if not c else 100 * c["coverage_50"],
                      None if not c else f"{100 * c['expected_50'][0]:.0f}-"
                                         f"{100 * c['expected_50'][1]:.0f}",
                      None if not c else 100 * c["coverage_90"],
                      None if not c else f"{100 * c['expected_90'][0]:.0f}-"
                                         f"{100 * c['expected_90'][1]:.0f}",
                      row["predictive_sd"], 100 * sh["noise"], 100 * sh["parameters"],
                      100 * sh["discrepancy"], row["dominant"]])
    parts.append(H.table(
        ["frequency [Hz]", "calibrated", "50 % band held %", "expected %",
         "90 % band held %", "expected %", f"predictive sd [{unit}]", "noise %",
         "parameters %", "discrepancy %", "dominant"], table,
        numeric=[True, False, True, False, True, False, True, True, True, True, False]))
    fig = out / "figures" / "uncertainty.png"
    if fig.is_file():
        parts.append(H.figure(fig, "Left: the predictive variance by source per frequency. "
                                   "Right: PIT histograms of the held-out cycles (flat at "
                                   "0.1 when calibrated)."))
    if section["tracking_band"]:
        rows = []
        for r in section["tracking_band"]:
            rows.append([r["frequency_hz"], _range(r.get("parameter_band_percent")),
                         _range(r.get("model_band_percent")), _range(r["band_percent"]),
                         r.get("residual_rms_percent"), r["realised_percent"],
                         H.badge(r["inside"], "yes", "no")])
        parts.append(H.paragraph(
            "The feedforward tracking band's budget (90 % range of the posterior command's "
            "NRMSE over held-out draws, % of the reference's stroke): from the parameters "
            "alone, with the discrepancy" + ("" if section["discrepancy"] else
                                              " (none in this fit: the same)")
            + ", and with the fit's residual resampled onto the command -- sensor noise and "
            "whatever the model leaves unexplained -- which is the band a measurement is "
            "compared with. What it cannot hold: error that only shows on paths the "
            "identification data never drove (minor loops of a narrower command)."))
        parts.append(H.table(["frequency [Hz]", "parameters %", "+ discrepancy %",
                              "+ residual: the band %", "residual RMS %", "realised %",
                              "inside"], rows,
                             numeric=[True, False, False, False, True, True, False]))
    return H.join(parts)


def _range(pair: Any) -> str:
    """``"[lo, hi]"`` of a band, an en dash without one."""
    if not pair or any(v is None for v in pair):
        return "\u2013"
    return f"[{pair[0]:.3g}, {pair[1]:.3g}]"


# --------------------------------------------------------------------- compensation
def _compensation_html(summary: dict[str, Any] | None, out: Path) -> H.Markup:
    if summary is None:
        return H.paragraph("No parametric model fitted, so no feedforward was designed.",
                           cls="warn")
    parts = [H.paragraph(
        f"Feedforward commands designed from the posterior of {summary['model']} and run on "
        f"{summary['plant']}. nominal: inverse of the MAP model; posterior: minimises the "
        "error averaged over posterior draws; robust: minimises the "
        f"{summary['settings'].get('robust_quantile', 0.9):.0%} quantile of the error over "
        "draws. The band is the predicted 90 % range of the robust command's error "
        "(from held-out draws); 'inside' says whether the realised error fell in it.")]
    rows = []
    for r in summary["per_frequency"]:
        band = r.get("predicted_band_percent") or [None, None]
        rows.append([r["frequency_hz"], r["reference"],
                     *[r.get(f"{c}_nrmse_percent") for c in COMMANDS],
                     r.get("robust_max_percent"), band[0], band[1],
                     H.badge(r.get("realised_inside_band"), "yes", "no")])
    parts.append(H.table(["frequency [Hz]", "reference",
                          *[f"{c} NRMSE %" for c in COMMANDS], "robust max %",
                          "band low %", "band high %", "inside band"], rows,
                         numeric=[True, False, True, True, True, True, True, True, True,
                                  False]))
    for s in summary.get("statements", []):
        parts.append(H.paragraph(s))
    for w in summary.get("warnings", []):
        parts.append(H.paragraph(w, cls="warn"))
    fig = out / "compensate" / "compensate.png"
    if fig.is_file():
        parts.append(H.figure(fig, "Tracking with each command per frequency, with the "
                                   "predicted band."))
    return H.join(parts)


def _averaged_html(section: dict[str, Any] | None) -> H.Markup:
    if section is None:
        return H.join([])
    parts = [H.Markup("<h3>Model-averaged design</h3>"), H.paragraph(
        "Per frequency, one command designed over the parametric models that frequency's "
        "comparison keeps, each at its stacking weight (" + POSTERIOR_WORDS.get(
            section.get("posteriors", ""), "") + "), run on " + section["plant"] + "; "
        "next to it, the heaviest model's own posterior-mean command on the same plant. "
        "The band is the mixture's predicted 90 % range of the averaged command's error.")]
    rows = []
    for r in section["per_frequency"]:
        band = r.get("predicted_band_percent") or [None, None]
        used = ", ".join(f"{m} ({w:.2f})" for m, w in zip(r["models"], r["weights"],
                                                          strict=True))
        rows.append([r["frequency_hz"], used, r.get("averaged_nrmse_percent"),
                     r.get("robust_nrmse_percent"), r.get("single_model"),
                     r.get("single_nrmse_percent"), band[0], band[1],
                     H.badge(r.get("realised_inside_band"), "yes", "no")])
    parts.append(H.table(["frequency [Hz]", "models (weight)", "averaged NRMSE %",
                          "robust NRMSE %", "heaviest model", "alone NRMSE %",
                          "band low %", "band high %", "inside band"], rows,
                         numeric=[True, False, True, True, False, True, True, True, False]))
    for n in section.get("notes", []):
        parts.append(H.paragraph(n, cls="warn"))
    return H.join(parts)


# ------------------------------------------------------------------------- overview
def _convergence_headline(summary: dict[str, Any]) -> str | None:
    """One sentence counting the fits that did not converge, or None when all did."""
    fits = summary["model_selection"].get("fits", [])
    bad_cmp = sum(1 for f in fits if f.get("error") is None and not f.get("converged"))
    dg = summary["diagnosis"]
    n_dg = 0 if dg is None else 1 + len(dg["steps"])
    bad_dg = 0
    if dg is not None:
        bad_dg = sum(1 for s in dg["steps"] if not s.get("converged"))
        bad_dg += 0 if summary["posteriors"].get("base_converged", True) else 1
    if not bad_cmp and not bad_dg:
        return None
    return (f"{bad_cmp} of {len(fits)} comparison fits and {bad_dg} of {n_dg} diagnosis fits "
            "did NOT converge: their intervals, rankings and decisions are indicative only "
            "(raise the step budget).")


def _glance_html(summary: dict[str, Any]) -> H.Markup:
    sel = summary["model_selection"]
    rows = [["all frequencies" if k == "all" else k, v or "—"]
            for k, v in sel["winners"].items()]
    parts = [H.table(["frequency", "best model (PSIS-LOO)"], rows,
                     caption="Model selection"),
             H.paragraph(f"Overall best: {sel['overall']['best'] or '—'}. Diagnosed and "
                         f"inverted: {summary['chosen_model'] or '—'}.")]
    dg = summary["diagnosis"]
    if dg is not None:
        parts.append(H.paragraph(
            f"Residual diagnosis: {', '.join(dg['effects_found']) or 'no effect'} added; "
            f"RMSE {H.number(dg['before']['rmse'])} → {H.number(dg['after']['rmse'])} "
            f"{H.unit_text(dg.get('output_unit') or '')}."))
    unc = summary.get("uncertainty")
    if unc is not None and unc["checked"]:
        rows_c = [r for r in unc["per_frequency"] if r.get("calibration") is not None]
        ok = [r for r in rows_c if r["calibration"]["calibrated"]]
        bad = ", ".join(frequency_label(r["frequency_hz"]) for r in rows_c if r not in ok)
        dominant = sorted({r["dominant"] for r in unc["per_frequency"]})
        parts.append(H.paragraph(
            f"Uncertainty of {unc['model']}: predictive calibrated on held-out cycles at "
            f"{len(ok)} of {len(rows_c)} frequencies{f' (not at {bad})' if bad else ''}; "
            f"dominated by {' / '.join(dominant)}.", cls=None if not bad else "warn"))
    comp = summary["compensation"]
    if comp is not None and comp["per_frequency"]:
        pieces = [f"{r['frequency_hz']:g} Hz: "
                  f"{H.number(r.get('uncompensated_nrmse_percent'), '.2f')} → "
                  f"{H.number(r.get('robust_nrmse_percent'), '.2f')} %"
                  for r in comp["per_frequency"] if r.get("frequency_hz") is not None]
        if pieces:
            parts.append(H.paragraph(
                "Feedforward (robust command), tracking NRMSE uncompensated → compensated on "
                f"{comp['plant_kind']}: " + "; ".join(pieces) + "."))
    warnings = summary["warnings"]
    headline = _convergence_headline(summary)
    if headline:
        parts.append(H.paragraph(headline, cls="warn"))
    if warnings:
        items = "".join(f"<li>{H.text(w)}</li>" for w in warnings)
        parts.append(H.details(f"all {len(warnings)} warnings of this run",
                               H.Markup(f"<ul>{items}</ul>")))
    else:
        parts.append(H.paragraph("Every fit converged; no warnings."))
    return H.join(parts)


def _flat(settings: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """``{"sampler": {"moves": ...}}`` -> ``[("sampler.moves", ...)]``: one row per setting."""
    rows: list[tuple[str, Any]] = []
    for k, v in settings.items():
        if isinstance(v, dict):
            rows += _flat(v, f"{prefix}{k}.")
        else:
            rows.append((f"{prefix}{k}", v))
    return rows


def _reproduce_html(summary: dict[str, Any]) -> H.Markup:
    rt = summary["runtime_s"]
    return H.join([
        H.paragraph(f"bayeshyst {summary['versions']['bayeshyst']}, Python "
                    f"{summary['versions']['python']}, seed {summary['seed']}. Same data, "
                    "settings and seed give the same numbers."),
        H.table(["setting", "value"], [[k, _short(v)] for k, v in _flat(summary["settings"])],
                numeric=[False, False]),
        H.paragraph("Wall time: " + ", ".join(f"{k} {v:.1f} s" for k, v in rt.items()) + "."),
        H.paragraph("Files next to this report: summary.json (every number shown here), "
                    "compare/, diagnose/, compensate/ (each command's own outputs, posteriors "
                    "as netCDF), figures/."),
    ])


# ----------------------------------------------------------------------------- page
def report_html(summary: dict[str, Any], out: Path, *, subtitle: str,
                overview: Path | None, evidence: list[str]) -> str:
    """The report page, from the summary as written.

    Parameters
    ----------
    summary : dict
        The report's summary after :func:`~bayeshyst.outputs.files.jsonable` (sections
        ``data``, ``posteriors``, ``model_selection``, ``diagnosis``, ``uncertainty``,
        ``compensation``, ``model_averaged_feedforward``, plus ``title`` and ``settings``;
        ``working_rate`` if the records were fitted at one).
    out : Path
        The report's folder: figures are read from under it and embedded.
    subtitle : str
        The line under the title (data, models, seed).
    overview : Path or None
        The data-overview figure, if one was written.
    evidence : list of str
        The diagnosis' evidence figures to show (names under ``out/diagnose``).

    Returns
    -------
    str
        The HTML document.
    """
    sections = [
        ("glance", "At a glance", _glance_html(summary)),
        ("data", "Data", _data_html(summary["data"], overview, summary.get("working_rate"))),
        ("posteriors", "Posteriors and convergence",
         _posteriors_html(summary["posteriors"], out)),
        ("model-selection", "Model selection per frequency",
         _selection_html(summary["model_selection"], out)),
        ("diagnosis", "Residual diagnosis: what the model misses",
         _diagnosis_html(summary["diagnosis"], out, evidence)),
        ("uncertainty", "Uncertainty analysis per frequency",
         _uncertainty_html(summary["uncertainty"], out)),
        ("compensation", "Feedforward compensation per frequency",
         H.join([_compensation_html(summary["compensation"], out),
                 _averaged_html(summary["model_averaged_feedforward"])])),
        ("reproduce", "How this was made", _reproduce_html(summary)),
    ]
    return H.page(summary["title"], subtitle, sections)
