"""Figures of the analyses above one fit: model selection, compensation and diagnosis.

Model selection per frequency, feedforward compensation, and the residual diagnosis
(residuals before and after, the evidence behind each effect's test).

Each ``*_figure`` function returns the Figure (drawn into the caller's empty figure, or
for the one-panel evidence figure into the caller's axes, when given); each ``plot_*``
function builds it and writes it as PNG (atomically, see
:func:`~bayeshyst.plotting.save_figure`) and returns the path. Bad input raises
:class:`~bayeshyst.errors.ParameterError` before anything is drawn or written; a fit
that did not converge is named in red in the title.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from bayeshyst.errors import ParameterError
from bayeshyst.plotting._common import (
    RED,
    axes_figure,
    fmt,
    label,
    new_figure,
    png_path,
    save_and_free,
    time_axis,
    unit,
    wrap_title,
)

__all__ = ["COMPENSATION_MAX_ROWS", "compensation_figure", "diagnosis_residuals_figure",
           "effect_evidence_figure", "model_comparison_figure", "plot_compensation",
           "plot_diagnosis_residuals", "plot_effect_evidence", "plot_model_comparison"]


# ------------------------------------------------------------------ model comparison
def model_comparison_figure(result: Any, *, fig: Figure | None = None) -> Figure:
    """Scores against frequency: elpd (relative to the best), tracking error, held-out elpd.

    Per-cycle values (elpd / number of cycles) make frequencies with different numbers
    of cycles comparable; fits that did not converge are marked with a red x and named
    in a red title. The held-out panel is drawn only when some fit has a
    leave-one-frequency-out score.

    Parameters
    ----------
    result : ComparisonResult
        From :func:`bayeshyst.selection.compare_models`; at least one record must have
        an excitation frequency.
    fig : Figure, optional
        An empty figure to draw into (two or three panels side by side); default a new
        one, 4.2 in wide per panel and 3.8 in high.

    Returns
    -------
    Figure
        With two or three axes.
    """
    from bayeshyst.selection import ComparisonResult

    if not isinstance(result, ComparisonResult):
        raise ParameterError(f"result must be a ComparisonResult, got {type(result).__name__}")
    rows = [fc for fc in result.per_frequency if fc.frequency_hz is not None]
    if not rows:
        raise ParameterError("no record has an excitation frequency: nothing to plot "
                             "against frequency")
    f = np.array([fc.frequency_hz for fc in rows], dtype=float)
    has_lofo = any(np.isfinite(s.elpd_lofo) for fc in rows for s in fc.scores)
    n_panels = 3 if has_lofo else 2
    fig = new_figure(fig, 4.2 * n_panels, 3.8)
    axes = fig.subplots(1, n_panels)
    colors = [f"C{i % 10}" for i in range(len(result.models))]
    unconverged = []
    for model, color in zip(result.models, colors, strict=True):
        scores = [fc.score(model) for fc in rows]
        d = np.array([s.delta_elpd / max(s.n_cycles, 1) for s in scores])
        dse = np.array([s.delta_se / max(s.n_cycles, 1) for s in scores])
        conv = np.array([s.converged for s in scores])
        if not conv.all():
            unconverged.append(model)
        axes[0].errorbar(f, d, yerr=np.where(np.isfinite(dse), 2 * dse, 0.0), color=color,
                         marker="o", ms=4, capsize=2, label=model)
        axes[0].plot(f[~conv], d[~conv], "x", color=RED, ms=9, mew=2)
        nrmse = np.array([s.nrmse_percent for s in scores])
        axes[1].plot(f, nrmse, marker="o", ms=4, color=color, label=model)
        if has_lofo:
            lofo = np.array([s.elpd_lofo / max(s.n_cycles, 1) for s in scores])
            axes[2].plot(f, lofo, marker="s", ms=4, color=color, label=model)
    axes[0].axhline(0.0, color="0.5", lw=0.8)
    axes[0].set_ylabel("Δelpd_loo per cycle vs best (±2 se)")
    axes[0].set_title("fitted at each frequency", fontsize=9)
    axes[1].set_ylabel("NRMSE of the posterior mean [% of stroke]")
    axes[1].set_title("tracking error", fontsize=9)
    positive = [s.nrmse_percent for fc in rows for s in fc.scores
                if np.isfinite(s.nrmse_percent) and s.nrmse_percent > 0]
    if positive and max(positive) / min(positive) > 20:
        axes[1].set_yscale("log")
    if has_lofo:
        axes[2].set_ylabel("held-out elpd per cycle")
        axes[2].set_title("fitted to the other frequencies", fontsize=9)
    for ax in axes:
        if f.size > 1 and f.max() / f.min() > 8:
            ax.set_xscale("log")
        # label the measured frequencies themselves, not log-decade minor ticks
        ax.set_xticks(f, [f"{x:g}" for x in f])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("excitation frequency [Hz]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    title = "model selection per frequency (higher elpd is better)"
    if unconverged:
        fig.suptitle(wrap_title(f"NOT CONVERGED (red x): {', '.join(unconverged)}\n{title}",
                                fig), fontsize=10, color=RED, fontweight="bold")
    else:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_model_comparison(result: Any, path: str | os.PathLike[str]) -> Path:
    """Write :func:`model_comparison_figure` as PNG.

    Parameters
    ----------
    result : ComparisonResult
        From :func:`bayeshyst.selection.compare_models`.
    path : path-like
        PNG file to write (atomically).

    Returns
    -------
    Path
        ``path``.
    """
    path = png_path(path)
    return save_and_free(model_comparison_figure(result), path)


# ---------------------------------------------------------------------- compensation
#: Rows of per-frequency panels drawn at most by :func:`plot_compensation`.
COMPENSATION_MAX_ROWS = 6
_COMMANDS = (("uncompensated", "uncompensated (scaled input)", "0.45"),
             ("nominal", "nominal (MAP inverse)", "C1"),
             ("posterior", "posterior-aware", "C0"),
             ("robust", "robust", "C2"))


def compensation_figure(result: Any, *, fig: Figure | None = None,
                        y_unit: str = "") -> Figure:
    """Feedforward tracking per frequency: plant outputs, errors, NRMSE against frequency.

    One row per reference (at most :data:`COMPENSATION_MAX_ROWS`; the title says when
    some are left out), over the scored samples: left, the reference, the plant's
    output under the nominal and the posterior-aware commands and the 90 % band the
    posterior predicts for the latter (shaded); middle, the tracking error ``y - y_d``
    of the four commands (uncompensated, nominal, posterior, robust) in % of the
    reference's stroke. Right, one panel for all rows: the realised tracking NRMSE of
    the four commands against frequency (log axis) with the predicted 90 % bands of the
    nominal and posterior commands as bars, a red x where the plant fell outside
    (with a reference file: the four commands side by side). The title names the plant
    and, in red, a fit that did not converge.

    Parameters
    ----------
    result : CompensationResult
        From :func:`bayeshyst.inverse.compensate.compensate`; at least one row.
    fig : Figure, optional
        An empty figure to draw into (a grid of panels); default a new one, 14 in wide
        and 2.9 in high per row.
    y_unit : str
        Unit of the output for the axis labels (e.g. ``"um"``).

    Returns
    -------
    Figure
        Two axes per row shown, and one for all rows.
    """
    from bayeshyst.inverse.compensate import CompensationResult

    if not isinstance(result, CompensationResult):
        raise ParameterError(f"result must be a CompensationResult, got "
                             f"{type(result).__name__}")
    if not result.rows:
        raise ParameterError("the compensation result has no rows: nothing to plot")
    rows = list(result.rows[:COMPENSATION_MAX_ROWS])
    n = len(rows)
    fig = new_figure(fig, 14.0, 2.9 * n + 1.2)
    grid = fig.add_gridspec(n, 3, width_ratios=[1.5, 1.5, 1.2])
    y_name = label("y", y_unit)
    for i, row in enumerate(rows):
        c = row.curves
        sc = np.asarray(c["scored"], dtype=bool)
        t, t_label = time_axis(np.asarray(c["t"], dtype=float)[sc])
        y_d = np.asarray(c["y_d"], dtype=float)
        stroke = float(np.ptp(y_d)) or 1.0
        ax_y = fig.add_subplot(grid[i, 0])
        ax_e = fig.add_subplot(grid[i, 1], sharex=ax_y)
        # left: what the plant did under the designed commands, with the predicted band
        ax_y.fill_between(t, np.asarray(c["band_lo"])[sc], np.asarray(c["band_hi"])[sc],
                          color="C0", alpha=0.25, lw=0,
                          label="90 % predicted output (posterior cmd)")
        ax_y.plot(t, y_d[sc], color="k", lw=1.6, ls="--", label="reference $y_d$")
        ax_y.plot(t, np.asarray(c["y_nominal"])[sc], color="C1", lw=1.0,
                  label="plant, nominal command")
        ax_y.plot(t, np.asarray(c["y_posterior"])[sc], color="C0", lw=1.0,
                  label="plant, posterior command")
        ax_y.set_ylabel(y_name)
        lo, hi = row.predicted_band_percent
        inside = row.realised_inside_band
        ax_y.set_title(f"{row.label}: plant output\nposterior command: NRMSE "
                       f"{fmt(row.posterior_nrmse_percent, '.3g')} %, predicted "
                       f"[{fmt(lo, '.3g')}, {fmt(hi, '.3g')}] %"
                       + ("" if inside else " (OUTSIDE)"),
                       fontsize=8.5, color="black" if inside else RED)
        # middle: tracking error of every command in % of the reference's stroke
        ax_e.fill_between(t, 100 * (np.asarray(c["band_lo"])[sc] - y_d[sc]) / stroke,
                          100 * (np.asarray(c["band_hi"])[sc] - y_d[sc]) / stroke,
                          color="C0", alpha=0.15, lw=0, label="90 % predicted (posterior)")
        for key, name, color in _COMMANDS:
            err = 100 * (np.asarray(c[f"y_{key}"], dtype=float)[sc] - y_d[sc]) / stroke
            ax_e.plot(t, err, color=color, lw=0.9 if key != "uncompensated" else 1.2,
                      label=name)
        ax_e.axhline(0.0, color="k", lw=0.6)
        ax_e.set_ylabel("$y - y_d$ [% of stroke]")
        nrmse = ", ".join(f"{'none' if key == 'uncompensated' else key} "
                          f"{fmt(getattr(row, f'{key}_nrmse_percent'), '.3g')}"
                          for key, _, _ in _COMMANDS)
        ax_e.set_title(f"{row.label}: tracking error\nNRMSE [%]: {nrmse}", fontsize=8.5)
        if i == 0:
            # one legend per column, above the curves of the first row
            for ax, ncols in ((ax_y, 2), (ax_e, 3)):
                lo_, hi_ = ax.get_ylim()
                ax.set_ylim(lo_, hi_ + 0.4 * (hi_ - lo_))
                ax.legend(fontsize=6.5, loc="upper center", ncols=ncols)
        if i == n - 1:
            ax_y.set_xlabel(t_label)
            ax_e.set_xlabel(t_label)
        for ax in (ax_y, ax_e):
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=8)
    # right: realised NRMSE of the four commands per frequency, predicted bands as bars
    ax_f = fig.add_subplot(grid[:, 2])
    every = list(result.rows)
    freq = [r for r in every if r.frequency_hz is not None]
    if freq:
        f = np.array([r.frequency_hz for r in freq], dtype=float)
        x_of = {key: f * 1.04 ** (j - 1.5) for j, (key, _, _) in enumerate(_COMMANDS)}
        ax_f.set_xscale("log")
        ax_f.set_xticks(f, [f"{x:g}" for x in f])
        ax_f.xaxis.set_minor_formatter(NullFormatter())
        ax_f.set_xlabel("excitation frequency [Hz]")
    else:  # one reference file: the commands side by side
        f = np.zeros(0)
        freq = every[:1]
        x_of = {key: np.array([j], dtype=float) for j, (key, _, _) in enumerate(_COMMANDS)}
        ax_f.set_xticks(range(len(_COMMANDS)), [k for k, _, _ in _COMMANDS], rotation=20,
                        fontsize=8)
        ax_f.set_xlim(-0.6, len(_COMMANDS) - 0.4)
        ax_f.set_xlabel(f"command (reference {every[0].reference})")
    for key, name, color in _COMMANDS:
        x = x_of[key]
        y = np.array([getattr(r, f"{key}_nrmse_percent") for r in freq], dtype=float)
        ax_f.plot(x, y, marker="o", ms=5, color=color, lw=1.0 if f.size else 0, label=name)
        band = {"posterior": "predicted_band_percent",
                "nominal": "nominal_predicted_band_percent"}.get(key)
        if band is not None:
            b = np.array([getattr(r, band) for r in freq], dtype=float).reshape(-1, 2)
            ax_f.errorbar(x, b.mean(axis=1), yerr=np.abs(np.diff(b, axis=1)).ravel() / 2,
                          fmt="none", ecolor=color, elinewidth=2.5, capsize=4, alpha=0.5,
                          label=f"{key}: 90 % predicted band")
            missed = np.array([not r.realised_inside_band for r in freq])
            if key == "posterior" and missed.any():
                ax_f.plot(x[missed], y[missed], "x", color=RED, ms=10, mew=2,
                          label="outside its predicted band")
    positive = [getattr(r, f"{k}_nrmse_percent") for r in freq for k, _, _ in _COMMANDS]
    positive = [v for v in positive if np.isfinite(v) and v > 0]
    if positive and max(positive) / min(positive) > 20:
        ax_f.set_yscale("log")
    ax_f.set_ylabel("tracking NRMSE [% of stroke]")
    ax_f.set_title("realised on the plant; bars: predicted 90 % band", fontsize=9)
    ax_f.grid(alpha=0.3)
    ax_f.legend(fontsize=7, loc="best")
    plant = {"virtual actuator": "virtual actuator (the simulator behind the data, measured "
                                 "with its sensor noise)",
             "posterior draw": "held-out posterior draws (no ground truth)"}.get(
                 result.plant_kind, result.plant_kind)
    title = f"feedforward compensation with {result.model}; plant: {plant}"
    if len(every) > n:
        title += f"\nfirst {n} of {len(every)} references shown (right panel: all)"
    if result.converged:
        fig.suptitle(wrap_title(title, fig), fontsize=10)
    else:
        fig.suptitle(wrap_title("NOT CONVERGED: the fit behind the design did not "
                                f"converge\n{title}", fig),
                     fontsize=10, color=RED, fontweight="bold")
    return fig


def plot_compensation(result: Any, path: str | os.PathLike[str], *, y_unit: str = "") -> Path:
    """Write :func:`compensation_figure` as PNG.

    Parameters
    ----------
    result : CompensationResult
        From :func:`bayeshyst.inverse.compensate.compensate`.
    path : path-like
        PNG file to write (atomically).
    y_unit : str
        Unit of the output for the axis labels (e.g. ``"um"``).

    Returns
    -------
    Path
        ``path``.
    """
    path = png_path(path)
    return save_and_free(compensation_figure(result, y_unit=y_unit), path)


# ------------------------------------------------------------------------- diagnosis
def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else math.nan


def diagnosis_residuals_figure(result: Any, *, fig: Figure | None = None) -> Figure:
    """Residuals before and after the diagnosis, against time, one panel per record.

    Grey: the residual of the base model's posterior-mean prediction; blue: that of the
    final (augmented) model, when the loop kept an effect. The title names both models
    once, the effects found and, in red, a fit that did not converge; each panel's
    legend gives the two RMS over the record's scored samples (model names in every
    legend covered a third of the panel on composites with four blocks).

    Parameters
    ----------
    result : DiagnosisResult
        From :func:`bayeshyst.diagnosis.diagnose`.
    fig : Figure, optional
        An empty figure to draw into (one panel per record); default a new one, 10 in
        wide and 2.4 in high per record.

    Returns
    -------
    Figure
        With one axes per record.
    """
    from bayeshyst.diagnosis import DiagnosisResult

    if not isinstance(result, DiagnosisResult):
        raise ParameterError(f"result must be a DiagnosisResult, got {type(result).__name__}")
    base, final = result.base, result.final
    same = final is base
    records = list(base.posterior.data)
    fig = new_figure(fig, 10.0, 2.4 * len(records) + 1.0)
    axes = fig.subplots(len(records), 1, squeeze=False)[:, 0]
    fits = [(base, "base model" if same else "before", "0.55")]
    if not same:
        fits.append((final, "after", "C0"))
    for i, (ax, rec) in enumerate(zip(axes, records, strict=True)):
        y_unit = unit(rec.units.get("y", ""))
        for fit, name, color in fits:
            t, t_label = time_axis(np.asarray(fit.analysis.time[i], dtype=float))
            r = np.asarray(fit.analysis.residual[i], dtype=float)
            rms = f"{fmt(_rms(r))} {y_unit}".strip()
            ax.plot(t, r, lw=0.7, color=color, label=f"{name} (RMS {rms})")
        ax.axhline(0.0, color="k", lw=0.6)
        f = "" if rec.frequency_hz is None else f" ({rec.frequency_hz:g} Hz)"
        ax.set_title(f"{rec.name}{f}", fontsize=9)
        ax.set_ylabel(label("residual", rec.units.get("y", "")))
        ax.legend(fontsize=7, loc="upper right", framealpha=0.85)
        ax.grid(alpha=0.3)
        if i == len(records) - 1:
            ax.set_xlabel(t_label)
    found = ", ".join(result.effects_found) or "none"
    models = (f"model: {result.base_model} (the base model was kept)" if same else
              f"before: {result.base_model}\nafter: {result.final_model}")
    title = (f"diagnosis: effects found: {found}\n{models}\n"
             "residual (measured − posterior-mean prediction) on the scored samples")
    if base.sampling.converged and final.sampling.converged:
        fig.suptitle(wrap_title(title, fig), fontsize=10)
    else:
        which = [f.label for f in ((base,) if same else (base, final))
                 if not f.sampling.converged]
        fig.suptitle(wrap_title(f"NOT CONVERGED: {'; '.join(which)}\n{title}", fig),
                     fontsize=10, color=RED, fontweight="bold")
    return fig


def plot_diagnosis_residuals(result: Any, path: str | os.PathLike[str]) -> Path:
    """Write :func:`diagnosis_residuals_figure` as PNG.

    Parameters
    ----------
    result : DiagnosisResult
        From :func:`bayeshyst.diagnosis.diagnose`.
    path : path-like
        PNG file to write (atomically).

    Returns
    -------
    Path
        ``path``.
    """
    path = png_path(path)
    return save_and_free(diagnosis_residuals_figure(result), path)


def effect_evidence_figure(test: Any, *, ax: Axes | None = None,
                           y_unit: str = "") -> Figure:
    """The evidence behind one effect's residual test, as a scatter plot.

    Grey: the residual beyond what the fit's own parameters can absorb (for coloured
    noise: the residual after the fit and the significant structural effects) against
    the effect's explaining variable (time for creep and drift, the model output's rate
    for delay and rate dependence, the normalised output for asymmetry, the previous
    residual for coloured noise). Coloured (red when the test fires): the effect's fitted
    contribution. The title gives the statistic, the p-value (unadjusted and Holm) and
    the log Bayes factor.

    Parameters
    ----------
    test : EffectTest
        A test that was carried out; a skipped test (``test.skipped``) has no evidence
        and raises :class:`~bayeshyst.errors.ParameterError`.
    ax : Axes, optional
        Axes to draw into; the verdict then becomes the axes' title (the caller's
        figure keeps its own). Default: a new 6.4 × 4.6 in figure, with the verdict as
        its title.
    y_unit : str
        Unit of the output (e.g. ``"um"``), for the labels.

    Returns
    -------
    Figure
        The new figure, or the figure ``ax`` belongs to.
    """
    from bayeshyst.diagnosis import EffectTest

    if not isinstance(test, EffectTest):
        raise ParameterError(f"test must be an EffectTest, got {type(test).__name__}")
    if test.skipped is not None:
        raise ParameterError(f"{test.effect} was not tested ({test.skipped}): no evidence "
                             "to plot")
    ev = test.evidence
    missing = [k for k in test.EVIDENCE_KEYS if k not in ev]
    if missing:
        raise ParameterError(f"{test.effect}: the evidence lacks {missing}")
    x = np.asarray(ev["x"], dtype=float)
    r = np.asarray(ev["partial_residual"], dtype=float)
    c = np.asarray(ev["component"], dtype=float)
    if not x.shape == r.shape == c.shape:
        raise ParameterError(f"{test.effect}: evidence arrays of different shapes "
                             f"{x.shape}, {r.shape}, {c.shape}")
    ok = np.isfinite(x) & np.isfinite(r) & np.isfinite(c)
    u = unit(y_unit)
    x_label = str(ev.get("x_label", "") or "x")
    if u:
        x_label = re.sub(r"\bunit\b", u, x_label)
    fig, ax, own = axes_figure(ax, 6.4, 4.6)
    color = RED if test.significant else "C0"
    ax.plot(x[ok], r[ok], ".", ms=2.0, color="0.75", label="partial residual")
    rms = f"{fmt(test.explained_rms)} {u}".strip()
    ax.plot(x[ok], c[ok], ".", ms=2.5, color=color,
            label=f"fitted {test.effect} component (RMS {rms})")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel(x_label)
    ax.set_ylabel(label("residual", y_unit))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best", markerscale=4)
    verdict = "FIRES" if test.significant else "does not fire"
    # a figure of its own carries the verdict as its title; a caller's axes as its own
    set_title = fig.suptitle if own else ax.set_title
    set_title(f"{test.effect}: {verdict}\n{test.statistic} = {fmt(test.value, '.3g')}, "
              f"p = {fmt(test.p_value, '.2g')} (Holm {fmt(test.p_adjusted, '.2g')}), "
              f"log BF {fmt(test.log_bayes_factor, '.1f')}", fontsize=10,
              color=color if test.significant else "black")
    return fig


def plot_effect_evidence(test: Any, path: str | os.PathLike[str], *, y_unit: str = "") -> Path:
    """Write :func:`effect_evidence_figure` as PNG.

    Parameters
    ----------
    test : EffectTest
        A test that was carried out; a skipped test (``test.skipped``) has no evidence
        and raises :class:`~bayeshyst.errors.ParameterError`, writing nothing.
    path : path-like
        PNG file to write (atomically).
    y_unit : str
        Unit of the output (e.g. ``"um"``), for the labels.

    Returns
    -------
    Path
        ``path``.
    """
    path = png_path(path)
    return save_and_free(effect_evidence_figure(test, y_unit=y_unit), path)
