"""numba kernel of the residual Gram matrices behind the linear-block sampler.

For one record, ``X = [Phi, r]`` (N samples x Q = P + 1 columns: the linear block's
design and a reference residual). :func:`gram_stats` accumulates, per walker and over
the kept samples ``k`` only,

* ``first`` = ``x_0 x_0^T`` when sample 0 is kept (the AR(1) likelihood's marginal term),
* ``lag0``  = ``sum_{k>=1} x_k x_k^T``,
* ``cross`` = ``sum_{k>=1} x_k x_{k-1}^T``, ``prev`` = ``sum_{k>=1} x_{k-1} x_{k-1}^T``
  (only with ``lagged``: the AR(1) innovations ``x_k - phi x_{k-1}``).

Written as explicit loops over one walker at a time: each walker's sums are taken in
the same order whatever the batch it is computed in, so a cached value and a
recomputed one agree to the bit (a resumed run makes the decisions of the
uninterrupted one).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["gram_stats"]


@njit(cache=True)
def _gram_one(phi, r, keep, lagged, first, lag0, cross, prev):
    n, p = phi.shape
    q = p + 1
    x = np.empty(q)
    xp = np.empty(q)
    for k in range(n):
        for a in range(p):
            x[a] = phi[k, a]
        x[p] = r[k]
        if keep[k]:
            if k == 0:
                for a in range(q):
                    for b in range(a, q):
                        first[a, b] += x[a] * x[b]
            else:
                for a in range(q):
                    xa = x[a]
                    for b in range(a, q):
                        lag0[a, b] += xa * x[b]
                if lagged:
                    for a in range(q):
                        xa = x[a]
                        xpa = xp[a]
                        for b in range(q):
                            cross[a, b] += xa * xp[b]
                        for b in range(a, q):
                            prev[a, b] += xpa * xp[b]
        for a in range(q):
            xp[a] = x[a]


@njit(cache=True)
def _symmetrise(m):
    q = m.shape[0]
    for a in range(q):
        for b in range(a + 1, q):
            m[b, a] = m[a, b]


@njit(cache=True)
def gram_stats(phi, r, keep, lagged, first, lag0, cross, prev):
    """Accumulate one record's Gram matrices into the walkers' running sums.

    Parameters
    ----------
    phi : ndarray, shape (Wp, N, P)
        Design over the scored samples; ``Wp`` is 1 (shared by every walker) or ``W``.
    r : ndarray, shape (W, N)
        Reference residual per walker.
    keep : ndarray of bool, shape (N,)
        Samples that are scored (held-out cycles are False).
    lagged : bool
        Also accumulate ``cross`` and ``prev`` (AR(1) likelihood).
    first, lag0, cross, prev : ndarray, shape (W, Q, Q)
        Running sums, updated in place (``first``, ``lag0``, ``prev`` are symmetrised on
        the fly: only their upper triangles are accumulated, then mirrored here for
        this record's contribution).
    """
    w_all = r.shape[0]
    q = phi.shape[2] + 1
    f = np.zeros((q, q))
    l0 = np.zeros((q, q))
    c = np.zeros((q, q))
    pv = np.zeros((q, q))
    for j in range(w_all):
        jp = j if phi.shape[0] > 1 else 0
        f[:, :] = 0.0
        l0[:, :] = 0.0
        c[:, :] = 0.0
        pv[:, :] = 0.0
        _gram_one(phi[jp], r[j], keep, lagged, f, l0, c, pv)
        _symmetrise(f)
        _symmetrise(l0)
        _symmetrise(pv)
        first[j] += f
        lag0[j] += l0
        if lagged:
            cross[j] += c
            prev[j] += pv
