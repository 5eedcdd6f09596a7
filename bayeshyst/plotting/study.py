"""Figures of a study (``bayeshyst study``): best models and scores.

The best model per dataset and frequency, and the scores against frequency.

Built like every figure of :mod:`bayeshyst.plotting` (object-oriented matplotlib on an
Agg canvas, no pyplot). Each model keeps one colour in both figures
(:func:`model_colors`, in the order of the study's models). Sizes grow with the number
of datasets and frequencies, fonts are small and legends sit outside the axes, so a
study of 20 datasets × 10 frequencies stays readable.

Each ``*_figure`` function returns the Figure and raises
:class:`~bayeshyst.errors.ParameterError` when the study has nothing to draw;
:func:`study_figures` returns those that have something; each ``plot_*`` function
writes its figure as PNG (atomically) and returns the path, or None when there was
nothing to draw.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import to_hex, to_rgb
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from matplotlib.ticker import NullFormatter

from bayeshyst.data.record import frequency_key, frequency_label
from bayeshyst.errors import ParameterError
from bayeshyst.plotting._common import RED, new_figure, png_path, save_and_free

__all__ = ["best_model_figure", "model_colors", "plot_best_model",
           "plot_scores_vs_frequency", "scores_vs_frequency_figure", "study_figures"]

_LABEL_CHARS = 32  # dataset and model names longer than this are shortened in figures
_MARKERS = ("o", "s", "^", "v", "D", "P", "X", "<", ">", "h", "p", "*")
_LINESTYLES = ("-", "--", ":", "-.")
_FAILED_GREY = "0.82"


# --------------------------------------------------------------------------- helpers
def model_colors(models: Sequence[str]) -> dict[str, str]:
    """One fixed colour per model, in the order given.

    Colours from tab10, tab20, then a sampled continuous map for more than 20 models.

    Parameters
    ----------
    models : sequence of str
        Model names, each once.

    Returns
    -------
    dict of str to str
        Model -> colour as ``"#rrggbb"``.
    """
    n = len(models)
    if n <= 10:
        cols = list(colormaps["tab10"].colors)[:n]
    elif n <= 20:
        tab = list(colormaps["tab20"].colors)
        cols = (tab[0::2] + tab[1::2])[:n]  # the ten strong colours first
    else:
        cmap = colormaps["turbo"]
        cols = [cmap(0.05 + 0.9 * i / (n - 1)) for i in range(n)]
    return {m: to_hex(c) for m, c in zip(models, cols, strict=True)}


def _plain(s: Any, limit: int = _LABEL_CHARS) -> str:
    r"""A name as figure text: shortened, and with ``$`` escaped.

    The escape keeps matplotlib from ever reading it as mathtext (a dataset named
    ``$\x$`` must not break the drawing).
    """
    s = str(s)
    if len(s) > limit:
        s = s[: limit - 1] + "…"
    return s.replace("$", r"\$")


def _num(x: float) -> str:
    """A score for a cell: one decimal, none from 1000 on; never 'nan'."""
    if not math.isfinite(x):
        return "n/a"
    return f"{x:.1f}" if abs(x) < 1000 else f"{x:.0f}"


def _likelihoods(result: Any) -> list[str]:
    """Likelihoods with rankings: the study's order, then any other (defensive)."""
    seen = [d.likelihood for d in result.rankings]
    order = [lik for lik in result.study.likelihoods if lik in seen]
    return order + [lik for lik in dict.fromkeys(seen) if lik not in order]


def _colors(result: Any) -> dict[str, str]:
    models = list(result.study.models)
    models += [m for d in result.rankings for m in [s.model for s in d.ranking] + list(d.failed)
               if m not in models]
    return model_colors(list(dict.fromkeys(models)))


def _text_color(face: str) -> str:
    r, g, b = to_rgb(face)
    return "black" if 0.299 * r + 0.587 * g + 0.114 * b > 0.5 else "white"


def _footnote(fig: Figure, notes: list[str]) -> None:
    """Notes under the axes (``supxlabel``, so constrained layout leaves room for them)."""
    if notes:
        fig.supxlabel("\n".join(notes), fontsize=7, color="0.3")


# ------------------------------------------------------------------- best model grid
def _cell_text(d: Any) -> tuple[str, bool]:
    """Annotation of one dataset's cell, and whether it is the 'all failed' kind."""
    if not d.ranking:
        return "all failed", True
    star = "" if d.ranking[0].converged else " *"
    if len(d.ranking) == 1:
        return "only model" + star, False
    second = d.ranking[1]
    return f"Δ {_num(-second.delta_elpd)} ± {_num(second.delta_se)}{star}", False


def _build_best_model(result: Any, fig: Figure | None) -> Figure | None:
    if not result.rankings:
        return None
    ranked = {d.dataset for d in result.rankings}
    # the study's order (the table's), not the rankings' (sorted by frequency first)
    datasets = [ds for ds in dict.fromkeys(r["dataset"] for r in result.rows) if ds in ranked]
    datasets += [ds for ds in dict.fromkeys(d.dataset for d in result.rankings)
                 if ds not in datasets]
    known = sorted({d.frequency_hz for d in result.rankings if d.frequency_hz is not None})
    freqs: list[float | None] = [*known]
    if any(d.frequency_hz is None for d in result.rankings):
        freqs.append(None)
    liks = _likelihoods(result)
    cells = {(d.likelihood, d.dataset, d.frequency_hz): d for d in result.rankings}
    colors = _colors(result)
    nrow, ncol, npan = len(datasets), len(freqs), len(liks)

    label_w = 0.35 + 0.062 * max(len(_plain(s)) for s in datasets)
    legend_w = 0.9 + 0.058 * max(len(_plain(m)) for m in colors)
    cell_w = 1.15
    panel_h = 0.55 + 0.27 * nrow
    fig = new_figure(fig, max(5.5, label_w + cell_w * ncol + legend_w),
                     1.1 + panel_h * npan)
    axes = np.atleast_1d(fig.subplots(npan, 1, squeeze=False)).ravel()
    cell_font = 6.5 if ncol <= 12 else 5.5
    tick_font = 7 if nrow <= 30 else 6
    any_failed = any_unconverged = False
    for ax, lik in zip(axes, liks, strict=True):
        for i, ds in enumerate(datasets):
            for j, f in enumerate(freqs):
                d = cells.get((lik, ds, f))
                if d is None:
                    continue  # no data: left blank
                label, failed = _cell_text(d)
                if failed:
                    any_failed = True
                    ax.add_patch(Rectangle((j, i), 1, 1, facecolor=_FAILED_GREY, hatch="///",
                                           edgecolor="0.55", lw=0))
                    ink = "0.2"
                else:
                    face = colors[d.best]
                    any_unconverged |= not d.ranking[0].converged
                    ax.add_patch(Rectangle((j, i), 1, 1, facecolor=face, edgecolor="none"))
                    ink = _text_color(face)
                ax.text(j + 0.5, i + 0.5, label, ha="center", va="center", fontsize=cell_font,
                        color=ink, clip_on=True)
        # cell borders (also around blank cells, so the reader sees they are empty)
        ax.hlines(np.arange(nrow + 1), 0, ncol, color="white", lw=1.2)
        ax.vlines(np.arange(ncol + 1), 0, nrow, color="white", lw=1.2)
        ax.set_xlim(0, ncol)
        ax.set_ylim(nrow, 0)
        ax.set_facecolor("0.97")
        ax.set_xticks(np.arange(ncol) + 0.5, [frequency_label(f) for f in freqs],
                      fontsize=tick_font, rotation=30 if ncol > 8 else 0)
        ax.set_yticks(np.arange(nrow) + 0.5, [_plain(s) for s in datasets], fontsize=tick_font)
        ax.tick_params(length=0)
        ax.xaxis.set_ticks_position("top")
        for side in ax.spines.values():
            side.set_visible(False)
        if npan > 1:
            ax.set_title(f"likelihood: {_plain(lik)}", fontsize=9, loc="left")
    handles = [Patch(facecolor=c, label=_plain(m)) for m, c in colors.items()]
    if any_failed:
        handles.append(Patch(facecolor=_FAILED_GREY, hatch="///", edgecolor="0.55",
                             label="all failed"))
    fig.legend(handles=handles, loc="outside right upper", fontsize=7, title="best model",
               title_fontsize=8, frameon=False)
    fig.suptitle("best model per dataset and excitation frequency", fontsize=9, x=0.01,
                 ha="left")
    notes = ["cell: the best model's elpd_loo lead over the runner-up ± se of the paired "
             "difference (seeds averaged)"]
    if any_unconverged:
        notes.append("* not every fit of the best model converged: its scores are not reliable")
    unranked = [r["dataset"] for r in result.rows if r["dataset"] not in datasets]
    if unranked:
        names = list(dict.fromkeys(unranked))
        notes.append(f"not shown (no fit produced a frequency to rank at): "
                     f"{', '.join(_plain(s) for s in names[:8])}"
                     + (f" and {len(names) - 8} more" if len(names) > 8 else ""))
    _footnote(fig, notes)
    return fig


def best_model_figure(result: Any, *, fig: Figure | None = None) -> Figure:
    """The best model at every dataset (rows) and excitation frequency (columns).

    Each cell is coloured by the model with the highest elpd_loo there (seeds averaged)
    and says by how much it leads the runner-up, ``Δ lead ± se`` (the paired difference
    over the cycles); "only model" when the others have no score there, hatched grey
    "all failed" when no model has one, blank when the dataset has no records at that
    frequency. One panel per likelihood.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult
        Its ``rankings`` (at least one) and ``rows`` (the order of the datasets).
    fig : Figure, optional
        An empty figure to draw into (one panel per likelihood); default a new one that
        grows with the number of datasets and frequencies.

    Returns
    -------
    Figure
        With one axes per likelihood.

    Raises
    ------
    ParameterError
        The study has no ranking (no fit produced a score): nothing to draw.
    """
    made = _build_best_model(result, fig)
    if made is None:
        raise ParameterError("the study has no ranking: no best model to draw")
    return made


def plot_best_model(result: Any, path: str | os.PathLike[str]) -> Path | None:
    """Write :func:`best_model_figure` as PNG, if the study has a ranking.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult
    path : path-like
        PNG file to write (atomically).

    Returns
    -------
    Path or None
        ``path``; None (nothing written) when the study has no ranking.
    """
    path = png_path(path)
    fig = _build_best_model(result, None)
    return None if fig is None else save_and_free(fig, path)


# ------------------------------------------------------------ scores vs frequency
def _n_cycles(result: Any) -> dict[tuple[str, str, float | None, str], int]:
    """Cycles scored per (likelihood, dataset, frequency, model), from the ok rows."""
    out: dict[tuple[str, str, float | None, str], int] = {}
    for r in result.rows:
        if r["status"] == "ok" and r.get("n_cycles"):
            key = (r["likelihood"], r["dataset"], frequency_key(r["frequency_hz"]), r["model"])
            out.setdefault(key, int(r["n_cycles"]))
    return out


def _build_scores_vs_frequency(result: Any, fig: Figure | None) -> Figure | None:
    liks = _likelihoods(result)
    if not liks:
        return None
    lik = liks[0]
    cycles = _n_cycles(result)
    colors = _colors(result)
    # (dataset, model) -> [(f, elpd per cycle, se per cycle, nrmse, converged)]
    series: dict[tuple[str, str], list[tuple[float, float, float, float, bool]]] = {}
    left_out: list[str] = []
    for d in result.rankings:
        if d.likelihood != lik:
            continue
        for s in d.ranking:
            if d.frequency_hz is None:
                left_out.append(d.dataset)
                continue
            n = cycles.get((lik, d.dataset, d.frequency_hz, s.model))
            if not n:
                continue
            series.setdefault((d.dataset, s.model), []).append(
                (d.frequency_hz, s.elpd_loo / n, s.se / n, s.nrmse_percent, s.converged))
    if not series:
        return None
    datasets = list(dict.fromkeys(k[0] for k in series))
    models = [m for m in colors if any(k[1] == m for k in series)]
    style = {ds: (_MARKERS[i % len(_MARKERS)],
                  _LINESTYLES[(i // len(_MARKERS)) % len(_LINESTYLES)])
             for i, ds in enumerate(datasets)}
    freqs = np.array(sorted({p[0] for pts in series.values() for p in pts}))

    n_legend = len(models) + len(datasets) + 3
    legend_w = 1.0 + 0.058 * max(len(_plain(x)) for x in [*models, *datasets])
    legend_cols = 1 if n_legend <= 34 else 2
    fig = new_figure(fig, 2 * 4.4 + legend_w * legend_cols,
                     max(4.0, 1.6 + 0.13 * math.ceil(n_legend / legend_cols)))
    ax_elpd, ax_err = fig.subplots(1, 2)
    many = len(series) > 40
    unconverged = False
    for (ds, m), pts in series.items():
        pts.sort()
        f = np.array([p[0] for p in pts])
        y = np.array([p[1] for p in pts])
        ye = np.array([p[2] for p in pts])
        nr = np.array([p[3] for p in pts])
        conv = np.array([p[4] for p in pts])
        marker, ls = style[ds]
        kw = {"color": colors[m], "marker": marker, "linestyle": ls, "ms": 3.5 if many else 4.5,
              "lw": 0.8 if many else 1.1, "alpha": 0.85}
        cont = ax_elpd.errorbar(f, y, yerr=np.where(np.isfinite(ye), ye, 0.0), capsize=2,
                                elinewidth=0.7, **kw)
        cont.lines[0].set_gid(f"{ds}|{m}")
        line = ax_err.plot(f, nr, **kw)[0]
        line.set_gid(f"{ds}|{m}")
        if not conv.all():
            unconverged = True
            for ax, v in ((ax_elpd, y), (ax_err, nr)):
                ax.plot(f[~conv], v[~conv], "x", color=RED, ms=7, mew=1.4, zorder=5)
    ax_elpd.set_ylabel("elpd_loo per cycle (± se per cycle)", fontsize=8)
    ax_elpd.set_title("(a) predictive score per cycle (higher is better)", fontsize=8.5)
    ax_err.set_ylabel("NRMSE of the posterior mean [% of stroke]", fontsize=8)
    ax_err.set_title("(b) tracking error", fontsize=8.5)
    positive = [p[3] for pts in series.values() for p in pts
                if math.isfinite(p[3]) and p[3] > 0]
    if positive and max(positive) / min(positive) > 20:
        ax_err.set_yscale("log")
    for ax in (ax_elpd, ax_err):
        if freqs.size > 1 and freqs.min() > 0 and freqs.max() / freqs.min() > 10:
            ax.set_xscale("log")
        # label the measured frequencies themselves, not log-decade minor ticks
        ax.set_xticks(freqs, [f"{x:g}" for x in freqs], fontsize=7,
                      rotation=45 if freqs.size > 6 else 0)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.tick_params(axis="y", labelsize=7)
        ax.set_xlabel("excitation frequency [Hz]", fontsize=8)
        ax.grid(alpha=0.3)
    handles: list[Any] = [Line2D([], [], color="none", label="model (colour)")]
    handles += [Line2D([], [], color=colors[m], lw=2, label=_plain(m)) for m in models]
    handles.append(Line2D([], [], color="none", label="dataset (marker, line)"))
    handles += [Line2D([], [], color="0.25", marker=style[ds][0], linestyle=style[ds][1],
                       ms=4, lw=1, label=_plain(ds)) for ds in datasets]
    if unconverged:
        handles.append(Line2D([], [], color=RED, marker="x", linestyle="none", ms=6,
                              mew=1.4, label="not every seed converged"))
    fig.legend(handles=handles, loc="outside right upper", fontsize=6.5, frameon=False,
               ncols=legend_cols, handlelength=2.6)
    several = len(liks) > 1
    fig.suptitle(f"scores against excitation frequency — likelihood {_plain(lik)}"
                 + (f" (first of {len(liks)}; the others are in the tables)" if several else ""),
                 fontsize=9)
    if left_out:
        names = list(dict.fromkeys(left_out))
        _footnote(fig, [f"left out: {len(left_out)} point(s) at unknown excitation frequency "
                        f"(dataset{'s' if len(names) > 1 else ''} "
                        f"{', '.join(_plain(s) for s in names[:8])}"
                        + (f" and {len(names) - 8} more" if len(names) > 8 else "") + ")"])
    return fig


def scores_vs_frequency_figure(result: Any, *, fig: Figure | None = None) -> Figure:
    """elpd_loo per cycle and NRMSE against excitation frequency, per dataset and model.

    (a) elpd_loo / n_cycles with error bars se / n_cycles (per cycle, so frequencies with
    different numbers of cycles compare); (b) NRMSE of the posterior mean in % of the
    stroke. Colour: model; marker and line style: dataset; a line joins the frequencies
    of one dataset and model; fits not converged are marked with a red x. Log-x when the
    frequencies span more than a decade. Points at unknown frequency are left out (a
    footnote says how many). Only the first likelihood of the study is drawn.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult
        Its ``rankings`` and the ``n_cycles`` of its ok ``rows``.
    fig : Figure, optional
        An empty figure to draw into (two panels and a legend outside them); default a
        new one, 8.8 in wide plus the legend.

    Returns
    -------
    Figure
        With two axes (elpd per cycle, NRMSE).

    Raises
    ------
    ParameterError
        No model has a score at a known frequency: nothing to draw.
    """
    made = _build_scores_vs_frequency(result, fig)
    if made is None:
        raise ParameterError("no model has a score at a known excitation frequency: no "
                             "scores to draw against frequency")
    return made


def plot_scores_vs_frequency(result: Any, path: str | os.PathLike[str]) -> Path | None:
    """Write :func:`scores_vs_frequency_figure` as PNG, if there is something to draw.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult
    path : path-like
        PNG file to write (atomically).

    Returns
    -------
    Path or None
        ``path``; None (nothing written) when no model has a score at a known frequency.
    """
    path = png_path(path)
    fig = _build_scores_vs_frequency(result, None)
    return None if fig is None else save_and_free(fig, path)


# ----------------------------------------------------------------------- all of them
def study_figures(result: Any) -> dict[str, Figure]:
    """Every figure of a study that has something to draw.

    Parameters
    ----------
    result : bayeshyst.study.StudyResult

    Returns
    -------
    dict of str to Figure
        ``"best_model"`` (:func:`best_model_figure`) and ``"scores_vs_frequency"``
        (:func:`scores_vs_frequency_figure`), in that order, each left out when the
        study has nothing to draw in it.
    """
    made = {"best_model": _build_best_model(result, None),
            "scores_vs_frequency": _build_scores_vs_frequency(result, None)}
    return {name: fig for name, fig in made.items() if fig is not None}
