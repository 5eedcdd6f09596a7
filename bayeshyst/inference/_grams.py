"""Gram products of the posterior's linear block (private to :mod:`bayeshyst.inference`).

Every likelihood the linear block needs is a function of the Gram matrices of
``X = [Phi, r]`` (the design and the reference residual) over the scored samples: for
white noise their sum, for AR(1) noise the three lagged sums of
:class:`~bayeshyst.inference.conditional.LinearStats`. This module computes them -- stacked
over walkers, for a design every walker shares, and with a fixed basis (the
discrepancy's) that joins the design -- always as products whose shape does not depend
on the batch, so a walker's Grams are the same to the bit whichever batch computes them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["WALKER_CHUNK", "BasisGrams", "Grams", "grams", "grams_shared", "lagged_grams",
           "sample_rows", "stacked"]

#: ``(first, lag0, cross, prev)``: the Grams of one record (W, Q, Q); ``cross`` and
#: ``prev`` None without AR(1) noise
Grams = tuple[np.ndarray, np.ndarray, "np.ndarray | None", "np.ndarray | None"]

#: Walkers' residuals per BLAS product against a shared design and basis: a fixed
#: width, zero-padded, so a walker's Gram never depends on the batch (see
#: :meth:`BasisGrams._grams_shared`). Four: OpenBLAS's fastest width for these tall,
#: thin products (6 000 x 33 design, 24 walkers: 0.40 ms at 4, 0.58 at 8, 0.63 at 2;
#: measured single-threaded)
WALKER_CHUNK = 4


def sample_rows(idx: np.ndarray) -> np.ndarray | slice:
    """Sample indices as a slice when they are a contiguous run (a view), else as they are."""
    if idx.size and int(idx[-1]) - int(idx[0]) + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def lagged_grams(gram: Callable[[np.ndarray, np.ndarray], np.ndarray], keep: np.ndarray,
                 shape: tuple[int, int, int], lagged: bool) -> Grams:
    """``first``, ``lag0`` (and ``cross``, ``prev`` for AR(1)) Grams from ``gram(a, b)``.

    ``gram(a, b)`` is the Gram of the sample sets ``a`` and ``b`` (index arrays); the
    first kept sample is ``first``, the others ``lag0``, their products with the samples
    before them ``cross`` and those samples' own ``prev``.
    """
    first = gram(np.array([0]), np.array([0])) if keep[0] else np.zeros(shape)
    idx = np.flatnonzero(keep[1:]) + 1
    if idx.size == 0:
        zero = np.zeros(shape)
        return first, zero, (zero if lagged else None), (zero if lagged else None)
    lag0 = gram(idx, idx)
    if not lagged:
        return first, lag0, None, None
    return first, lag0, gram(idx, idx - 1), gram(idx - 1, idx - 1)


def stacked(phi: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``X = [Phi, r]`` per walker, shape (W, N, P + 1), non-finite entries zeroed.

    The walkers with non-finite entries are flagged failed by the caller.
    """
    w, n = r.shape
    p = phi.shape[2]
    x = np.empty((w, n, p + 1))
    x[:, :, :p] = phi
    x[:, :, p] = r
    return x if np.all(np.isfinite(x)) else np.where(np.isfinite(x), x, 0.0)


def grams(x: np.ndarray, keep: np.ndarray, lagged: bool) -> Grams:
    """Gram matrices (W, Q, Q) of the kept samples of one record.

    ``first = x_0 x_0^T`` (when sample 0 is kept), ``lag0 = sum_{k>=1} x_k x_k^T``; with
    ``lagged`` also ``cross = sum x_k x_{k-1}^T`` and ``prev = sum x_{k-1} x_{k-1}^T`` (the
    AR(1) innovations ``x_k - phi x_{k-1}``), sums over the kept ``k >= 1``. Stacked BLAS
    products: each walker's matrix is one product of the same shape whatever the batch,
    so cached and recomputed values agree to the bit (tested).
    """
    w, _, q = x.shape
    first = (x[:, 0, :, None] * x[:, 0, None, :]) if keep[0] else np.zeros((w, q, q))
    idx = np.flatnonzero(keep[1:]) + 1
    xk, xp = x[:, sample_rows(idx)], x[:, sample_rows(idx - 1)]  # views on a run
    xkt = xk.transpose(0, 2, 1)
    lag0 = xkt @ xk
    if not lagged:
        return first, lag0, None, None
    return first, lag0, xkt @ xp, xp.transpose(0, 2, 1) @ xp


def grams_shared(phi: np.ndarray, r: np.ndarray, keep: np.ndarray, lagged: bool) -> Grams:
    """:func:`grams` for a design shared by every walker (``phi`` (N, P)).

    Used e.g. for Bouc–Wen's ``[u, 1]``: the design's own products once, its products
    with each walker's residual one ``r_w @ phi`` each (one call per walker: values
    independent of the batch), and no ``W``-fold copy of the design.
    """
    w, _ = r.shape
    p = phi.shape[1]
    q = p + 1
    r = np.where(np.isfinite(r), r, 0.0)

    def block(a_phi: np.ndarray, a_r: np.ndarray, b_phi: np.ndarray,
              b_r: np.ndarray) -> np.ndarray:
        out = np.empty((w, q, q))
        out[:, :p, :p] = a_phi.T @ b_phi
        out[:, :p, p] = np.stack([b_r[j] @ a_phi for j in range(w)]) if p else 0.0
        out[:, p, :p] = np.stack([a_r[j] @ b_phi for j in range(w)]) if p else 0.0
        out[:, p, p] = np.einsum("wn,wn->w", a_r, b_r, optimize=False)
        return out

    if not lagged:
        # the Gaussian likelihood needs only the sum over every kept sample: one block
        rows = sample_rows(np.flatnonzero(keep))
        return (np.zeros((w, q, q)), block(phi[rows], r[:, rows], phi[rows], r[:, rows]),
                None, None)
    first = (block(phi[:1], r[:, :1], phi[:1], r[:, :1]) if keep[0]
             else np.zeros((w, q, q)))
    idx = np.flatnonzero(keep[1:]) + 1
    sk, sp = sample_rows(idx), sample_rows(idx - 1)  # views on a run
    pk, rk, pp, rp = phi[sk], r[:, sk], phi[sp], r[:, sp]
    return first, block(pk, rk, pk, rk), block(pk, rk, pp, rp), block(pp, rp, pp, rp)


class BasisGrams:
    """Grams of ``[phi, B, r]`` for records whose design is joined by a fixed basis ``B``.

    The basis (the discrepancy's, unscaled) is the same for every walker: its own
    products are computed once per record and sample set and cached here, its products
    with the walkers' columns one product per record for all walkers.

    Parameters
    ----------
    records : sequence of dict
        The posterior's records; each has ``"basis"`` (N_all, m) and ``"s0"`` (the first
        scored sample).
    p_design : int
        Columns of the simulated design (before the basis).
    p : int
        All linear columns: the design's and the basis'.
    lagged : bool
        Whether the AR(1) lagged Grams are wanted too.
    """

    def __init__(self, records: Sequence[dict], p_design: int, p: int, lagged: bool) -> None:
        self._records = records
        self.p_design = p_design
        self.p = p
        self.lagged = lagged
        self._cache: dict[tuple, np.ndarray] = {}

    def _basis(self, rec_index: int) -> np.ndarray:
        rec = self._records[rec_index]
        return rec["basis"][rec["s0"]:]

    def _basis_gram(self, rec_index: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``B[a]^T B[b]`` (m, m) of one record's basis rows ``a``, ``b``, cached."""
        key = (rec_index, a.tobytes(), b.tobytes())
        if key not in self._cache:
            basis = self._basis(rec_index)
            self._cache[key] = basis[a].T @ basis[b]
        return self._cache[key]

    def grams(self, rec_index: int, phi: np.ndarray, r: np.ndarray, keep: np.ndarray,
              shared: bool) -> Grams:
        """:func:`grams` of ``[phi, B, r]`` with the basis ``B`` unscaled (W, Q, Q).

        The basis is the same for every walker: its own products are computed once per
        record and sample set, its products with the walkers' columns one product per
        walker (values independent of the batch, as in :func:`grams_shared`).
        """
        if shared and phi.shape[0] == 1 and np.all(np.isfinite(phi)):
            return self._grams_shared(rec_index, phi[0], r, keep)
        w = r.shape[0]
        basis = self._basis(rec_index)
        pd = self.p_design
        q = self.p + 1
        # the walkers' own columns in (N, W, pd + 1) layout: a run of samples is then one
        # (n, W (pd + 1)) matrix for the basis product without a copy (the (W, N, .)
        # layout copied the walkers' columns twice per Gram: 2.5x the time, measured)
        xt = np.empty((r.shape[1], w, pd + 1))
        xt[:, :, :pd] = np.broadcast_to(phi, (w, *phi.shape[1:])).transpose(1, 0, 2)
        xt[:, :, pd] = r.T
        if not np.all(np.isfinite(xt)):  # as stacked(): zeroed, the caller flags them failed
            xt = np.where(np.isfinite(xt), xt, 0.0)
        ix = np.r_[np.arange(pd), self.p]
        ib = np.arange(pd, self.p)

        def gram(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            out = np.empty((w, q, q))
            same = np.array_equal(a, b)
            ra, rb = sample_rows(a), sample_rows(b)
            xa = xt[ra]
            xb = xa if same else xt[rb]
            out[:, ix[:, None], ix[None, :]] = xa.transpose(1, 2, 0) @ xb.transpose(1, 0, 2)
            # one product over all walkers: the basis (N x m, tens of MB on long records)
            # is read once, not once per walker (W skinny products were memory-bound)
            n_b = xb.shape[0]
            cross_b = (basis[ra].T @ xb.reshape(n_b, -1)).reshape(-1, w, ix.size)
            out[:, ib[:, None], ix[None, :]] = cross_b.transpose(1, 0, 2)
            if same:
                out[:, ix[:, None], ib[None, :]] = cross_b.transpose(1, 2, 0)
            else:
                cross_a = (basis[rb].T @ xa.reshape(n_b, -1)).reshape(-1, w, ix.size)
                out[:, ix[:, None], ib[None, :]] = cross_a.transpose(1, 2, 0)
            out[:, ib[:, None], ib[None, :]] = self._basis_gram(rec_index, a, b)[None]
            return out

        return lagged_grams(gram, keep, (w, q, q), self.lagged)

    def _design_basis(self, rec_index: int, phi: np.ndarray) -> np.ndarray:
        """``[phi, B]`` (N, P) of one record for a shared design ``phi`` (N, pd), cached."""
        key = ("design_basis", rec_index)
        cached = self._cache.get(key)
        if cached is None or not np.array_equal(cached[:, :self.p_design], phi):
            basis = self._basis(rec_index)
            cached = np.ascontiguousarray(np.concatenate([phi, basis], axis=1))
            self._cache[key] = cached
        return cached

    def _grams_shared(self, rec_index: int, phi: np.ndarray, r: np.ndarray,
                      keep: np.ndarray) -> Grams:
        """:meth:`grams` for a design shared by every walker (``phi`` (N, pd)).

        Bouc–Wen's ``[u, 1]``: with ``A = [phi, B]`` the same for every walker, its own
        Gram ``A^T A`` is computed once per record and sample set, and each walker adds
        ``A^T r_w`` (and ``r_w^T r_w``) -- ``W`` columns against ``A``, not the ``W (pd +
        1)`` of multiplying the design anew for each walker. The walkers' residuals go
        through BLAS in chunks of :data:`WALKER_CHUNK` columns, zero-padded, so every
        product has the same shape whatever the batch: a walker's values do not depend
        on the batch it is computed in (a product's shape can change its rounding;
        tested).
        """
        w = r.shape[0]
        a_all = self._design_basis(rec_index, phi)
        q = self.p + 1
        p = self.p
        r = np.where(np.isfinite(r), r, 0.0)  # the caller flags these walkers failed

        def products(a_rows: np.ndarray, r_rows: np.ndarray) -> np.ndarray:
            # A_a^T r_w (W, P) in fixed-shape chunks of walkers
            out = np.empty((w, p))
            chunk = np.zeros((r_rows.shape[1], WALKER_CHUNK))
            for c in range(0, w, WALKER_CHUNK):
                k = min(WALKER_CHUNK, w - c)
                chunk[:, :k] = r_rows[c:c + k].T
                chunk[:, k:] = 0.0
                out[c:c + k] = (a_rows.T @ chunk)[:, :k].T
            return out

        def gram(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            out = np.empty((w, q, q))
            ra, rb = sample_rows(a), sample_rows(b)
            key = ("design_gram", rec_index, a.tobytes(), b.tobytes())
            if key not in self._cache:
                self._cache[key] = a_all[ra].T @ a_all[rb]
            out[:, :p, :p] = self._cache[key][None]
            r_a, r_b = r[:, ra], r[:, rb]
            out[:, :p, p] = products(a_all[ra], r_b)
            out[:, p, :p] = (out[:, :p, p] if np.array_equal(a, b)
                             else products(a_all[rb], r_a))
            out[:, p, p] = np.einsum("wn,wn->w", r_a, r_b, optimize=False)
            return out

        return lagged_grams(gram, keep, (w, q, q), self.lagged)
