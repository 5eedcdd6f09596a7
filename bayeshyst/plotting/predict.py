"""The figure of a prediction on a record: measured against predicted, the error, the loops.

One figure per record of a :class:`~bayeshyst.inference.predict.PredictionResult`
(what ``bayeshyst predict`` writes): the measured output and the predictive mean with
its 50 % and 90 % bands over time; the error ``y - mean`` with the bands about the
mean (a calibrated band holds the error 50 and 90 % of the time); and the loops, output
against input, measured and predicted.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from bayeshyst.errors import ParameterError
from bayeshyst.inference.predict import PredictionResult
from bayeshyst.plotting._common import (
    RED,
    fmt,
    label,
    new_figure,
    save_and_free,
    time_axis,
    unit,
    wrap_title,
)

__all__ = ["plot_prediction", "prediction_figure"]

#: samples drawn per line at most: a 150 000-sample sweep is thinned evenly (every k-th
#: sample) so that the figure stays light; the scores use every sample
MAX_POINTS = 20_000


def _record(result: Any, record: str | None) -> Any:
    if not isinstance(result, PredictionResult):
        raise ParameterError(f"result must be a PredictionResult, got {type(result).__name__}")
    if record is None:
        return result.records[0]
    try:
        return result[record]
    except KeyError as exc:
        raise ParameterError(str(exc)) from exc


def prediction_figure(result: Any, record: str | None = None, *,
                      fig: Figure | None = None) -> Figure:
    """Measured against predicted for one record of a prediction (see the module).

    Parameters
    ----------
    result : PredictionResult
    record : str, optional
        The record's name; default the first.
    fig : Figure, optional
        An empty figure to draw into.

    Returns
    -------
    Figure
    """
    rec = _record(result, record)
    score = next((s for s in result.per_record if s.name == rec.name), None)
    fig = new_figure(fig, 11.0, 7.0)
    grid = fig.add_gridspec(2, 3)
    ax_t = fig.add_subplot(grid[0, :2])
    ax_e = fig.add_subplot(grid[1, :2], sharex=ax_t)
    ax_l = fig.add_subplot(grid[:, 2])
    step = max(1, rec.t.size // MAX_POINTS)
    k = slice(None, None, step)
    t, t_label = time_axis(rec.t)
    t = t[k]
    y_unit, u_unit = result.units.get("y", ""), result.units.get("u", "")
    lo90, hi90 = rec.band(0.9)
    lo50, hi50 = rec.band(0.5)
    ax_t.fill_between(t, lo90[k], hi90[k], color="C0", alpha=0.18, lw=0, label="90 % band")
    ax_t.fill_between(t, lo50[k], hi50[k], color="C0", alpha=0.35, lw=0, label="50 % band")
    if rec.measured:
        ax_t.plot(t, rec.y[k], color="k", lw=0.7, label="measured")
    ax_t.plot(t, rec.mean[k], color="C0", lw=0.9, label="predicted mean")
    if not rec.scored.all():
        # the samples not scored (warm-up): shaded so that nobody reads the error there
        first = int(np.argmax(rec.scored))
        if first > 0:
            for ax in (ax_t, ax_e):
                ax.axvspan(t[0], time_axis(rec.t)[0][first], color="0.85", lw=0,
                           label="not scored" if ax is ax_t else None)
    ax_t.set_ylabel(label("output", y_unit))
    ax_t.legend(loc="upper right", fontsize=8, ncols=3)
    err = (rec.y - rec.mean)[k]
    ax_e.fill_between(t, (lo90 - rec.mean)[k], (hi90 - rec.mean)[k], color="C0", alpha=0.18,
                      lw=0)
    ax_e.fill_between(t, (lo50 - rec.mean)[k], (hi50 - rec.mean)[k], color="C0", alpha=0.35,
                      lw=0)
    if rec.measured:
        ax_e.plot(t, err, color="k", lw=0.6)
    ax_e.axhline(0.0, color="0.5", lw=0.5)
    ax_e.set_ylabel(label("measured - predicted" if rec.measured else "band about the mean",
                          y_unit))
    ax_e.set_xlabel(t_label)
    if rec.measured:
        ax_l.plot(rec.u[k], rec.y[k], color="k", lw=0.6, label="measured")
    ax_l.plot(rec.u[k], rec.mean[k], color="C0", lw=0.8, label="predicted")
    ax_l.set_xlabel(label("input", u_unit))
    ax_l.set_ylabel(label("output", y_unit))
    ax_l.legend(loc="best", fontsize=8)
    text = (f"{result.model} on {rec.name} ({rec.group}); initial state: "
            f"{result.initial.kind}\n")
    if score is None:  # an input alone: nothing measured to score against
        text += "no measured output: the predictive mean and its 50 / 90 % bands"
    else:
        cov = ", ".join(f"{int(100 * p)} % band {100 * c:.1f} %"
                        for p, c in score.coverage.items())
        text += (f"RMSE {fmt(score.rmse)} {unit(y_unit)} "
                 f"({fmt(score.nrmse_percent, '.3g')} %), fit "
                 f"{fmt(score.fit_percent, '.2f')} %, {cov}")
    calibrated = score is None or score.calibrated
    if not calibrated:
        text += " - bands NOT calibrated here"
    fig.suptitle(wrap_title(text, fig), fontsize=10,
                 color="k" if calibrated else RED)
    return fig


def plot_prediction(result: Any, path: str | os.PathLike[str], record: str | None = None
                    ) -> Path:
    """:func:`prediction_figure` written as PNG to ``path`` (atomically)."""
    return save_and_free(prediction_figure(result, record), Path(path))
