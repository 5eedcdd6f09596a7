"""What every figure of :mod:`bayeshyst.plotting` shares: the canvas, PNG output, labels.

Figures are built with matplotlib's object-oriented API on an Agg canvas
(``matplotlib.figure.Figure`` + ``FigureCanvasAgg``): pyplot is never imported, so no
global figure registry, no window and nothing to close — a figure is freed as soon as
it is no longer referenced, and the interactive backend of the caller's session is left
alone. A caller may instead hand in a figure of its own (a notebook's ``plt.figure()``);
it is drawn into as it is, with constrained layout switched on when it has no layout of
its own.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from bayeshyst.errors import ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.inference.sampling_result import SamplingResult

__all__ = ["DPI", "RED", "axes_figure", "check_result", "fmt", "label", "new_figure",
           "png_path", "positive_int", "probability", "save_and_free", "save_figure",
           "time_axis", "title", "unit", "wrap_title"]

#: Resolution of the PNG files of a new figure (dots per inch).
DPI = 120
#: The colour of a warning: a run that did not converge, a test that fires.
RED = "#c0392b"


# --------------------------------------------------------------------------- labels
def fmt(x: float, spec: str = ".4g") -> str:
    """A number for a label; never 'nan'."""
    return format(x, spec) if np.isfinite(x) else "n/a"


def unit(text: str) -> str:
    """A unit as a reader writes it: ``um`` -> ``µm`` (also inside ``um/V``)."""
    return re.sub(r"\bum\b", "µm", text or "")


def label(name: str, unit_: str) -> str:
    """``name [unit]``, or just ``name`` for a dimensionless quantity."""
    u = unit(unit_)
    return f"{name} [{u}]" if u and u != "1" else name


def time_axis(t: np.ndarray) -> tuple[np.ndarray, str]:
    """Times in s, or in ms when the record is shorter than half a second."""
    span = float(t[-1] - t[0]) if t.size else 0.0
    return (1e3 * t, "t [ms]") if 0 < span < 0.5 else (t, "t [s]")


def _wrap_line(line: str, width: int) -> str:
    # break before a '+' that joins two blocks of a composite's name, or after a space;
    # a piece longer than the width stays whole on a line of its own
    pieces = [p for p in re.split(r"(?=\+)|(?<= )(?=\S)", line) if p]
    lines, current = [], ""
    for piece in pieces:
        if current and len(current) + len(piece.rstrip()) > width:
            lines.append(current.rstrip())
            current = piece
        else:
            current += piece
    lines.append(current.rstrip())
    return "\n".join(lines)


def wrap_title(text: str, fig: Figure, fontsize: float = 10.0) -> str:
    """``text`` with each line longer than ``fig`` is wide broken into several.

    A composite model's name runs to 150 characters and more; a figure title does not
    wrap, so such a line was cut off at both edges of the figure. Lines are broken
    before a ``+`` joining two blocks or after a space, for a width estimated from the
    figure's width and the font size (0.62 em per character, which DejaVu Sans' average
    character does not exceed).

    Parameters
    ----------
    text : str
        The title, lines separated by ``\\n``.
    fig : Figure
        The figure it goes on; its width sets the line length.
    fontsize : float
        Of the title, in points.

    Returns
    -------
    str
        ``text``, its long lines broken with ``\\n``; short lines as they were.
    """
    width = max(20, int(fig.get_figwidth() * 72.0 / (0.62 * fontsize)))
    return "\n".join(_wrap_line(line, width) for line in text.split("\n"))


def title(fig: Figure, result: SamplingResult, what: str) -> None:
    """Figure title; a run that has not converged gets a red banner."""
    conv = result.convergence
    if conv.converged:
        text = (f"{result.model} / {result.likelihood}: {what}\nconverged (R-hat max "
                f"{fmt(conv.rhat_max, '.3f')}, ESS bulk min "
                f"{fmt(conv.ess_bulk_min, '.0f')})")
        fig.suptitle(wrap_title(text, fig), fontsize=10)
    else:
        reasons = "; ".join(conv.reasons) or "see the convergence report"
        text = f"NOT CONVERGED: {reasons}\n{result.model} / {result.likelihood}: {what}"
        fig.suptitle(wrap_title(text, fig), fontsize=10, color=RED, fontweight="bold")


# ------------------------------------------------------------------------ arguments
def positive_int(value: Any, what: str) -> int:
    """``value`` as an int >= 1, else :class:`ParameterError` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ParameterError(f"{what} must be a positive integer, got {value!r}")
    return int(value)


def probability(prob: Any) -> float:
    """``prob`` as a float in (0, 1), else :class:`ParameterError`."""
    if not (isinstance(prob, float | int) and 0.0 < float(prob) < 1.0):
        raise ParameterError(f"prob must be in (0, 1), got {prob!r}")
    return float(prob)


def check_result(result: Any) -> None:
    """:class:`ParameterError` unless ``result`` is a :class:`SamplingResult`."""
    if not isinstance(result, SamplingResult):
        raise ParameterError(f"result must be a SamplingResult, got {type(result).__name__}")


def png_path(path: str | os.PathLike[str]) -> Path:
    """``path`` as a Path, refused (:class:`ParameterError`) unless it ends in .png."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ParameterError(f"figures are written as PNG: {path} must end in .png")
    return path


# -------------------------------------------------------------------------- figures
def new_figure(fig: Figure | None, width: float, height: float, *,
               dpi: float = DPI) -> Figure:
    """The figure a multi-panel function draws on.

    Parameters
    ----------
    fig : Figure or None
        The caller's figure, which must have no axes yet (a figure's panels are laid out
        by the function that draws them); None for a new one.
    width, height : float
        Size in inches of a new figure (the caller's keeps its own).
    dpi : float
        Resolution of a new figure, used when it is saved (:func:`save_figure`).

    Returns
    -------
    Figure
        A new figure on an Agg canvas with constrained layout, or ``fig``.
    """
    if fig is None:
        new = Figure(figsize=(width, height), layout="constrained", dpi=dpi)
        FigureCanvasAgg(new)
        return new
    if not isinstance(fig, Figure):
        raise ParameterError(f"fig must be a matplotlib Figure, got {type(fig).__name__}")
    if fig.axes:
        raise ParameterError(f"fig must be empty: it has {len(fig.axes)} axes already (this "
                             "figure lays out its own panels)")
    if fig.get_layout_engine() is None:
        # the panels, titles and outside legends are placed by constrained layout
        fig.set_layout_engine("constrained")
    return fig


def axes_figure(ax: Axes | None, width: float, height: float) -> tuple[Figure, Axes, bool]:
    """The figure and axes a one-panel function draws on, and whether it owns the figure.

    Parameters
    ----------
    ax : Axes or None
        The caller's axes; None for a new figure with one axes.
    width, height : float
        Size in inches of a new figure.

    Returns
    -------
    fig : Figure
        The (root) figure of ``ax``, or the new one.
    ax : Axes
    own : bool
        True for a new figure (its title may be the figure's), False for the caller's.
    """
    if ax is None:
        fig = new_figure(None, width, height)
        return fig, fig.add_subplot(), True
    if not isinstance(ax, Axes):
        raise ParameterError(f"ax must be a matplotlib Axes, got {type(ax).__name__}")
    root = ax.figure
    while not isinstance(root, Figure):  # an axes of a SubFigure: its root figure
        root = root.figure
    return root, ax, False


def save_figure(fig: Figure, path: str | os.PathLike[str]) -> Path:
    """Write ``fig`` to ``path`` as PNG, atomically, at the figure's own resolution.

    The image goes to a temporary file in the same folder, renamed into place once it is
    whole (:func:`bayeshyst.files.atomic_path`): a failure leaves no file behind and an
    existing file as it was. The figure is left as it is (draw on, save again).

    Parameters
    ----------
    fig : Figure
        Any matplotlib figure (one of this package's, or a pyplot one).
    path : path-like
        Target file; must end in ``.png``. Its folder is created if needed.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        ``path`` does not end in .png, or ``fig`` is not a Figure (nothing is written).
    """
    path = png_path(path)
    if not isinstance(fig, Figure):
        raise ParameterError(f"fig must be a matplotlib Figure, got {type(fig).__name__}")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fig.savefig(fh, format="png", dpi="figure")
    return path


def save_and_free(fig: Figure, path: Path) -> Path:
    """:func:`save_figure`, then clear the figure (the ``plot_*`` functions own theirs,
    and a cleared figure frees its artists at once, not at the next garbage collection)."""
    try:
        return save_figure(fig, path)
    finally:
        fig.clear()
