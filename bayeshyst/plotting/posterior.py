"""Figures in parameter space: traces with rank plots, and corner plots.

Corner plots of a sampling result, or of draws given as arrays (e.g. read from a saved
netCDF).

Each ``*_figure`` function returns the Figure (drawn into the caller's empty figure when
given one); each ``plot_*`` function builds it and writes it as PNG (atomically, see
:func:`~bayeshyst.plotting.save_figure`) and returns the path. Values are in physical
units; no third-party corner package is used. Naming an unknown or fixed parameter
raises :class:`~bayeshyst.errors.ParameterError` before anything is drawn or written.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from bayeshyst.errors import ParameterError
from bayeshyst.inference.convergence import hdi, rhat
from bayeshyst.inference.sampling_result import SamplingResult
from bayeshyst.params import ParamSpace
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
)

__all__ = ["corner_figure", "draws_corner_figure", "plot_corner", "plot_draws_corner",
           "plot_trace", "trace_figure"]


@dataclass(frozen=True)
class _Element:
    """One free scalar element of the parameter vector."""

    label: str
    name: str
    index: int  # flat index within the parameter
    unit: str

    @property
    def axis_label(self) -> str:
        return label(self.label, self.unit)


def _elements(space: ParamSpace, params: Any, max_params: int) -> tuple[list[_Element], int]:
    """The selected elements (parameter names or element labels) and how many there were.

    Raises
    ------
    ParameterError
        Naming an unknown or fixed parameter.
    """
    every = [_Element(lab, p.name, j, p.unit)
             for p in space.params for j, lab in enumerate(p.labels())]
    if params is None:
        chosen = every
    else:
        if isinstance(params, str):
            params = [params]
        chosen = []
        for name in params:
            hit = [e for e in every if e.name == name or e.label == name]
            if not hit:
                why = "is fixed" if name in space.fixed else "is not a parameter"
                raise ParameterError(f"parameter {name!r} {why}; free: {space.labels}")
            chosen += [e for e in hit if e not in chosen]
    return chosen[:max_params], len(chosen)


def _values(result: SamplingResult, elements: list[_Element]) -> np.ndarray:
    """Physical values of ``elements`` over the chains, shape (E, S, W, k)."""
    n_ens, n_steps, n_walk, _ = result.chains.shape
    theta = result.space.unpack(result.flat_z)
    cols = [np.asarray(theta[e.name]).reshape(n_ens * n_steps * n_walk, -1)[:, e.index]
            for e in elements]
    return np.stack(cols, axis=-1).reshape(n_ens, n_steps, n_walk, len(elements))


def _shown(n: int, total: int, what: str) -> str:
    return what if n == total else f"{what} (first {n} of {total} elements)"


# ----------------------------------------------------------------------------- trace
def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 0..n-1 of all values of ``x`` jointly (ties broken by position)."""
    flat = x.ravel()
    r = np.empty(flat.size, dtype=np.int64)
    r[np.argsort(flat, kind="stable")] = np.arange(flat.size)
    return r.reshape(x.shape)


def trace_figure(result: SamplingResult, *, fig: Figure | None = None, params: Any = None,
                 max_params: int = 12, walkers_shown: int = 3, bins: int = 20) -> Figure:
    """Trace and rank plot of each free scalar element.

    Left: the post-burn-in trace of a few walkers of every ensemble (one colour per
    ensemble) in physical units, titled with the element's R-hat (the larger of the
    walkers-as-chains and ensembles-as-chains values, as in the convergence report).
    Right: rank plot — histogram, per ensemble, of the ranks of its draws among all
    draws; flat histograms mean the ensembles sample the same distribution. A run
    that has not converged gets a red "NOT CONVERGED" title.

    Parameters
    ----------
    result : SamplingResult
        The chains, shape (ensembles, steps, walkers, dimensions).
    fig : Figure, optional
        An empty figure to draw into (two panels per element); default a new one, 10 in
        wide and 1.9 in high per element.
    params : str or list of str, optional
        Parameter names (all their elements) or element labels (``"w[0]"``); default
        every free element.
    max_params : int
        At most this many elements are drawn (the title says when some are left out).
    walkers_shown : int
        Walkers traced per ensemble (evenly spread over the ensemble).
    bins : int
        Bins of each rank histogram.

    Returns
    -------
    Figure
        With two axes per element (trace, rank plot).

    Raises
    ------
    ParameterError
        Naming an unknown or fixed parameter.
    """
    check_result(result)
    max_params = positive_int(max_params, "max_params")
    elements, total = _elements(result.space, params, max_params)
    values = _values(result, elements)  # (E, S, W, k)
    n_ens, n_steps, n_walk, k = values.shape
    steps = result.convergence.burn + np.arange(n_steps)
    show = np.unique(np.linspace(0, n_walk - 1, min(walkers_shown, n_walk)).astype(int))
    fig = new_figure(fig, 10.0, 1.9 * k + 0.9)
    axes = fig.subplots(k, 2, squeeze=False, width_ratios=[2.2, 1.0])
    for j, el in enumerate(elements):
        v = values[..., j]
        walkers = v.transpose(0, 2, 1).reshape(n_ens * n_walk, n_steps)
        ensembles = v.reshape(n_ens, n_steps * n_walk)
        r = max(rhat(walkers), rhat(ensembles))
        ax_t, ax_r = axes[j]
        for e in range(n_ens):
            for w in show:
                ax_t.plot(steps, v[e, :, w], color=f"C{e}", lw=0.6, alpha=0.7,
                          label=f"ensemble {e}" if w == show[0] else None)
        ax_t.set_title(f"{el.axis_label}: R-hat {fmt(r, '.3f')}", fontsize=9,
                       color=RED if not r < 1.01 else "black")
        ax_t.set_ylabel(label(el.label, el.unit), fontsize=8)
        ranks = _ranks(ensembles)
        edges = np.linspace(0, ranks.size, bins + 1)
        for e in range(n_ens):
            counts, _ = np.histogram(ranks[e], bins=edges)
            ax_r.stairs(counts, edges, color=f"C{e}", lw=1.0, baseline=None)
        ax_r.axhline(ranks.shape[1] / bins, color="0.3", ls="--", lw=0.8)
        ax_r.set_title("rank plot (uniform when mixed)", fontsize=8)
        ax_r.set_yticks([])
        if j == k - 1:
            ax_t.set_xlabel("step")
            ax_r.set_xlabel("rank of draw over all ensembles")
        if j == 0:
            ax_t.legend(fontsize=7, loc="upper right", ncols=n_ens)
    title(fig, result, _shown(k, total, f"traces ({len(show)} walkers per ensemble) "
                                        f"and rank plots"))
    return fig


def plot_trace(result: SamplingResult, path: str | os.PathLike[str], *,
               params: Any = None, max_params: int = 12) -> Path:
    """Write :func:`trace_figure` as PNG.

    Parameters
    ----------
    result : SamplingResult
    path : path-like
        Target PNG file.
    params : str or list of str, optional
        Parameter names or element labels; default every free element.
    max_params : int
        At most this many elements are drawn.

    Returns
    -------
    Path
        ``path``, written atomically.

    Raises
    ------
    ParameterError
        Naming an unknown or fixed parameter (nothing is written).
    """
    path = png_path(path)
    return save_and_free(trace_figure(result, params=params, max_params=max_params), path)


# ---------------------------------------------------------------------------- corner
def _hdr_levels(h: np.ndarray, masses: tuple[float, ...]) -> list[float]:
    """Density thresholds enclosing ``masses`` of a 2-D histogram (increasing)."""
    flat = np.sort(h.ravel())[::-1]
    cum = np.cumsum(flat) / max(flat.sum(), 1e-300)
    levels = [float(flat[min(np.searchsorted(cum, m), flat.size - 1)]) for m in masses]
    return sorted(set(lv for lv in levels if lv > 0))


def _limits(x: np.ndarray) -> tuple[float, float]:
    """Axis limits of a column of draws (a small margin; never a zero-width range)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    pad = 0.03 * (hi - lo) if hi > lo else max(abs(lo) * 1e-3, 1e-12)
    return lo - pad, hi + pad


def _corner_grid(fig: Figure | None, x: np.ndarray, labels: list[str],
                 axis_labels: list[str], best: list[float] | None, prob: float,
                 bins: int) -> Figure:
    """Corner plot of draws ``x`` (n, k).

    HDI-shaded histograms on the diagonal, 2-D histograms with 50/90 % contours below it,
    ``best`` (if given) in red.
    """
    k = len(labels)
    fig = new_figure(fig, max(4.0, 2.1 * k), max(4.0, 2.1 * k) + 0.6)
    axes = fig.subplots(k, k, squeeze=False)
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                fig.delaxes(ax)
                continue
            if i == j:
                lo, hi = hdi(x[:, i], prob)
                ax.hist(x[:, i], bins=bins, histtype="stepfilled", color="C0", alpha=0.5)
                ax.axvspan(lo, hi, color="C0", alpha=0.12, lw=0)
                for edge in (lo, hi):
                    ax.axvline(edge, color="C0", ls="--", lw=0.8)
                if best is not None:
                    ax.axvline(best[i], color=RED, lw=1.0)
                ax.set_yticks([])
                ax.set_title(f"{labels[i]}: {prob:.0%} HDI\n[{fmt(lo)}, {fmt(hi)}]",
                             fontsize=8)
            else:
                h, xe, ye = np.histogram2d(x[:, j], x[:, i], bins=bins)
                ax.pcolormesh(xe, ye, h.T, cmap="Blues", shading="flat")
                levels = _hdr_levels(h, (0.9, 0.5))
                if len(levels) > 1 or (levels and levels[0] < h.max()):
                    xc, yc = 0.5 * (xe[1:] + xe[:-1]), 0.5 * (ye[1:] + ye[:-1])
                    ax.contour(xc, yc, h.T, levels=levels, colors="k", linewidths=0.6)
                if best is not None:
                    ax.plot(best[j], best[i], "x", color=RED, ms=6, mew=1.5)
            if i == k - 1:
                ax.set_xlabel(axis_labels[j], fontsize=8)
            else:
                ax.tick_params(labelbottom=False)
            if j == 0 and i > 0:
                ax.set_ylabel(axis_labels[i], fontsize=8)
            elif j > 0:
                ax.tick_params(labelleft=False)
            ax.tick_params(labelsize=7)
            ax.set_xlim(*_limits(x[:, j]))
            if j < i:
                ax.set_ylim(*_limits(x[:, i]))
    return fig


def corner_figure(result: SamplingResult, *, fig: Figure | None = None, params: Any = None,
                  max_params: int = 8, prob: float = 0.9, bins: int = 40) -> Figure:
    """Corner plot of the posterior in physical units.

    Diagonal: histogram of each element with its ``prob`` highest-density interval
    (shaded, dashed edges) and the MAP (red line). Below: 2-D histograms of each pair
    with the contours enclosing 50 % and 90 % of the draws and the MAP (red cross).

    Parameters
    ----------
    result : SamplingResult
        The chains (all post-burn-in draws are used) and the MAP (``result.start``).
    fig : Figure, optional
        An empty figure to draw into (``k (k + 1) / 2`` panels for ``k`` elements);
        default a new one, 2.1 in per element and side.
    params : str or list of str, optional
        Parameter names or element labels, e.g. ``["alpha", "beta", "gamma", "n"]`` for
        Bouc–Wen; default every free element.
    max_params : int
        At most this many elements (the title says when some are left out).
    prob : float
        Mass of the HDI, in (0, 1).
    bins : int
        Bins per axis of the histograms.

    Returns
    -------
    Figure
        With ``k (k + 1) / 2`` axes.

    Raises
    ------
    ParameterError
        Naming an unknown or fixed parameter.
    """
    check_result(result)
    max_params = positive_int(max_params, "max_params")
    prob = probability(prob)
    elements, total = _elements(result.space, params, max_params)
    x = _values(result, elements).reshape(-1, len(elements))
    map_theta = result.space.unpack(np.asarray(result.start.z, dtype=float))
    best = [float(np.ravel(map_theta[e.name])[e.index]) for e in elements]
    fig = _corner_grid(fig, x, [e.label for e in elements], [e.axis_label for e in elements],
                       best, prob, bins)
    title(fig, result, _shown(len(elements), total, f"posterior (MAP in red, {prob:.0%} HDI "
                                                    f"dashed, contours 50/90 %)"))
    return fig


def plot_corner(result: SamplingResult, path: str | os.PathLike[str], *,
                params: Any = None, max_params: int = 8, prob: float = 0.9) -> Path:
    """Write :func:`corner_figure` as PNG.

    Parameters
    ----------
    result : SamplingResult
    path : path-like
        Target PNG file.
    params : str or list of str, optional
        Parameter names or element labels; default every free element.
    max_params : int
        At most this many elements.
    prob : float
        Mass of the HDI.

    Returns
    -------
    Path
        ``path``, written atomically.

    Raises
    ------
    ParameterError
        Naming an unknown or fixed parameter (nothing is written).
    """
    path = png_path(path)
    return save_and_free(corner_figure(result, params=params, max_params=max_params,
                                       prob=prob), path)


def draws_corner_figure(draws: Mapping[str, np.ndarray], *, fig: Figure | None = None,
                        units: Mapping[str, str] | None = None, title: str = "posterior",
                        prob: float = 0.9, bins: int = 30) -> Figure:
    """Corner plot of posterior draws given as arrays (e.g. read from a saved netCDF).

    Parameters
    ----------
    draws : mapping of str to ndarray, each of n_draws values
        Scalar parameter name -> its draws, in physical units (any shape, flattened;
        the same count for every parameter, at least 2, all finite).
    fig : Figure, optional
        An empty figure to draw into; default a new one, 2.1 in per parameter and side.
    units : mapping of str to str, optional
        Unit of each parameter, for the axis labels.
    title : str
        Figure title (say there whether the run converged).
    prob : float
        Mass of the HDI shaded on the diagonal, in (0, 1).
    bins : int
        Bins per axis of the histograms.

    Returns
    -------
    Figure
        With ``k (k + 1) / 2`` axes for ``k`` parameters.
    """
    prob = probability(prob)
    units = units or {}
    if not draws:
        raise ParameterError("draws: no parameter to plot")
    cols = []
    for name, v in draws.items():
        v = np.asarray(v, dtype=float).ravel()
        if v.size < 2 or not np.all(np.isfinite(v)):
            raise ParameterError(f"draws[{name!r}]: expected >= 2 finite draws, got {v.size} "
                                 f"({int(np.sum(~np.isfinite(v)))} non-finite)")
        cols.append(v)
    if len({c.size for c in cols}) != 1:
        raise ParameterError(f"draws: every parameter needs the same number of draws, got "
                             f"{ {k: c.size for k, c in zip(draws, cols, strict=True)} }")
    names = list(draws)
    fig = _corner_grid(fig, np.stack(cols, axis=-1), names,
                       [label(n, units.get(n, "")) for n in names], None, prob, bins)
    fig.suptitle(title, fontsize=10)
    return fig


def plot_draws_corner(draws: Mapping[str, np.ndarray], path: str | os.PathLike[str], *,
                      units: Mapping[str, str] | None = None, title: str = "posterior",
                      prob: float = 0.9) -> Path:
    """Write :func:`draws_corner_figure` as PNG.

    Parameters
    ----------
    draws : mapping of str to ndarray, each of n_draws values
        Scalar parameter name -> its draws (same count for every parameter).
    path : path-like
        Target PNG file.
    units : mapping of str to str, optional
        Unit of each parameter, for the axis labels.
    title : str
        Figure title (say there whether the run converged).
    prob : float
        Mass of the HDI shaded on the diagonal.

    Returns
    -------
    Path
        ``path``, written atomically.
    """
    path = png_path(path)
    return save_and_free(draws_corner_figure(draws, units=units, title=title, prob=prob),
                         path)
