"""Score (Lagrange-multiplier) tests of a fitted model's residual, robust to coloured noise.

A model fitted to data leaves the residual ``r = y - y_hat``. If an effect with
parameters ``eta`` (zero when absent) is missing, the Gauss–Newton regression of the
residual on the model's own sensitivities ``J = d y_hat / d z`` *and* the effect's
sensitivities ``X = d y / d eta |_{eta = 0}`` gives the score test of ``eta = 0``
(Davidson & MacKinnon 1993, *Estimation and Inference in Econometrics*, §6.4, §12.7):
``J`` absorbs what the fit's own parameters can still explain, so the test asks only
whether the *new* directions explain the residual. Under the null hypothesis (no
missing effect, Gaussian noise) the F statistic of ``X`` is exactly F-distributed for a
linear model and asymptotically so for a nonlinear one.

Measurement noise is rarely white. Serial correlation would make an ordinary F test
fire on any smooth regressor, so the regression is estimated by feasible generalised
least squares: an AR(p) model of the errors (order by BIC) is fitted to the residual of
the widest regression and every column is filtered with it, segment by segment
(Cochrane–Orcutt with ``p`` lags; Davidson & MacKinnon §7.8). Everything here is plain
linear algebra on the stacked samples of all records; a *segment* is one record's
scored samples (filters restart there).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

__all__ = [
    "ARFit",
    "FTest",
    "f_test",
    "fit_ar",
    "holm",
    "lag_test",
    "orthonormal_basis",
    "project_out",
    "whiten",
]

Segments = Sequence[tuple[int, int]]

#: a regressor whose part outside span(Z) is below this fraction of its norm adds no rank
_SPAN_RTOL = 1e-8


def orthonormal_basis(a: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Orthonormal basis (n, rank) of the column space of ``a`` (n, q).

    Columns are scaled to unit norm first (a Jacobian mixes units), zero columns are
    dropped, and directions with singular value below ``rtol`` times the largest are
    treated as numerically absent.
    """
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] == 0:
        return np.zeros((a.shape[0], 0))
    norms = np.linalg.norm(a, axis=0)
    keep = np.isfinite(norms) & (norms > 0)
    if not np.any(keep):
        return np.zeros((a.shape[0], 0))
    u, s, _ = np.linalg.svd(a[:, keep] / norms[keep], full_matrices=False)
    return u[:, s > rtol * s[0]]


def project_out(basis: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``b - Q Q^T b``: the part of ``b`` orthogonal to the orthonormal ``basis``."""
    return b - basis @ (basis.T @ b) if basis.shape[1] else b


@dataclass(frozen=True)
class ARFit:
    """AR(p) model of a residual, ``e_t = sum_i phi_i e_{t-i} + a_t``.

    Attributes
    ----------
    phi : ndarray, shape (p,)
        Coefficients (empty: white noise).
    sigma : float
        Innovation standard deviation (residual unit).
    bic : ndarray, shape (max_order + 1,)
        BIC of each order tried (the chosen one is the smallest).
    """

    phi: np.ndarray
    sigma: float
    bic: np.ndarray

    @property
    def order(self) -> int:
        """Chosen order ``p``."""
        return int(self.phi.size)


def _lagged(e: np.ndarray, segments: Segments, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Targets ``e_t`` and lags ``[e_{t-1} .. e_{t-p}]``.

    One row for every t with p past samples inside its own segment.
    """
    ys, xs = [], []
    for a, b in segments:
        if b - a <= p:
            continue
        seg = e[a:b]
        ys.append(seg[p:])
        xs.append(np.column_stack([seg[p - i:b - a - i] for i in range(1, p + 1)])
                  if p else np.zeros((b - a - p, 0)))
    if not ys:
        return np.zeros(0), np.zeros((0, p))
    return np.concatenate(ys), np.concatenate(xs)


def fit_ar(e: np.ndarray, segments: Segments, max_order: int = 10) -> ARFit:
    """AR(p) of ``e`` by least squares on each order ``p <= max_order``, order by BIC.

    All orders are compared on the same samples (those with ``max_order`` predecessors
    in their segment), so their BICs are comparable.

    Parameters
    ----------
    e : ndarray, shape (n,)
        Residual (stacked segments).
    segments : sequence of (start, stop)
        Index ranges of independent segments (records) in ``e``.
    max_order : int
        Largest order tried.
    """
    e = np.asarray(e, dtype=float)
    y, lags = _lagged(e, segments, max_order)
    n = y.size
    if n < 10 * (max_order + 1):
        raise ValueError(f"an AR({max_order}) fit needs at least {10 * (max_order + 1)} "
                         f"samples with {max_order} predecessors; got {n}")
    bic = np.empty(max_order + 1)
    fits = []
    for p in range(max_order + 1):
        x = lags[:, :p]
        phi = np.linalg.lstsq(x, y, rcond=None)[0] if p else np.zeros(0)
        rss = float(np.sum((y - x @ phi) ** 2)) if p else float(np.sum(y ** 2))
        bic[p] = n * math.log(max(rss, 1e-300) / n) + p * math.log(n)
        fits.append((phi, rss))
    best = int(np.argmin(bic))
    phi, rss = fits[best]
    return ARFit(np.asarray(phi, dtype=float), math.sqrt(rss / n), bic)


def whiten(a: np.ndarray, segments: Segments, phi: np.ndarray) -> np.ndarray:
    """Filter the rows of ``a`` (n,) or (n, q) with ``1 - sum phi_i B^i`` per segment.

    The first ``p`` samples of each segment (no past inside the segment) are dropped,
    so the output has ``n - p * n_segments`` rows.
    """
    a = np.asarray(a, dtype=float)
    p = int(np.size(phi))
    out = []
    for s0, s1 in segments:
        seg = a[s0:s1]
        if s1 - s0 <= p:
            continue
        w = seg[p:].copy()
        for i in range(1, p + 1):
            w -= phi[i - 1] * seg[p - i:s1 - s0 - i]
        out.append(w)
    return np.concatenate(out) if out else a[:0]


@dataclass(frozen=True)
class FTest:
    """F test of adding the columns ``X`` to a regression on ``Z``.

    Attributes
    ----------
    statistic : float
        ``F = ((RSS_0 - RSS_1) / df1) / (RSS_1 / df2)``.
    df1, df2 : int
        Rank added by ``X`` (beyond ``Z``) and residual degrees of freedom.
    p_value : float
        Upper tail of ``F(df1, df2)``.
    log_bayes_factor : float
        BIC approximation of the log Bayes factor in favour of adding ``X``:
        ``(n log(RSS_0 / RSS_1) - df1 log n) / 2`` (Kass & Raftery 1995, §4.1.3).
    partial_r2 : float
        Share of the residual (after ``Z``) that ``X`` explains, ``1 - RSS_1 / RSS_0``.
    coef : ndarray, shape (k,)
        Coefficients of ``X`` in the full regression (minimum-norm if ``X`` is rank
        deficient), in the units of ``X``'s columns.
    n : int
        Samples used.
    cov : ndarray, shape (k, k)
        Covariance of ``coef`` (``s^2 (X'M_Z X)^+``, ``s^2 = RSS_1 / df2``).
    """

    statistic: float
    df1: int
    df2: int
    p_value: float
    log_bayes_factor: float
    partial_r2: float
    coef: np.ndarray
    n: int
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def f_test(y: np.ndarray, z: np.ndarray, x: np.ndarray) -> FTest:
    """F test (and BIC Bayes factor) of the columns ``x`` added to a regression on ``z``.

    Parameters
    ----------
    y : ndarray, shape (n,)
    z : ndarray, shape (n, q)
        Nuisance regressors, always in the model (the fit's own sensitivities).
    x : ndarray, shape (n, k)
        Regressors under test.
    """
    y = np.asarray(y, dtype=float)
    n = y.size
    qz = orthonormal_basis(z)
    yr = project_out(qz, y)
    x = np.asarray(x, dtype=float).reshape(n, -1)
    xr = project_out(qz, x)
    # a column of X inside span(Z) leaves rounding noise after the projection; judge it
    # against the column's own size, before orthonormal_basis rescales it to unit norm
    inside = np.linalg.norm(xr, axis=0) <= _SPAN_RTOL * np.linalg.norm(x, axis=0)
    xr[:, inside] = 0.0
    qx = orthonormal_basis(xr)
    df1 = int(qx.shape[1])
    df2 = n - qz.shape[1] - df1
    rss0 = float(yr @ yr)
    fitted = qx @ (qx.T @ yr) if df1 else np.zeros_like(yr)
    rss1 = float(np.sum((yr - fitted) ** 2))
    coef = np.linalg.lstsq(xr, fitted, rcond=None)[0] if xr.shape[1] else np.zeros(0)
    if df1 == 0 or df2 <= 0 or rss0 <= 0.0:
        return FTest(0.0, df1, max(df2, 0), 1.0, 0.0, 0.0, coef, n)
    rss1 = max(rss1, rss0 * 1e-15)
    stat = ((rss0 - rss1) / df1) / (rss1 / df2)
    cov = (rss1 / df2) * np.linalg.pinv(xr.T @ xr)
    return FTest(float(stat), df1, df2, float(stats.f.sf(stat, df1, df2)),
                 0.5 * (n * math.log(rss0 / rss1) - df1 * math.log(n)),
                 1.0 - rss1 / rss0, coef, n, cov)


def lag_test(e: np.ndarray, z: np.ndarray, segments: Segments) -> tuple[FTest, float]:
    """Breusch–Godfrey test of first-order serial correlation in the residual ``e``.

    Regresses ``e_t`` on the nuisance regressors ``z_t`` and ``e_{t-1}`` (within
    segments) and F-tests the lag — the score test of ``phi = 0`` in AR(1) errors
    (Breusch 1978; Godfrey 1978). Returns the test and the lag-1 autocorrelation of
    ``e`` (the effect size).
    """
    e = np.asarray(e, dtype=float)
    rows = np.concatenate([np.arange(a + 1, b) for a, b in segments if b - a > 1])
    prev = rows - 1
    test = f_test(e[rows], np.asarray(z)[rows], e[prev][:, None])
    rho = float(np.sum(e[rows] * e[prev]) / max(float(np.sum(e ** 2)), 1e-300))
    return test, rho


def holm(p_values: Sequence[float]) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error control, Holm 1979)."""
    p = np.asarray(p_values, dtype=float)
    m = p.size
    order = np.argsort(p)
    adjusted = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adjusted[i] = running
    return adjusted
