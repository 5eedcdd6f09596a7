"""The linear block's statistics and its conditional Gaussian, per walker.

:class:`LinearStats` holds the Gram matrices a :class:`~bayeshyst.inference.linear.\
LinearStructure` computes for a batch of walkers; :class:`Conditional` is the Gaussian
``beta | z_n`` it derives from them. :func:`triangular` is the stacked triangular solve
both use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

__all__ = ["Conditional", "LinearStats", "one_for_all", "triangular"]

#: log(2 pi), the Normal density's constant
LOG_2PI = math.log(2.0 * math.pi)
_TRTRS = lapack.dtrtrs
#: Linear blocks up to this size are solved for every walker in one stacked call.
_SMALL = 16


@dataclass(frozen=True)
class LinearStats:
    """Gram matrices of ``[Phi, r_ref]`` for ``W`` walkers, summed over the records.

    ``first`` holds the first scored sample of each record, ``lag0`` the others (None
    when they are summed into ``first``: a white-noise likelihood whitens nothing, and
    the held-out marginals then pass one array instead of two);
    ``cross``/``prev`` the lag-one products (AR(1) only, else None). ``n`` scored
    samples, ``n_first`` of them first samples (integers, or one per walker (W,) when
    the walkers' Grams cover different samples, as in the held-out marginals).
    ``failed`` marks walkers whose design could not be computed (outside the model's
    support, failed simulation).
    """

    first: np.ndarray
    lag0: np.ndarray | None
    cross: np.ndarray | None
    prev: np.ndarray | None
    n: int | np.ndarray
    n_first: int | np.ndarray
    failed: np.ndarray

    def take(self, idx: np.ndarray) -> LinearStats:
        """The statistics of the walkers ``idx`` (broadcast ones stay broadcast)."""
        n = np.arange(self.failed.shape[0])[idx].size

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            if a is None:
                return None
            if a.strides[0] == 0:  # one walker's Grams for all: no copy
                return np.broadcast_to(a[:1], (n, *a.shape[1:]))
            return a[idx]

        return LinearStats(pick(self.first), pick(self.lag0), pick(self.cross),
                           pick(self.prev), self.n, self.n_first, self.failed[idx])


@dataclass(frozen=True)
class Conditional:
    """The conditional posterior ``beta | z_n ~ N(mean, Lambda^-1)`` for ``W`` walkers.

    ``chol`` is Lambda's lower Cholesky factor; ``ok`` is False where the conditional is
    undefined (failed design, bad noise).
    """

    mean: np.ndarray
    chol: np.ndarray
    ok: np.ndarray

    def log_density(self, beta: np.ndarray) -> np.ndarray:
        """``log N(beta; mean, Lambda^-1)`` per walker (W,); -inf where not ok."""
        d = np.where(self.ok[:, None], beta - self.mean, 0.0)
        u = np.einsum("wji,wj->wi", self.chol, d)  # L^T d
        p = self.mean.shape[1]
        logdet = np.sum(np.log(np.abs(np.diagonal(self.chol, axis1=1, axis2=2))), axis=1)
        out = -0.5 * p * LOG_2PI + logdet - 0.5 * np.sum(u * u, axis=1)
        return np.where(self.ok, out, -np.inf)

    def draw(self, random: np.random.RandomState) -> np.ndarray:
        """One draw per walker, ``mean + L^-T xi`` (W, P), from emcee's random state."""
        w, p = self.mean.shape
        xi = random.randn(w, p)
        step = triangular(self.chol, xi, transpose=True)
        return self.mean + np.where(self.ok[:, None], step, 0.0)


def triangular(chol: np.ndarray, rhs: np.ndarray, *, transpose: bool) -> np.ndarray:
    """``L^-1 b`` (or ``L^-T b``) per walker for lower factors ``chol`` (W, P, P), ``rhs`` (W, P).

    Up to :data:`_SMALL` coefficients numpy's stacked solve (one call for all walkers;
    the per-walker loop's overhead would dominate), above it LAPACK's ``trtrs`` walker
    by walker: a general solve of a ~100 x 100 system cost 5x its factorisation, and
    scipy's batched ``solve_triangular`` spent three times the solve in its argument
    handling.
    """
    if chol.shape[1] <= _SMALL:  # numpy's stacked solve: one call for every walker
        a = chol.transpose(0, 2, 1) if transpose else chol
        return np.linalg.solve(a, rhs[:, :, None])[:, :, 0]
    out = np.empty(rhs.shape)
    # L in C order is U = L^T in Fortran order: solve with U (no copy), L b -> U^T b
    trans = 0 if transpose else 1
    for j in range(rhs.shape[0]):
        out[j], _ = _TRTRS(chol[j].T, rhs[j], lower=0, trans=trans)
    return out


def one_for_all(st: LinearStats) -> bool:
    """Whether ``st`` is one walker's Grams broadcast to all (zero stride, same status)."""
    arrays = [a for a in (st.first, st.lag0, st.cross, st.prev) if a is not None]
    return (all(a.strides[0] == 0 for a in arrays)
            and bool(np.all(st.failed == st.failed[0])))
