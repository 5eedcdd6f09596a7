"""Figures in the data's own space: loops with predictive bands, residuals, loops per frequency.

Measured loops with the posterior's predictive band, residuals of the posterior-mean
prediction, and the measured loops per frequency.

Each ``*_figure`` function returns the Figure (drawn into the caller's empty figure when
given one); each ``plot_*`` function builds it and writes it as PNG (atomically, see
:func:`~bayeshyst.plotting.save_figure`) and returns the path. Bad input raises
:class:`~bayeshyst.errors.ParameterError` before anything is drawn or written. A run that
has not converged says so in red in the title.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from bayeshyst.data.dataset import Dataset
from bayeshyst.errors import ParameterError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling_result import SamplingResult
from bayeshyst.plotting._common import (
    RED,
    check_result,
    fmt,
    label,
    new_figure,
    png_path,
    positive_int,
    probability,
    save_and_free,
    title,
    unit,
)

__all__ = ["DATA_OVERVIEW_DPI", "data_overview_figure", "loops_figure", "plot_data_overview",
           "plot_loops", "plot_residuals", "residuals_figure", "uncertainty_figure"]

#: Resolution of a new data-overview figure (it is embedded in the HTML report).
DATA_OVERVIEW_DPI = 110


def _check_pair(post: Posterior, result: SamplingResult) -> None:
    if not isinstance(post, Posterior):
        raise ParameterError(f"post must be a Posterior, got {type(post).__name__}")
    check_result(result)
    if post.space != result.space:
        raise ParameterError("the result was not sampled from this posterior: their "
                             "parameter spaces differ")


def _predictions(post: Posterior, result: SamplingResult, n_draws: int,
                 seed: int) -> tuple[list[np.ndarray], int]:
    z = result.draws(n_draws, seed=seed)
    return post.predict(z), z.shape[0]


# ----------------------------------------------------------------------------- loops
def loops_figure(post: Posterior, result: SamplingResult, *, fig: Figure | None = None,
                 n_draws: int = 100, prob: float = 0.9, seed: int = 0) -> Figure:
    """Measured loops with the posterior-predictive mean and band of the model.

    One panel per record (titled with its name and frequency): measured ``y`` against
    ``u`` over the scored samples (points), the mean over ``n_draws`` posterior draws of
    the noise-free prediction (``post.predict``, offset included) and the equal-tailed
    ``prob`` interval of those predictions as a shaded band.

    Parameters
    ----------
    post : Posterior
        The posterior ``result`` sampled; its data are drawn.
    result : SamplingResult
        Draws of ``post``.
    fig : Figure, optional
        An empty figure to draw into (one panel per record, so it takes a figure, not an
        axes); default a new one, 4.4 in wide per column (at most 3) and 3.6 in high per
        row.
    n_draws : int
        Posterior draws predicted (``result.draws(n_draws, seed=seed)``).
    prob : float
        Mass of the band, in (0, 1).
    seed : int
        Selects the draws.

    Returns
    -------
    Figure
        ``fig`` or the new figure, with one axes per record.
    """
    _check_pair(post, result)
    n_draws = positive_int(n_draws, "n_draws")
    prob = probability(prob)
    preds, n = _predictions(post, result, n_draws, seed)
    records = list(post.data)
    ncols = min(3, len(records))
    nrows = math.ceil(len(records) / ncols)
    # one panel still needs room for the two-line title
    fig = new_figure(fig, max(6.4, 4.4 * ncols), 3.6 * nrows + 0.6)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[len(records):]:
        fig.delaxes(ax)
    q = [(1 - prob) / 2, (1 + prob) / 2]
    for i, (ax, rec, pred) in enumerate(zip(axes, records, preds, strict=False)):
        sl = rec.scored
        u, y, p = rec.u[sl], rec.y[sl], pred[:, sl]
        ok = np.all(np.isfinite(p), axis=1)
        ax.plot(u, y, ".", ms=1.5, color="0.45", alpha=0.6, label="measured")
        if ok.any():
            mean = p[ok].mean(axis=0)
            lo, hi = np.quantile(p[ok], q, axis=0)
            quads = np.stack([np.column_stack([u[:-1], lo[:-1]]),
                              np.column_stack([u[1:], lo[1:]]),
                              np.column_stack([u[1:], hi[1:]]),
                              np.column_stack([u[:-1], hi[:-1]])], axis=1)
            ax.add_collection(PolyCollection(quads, facecolors="C0", alpha=0.3,
                                             linewidths=0, antialiaseds=False,
                                             label=f"{prob:.0%} interval"))
            ax.plot(u, mean, color="C0", lw=1.0, label="posterior mean")
        freq = rec.frequency_hz
        fstr = f"{freq:g} Hz" if freq is not None and np.isfinite(freq) else "frequency unknown"
        failed = "" if ok.all() else f" ({int((~ok).sum())} of {n} draws failed)"
        ax.set_title(f"{rec.name}, {fstr}{failed}", fontsize=9)
        ax.set_xlabel(label("u", rec.units.get("u", "")))
        ax.set_ylabel(label("y", rec.units.get("y", "")))
        if i == 0:
            ax.legend(fontsize=7, loc="upper left", markerscale=4)
    title(fig, result, f"loops, noise-free prediction ({n} draws)")
    return fig


def plot_loops(post: Posterior, result: SamplingResult, path: str | os.PathLike[str], *,
               n_draws: int = 100, prob: float = 0.9, seed: int = 0) -> Path:
    """Write :func:`loops_figure` as PNG.

    Parameters
    ----------
    post : Posterior
    result : SamplingResult
        Draws of ``post``.
    path : path-like
        Target PNG file.
    n_draws : int
        Posterior draws predicted.
    prob : float
        Mass of the band.
    seed : int
        Selects the draws.

    Returns
    -------
    Path
        ``path``, written atomically.
    """
    path = png_path(path)
    return save_and_free(loops_figure(post, result, n_draws=n_draws, prob=prob, seed=seed),
                         path)


# ------------------------------------------------------------------------- residuals
def residuals_figure(post: Posterior, result: SamplingResult, *, fig: Figure | None = None,
                     n_draws: int = 100, seed: int = 0) -> Figure:
    """Residuals of the posterior-mean prediction against time and input, per record.

    The residual is measured ``y`` minus the mean, over ``n_draws`` posterior draws,
    of the noise-free prediction (offset included). Scored samples are blue, warm-up
    samples grey; dashed lines at ±2 ``noise.sigma`` when the likelihood has one.
    Structure in these plots (loops against ``u``, trends against ``t``) points to a
    missing effect.

    Parameters
    ----------
    post : Posterior
        The posterior ``result`` sampled.
    result : SamplingResult
        Draws of ``post``.
    fig : Figure, optional
        An empty figure to draw into (two panels per record: against time, against
        input); default a new one, 10 in wide and 2.6 in high per record.
    n_draws : int
        Posterior draws averaged.
    seed : int
        Selects the draws.

    Returns
    -------
    Figure
        With two axes per record (time, input).
    """
    _check_pair(post, result)
    n_draws = positive_int(n_draws, "n_draws")
    preds, n = _predictions(post, result, n_draws, seed)
    sigma = None
    if "noise.sigma" in post.space.names:
        sigma = float(np.mean(result.theta()["noise.sigma"]))
    records = list(post.data)
    fig = new_figure(fig, 10.0, 2.6 * len(records) + 0.8)
    axes = fig.subplots(len(records), 2, squeeze=False, width_ratios=[1.6, 1.0])
    for (ax_t, ax_u), rec, pred in zip(axes, records, preds, strict=True):
        ok = np.all(np.isfinite(pred), axis=1)
        mean = pred[ok].mean(axis=0) if ok.any() else np.full(rec.n, np.nan)
        res = rec.y - mean
        sc, wu = rec.scored_mask, ~rec.scored_mask
        rms = float(np.sqrt(np.mean(res[sc] ** 2)))
        y_unit = rec.units.get("y", "")
        for ax, xv, xname in ((ax_t, rec.t, "t"), (ax_u, rec.u, "u")):
            if wu.any():
                ax.plot(xv[wu], res[wu], ".", ms=1.5, color="0.75",
                        label="warm-up (not scored)")
            ax.plot(xv[sc], res[sc], ".", ms=1.5, color="C0", label="scored")
            ax.axhline(0.0, color="k", lw=0.7)
            if sigma is not None and np.isfinite(sigma):
                for s in (-2 * sigma, 2 * sigma):
                    ax.axhline(s, color=RED, ls="--", lw=0.7)
            ax.set_xlabel(label(xname, rec.units.get(xname, "")))
            ax.set_ylabel(label("residual", y_unit))
        failed = "" if ok.all() else f", {int((~ok).sum())} of {n} draws failed"
        ax_t.set_title(f"{rec.name}: RMS {fmt(rms)} {unit(y_unit)} (scored{failed})",
                       fontsize=9)
        ax_u.set_title(f"{rec.name}: residual against input", fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="upper right", markerscale=4)
    band = "" if sigma is None else ", dashed: ±2 noise.sigma (posterior mean)"
    title(fig, result, f"residuals, measured − posterior-mean prediction ({n} draws{band})")
    return fig


def plot_residuals(post: Posterior, result: SamplingResult, path: str | os.PathLike[str],
                   *, n_draws: int = 100, seed: int = 0) -> Path:
    """Write :func:`residuals_figure` as PNG.

    Parameters
    ----------
    post : Posterior
    result : SamplingResult
        Draws of ``post``.
    path : path-like
        Target PNG file.
    n_draws : int
        Posterior draws averaged.
    seed : int
        Selects the draws.

    Returns
    -------
    Path
        ``path``, written atomically.
    """
    path = png_path(path)
    return save_and_free(residuals_figure(post, result, n_draws=n_draws, seed=seed), path)


# ------------------------------------------------------------------------------ data
def _group_label(freq: float | None) -> str:
    return "unknown frequency" if freq is None else f"{freq:g} Hz"


def data_overview_figure(data: Dataset, *, fig: Figure | None = None,
                         max_panels: int = 12) -> Figure:
    """Measured loops (output against input), one panel per excitation frequency.

    The scored part of each record is drawn in colour, its warm-up in grey, so the
    reader sees what the likelihood is evaluated on.

    Parameters
    ----------
    data : Dataset
        The records; grouped by :meth:`Dataset.by_frequency`.
    fig : Figure, optional
        An empty figure to draw into (one panel per frequency); default a new one,
        3.2 in wide per column (at most 4) and 2.9 in high per row, at
        :data:`DATA_OVERVIEW_DPI`.
    max_panels : int
        At most this many frequencies are drawn (the lowest ones; the title says so).

    Returns
    -------
    Figure
        With one axes per frequency drawn.
    """
    if not isinstance(data, Dataset):
        raise ParameterError(f"data must be a Dataset, got {type(data).__name__}")
    max_panels = positive_int(max_panels, "max_panels")
    groups = data.by_frequency()
    keys = sorted(k for k in groups if k is not None) + ([None] if None in groups else [])
    shown = keys[:max_panels]
    n = len(shown)
    ncol = min(n, 4)
    nrow = math.ceil(n / ncol)
    fig = new_figure(fig, 3.2 * ncol + 0.4, 2.9 * nrow + 0.6, dpi=DATA_OVERVIEW_DPI)
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    for ax, key in zip(axes, shown, strict=False):
        for i, rec in enumerate(groups[key]):
            m = rec.scored_mask
            ax.plot(rec.u[~m], rec.y[~m], color="0.7", lw=0.7)
            ax.plot(rec.u[m], rec.y[m], color=f"C{i % 10}", lw=0.9,
                    label=rec.name if len(groups[key]) > 1 else None)
        first = groups[key][0]
        ax.set_title(f"{_group_label(key)} ({len(groups[key])} record"
                     f"{'s' if len(groups[key]) > 1 else ''})", fontsize=9)
        ax.set_xlabel(f"input [{unit(first.units.get('u', ''))}]", fontsize=8)
        ax.set_ylabel(f"output [{unit(first.units.get('y', ''))}]", fontsize=8)
        ax.tick_params(labelsize=7)
        if len(groups[key]) > 1 and len(groups[key]) <= 6:
            ax.legend(fontsize=6)
    for ax in axes[n:]:
        fig.delaxes(ax)
    more = f" (first {n} of {len(keys)} frequencies)" if n < len(keys) else ""
    fig.suptitle(f"measured loops per excitation frequency{more}; warm-up in grey",
                 fontsize=10)
    return fig


def plot_data_overview(data: Dataset, path: str | os.PathLike[str], *,
                       max_panels: int = 12) -> Path:
    """Write :func:`data_overview_figure` as PNG.

    Parameters
    ----------
    data : Dataset
    path : path-like
        Target PNG file.
    max_panels : int
        At most this many frequencies are drawn.

    Returns
    -------
    Path
        ``path``, written atomically.
    """
    path = png_path(path)
    return save_and_free(data_overview_figure(data, max_panels=max_panels), path)


# ------------------------------------------------------------------ uncertainty analysis
_BUDGET_COLOURS = {"noise": "0.65", "parameters": "C0", "discrepancy": "C1"}


def uncertainty_figure(budget: Sequence[Any], calibration: Any = None, *,
                       fig: Figure | None = None, y_unit: str = "") -> Figure:
    """The predictive's uncertainty budget per frequency, and its calibration check.

    Left: the predictive variance split into sensor noise, parameters and discrepancy
    (shares, stacked to 1), the predictive sd written above each bar. Right (with a
    calibration check): the PIT histogram of the held-out cycles per frequency, against
    the uniform share a calibrated predictive gives (a U shape: over-confident; a hump:
    under-confident).

    Parameters
    ----------
    budget : sequence of FrequencyBudget
        :attr:`~bayeshyst.inference.fit.FitResult.budget`.
    calibration : Calibration, optional
        :attr:`~bayeshyst.inference.fit.FitResult.calibration`.
    fig : Figure, optional
        An empty figure to draw into.
    y_unit : str
        Output unit (for the sd labels).

    Returns
    -------
    Figure
    """
    budget = list(budget)
    if not budget:
        raise ParameterError("budget is empty: nothing to draw")
    panels = 2 if calibration is not None else 1
    fig = new_figure(fig, 4.2 * panels + 0.4, 3.2)
    axes = fig.subplots(1, panels, squeeze=False)[0]
    ax = axes[0]
    x = np.arange(len(budget))
    bottom = np.zeros(len(budget))
    for source, colour in _BUDGET_COLOURS.items():
        share = np.array([b.shares[source] for b in budget])
        ax.bar(x, share, bottom=bottom, color=colour, label=source, width=0.7)
        bottom += share
    for i, b in enumerate(budget):
        ax.text(i, 1.02, f"{fmt(math.sqrt(b.total), '.3g')}", ha="center", fontsize=7)
    ax.set_xticks(x, [_group_label(b.frequency_hz) for b in budget], fontsize=7)
    ax.set_ylim(0, 1.12)
    ax.set_ylabel("share of the predictive variance", fontsize=8)
    sd_unit = unit(y_unit)
    ax.set_title(f"uncertainty budget (numbers: predictive sd{f' [{sd_unit}]' if sd_unit else ''})",
                 fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.tick_params(labelsize=7)
    if calibration is not None:
        ax = axes[1]
        for i, c in enumerate(calibration.per_frequency):
            hist = np.asarray(c.pit_histogram)
            edges = np.linspace(0.0, 1.0, hist.size + 1)
            ax.stairs(hist, edges, color=f"C{i % 10}", lw=1.2,
                      label=f"{_group_label(c.frequency_hz)}"
                            f"{'' if c.calibrated else ' (NOT calibrated)'}")
        ax.axhline(0.1, color="k", lw=0.8, ls="--", label="calibrated")
        ax.set_xlabel("PIT of the held-out samples", fontsize=8)
        ax.set_ylabel("share per bin", fontsize=8)
        ax.set_title("calibration on held-out cycles", fontsize=9)
        ax.legend(fontsize=6)
        ax.tick_params(labelsize=7)
    return fig
