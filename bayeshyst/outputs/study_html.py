"""``study.html``: the self-contained report of a study (``bayeshyst study --report``).

Built only with :mod:`bayeshyst.outputs.html`, which escapes every piece of text (dataset
names, model specs, error messages can hold anything, ``<script>`` included), shows a
missing or non-finite number as an em dash, and embeds the figures as base64 PNG: the
page needs no network and no neighbouring file, and runs no script.

Sections, in order: :data:`SECTIONS`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bayeshyst._version import __version__
from bayeshyst.outputs import html as H

__all__ = ["SECTIONS", "study_html"]

#: (anchor, heading) of the page's sections, in order.
SECTIONS = (
    ("glance", "At a glance"),
    ("by-frequency", "Model selection per frequency"),
    ("by-dataset", "Best model per dataset"),
    ("failed", "Failed fits"),
    ("fits", "Every fit"),
    ("made", "How this was made"),
)

_FAILED_INLINE = 50  # longer lists of failed fits are collapsed


# --------------------------------------------------------------------------- helpers
def _n(count: int, word: str, plural: str | None = None) -> str:
    return f"{count} {word if count == 1 else (plural or word + 's')}"


def _freq(f: float | None) -> str:
    return "unknown frequency" if f is None else f"{f:g} Hz"


def _num(x: Any, spec: str = ".1f") -> str:
    """A number in a sentence (an em dash when missing or non-finite)."""
    return str(H.number(x, spec))


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return H.MISSING
    if seconds < 120:
        return f"{seconds:.1f} s"
    minutes = seconds / 60
    if minutes < 120:
        return f"{minutes:.1f} min"
    hours, mins = divmod(round(minutes), 60)
    return f"{hours} h {mins:02d} min"


def _ul(items: Sequence[Any]) -> H.Markup:
    return H.Markup("<ul>" + "".join(f"<li>{H.text(i)}</li>" for i in items) + "</ul>")


def _h3(title: str) -> H.Markup:
    return H.Markup(f"<h3>{H.text(title)}</h3>")


def _datasets(result: Any) -> list[str]:
    """Dataset labels in table order."""
    return list(dict.fromkeys(r["dataset"] for r in result.rows))


def _several_likelihoods(result: Any) -> bool:
    return len({s.likelihood for s in result.by_frequency}) > 1 or len(
        result.study.likelihoods) > 1


def _lead(second: Any) -> str:
    """``lead ± se`` of the best model over the runner-up (from the runner-up's Δ)."""
    return f"{_num(-second.delta_elpd)} ± {_num(second.delta_se)}"


# ------------------------------------------------------------------------ at a glance
def _counts(result: Any) -> tuple[int, int, int, int]:
    ok = [r for r in result.rows if r["status"] == "ok"]
    n_conv = sum(bool(r["converged"]) for r in ok)
    return len(result.rows), len(ok), n_conv, len(result.rows) - len(ok)


def _frequency_sentence(s: Any, with_likelihood: bool) -> str:
    where = _freq(s.frequency_hz) + (f" ({s.likelihood})" if with_likelihood else "")
    left = (f"; {_n(len(s.incomplete), 'dataset')} left out because a model has no score "
            f"there" if s.incomplete else "")
    if not s.models:
        return f"{where}: no dataset where every model has a score{left}."
    best = s.models[0]
    text = f"{best.model} wins {best.wins} of {_n(best.n_datasets, 'dataset')} at {where}"
    if len(s.models) > 1:
        text += f"; Δelpd to {s.models[1].model} {_lead(s.models[1])}"
    else:
        text += " (the only model)"
    if best.converged_fraction < 1:
        text += (f"; {best.model} converged in {_num(best.converged_fraction, '.0%')} of "
                 f"these datasets")
    return text + left + "."


def _glance(result: Any) -> H.Markup:
    n, n_ok, n_conv, n_fail = _counts(result)
    st = result.study
    parts = [H.paragraph(
        f"{_n(n, 'fit')} ({_n(len(_datasets(result)), 'dataset')} × "
        f"{_n(len(st.models), 'model')} × {_n(len(st.likelihoods), 'likelihood')} × "
        f"{_n(len(st.seeds), 'seed')}, at every excitation frequency of each dataset): "
        f"{n_ok} ok — {n_conv} of them converged, {n_ok - n_conv} not converged — and "
        f"{n_fail} failed."),
        H.paragraph(
        f"Where it ran: {result.cluster}; wall time {_duration(result.runtime_s)}; "
        f"{_n(result.n_run, 'fit')} run now, {result.n_reused} reused from an earlier run "
        f"of the same study.")]
    if result.by_frequency:
        parts.append(H.paragraph(
            "Best model per frequency (highest elpd_loo pooled over the datasets where every "
            "model has a score; Δelpd: its lead over the runner-up ± the paired standard "
            "error; a lead under about 2 se is not a difference):"))
        several = _several_likelihoods(result)
        parts.append(_ul([_frequency_sentence(s, several) for s in result.by_frequency]))
    else:
        parts.append(H.paragraph("No fit produced a score: there is no model selection.",
                                 cls="warn"))
    if n_ok - n_conv:
        parts.append(H.paragraph(
            f"{n_ok - n_conv} of the {n_ok} successful fits did not converge: their scores "
            "are not reliable (see the converged column; rerun with a larger max_steps).",
            cls="warn"))
    if n_fail:
        parts.append(H.paragraph(f"{_n(n_fail, 'fit')} failed: see Failed fits.", cls="warn"))
    return H.join(parts)


# --------------------------------------------------------- model selection per frequency
def _by_frequency(result: Any) -> H.Markup:
    parts = [H.paragraph(
        "At each excitation frequency, every model's pointwise leave-one-cycle-out elpd "
        "(seeds averaged) is pooled over the datasets where every model has a score, so "
        "that the models are compared on the same cycles. Δelpd and Δse: the difference to "
        "the best model, paired over those cycles, and its standard error. Wins: datasets "
        "where the model has the highest elpd. NRMSE: tracking error of the posterior mean "
        "in % of the stroke (mean and worst over the datasets). Converged: fraction of the "
        "datasets where all the model's fits converged.")]
    if not result.by_frequency:
        parts.append(H.paragraph("No fit produced a score."))
    several = _several_likelihoods(result)
    for s in result.by_frequency:
        parts.append(_h3(_freq(s.frequency_hz) + (f" — {s.likelihood}" if several else "")))
        if s.datasets:
            parts.append(H.paragraph(f"Pooled over {_n(len(s.datasets), 'dataset')}: "
                                     f"{', '.join(s.datasets)}."))
        if s.incomplete:
            parts.append(H.paragraph(
                f"Left out because a model has no score there (its errors are under Failed "
                f"fits): {', '.join(s.incomplete)}.", cls="warn"))
        if not s.models:
            parts.append(H.paragraph("No dataset where every model has a score: nothing to "
                                     "compare at this frequency."))
            continue
        rows = [[i, m.model, m.wins, m.n_datasets, m.elpd_loo, m.se, m.delta_elpd, m.delta_se,
                 m.mean_nrmse_percent, m.max_nrmse_percent, m.converged_fraction]
                for i, m in enumerate(s.models, 1)]
        parts.append(H.table(
            ["rank", "model", "wins", "n_datasets", "elpd_loo", "se", "Δelpd", "Δse",
             "mean NRMSE %", "max NRMSE %", "converged fraction"], rows,
            numeric=[True, False] + [True] * 9,
            formats=[".0f", None, ".0f", ".0f", ".1f", ".1f", ".1f", ".1f", ".3f", ".3f", ".0%"]))
    return H.join(parts)


# -------------------------------------------------------------- best model per dataset
def _cell(d: Any) -> H.Markup:
    if d is None:
        return H.text(H.MISSING)
    if not d.ranking:
        return H.Markup('<span class="badge bad">all failed</span>')
    best = d.ranking[0]
    lead = "only model" if len(d.ranking) == 1 else f"Δ {_lead(d.ranking[1])}"
    if not best.converged:
        lead += " · not converged"
    return H.Markup(f'{H.text(best.model)}<br><span class="meta">{H.text(lead)}</span>')


def _by_dataset(result: Any, figures: dict[str, Path]) -> H.Markup:
    parts = []
    if figures.get("best_model"):
        parts.append(H.figure(figures["best_model"],
                              "Best model at each dataset (rows) and excitation frequency "
                              "(columns): colour = model; Δ = its elpd_loo lead over the "
                              "runner-up ± the paired standard error; hatched grey: every "
                              "model failed; blank: no records at that frequency."))
    if figures.get("scores_vs_frequency"):
        parts.append(H.figure(figures["scores_vs_frequency"],
                              "(a) elpd_loo per cycle (± se per cycle) and (b) tracking error "
                              "against excitation frequency; colour = model, marker and line "
                              "= dataset; red x: not every fit converged."))
    if not result.rankings:
        parts.append(H.paragraph("No dataset has a ranking: no fit produced a score."))
        return H.join(parts)
    ranked = {d.dataset for d in result.rankings}
    datasets = [ds for ds in _datasets(result) if ds in ranked]
    datasets += [ds for ds in dict.fromkeys(d.dataset for d in result.rankings)
                 if ds not in datasets]
    freqs: list[float | None] = sorted({d.frequency_hz for d in result.rankings
                                        if d.frequency_hz is not None})
    if any(d.frequency_hz is None for d in result.rankings):
        freqs.append(None)
    cells = {(d.likelihood, d.dataset, d.frequency_hz): d for d in result.rankings}
    liks = list(dict.fromkeys(d.likelihood for d in result.rankings))
    parts.append(H.paragraph(
        "Each cell: the model with the highest elpd_loo at that dataset and frequency (seeds "
        "averaged) and its lead over the runner-up ± the paired standard error; "
        f"{H.MISSING}: no records at that frequency."))
    for lik in liks:
        rows = [[ds, *[_cell(cells.get((lik, ds, f))) for f in freqs]] for ds in datasets]
        parts.append(H.table(["dataset", *[_freq(f) for f in freqs]], rows,
                             caption=f"likelihood {lik}" if len(liks) > 1 else None,
                             numeric=[False] * (len(freqs) + 1)))
    missing = [ds for ds in _datasets(result) if ds not in datasets]
    if missing:
        parts.append(H.paragraph(
            f"Not in the table (no fit gave a frequency to rank at; see Failed fits): "
            f"{', '.join(missing)}.", cls="warn"))
    return H.join(parts)


# ------------------------------------------------------------------------ failed fits
def _row_freq(r: dict[str, Any]) -> Any:
    if r["frequency_hz"] is not None:
        return r["frequency_hz"]
    return H.MISSING if r.get("n_records") in (None, 0) else "unknown"


def _failed(result: Any) -> H.Markup:
    failed = result.failed
    if not failed:
        return H.paragraph(f"None of the {_n(len(result.rows), 'fit')} failed.")
    rows = [[r["dataset"], r["model"], r["likelihood"], r["seed"], _row_freq(r),
             r["error"] or ""] for r in failed]
    tab = H.table(["dataset", "model", "likelihood", "seed", "frequency [Hz]", "error"], rows,
                  numeric=[False, False, False, True, True, False],
                  formats=[None, None, None, ".0f", "g", None])
    head = H.paragraph(
        f"{len(failed)} of the {_n(len(result.rows), 'fit')} produced no score. A dataset "
        f"that could not be read has no frequency ({H.MISSING}). A re-run of the study "
        "repeats only the fits lost on the cluster (or every failed fit with retry_failed).")
    if len(failed) > _FAILED_INLINE:
        return H.join([head, H.details(f"the {len(failed)} failed fits", tab)])
    return H.join([head, tab])


# -------------------------------------------------------------------------- every fit
def _every_fit(result: Any) -> H.Markup:
    rows = []
    for r in result.rows:
        ok = r["status"] == "ok"
        rows.append([r["dataset"], r["model"], r["likelihood"], r["seed"], _row_freq(r),
                     H.badge(ok, "ok", str(r["status"])), r["elpd_loo"], r["elpd_se"],
                     r["nrmse_percent"], H.badge(bool(r["converged"]), "yes", "no") if ok
                     else H.text(H.MISSING), r["n_cycles"], r["runtime_s"],
                     r["error"] or ""])
    tab = H.table(["dataset", "model", "likelihood", "seed", "frequency [Hz]", "status",
                   "elpd_loo", "se", "NRMSE %", "converged", "n_cycles", "runtime [s]",
                   "error"], rows,
                  numeric=[False, False, False, True, True, False, True, True, True, False,
                           True, True, False],
                  formats=[None, None, None, ".0f", "g", None, ".1f", ".1f", ".3f", None, ".0f",
                           ".1f", None])
    return H.join([H.paragraph("Every fit of the study, in table order (table.csv has every "
                               "column, warnings included)."),
                   H.details(f"all {_n(len(result.rows), 'fit')}", tab)])


# ----------------------------------------------------------------- how this was made
def _value(v: Any) -> str:
    if v is None:
        return "default"
    if isinstance(v, list | tuple):
        return ", ".join(str(x) for x in v)
    return str(v)


def _made(result: Any) -> H.Markup:
    st = result.study.to_dict()
    settings = [["study", st["name"]], ["study file", st["path"]],
                ["models", _value(st["models"])], ["likelihoods", _value(st["likelihoods"])],
                ["seeds", _value(st["seeds"])],
                ["frequencies_hz", "every frequency of each dataset"
                 if st["frequencies_hz"] is None else _value(st["frequencies_hz"])]]
    settings += [[f"sampler.{k}", _value(v)] for k, v in st["sampler"].items()]
    settings += [["bayeshyst", __version__], ["ran on", result.cluster],
                 ["fits run now / reused", f"{result.n_run} / {result.n_reused}"],
                 ["wall time", _duration(result.runtime_s)], ["output folder", result.out_dir]]
    ds_rows = [[d["label"], d["path"] or f"measured: {d['measured']}",
                json.dumps(d["options"], default=str) if d["options"] else "",
                d["error"] or ""] for d in st["datasets"]]
    return H.join([
        H.paragraph(f"Study {st['name']} read from {st['path']}; every fit used the sampler "
                    "settings below (sampler keys not set in the study file show bayeshyst's "
                    "defaults; n_walkers default: set from the number of parameters)."),
        H.table(["setting", "value"], settings, numeric=[False, False]),
        H.table(["dataset", "source", "options", "error"], ds_rows,
                numeric=[False] * 4, caption="datasets of the study file"),
        H.paragraph("Files next to this page: table.csv and table.json (every fit), "
                    "by_frequency.csv/.json, best_by_dataset.csv/.json, figures/, fits/ (each "
                    "fit's posterior as netCDF and its record as JSON) and summary.json. "
                    "Running the study again reuses every stored fit whose inputs are "
                    "unchanged; the same inputs and seeds give the same numbers."),
    ])


# ---------------------------------------------------------------------------- page
def study_html(result: Any, figures: dict[str, Path]) -> str:
    """The study report as one self-contained HTML document.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult
    figures : dict of str to Path
        The PNGs to embed: ``"best_model"`` and ``"scores_vs_frequency"`` (either may be
        missing).

    Returns
    -------
    str
        The document (sections :data:`SECTIONS`).
    """
    bodies = {
        "glance": _glance(result),
        "by-frequency": _by_frequency(result),
        "by-dataset": _by_dataset(result, figures),
        "failed": _failed(result),
        "fits": _every_fit(result),
        "made": _made(result),
    }
    st = result.study
    n, n_ok, _, n_fail = _counts(result)
    subtitle = (f"{_n(len(_datasets(result)), 'dataset')} × {_n(len(st.models), 'model')} × "
                f"{_n(len(st.likelihoods), 'likelihood')} × {_n(len(st.seeds), 'seed')} · "
                f"{_n(n, 'fit')}: {n_ok} ok, {n_fail} failed · bayeshyst {__version__}")
    return H.page(f"bayeshyst study: {st.name}", subtitle,
                  [(a, h, bodies[a]) for a, h in SECTIONS])
