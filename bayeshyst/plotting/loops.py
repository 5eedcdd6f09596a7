"""The compared models' predicted loops per frequency (the report's model-selection view).

:func:`model_loops_figure` draws, for each frequency, the measured loop with every
parametric model's posterior-mean loop overlaid and the 90 % band of the frequency's
best of them, and below it each model's error against time with that band.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from bayeshyst.errors import ParameterError
from bayeshyst.plotting._common import (
    fmt,
    label,
    new_figure,
    png_path,
    save_and_free,
    time_axis,
)

__all__ = ["LOOPS_MAX_COLUMNS", "model_loops_figure", "plot_model_loops"]

#: frequencies shown side by side (the rest are in the report's tables)
LOOPS_MAX_COLUMNS = 6


def model_loops_figure(loops: Sequence[Any], *, fig: Figure | None = None,
                       u_unit: str = "", y_unit: str = "") -> Figure:
    """Measured and predicted loops per frequency, competing models overlaid.

    One column per frequency (at most :data:`LOOPS_MAX_COLUMNS`), over the scored
    samples of that frequency's first record: top, the measured loop (grey) with each
    parametric model's posterior-mean loop (one colour per model, the same in every
    column) and the band of the first-ranked of them (dashed, its colour); bottom, each
    model's error ``mean - y`` against time with that model's band around zero.

    Parameters
    ----------
    loops : sequence of FrequencyLoops
        From :func:`bayeshyst.selection.predictions.predicted_loops`; at least one.
    fig : Figure, optional
        An empty figure to draw into; default a new one, 3.4 in wide per column.
    u_unit, y_unit : str
        Units for the axis labels.

    Returns
    -------
    Figure
    """
    from bayeshyst.plotting.study import model_colors

    loops = list(loops)[:LOOPS_MAX_COLUMNS]
    if not loops:
        raise ParameterError("no predicted loops to plot")
    names = list(dict.fromkeys(m.model for fl in loops for m in fl.models))
    colors = model_colors(names)
    n = len(loops)
    fig = new_figure(fig, max(3.4 * n, 6.0), 6.6)
    grid = fig.add_gridspec(2, n, height_ratios=[1.3, 1.0])
    for j, fl in enumerate(loops):
        sc = np.asarray(fl.scored, dtype=bool)
        ax = fig.add_subplot(grid[0, j])
        ax.plot(fl.u[sc], fl.y[sc], color="0.55", lw=2.2, alpha=0.6, label="measured")
        first = fl.models[0]
        ax.plot(fl.u[sc], first.lo[sc], color=colors[first.model], lw=0.8, ls="--",
                label=f"{first.model}: {round(100 * fl.prob)} % band")
        ax.plot(fl.u[sc], first.hi[sc], color=colors[first.model], lw=0.8, ls="--")
        for m in fl.models:
            ax.plot(fl.u[sc], m.mean[sc], color=colors[m.model], lw=1.0,
                    label=f"{m.model} ({fmt(m.nrmse_percent, '.3g')} %)")
        best = "" if fl.best is None else f"\nbest by elpd: {fl.best}"
        ax.set_title(f"{fl.frequency_hz:g} Hz: loops{best}", fontsize=8.5)
        ax.set_xlabel(label("u", u_unit), fontsize=8)
        if j == 0:
            ax.set_ylabel(label("y", y_unit), fontsize=8)
        ax.legend(fontsize=6, loc="upper left")
        ax_e = fig.add_subplot(grid[1, j])
        t, t_label = time_axis(np.asarray(fl.t, float)[sc])
        ax_e.fill_between(t, (first.lo - first.mean)[sc], (first.hi - first.mean)[sc],
                          color=colors[first.model], alpha=0.2, lw=0)
        for m in fl.models:
            ax_e.plot(t, (m.mean - fl.y)[sc], color=colors[m.model], lw=0.8)
        ax_e.axhline(0.0, color="k", lw=0.6)
        ax_e.set_xlabel(t_label, fontsize=8)
        if j == 0:
            ax_e.set_ylabel(f"prediction - measured [{y_unit}]" if y_unit else
                            "prediction - measured", fontsize=8)
        ax_e.set_title("error (band of the first-ranked model)", fontsize=8)
        for a in (ax, ax_e):
            a.grid(alpha=0.3)
            a.tick_params(labelsize=7)
    fig.suptitle("Compared models' predicted loops per frequency\n(posterior mean; NRMSE "
                 "in % of the measured peak-to-peak)", fontsize=9.5)
    return fig


def plot_model_loops(loops: Sequence[Any], path: str | os.PathLike[str], *,
                     u_unit: str = "", y_unit: str = "") -> Path:
    """Write :func:`model_loops_figure` as PNG (atomically); returns ``path``."""
    path = png_path(path)
    return save_and_free(model_loops_figure(loops, u_unit=u_unit, y_unit=y_unit), path)
