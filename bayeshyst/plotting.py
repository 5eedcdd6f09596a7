"""Figures of a fit: hysteresis loops with predictive bands, traces, corner plot, residuals.

This is the only module of bayeshyst that imports matplotlib. Figures are built with
the object-oriented API on an Agg canvas (``matplotlib.figure.Figure`` +
``FigureCanvasAgg``): pyplot is never imported, so no global figure registry, no
window and nothing to close — a figure is freed as soon as it is no longer
referenced, and the interactive backend of the caller's session is left alone.

Every public function writes one PNG **atomically** (a temporary file in the same
folder, then ``os.replace``) and returns its path; bad input raises
:class:`~bayeshyst.errors.ParameterError` before anything is written, and a failure
while writing leaves no file behind. A run that has not converged says so in red in
the title of every figure. The ``_build_*`` functions return the Figure itself (for
tests and for callers that compose their own output).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from bayeshyst.errors import ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.inference.convergence import hdi, rhat
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import SamplingResult
from bayeshyst.params import ParamSpace

__all__ = ["plot_compensation", "plot_corner", "plot_diagnosis_residuals", "plot_draws_corner",
           "plot_effect_evidence", "plot_loops", "plot_model_comparison", "plot_residuals",
           "plot_trace"]

DPI = 120
_RED = "#c0392b"


# --------------------------------------------------------------------------- helpers
def _fmt(x: float, spec: str = ".4g") -> str:
    """A number for a label; never 'nan'."""
    return format(x, spec) if np.isfinite(x) else "n/a"


def _unit(unit: str) -> str:
    return re.sub(r"\bum\b", "µm", unit or "")


def _label(name: str, unit: str) -> str:
    """``name [unit]``, or just ``name`` for a dimensionless quantity."""
    u = _unit(unit)
    return f"{name} [{u}]" if u and u != "1" else name


def _positive_int(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ParameterError(f"{what} must be a positive integer, got {value!r}")
    return int(value)


def _prob(prob: Any) -> float:
    if not (isinstance(prob, float | int) and 0.0 < float(prob) < 1.0):
        raise ParameterError(f"prob must be in (0, 1), got {prob!r}")
    return float(prob)


def _png_path(path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ParameterError(f"figures are written as PNG: {path} must end in .png")
    return path


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` as PNG atomically (:func:`bayeshyst.files.atomic_path`)."""
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            fig.savefig(fh, format="png", dpi=DPI)
    finally:
        fig.clear()
    return path


def _title(fig: Figure, result: SamplingResult, what: str) -> None:
    """Figure title; a run that has not converged gets a red banner."""
    conv = result.convergence
    if conv.converged:
        fig.suptitle(f"{result.model} / {result.likelihood}: {what}\nconverged (R-hat max "
                     f"{_fmt(conv.rhat_max, '.3f')}, ESS bulk min "
                     f"{_fmt(conv.ess_bulk_min, '.0f')})", fontsize=10)
    else:
        reasons = "; ".join(conv.reasons) or "see the convergence report"
        fig.suptitle(f"NOT CONVERGED: {reasons}\n{result.model} / {result.likelihood}: "
                     f"{what}", fontsize=10, color=_RED, fontweight="bold")


def _check_pair(post: Posterior, result: SamplingResult) -> None:
    if not isinstance(post, Posterior):
        raise ParameterError(f"post must be a Posterior, got {type(post).__name__}")
    _check_result(result)
    if post.space != result.space:
        raise ParameterError("the result was not sampled from this posterior: their "
                             "parameter spaces differ")


def _check_result(result: SamplingResult) -> None:
    if not isinstance(result, SamplingResult):
        raise ParameterError(f"result must be a SamplingResult, got {type(result).__name__}")


@dataclass(frozen=True)
class _Element:
    """One free scalar element of the parameter vector."""

    label: str
    name: str
    index: int  # flat index within the parameter
    unit: str

    @property
    def axis_label(self) -> str:
        return _label(self.label, self.unit)


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


def _predictions(post: Posterior, result: SamplingResult, n_draws: int,
                 seed: int) -> tuple[list[np.ndarray], int]:
    z = result.draws(n_draws, seed=seed)
    return post.predict(z), z.shape[0]


# ----------------------------------------------------------------------------- loops
def _build_loops(post: Posterior, result: SamplingResult, *, n_draws: int = 100,
                 prob: float = 0.9, seed: int = 0) -> Figure:
    """The figure of :func:`plot_loops` (one axes per record)."""
    _check_pair(post, result)
    n_draws = _positive_int(n_draws, "n_draws")
    prob = _prob(prob)
    preds, n = _predictions(post, result, n_draws, seed)
    records = list(post.data)
    ncols = min(3, len(records))
    nrows = math.ceil(len(records) / ncols)
    # one panel still needs room for the two-line title
    fig = _figure(max(6.4, 4.4 * ncols), 3.6 * nrows + 0.6)
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
        ax.set_xlabel(_label("u", rec.units.get("u", "")))
        ax.set_ylabel(_label("y", rec.units.get("y", "")))
        if i == 0:
            ax.legend(fontsize=7, loc="upper left", markerscale=4)
    _title(fig, result, f"loops, noise-free prediction ({n} draws)")
    return fig


def plot_loops(post: Posterior, result: SamplingResult, path: str | os.PathLike[str], *,
               n_draws: int = 100, prob: float = 0.9, seed: int = 0) -> Path:
    """Measured loops with the posterior-predictive mean and band of the model.

    One subplot per record (titled with its name and frequency): measured ``y``
    against ``u`` over the scored samples (points), the mean over ``n_draws``
    posterior draws of the noise-free prediction (``post.predict``, offset included)
    and the equal-tailed ``prob`` interval of those predictions as a shaded band.

    Parameters
    ----------
    post : Posterior
    result : SamplingResult
        Draws of ``post``.
    path : path-like
        Target PNG file.
    n_draws : int
        Posterior draws predicted (``result.draws(n_draws, seed=seed)``).
    prob : float
        Mass of the band.
    seed : int
        Selects the draws.

    Returns
    -------
    Path
        ``path``, written atomically.
    """
    path = _png_path(path)
    return _save(_build_loops(post, result, n_draws=n_draws, prob=prob, seed=seed), path)


# ----------------------------------------------------------------------------- trace
def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 0..n-1 of all values of ``x`` jointly (ties broken by position)."""
    flat = x.ravel()
    r = np.empty(flat.size, dtype=np.int64)
    r[np.argsort(flat, kind="stable")] = np.arange(flat.size)
    return r.reshape(x.shape)


def _build_trace(result: SamplingResult, *, params: Any = None, max_params: int = 12,
                 walkers_shown: int = 3, bins: int = 20) -> Figure:
    """The figure of :func:`plot_trace` (two axes per element: trace, rank plot)."""
    _check_result(result)
    max_params = _positive_int(max_params, "max_params")
    elements, total = _elements(result.space, params, max_params)
    values = _values(result, elements)  # (E, S, W, k)
    n_ens, n_steps, n_walk, k = values.shape
    steps = result.convergence.burn + np.arange(n_steps)
    show = np.unique(np.linspace(0, n_walk - 1, min(walkers_shown, n_walk)).astype(int))
    fig = _figure(10.0, 1.9 * k + 0.9)
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
        ax_t.set_title(f"{el.axis_label}: R-hat {_fmt(r, '.3f')}", fontsize=9,
                       color=_RED if not r < 1.01 else "black")
        ax_t.set_ylabel(_label(el.label, el.unit), fontsize=8)
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
    _title(fig, result, _shown(k, total, f"traces ({len(show)} walkers per ensemble) "
                                         f"and rank plots"))
    return fig


def plot_trace(result: SamplingResult, path: str | os.PathLike[str], *,
               params: Any = None, max_params: int = 12) -> Path:
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
    path : path-like
        Target PNG file.
    params : str or list of str, optional
        Parameter names (all their elements) or element labels (``"w[0]"``); default
        every free element.
    max_params : int
        At most this many elements are drawn (the title says when some are left out).

    Returns
    -------
    Path
        ``path``, written atomically.

    Raises
    ------
    ParameterError
        Naming an unknown or fixed parameter (nothing is written).
    """
    path = _png_path(path)
    return _save(_build_trace(result, params=params, max_params=max_params), path)


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


def _corner_grid(x: np.ndarray, labels: list[str], axis_labels: list[str],
                 best: list[float] | None, prob: float, bins: int) -> Figure:
    """Corner plot of draws ``x`` (n, k): HDI-shaded histograms on the diagonal, 2-D
    histograms with 50/90 % contours below it, ``best`` (if given) in red."""
    k = len(labels)
    fig = _figure(max(4.0, 2.1 * k), max(4.0, 2.1 * k) + 0.6)
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
                    ax.axvline(best[i], color=_RED, lw=1.0)
                ax.set_yticks([])
                ax.set_title(f"{labels[i]}: {prob:.0%} HDI\n[{_fmt(lo)}, {_fmt(hi)}]",
                             fontsize=8)
            else:
                h, xe, ye = np.histogram2d(x[:, j], x[:, i], bins=bins)
                ax.pcolormesh(xe, ye, h.T, cmap="Blues", shading="flat")
                levels = _hdr_levels(h, (0.9, 0.5))
                if len(levels) > 1 or (levels and levels[0] < h.max()):
                    xc, yc = 0.5 * (xe[1:] + xe[:-1]), 0.5 * (ye[1:] + ye[:-1])
                    ax.contour(xc, yc, h.T, levels=levels, colors="k", linewidths=0.6)
                if best is not None:
                    ax.plot(best[j], best[i], "x", color=_RED, ms=6, mew=1.5)
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


def _build_corner(result: SamplingResult, *, params: Any = None, max_params: int = 8,
                  prob: float = 0.9, bins: int = 40) -> Figure:
    """The figure of :func:`plot_corner` (``k (k + 1) / 2`` axes for ``k`` elements)."""
    _check_result(result)
    max_params = _positive_int(max_params, "max_params")
    prob = _prob(prob)
    elements, total = _elements(result.space, params, max_params)
    x = _values(result, elements).reshape(-1, len(elements))
    map_theta = result.space.unpack(np.asarray(result.start.z, dtype=float))
    best = [float(np.ravel(map_theta[e.name])[e.index]) for e in elements]
    fig = _corner_grid(x, [e.label for e in elements], [e.axis_label for e in elements],
                       best, prob, bins)
    _title(fig, result, _shown(len(elements), total, f"posterior (MAP in red, {prob:.0%} HDI "
                                                     f"dashed, contours 50/90 %)"))
    return fig


def _build_draws_corner(draws: dict[str, np.ndarray], units: dict[str, str], title: str,
                        *, prob: float = 0.9, bins: int = 30) -> Figure:
    """The figure of :func:`plot_draws_corner`."""
    prob = _prob(prob)
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
    fig = _corner_grid(np.stack(cols, axis=-1), names,
                       [_label(n, units.get(n, "")) for n in names], None, prob, bins)
    fig.suptitle(title, fontsize=10)
    return fig


def plot_corner(result: SamplingResult, path: str | os.PathLike[str], *,
                params: Any = None, max_params: int = 8, prob: float = 0.9) -> Path:
    """Corner plot of the posterior in physical units (no third-party package).

    Diagonal: histogram of each element with its ``prob`` highest-density interval
    (shaded, dashed edges) and the MAP (red line). Below: 2-D histograms of each pair
    with the contours enclosing 50 % and 90 % of the draws and the MAP (red cross).

    Parameters
    ----------
    result : SamplingResult
    path : path-like
        Target PNG file.
    params : str or list of str, optional
        Parameter names or element labels, e.g. ``["alpha", "beta", "gamma", "n"]`` for
        Bouc–Wen; default every free element.
    max_params : int
        At most this many elements (the title says when some are left out).
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
    path = _png_path(path)
    return _save(_build_corner(result, params=params, max_params=max_params, prob=prob), path)


def plot_draws_corner(draws: dict[str, np.ndarray], path: str | os.PathLike[str], *,
                      units: dict[str, str] | None = None, title: str = "posterior",
                      prob: float = 0.9) -> Path:
    """Corner plot of posterior draws given as arrays (e.g. read from a saved netCDF).

    Parameters
    ----------
    draws : dict of str to ndarray, each shape (n_draws,)
        Scalar parameter name -> its draws (same count for every parameter).
    path : path-like
        Target PNG file.
    units : dict of str to str, optional
        Unit of each parameter, for the axis labels.
    title : str
        Figure title (say there whether the run converged).
    prob : float
        Mass of the HDI shaded on the diagonal.
    """
    path = _png_path(path)
    return _save(_build_draws_corner(draws, units or {}, title, prob=prob), path)


# ------------------------------------------------------------------------- residuals
def _build_residuals(post: Posterior, result: SamplingResult, *, n_draws: int = 100,
                     seed: int = 0) -> Figure:
    """The figure of :func:`plot_residuals` (two axes per record)."""
    _check_pair(post, result)
    n_draws = _positive_int(n_draws, "n_draws")
    preds, n = _predictions(post, result, n_draws, seed)
    sigma = None
    if "noise.sigma" in post.space.names:
        sigma = float(np.mean(result.theta()["noise.sigma"]))
    records = list(post.data)
    fig = _figure(10.0, 2.6 * len(records) + 0.8)
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
                    ax.axhline(s, color=_RED, ls="--", lw=0.7)
            ax.set_xlabel(_label(xname, rec.units.get(xname, "")))
            ax.set_ylabel(_label("residual", y_unit))
        failed = "" if ok.all() else f", {int((~ok).sum())} of {n} draws failed"
        ax_t.set_title(f"{rec.name}: RMS {_fmt(rms)} {_unit(y_unit)} (scored{failed})",
                       fontsize=9)
        ax_u.set_title(f"{rec.name}: residual against input", fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="upper right", markerscale=4)
    band = "" if sigma is None else ", dashed: ±2 noise.sigma (posterior mean)"
    _title(fig, result, f"residuals, measured − posterior-mean prediction ({n} draws{band})")
    return fig


def plot_residuals(post: Posterior, result: SamplingResult, path: str | os.PathLike[str],
                   *, n_draws: int = 100, seed: int = 0) -> Path:
    """Residuals of the posterior-mean prediction against time and input, per record.

    The residual is measured ``y`` minus the mean, over ``n_draws`` posterior draws,
    of the noise-free prediction (offset included). Scored samples are blue, warm-up
    samples grey; dashed lines at ±2 ``noise.sigma`` when the likelihood has one.
    Structure in these plots (loops against ``u``, trends against ``t``) points to a
    missing effect.

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
    path = _png_path(path)
    return _save(_build_residuals(post, result, n_draws=n_draws, seed=seed), path)


# ------------------------------------------------------------------ model comparison
def _build_model_comparison(result: Any) -> Figure:
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
    fig = _figure(4.2 * n_panels, 3.8)
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
        axes[0].plot(f[~conv], d[~conv], "x", color=_RED, ms=9, mew=2)
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
        fig.suptitle(f"NOT CONVERGED (red x): {', '.join(unconverged)}\n{title}", fontsize=10,
                     color=_RED, fontweight="bold")
    else:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_model_comparison(result: Any, path: str | os.PathLike[str]) -> Path:
    """elpd (relative to the best), tracking error and held-out elpd against frequency.

    Parameters
    ----------
    result : ComparisonResult
        From :func:`bayeshyst.selection.compare_models`.
    path : path
        PNG file to write (atomically).

    Returns
    -------
    Path
        ``path``. Per-cycle values (elpd / number of cycles) make frequencies with
        different numbers of cycles comparable; fits that did not converge are marked
        with a red x and named in a red title.
    """
    path = _png_path(path)
    return _save(_build_model_comparison(result), path)


# ---------------------------------------------------------------------- compensation
#: Rows of per-frequency panels drawn at most by :func:`plot_compensation`.
COMPENSATION_MAX_ROWS = 6
_COMMANDS = (("uncompensated", "uncompensated (scaled input)", "0.45"),
             ("nominal", "nominal (MAP inverse)", "C1"),
             ("posterior", "posterior-aware", "C0"),
             ("robust", "robust", "C2"))


def _time_axis(t: np.ndarray) -> tuple[np.ndarray, str]:
    """Times in s, or in ms when the record is shorter than half a second."""
    span = float(t[-1] - t[0]) if t.size else 0.0
    return (1e3 * t, "t [ms]") if 0 < span < 0.5 else (t, "t [s]")


def _build_compensation(result: Any, *, y_unit: str = "") -> Figure:
    from bayeshyst.inverse.compensate import CompensationResult

    if not isinstance(result, CompensationResult):
        raise ParameterError(f"result must be a CompensationResult, got "
                             f"{type(result).__name__}")
    if not result.rows:
        raise ParameterError("the compensation result has no rows: nothing to plot")
    rows = list(result.rows[:COMPENSATION_MAX_ROWS])
    n = len(rows)
    fig = _figure(14.0, 2.9 * n + 1.2)
    grid = fig.add_gridspec(n, 3, width_ratios=[1.5, 1.5, 1.2])
    y_name = _label("y", y_unit)
    for i, row in enumerate(rows):
        c = row.curves
        sc = np.asarray(c["scored"], dtype=bool)
        t, t_label = _time_axis(np.asarray(c["t"], dtype=float)[sc])
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
                       f"{_fmt(row.posterior_nrmse_percent, '.3g')} %, predicted "
                       f"[{_fmt(lo, '.3g')}, {_fmt(hi, '.3g')}] %"
                       + ("" if inside else " (OUTSIDE)"),
                       fontsize=8.5, color="black" if inside else _RED)
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
                          f"{_fmt(getattr(row, f'{key}_nrmse_percent'), '.3g')}"
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
                ax_f.plot(x[missed], y[missed], "x", color=_RED, ms=10, mew=2,
                          label="outside its predicted band")
    positive = [getattr(r, f"{k}_nrmse_percent") for r in freq for k, _, _ in _COMMANDS]
    positive = [v for v in positive if np.isfinite(v) and v > 0]
    if positive and max(positive) / min(positive) > 20:
        ax_f.set_yscale("log")
    ax_f.set_ylabel("tracking NRMSE [% of stroke]")
    ax_f.set_title("realised on the plant; bars: predicted 90 % band", fontsize=9)
    ax_f.grid(alpha=0.3)
    ax_f.legend(fontsize=7, loc="best")
    plant = {"virtual actuator": "virtual actuator (the simulator behind the data, noise off)",
             "posterior draw": "held-out posterior draws (no ground truth)"}.get(
                 result.plant_kind, result.plant_kind)
    title = f"feedforward compensation with {result.model}; plant: {plant}"
    if len(every) > n:
        title += f"\nfirst {n} of {len(every)} references shown (right panel: all)"
    if result.converged:
        fig.suptitle(title, fontsize=10)
    else:
        fig.suptitle(f"NOT CONVERGED: the fit behind the design did not converge\n{title}",
                     fontsize=10, color=_RED, fontweight="bold")
    return fig


def plot_compensation(result: Any, path: str | os.PathLike[str], *, y_unit: str = "") -> Path:
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
    path = _png_path(path)
    return _save(_build_compensation(result, y_unit=y_unit), path)


# ------------------------------------------------------------------------- diagnosis
def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else math.nan


def _build_diagnosis_residuals(result: Any) -> Figure:
    from bayeshyst.diagnosis import DiagnosisResult

    if not isinstance(result, DiagnosisResult):
        raise ParameterError(f"result must be a DiagnosisResult, got {type(result).__name__}")
    base, final = result.base, result.final
    same = final is base
    records = list(base.posterior.data)
    fig = _figure(10.0, 2.4 * len(records) + 1.0)
    axes = fig.subplots(len(records), 1, squeeze=False)[:, 0]
    fits = [(base, "before: " + result.base_model, "0.55")]
    if not same:
        fits.append((final, "after: " + result.final_model, "C0"))
    for i, (ax, rec) in enumerate(zip(axes, records, strict=True)):
        y_unit = _unit(rec.units.get("y", ""))
        for fit, name, color in fits:
            t, t_label = _time_axis(np.asarray(fit.analysis.time[i], dtype=float))
            r = np.asarray(fit.analysis.residual[i], dtype=float)
            rms = f"{_fmt(_rms(r))} {y_unit}".strip()
            ax.plot(t, r, lw=0.7, color=color, label=f"{name} (RMS {rms})")
        ax.axhline(0.0, color="k", lw=0.6)
        f = "" if rec.frequency_hz is None else f" ({rec.frequency_hz:g} Hz)"
        ax.set_title(f"{rec.name}{f}", fontsize=9)
        ax.set_ylabel(_label("residual", rec.units.get("y", "")))
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
        if i == len(records) - 1:
            ax.set_xlabel(t_label)
    found = ", ".join(result.effects_found) or "none"
    title = (f"diagnosis of {result.base_model}: effects found: {found}\n"
             "residual (measured − posterior-mean prediction) on the scored samples")
    if same:
        title += "; the base model was kept"
    if base.sampling.converged and final.sampling.converged:
        fig.suptitle(title, fontsize=10)
    else:
        which = [f.label for f in ((base,) if same else (base, final))
                 if not f.sampling.converged]
        fig.suptitle(f"NOT CONVERGED: {'; '.join(which)}\n{title}", fontsize=10, color=_RED,
                     fontweight="bold")
    return fig


def plot_diagnosis_residuals(result: Any, path: str | os.PathLike[str]) -> Path:
    """Residuals before and after the diagnosis, against time, one panel per record.

    Grey: the residual of the base model's posterior-mean prediction; blue: that of the
    final (augmented) model, when the loop kept an effect. The legend gives each one's
    RMS over the record's scored samples; the title names the effects found and, in
    red, a fit that did not converge.

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
    path = _png_path(path)
    return _save(_build_diagnosis_residuals(result), path)


def _build_effect_evidence(test: Any, *, y_unit: str = "") -> Figure:
    from bayeshyst.diagnosis import EffectTest

    if not isinstance(test, EffectTest):
        raise ParameterError(f"test must be an EffectTest, got {type(test).__name__}")
    if test.skipped is not None:
        raise ParameterError(f"{test.effect} was not tested ({test.skipped}): no evidence "
                             "to plot")
    ev = test.evidence
    missing = [k for k in ("x", "partial_residual", "component") if k not in ev]
    if missing:
        raise ParameterError(f"{test.effect}: the evidence lacks {missing}")
    x = np.asarray(ev["x"], dtype=float)
    r = np.asarray(ev["partial_residual"], dtype=float)
    c = np.asarray(ev["component"], dtype=float)
    if not x.shape == r.shape == c.shape:
        raise ParameterError(f"{test.effect}: evidence arrays of different shapes "
                             f"{x.shape}, {r.shape}, {c.shape}")
    ok = np.isfinite(x) & np.isfinite(r) & np.isfinite(c)
    u = _unit(y_unit)
    x_label = str(ev.get("x_label", "") or "x")
    if u:
        x_label = re.sub(r"\bunit\b", u, x_label)
    fig = _figure(6.4, 4.6)
    ax = fig.add_subplot()
    color = _RED if test.significant else "C0"
    ax.plot(x[ok], r[ok], ".", ms=2.0, color="0.75", label="partial residual")
    rms = f"{_fmt(test.explained_rms)} {u}".strip()
    ax.plot(x[ok], c[ok], ".", ms=2.5, color=color,
            label=f"fitted {test.effect} component (RMS {rms})")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel(x_label)
    ax.set_ylabel(_label("residual", y_unit))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best", markerscale=4)
    verdict = "FIRES" if test.significant else "does not fire"
    fig.suptitle(f"{test.effect}: {verdict}\n{test.statistic} = {_fmt(test.value, '.3g')}, "
                 f"p = {_fmt(test.p_value, '.2g')} (Holm {_fmt(test.p_adjusted, '.2g')}), "
                 f"log BF {_fmt(test.log_bayes_factor, '.1f')}", fontsize=10,
                 color=color if test.significant else "black")
    return fig


def plot_effect_evidence(test: Any, path: str | os.PathLike[str], *, y_unit: str = "") -> Path:
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
    path = _png_path(path)
    return _save(_build_effect_evidence(test, y_unit=y_unit), path)
