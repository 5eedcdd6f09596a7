"""Figures: of a fit, of the analyses above it, of the data and of a study.

This package is the only part of bayeshyst that imports matplotlib. Its figures are
built with the object-oriented API on an Agg canvas (no pyplot: no global figure
registry, no window, nothing to close), so they work the same in a script, on a
cluster and in a notebook.

Two kinds of public function:

- ``*_figure(...)`` builds and **returns** a :class:`matplotlib.figure.Figure`. Given
  ``fig=`` (an empty figure, e.g. a notebook's ``plt.figure()``) it draws into it; the
  one-panel :func:`effect_evidence_figure` takes ``ax=`` instead. Multi-panel figures
  take a figure, not an axes, because they lay out their own panels.
- ``plot_*(..., path)`` builds the same figure and writes it as PNG with
  :func:`save_figure` (atomically: a temporary file in the same folder, then
  ``os.replace``), returning the path.

Bad input raises :class:`~bayeshyst.errors.ParameterError` before anything is drawn or
written. A run that has not converged says so in red in the title of every figure.
"""

from __future__ import annotations

from bayeshyst.plotting._common import DPI, save_figure
from bayeshyst.plotting.fit import (
    DATA_OVERVIEW_DPI,
    data_overview_figure,
    loops_figure,
    plot_data_overview,
    plot_loops,
    plot_residuals,
    residuals_figure,
    uncertainty_figure,
)
from bayeshyst.plotting.loops import LOOPS_MAX_COLUMNS, model_loops_figure, plot_model_loops
from bayeshyst.plotting.posterior import (
    corner_figure,
    draws_corner_figure,
    plot_corner,
    plot_draws_corner,
    plot_trace,
    trace_figure,
)
from bayeshyst.plotting.selection import (
    COMPENSATION_MAX_ROWS,
    compensation_figure,
    diagnosis_residuals_figure,
    effect_evidence_figure,
    model_comparison_figure,
    plot_compensation,
    plot_diagnosis_residuals,
    plot_effect_evidence,
    plot_model_comparison,
)
from bayeshyst.plotting.study import (
    best_model_figure,
    model_colors,
    plot_best_model,
    plot_scores_vs_frequency,
    scores_vs_frequency_figure,
    study_figures,
)

__all__ = [
    "COMPENSATION_MAX_ROWS",
    "DATA_OVERVIEW_DPI",
    "DPI",
    "LOOPS_MAX_COLUMNS",
    "best_model_figure",
    "compensation_figure",
    "corner_figure",
    "data_overview_figure",
    "diagnosis_residuals_figure",
    "draws_corner_figure",
    "effect_evidence_figure",
    "loops_figure",
    "model_colors",
    "model_comparison_figure",
    "model_loops_figure",
    "plot_best_model",
    "plot_compensation",
    "plot_corner",
    "plot_data_overview",
    "plot_diagnosis_residuals",
    "plot_draws_corner",
    "plot_effect_evidence",
    "plot_loops",
    "plot_model_comparison",
    "plot_model_loops",
    "plot_residuals",
    "plot_scores_vs_frequency",
    "plot_trace",
    "residuals_figure",
    "save_figure",
    "scores_vs_frequency_figure",
    "study_figures",
    "trace_figure",
    "uncertainty_figure",
]
