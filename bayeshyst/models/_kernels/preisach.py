"""Kernels of the Preisach family: Everett tables and the staircase (memory) algorithm.

Equations (MODELS.md §3, review Eq. 1–4 and 7–8)::

    Y(a, b) = mass of mu over the triangle {b < beta <= alpha <= a}      (Everett)
    rising:  P = sum_k [Y(A_k, B_{k-1}) - Y(A_k, B_k)] + Y(u, B_{n-1})     (Eq. 7)
    falling: P = sum_k [Y(A_k, B_{k-1}) - Y(A_k, B_k)] + Y(A_n, B_{n-1}) - Y(A_n, u)  (Eq. 8)

with the memory ``A_1 > A_2 > ...`` (dominant maxima) and ``B_1 < B_2 < ...``
(dominant minima), ``B_0 = -inf``; ``P`` is the 1-0 relay sum. An Everett table holds
``Y`` on nodes; ``bilinear=False`` reads it as a step function (exact for a discrete
relay grid, the nodes being the relay thresholds), ``bilinear=True`` interpolates
between nodes (review ref. [40]).

State of one walker, a float vector of length ``3 + D`` (``D`` = maximal memory)::

    [0] n        number of stored extrema (an integer, 0 <= n <= D)
    [1] merges   how many times the memory was full and its innermost pair was dropped
    [2] tip      the current input: end of the running monotone segment
    [3:3+n]      extrema e_0 > e_1 < e_2 > ... (even entries maxima, odd entries minima);
                 the slots after them are zero

``n`` even means rising from ``e_{n-1}`` (or from -inf) to ``tip``; odd means falling
from ``e_{n-1}`` to ``tip``. Partial sums of the Everett terms are rebuilt from the
stored extrema at the start of every call with the same recurrence used while running,
so a record simulated in pieces gives bit-identical output.

Each kernel is a one-walker function plus a loop over walkers that runs in parallel for
large batches and serially otherwise (:func:`bayeshyst.models._kernels.batch_kernel`):
for a single walker, waking numba's thread pool costs more than the work (milliseconds
on a loaded machine).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = [
    "density_everett_table",
    "density_everett_tables",
    "everett_eval",
    "memory_valid",
    "relay_everett_table",
    "relay_everett_tables",
    "staircase_batch",
    "staircase_one",
]

# two-point Gauss-Legendre rule on [0, 1]
_GX0 = 0.5 - 0.5 / math.sqrt(3.0)
_GX1 = 0.5 + 0.5 / math.sqrt(3.0)


@njit(cache=True)
def _count_le(nodes, x):
    """Number of nodes ``<= x`` (binary search; nodes strictly increasing)."""
    lo = 0
    hi = nodes.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if nodes[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _locate(nodes, x):
    """Interval index ``i`` and fraction ``f`` of ``x`` between nodes ``i`` and ``i+1``.

    Values outside the nodes are clamped to the end nodes: the Preisach plane is bounded
    (review Fig. 10a), relays beyond it do not exist.
    """
    k = nodes.shape[0]
    i = _count_le(nodes, x) - 1
    if i < 0:
        return 0, 0.0
    if i >= k - 1:
        return k - 2, 1.0
    return i, (x - nodes[i]) / (nodes[i + 1] - nodes[i])


@njit(cache=True)
def _everett(nodes, table, bilinear, a, b):
    """``Y(a, b)`` from a table: step lookup or bilinear interpolation."""
    if not bilinear:
        # table[I, J] = mass of the relays with alpha <= a (I of them) and beta > b
        return table[_count_le(nodes, a), _count_le(nodes, b)]
    i, fa = _locate(nodes, a)
    j, fb = _locate(nodes, b)
    lo = (1.0 - fb) * table[i, j] + fb * table[i, j + 1]
    hi = (1.0 - fb) * table[i + 1, j] + fb * table[i + 1, j + 1]
    return (1.0 - fa) * lo + fa * hi


@njit(cache=True)
def everett_eval(nodes, table, bilinear, alpha, beta, out):
    """Evaluate ``Y(alpha[k], beta[k])`` into ``out[k]`` (for plots and tests)."""
    for k in range(alpha.shape[0]):
        out[k] = _everett(nodes, table, bilinear, alpha[k], beta[k])


@njit(cache=True)
def relay_everett_table(mu, tab):
    """Everett table of one discrete relay grid.

    Parameters
    ----------
    mu : (L(L+1)/2,) cell weights; cell ``(i, j)`` (0-based, ``j <= i``, thresholds
        ``alpha = q_i``, ``beta = q_j``) is entry ``i (i + 1) / 2 + j``.
    tab : (L+1, L+1), written: ``tab[I, J]`` is the sum of the weights of the cells
        with ``alpha`` among the lowest ``I`` levels and ``beta`` above the lowest ``J``.
    """
    n_lev = tab.shape[0] - 1
    for jj in range(n_lev + 1):
        tab[0, jj] = 0.0
    for i in range(1, n_lev + 1):
        base = (i - 1) * i // 2
        s = 0.0
        # sweep beta downwards so that s is the row's suffix sum of weights
        for jj in range(i - 1, -1, -1):
            s += mu[base + jj]
            tab[i, jj] = tab[i - 1, jj] + s
        for jj in range(i, n_lev + 1):
            tab[i, jj] = 0.0


@njit(cache=True, parallel=True)
def _relay_everett_tables_par(mu, out):
    """:func:`relay_everett_table` for W walkers: ``mu`` (W, n_cells), ``out`` (W, L+1, L+1)."""
    for w in prange(mu.shape[0]):
        relay_everett_table(mu[w], out[w])


@njit(cache=True)
def _relay_everett_tables_ser(mu, out):
    for w in range(mu.shape[0]):
        relay_everett_table(mu[w], out[w])


relay_everett_tables = batch_kernel(_relay_everett_tables_par, _relay_everett_tables_ser,
                                    work_arg=1, name="relay_everett_tables")


@njit(cache=True)
def _log_density(a, b, c0, sc, m_r, s_r, rho, lognormal):
    """Log Preisach density (up to a constant) in mean/half-width coordinates."""
    r = 0.5 * (a - b)
    if r <= 0.0:
        return -np.inf
    zc = (0.5 * (a + b) - c0) / sc
    if lognormal:
        lr = math.log(r)
        zr = (lr - m_r) / s_r
        extra = -lr  # the density is Gaussian in log r: Jacobian 1/r back to r
    else:
        zr = (r - m_r) / s_r
        extra = 0.0
    q = (zc * zc - 2.0 * rho * zc * zr + zr * zr) / (1.0 - rho * rho)
    return -0.5 * q + extra


@njit(cache=True)
def _cell_mass(nodes, i, j, dens, lognormal, shift):
    """Quadrature of ``exp(log f - shift)`` over cell (alpha in node interval i, beta in j)."""
    c0, sc, m_r, s_r, rho = dens[0], dens[1], dens[2], dens[3], dens[4]
    a0 = nodes[i]
    ha = nodes[i + 1] - a0
    acc = 0.0
    if j < i:
        b0 = nodes[j]
        hb = nodes[j + 1] - b0
        for p in range(2):
            xa = a0 + ha * (_GX0 if p == 0 else _GX1)
            for q in range(2):
                xb = b0 + hb * (_GX0 if q == 0 else _GX1)
                acc += math.exp(_log_density(xa, xb, c0, sc, m_r, s_r, rho, lognormal) - shift)
        return 0.25 * ha * hb * acc
    # diagonal cell: the half-square beta <= alpha, by the collapsed (Duffy) map
    # (s, t) -> (alpha, beta) = (a0 + h s, a0 + h s t) with Jacobian h^2 s
    for p in range(2):
        s = _GX0 if p == 0 else _GX1
        for q in range(2):
            t = _GX0 if q == 0 else _GX1
            ld = _log_density(a0 + ha * s, a0 + ha * s * t, c0, sc, m_r, s_r, rho, lognormal)
            acc += s * math.exp(ld - shift)
    return 0.25 * ha * ha * acc


@njit(cache=True)
def density_everett_table(nd, dw, lognormal, tab):
    """Normalised Everett table of a parametric Preisach density; False if it has no mass.

    Parameters
    ----------
    nd : (G+1,) strictly increasing grid over the bounded Preisach plane (V).
    dw : (5,) ``centre, sd_centre, m_r, s_r, rho``: the density is a bivariate Gaussian
        in ``c = (alpha + beta)/2`` and ``log r`` (``lognormal``) or ``r`` (otherwise),
        ``r = (alpha - beta)/2``, with means ``centre, m_r``, standard deviations
        ``sd_centre, s_r`` and correlation ``rho``.
    lognormal : bool
    tab : (G+1, G+1), written: ``Y`` at the nodes divided by the density's mass inside
        the plane, so that ``Y`` rises from 0 to 1.
    """
    g = nd.shape[0] - 1
    # the largest log density at the cell centres is subtracted before exponentiating,
    # so that a density far from the plane is rescaled instead of underflowing to 0
    shift = -np.inf
    for i in range(g):
        for j in range(i + 1):
            if j < i:
                xa = 0.5 * (nd[i] + nd[i + 1])
                xb = 0.5 * (nd[j] + nd[j + 1])
            else:
                xa = nd[i] + (nd[i + 1] - nd[i]) * (2.0 / 3.0)
                xb = nd[i] + (nd[i + 1] - nd[i]) * (1.0 / 3.0)
            ld = _log_density(xa, xb, dw[0], dw[1], dw[2], dw[3], dw[4], lognormal)
            if ld > shift:
                shift = ld
    if not math.isfinite(shift):
        return False
    for jj in range(g + 1):
        tab[0, jj] = 0.0
    for i in range(1, g + 1):
        s = 0.0
        for jj in range(i - 1, -1, -1):
            s += _cell_mass(nd, i - 1, jj, dw, lognormal, shift)
            tab[i, jj] = tab[i - 1, jj] + s
        for jj in range(i, g + 1):
            tab[i, jj] = 0.0
    total = tab[g, 0]
    if not (total > 0.0 and math.isfinite(total)):
        return False
    for i in range(g + 1):
        for jj in range(g + 1):
            tab[i, jj] /= total
    return True


@njit(cache=True, parallel=True)
def _density_everett_tables_par(nodes, dens, lognormal, out, ok):
    """:func:`density_everett_table` for W walkers: ``nodes`` (W, G+1), ``dens`` (W, 5),
    ``out`` (W, G+1, G+1) and ``ok`` (W,) written."""
    for w in prange(nodes.shape[0]):
        ok[w] = density_everett_table(nodes[w], dens[w], lognormal, out[w])


@njit(cache=True)
def _density_everett_tables_ser(nodes, dens, lognormal, out, ok):
    for w in range(nodes.shape[0]):
        ok[w] = density_everett_table(nodes[w], dens[w], lognormal, out[w])


density_everett_tables = batch_kernel(_density_everett_tables_par, _density_everett_tables_ser,
                                      work_arg=3, name="density_everett_tables")


@njit(cache=True)
def memory_valid(state):
    """Whether each row of ``state`` (W, 3 + D) is a consistent staircase memory."""
    width = state.shape[0]
    depth = state.shape[1] - 3
    res = np.zeros(width, dtype=np.bool_)
    for w in range(width):
        row = state[w]
        nf = row[0]
        if not (math.isfinite(nf) and nf == math.floor(nf) and 0 <= nf <= depth):
            continue
        if not (math.isfinite(row[1]) and row[1] >= 0 and math.isfinite(row[2])):
            continue
        n = int(nf)
        good = True
        for k in range(n):
            e = row[3 + k]
            if not math.isfinite(e):
                good = False
            elif k >= 1 and (e >= row[2 + k] if k % 2 == 1 else e <= row[2 + k]):
                good = False  # a minimum below the maximum before it, and vice versa
            elif k >= 2 and (e <= row[1 + k] if k % 2 == 1 else e >= row[1 + k]):
                good = False  # nested: inside the previous pair
        if good and n >= 1:
            tip, last = row[2], row[2 + n]
            good = tip >= last if n % 2 == 0 else tip <= last
            if good and n >= 2:
                prev = row[1 + n]
                good = tip < prev if n % 2 == 0 else tip > prev
        res[w] = good
    return res


@njit(cache=True)
def _pref_after_push(e, pref, i, nodes, table, bilinear):
    """Partial sum after storing extremum ``e[i]`` (Eq. 7: one term per max/min pair)."""
    if i % 2 == 0:
        # a maximum A: its positive term Y(A, B_prev), B_prev = -inf for the first one
        bprev = e[i - 1] if i >= 1 else -np.inf
        pref[i + 1] = pref[i] + _everett(nodes, table, bilinear, e[i], bprev)
    else:
        pref[i + 1] = pref[i] - _everett(nodes, table, bilinear, e[i - 1], e[i])


@njit(cache=True)
def staircase_one(u, nodes, table, bilinear, c0, c1, c2, st, y):
    """One walker of :func:`staircase_batch`; returns True if an output was not finite."""
    depth = st.shape[0] - 3
    n = int(st[0])
    merges = st[1]
    tip = st[2]
    e = st[3:]
    pref = np.empty(depth + 1)
    pref[0] = 0.0
    for i in range(n):
        _pref_after_push(e, pref, i, nodes, table, bilinear)
    failed = False
    for k in range(u.shape[0]):
        uk = u[k]
        rising = n % 2 == 0
        if (rising and uk < tip) or (not rising and uk > tip):
            # reversal: the tip becomes a stored extremum
            if n == depth:
                # memory full: forget the innermost (smallest, most recent) pair of
                # extrema, as if the input had wiped it out; counted in the state
                n -= 2
                merges += 1.0
            e[n] = tip
            _pref_after_push(e, pref, n, nodes, table, bilinear)
            n += 1
            rising = not rising
        tip = uk
        # wiping-out: a new extremum erases the earlier pairs it exceeds
        if rising:
            while n >= 2 and uk >= e[n - 2]:
                n -= 2
            bl = e[n - 1] if n >= 1 else -np.inf
            p = pref[n] + _everett(nodes, table, bilinear, uk, bl)
        else:
            while n >= 2 and uk <= e[n - 2]:
                n -= 2
            p = pref[n] - _everett(nodes, table, bilinear, e[n - 1], uk)
        yk = c0 + c1 * uk + c2 * p
        if not math.isfinite(yk):
            failed = True
        y[k] = yk
    st[0] = n
    st[1] = merges
    st[2] = tip
    # unused slots are zeroed so that equal memories give equal state vectors
    for i in range(n, depth):
        e[i] = 0.0
    return failed


@njit(cache=True, parallel=True)
def _staircase_par(u, nodes, tables, bilinear, coef, skip, state, y, failed):
    """Preisach output ``y = c0 + c1 u + c2 P`` for W walkers (Eq. 7–8).

    Parameters
    ----------
    u : (N,) input (V).
    nodes : (W, K) table nodes (V), strictly increasing.
    tables : (W, T, T) Everett tables: ``T = K + 1`` for step lookup (``bilinear``
        False), ``T = K`` for bilinear interpolation.
    bilinear : bool
    coef : (W, 3) ``c0, c1, c2`` of the affine output map.
    skip : (W,) bool; walkers marked here are reported failed and not simulated.
    state : (W, 3 + D) memory (module docstring), updated in place.
    y : (W, N) output, written.
    failed : (W,) bool, written: True where an output was not finite.
    """
    for w in prange(tables.shape[0]):
        failed[w] = skip[w] or staircase_one(u, nodes[w], tables[w], bilinear, coef[w, 0],
                                             coef[w, 1], coef[w, 2], state[w], y[w])


@njit(cache=True)
def _staircase_ser(u, nodes, tables, bilinear, coef, skip, state, y, failed):
    for w in range(tables.shape[0]):
        failed[w] = skip[w] or staircase_one(u, nodes[w], tables[w], bilinear, coef[w, 0],
                                             coef[w, 1], coef[w, 2], state[w], y[w])


staircase_batch = batch_kernel(_staircase_par, _staircase_ser, work_arg=-2,
                               name="staircase_batch")
