"""The held-out statistic of the driver scan, as sums of per-unit Gram matrices.

Private to :mod:`bayeshyst.diagnosis`: :mod:`~bayeshyst.diagnosis.drivers` documents
the method. Everything here is exact linear algebra: the held-out sum of squares of a
ridge regression fitted on some units and scored on the others is a function of the
units' Gram matrices ``X_u^T X_u``, ``X_u^T r_u``, ``r_u^T r_u``, and flipping a unit's
sign flips its cross products only -- so every randomisation costs a few small solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import product

import numpy as np

__all__ = ["correlation_length", "sign_patterns"]

#: Folds of the held-out scoring.
_FOLDS = 6
#: Ridge penalty per training sample, on columns scaled to unit RMS.
_RIDGE = 1e-4


class _Part:
    """Gram matrices ``X_u^T X_u``, ``X_u^T r_u`` and ``r_u^T r_u`` of sample ranges."""

    def __init__(self, x: np.ndarray, r: np.ndarray, ranges: Sequence[tuple[int, int]],
                 fold: np.ndarray):
        self.G = np.stack([x[a:b].T @ x[a:b] for a, b in ranges])          # (U, M, M)
        self.c = np.stack([x[a:b].T @ r[a:b] for a, b in ranges])          # (U, M)
        self.rr = np.array([r[a:b] @ r[a:b] for a, b in ranges])           # (U,)
        self.n = np.array([b - a for a, b in ranges], dtype=float)
        self.Gf = np.einsum("ku,umn->kmn", fold, self.G)
        self.Gt = self.G.sum(axis=0)
        self.nf = fold @ self.n

    def split(self, cols: np.ndarray, beta: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per-unit parts of the fit ``a = X beta`` and the rest ``e = r - a``.

        Returns ``X^T a (U, M)``, ``X^T e (U, M)`` and ``a^T a``, ``a^T e``, ``e^T e`` (U,).
        """
        xa = self.G[:, :, cols] @ beta
        aa = xa[:, cols] @ beta
        ca = self.c[:, cols] @ beta
        return xa, self.c - xa, aa, ca - aa, self.rr - 2.0 * ca + aa


class _Grams:
    """Per-unit Gram matrices of the design and the residual (see module notes).

    Every unit is fitted on whole (``train``) but scored only on its interior
    (``test``: ``guard`` samples left out at each end), so that no held-out sample lies
    within the noise's correlation length of a training sample.
    """

    def __init__(self, x: np.ndarray, r: np.ndarray, units: Sequence[tuple[int, int]],
                 guard: int):
        n_units = len(units)
        k = min(_FOLDS, n_units)
        self.fold = np.zeros((k, n_units))
        self.fold[np.arange(n_units) % k, np.arange(n_units)] = 1.0
        inner = [(a + min(guard, (b - a) // 4), b - min(guard, (b - a) // 4)) for a, b in units]
        self.train = _Part(x, r, units, self.fold)
        self.test = _Part(x, r, inner, self.fold)

    def versions(self, cols: np.ndarray, signs: np.ndarray) -> tuple[np.ndarray, ...]:
        """Residual versions ``X cols beta + s_u e_u`` (Freedman–Lane) for sign patterns.

        ``beta`` is the ridge fit of ``cols`` on all samples; returns ``X^T r`` of the
        training parts (P, U, M), of the test parts (P, U, M) and ``r^T r`` of the test
        parts (P, U).
        """
        tr, te = self.train, self.test
        if cols.size == 0:
            beta = np.zeros(0)
        else:
            g = tr.Gt[np.ix_(cols, cols)] + _RIDGE * tr.n.sum() * np.eye(cols.size)
            beta = np.linalg.solve(g, tr.c.sum(axis=0)[cols])
        xa, xe, *_ = tr.split(cols, beta)
        v_tr = xa[None] + signs[:, :, None] * xe[None]
        xa, xe, aa, ae, ee = te.split(cols, beta)
        v_te = xa[None] + signs[:, :, None] * xe[None]
        return v_tr, v_te, aa[None] + 2.0 * signs * ae[None] + ee[None]

    def sse(self, cols: np.ndarray, v_tr: np.ndarray, v_te: np.ndarray,
            rr: np.ndarray) -> np.ndarray:
        """Held-out SSE (P,) of ridge fits on ``cols`` for P residual versions."""
        out = rr.sum(axis=1).copy()
        if cols.size == 0:
            return out
        fold = self.fold
        vf_tr = np.einsum("ku,pum->pkm", fold, v_tr[:, :, cols])        # (P, K, C)
        vt_tr = vf_tr.sum(axis=1)
        vf_te = np.einsum("ku,pum->pkm", fold, v_te[:, :, cols])
        eye = np.eye(cols.size)
        tr, te = self.train, self.test
        total_n = tr.n.sum()
        for k in range(fold.shape[0]):
            a = (tr.Gt[np.ix_(cols, cols)] - tr.Gf[k][np.ix_(cols, cols)]
                 + _RIDGE * (total_n - tr.nf[k]) * eye)
            beta = np.linalg.solve(a, (vt_tr - vf_tr[:, k]).T).T             # (P, C)
            out += -2.0 * np.sum(beta * vf_te[:, k], axis=1) + np.einsum(
                "pc,cd,pd->p", beta, te.Gf[k][np.ix_(cols, cols)], beta)
        return out


def correlation_length(r: np.ndarray, units: Sequence[tuple[int, int]]) -> int:
    """Lags (samples) until the residual's autocorrelation first falls below 0.1.

    Estimated within units (no lag crosses a unit boundary), up to a quarter of the
    shortest unit.
    """
    shortest = min(b - a for a, b in units)
    top = max(1, shortest // 4)
    den = sum(float(np.sum((r[a:b] - r[a:b].mean()) ** 2)) for a, b in units) or 1.0
    for lag in range(1, top + 1):
        num = sum(float(np.sum((r[a:b - lag] - r[a:b].mean()) * (r[a + lag:b] - r[a:b].mean())))
                  for a, b in units)
        if num / den < 0.1:
            return lag
    return top


def sign_patterns(n_units: int, n_permutations: int, rng: np.random.Generator
           ) -> tuple[np.ndarray, bool]:
    """Sign patterns (P, U): every one when there are few units, else random ones."""
    if 2 ** n_units <= n_permutations:
        return np.array(list(product((1.0, -1.0), repeat=n_units))), True
    return rng.choice((-1.0, 1.0), size=(n_permutations, n_units)), False
