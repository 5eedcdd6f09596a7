"""Figures only the HTML report draws (the per-command figures live in :mod:`bayeshyst.plotting`).

Built with matplotlib's object-oriented API on an Agg canvas (no pyplot), written
atomically as PNG.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from bayeshyst.data.record import Dataset
from bayeshyst.files import atomic_path
from bayeshyst.report.html import unit_text

__all__ = ["plot_data_overview"]

DPI = 110


def _group_label(freq: float | None) -> str:
    return "unknown frequency" if freq is None else f"{freq:g} Hz"


def plot_data_overview(data: Dataset, path: str | Path, *, max_panels: int = 12) -> Path:
    """Measured loops (output against input), one panel per excitation frequency.

    The scored part of each record is drawn in colour, its warm-up in grey, so the
    reader sees what the likelihood is evaluated on.

    Parameters
    ----------
    data : Dataset
    path : path-like
        Target PNG file (written atomically).
    max_panels : int
        At most this many frequencies are drawn (the lowest ones; the caption says so).
    """
    groups = data.by_frequency()
    keys = sorted(k for k in groups if k is not None) + ([None] if None in groups else [])
    shown = keys[:max_panels]
    n = len(shown)
    ncol = min(n, 4)
    nrow = math.ceil(n / ncol)
    fig = Figure(figsize=(3.2 * ncol + 0.4, 2.9 * nrow + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
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
        ax.set_xlabel(f"input [{unit_text(first.units.get('u', ''))}]", fontsize=8)
        ax.set_ylabel(f"output [{unit_text(first.units.get('y', ''))}]", fontsize=8)
        ax.tick_params(labelsize=7)
        if len(groups[key]) > 1 and len(groups[key]) <= 6:
            ax.legend(fontsize=6)
    for ax in axes[n:]:
        fig.delaxes(ax)
    more = f" (first {n} of {len(keys)} frequencies)" if n < len(keys) else ""
    fig.suptitle(f"measured loops per excitation frequency{more}; warm-up in grey",
                 fontsize=10)
    path = Path(path)
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            fig.savefig(fh, format="png", dpi=DPI)
    finally:
        fig.clear()
    return path
