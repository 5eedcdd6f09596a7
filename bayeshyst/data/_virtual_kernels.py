"""Numba time loops of the virtual actuator (:mod:`bayeshyst.data.virtual`).

This is a private, independent implementation: it shares no code with
:mod:`bayeshyst.models`, so that tests of the models compare two different codes.
The effects whose loops these are live in :mod:`bayeshyst.data._virtual_effects`.

Preisach memory
---------------
The memory of the Preisach part is the staircase of alternating dominant extrema
``ext[0..depth-1]``: ``ext[0]`` is a floor below the Preisach plane (the virgin state
"came up from negative saturation"), ``ext[depth-1]`` is the current input, and
consecutive entries alternate between minima and maxima with shrinking amplitude.
``acc[k]`` is the output contributed by the closed segments ``ext[0] -> ... -> ext[k]``;
the output is ``acc[depth-2]`` plus the running segment. A rising segment
``m -> M`` contributes ``+E(M, m)``, a falling one ``M -> m`` contributes ``-E(M, m)``,
with ``E(alpha, beta)`` the Everett function of 0/1 relays (mass of the triangle
``beta <= b <= a <= alpha``). Wiping-out: when the input passes the extremum two steps
back, the minor loop is closed and both entries are removed. Only the memory
structure, not the tabulated ``E``, gives wiping-out and return-point memory, so both
hold exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["ar1", "run_chain", "static_path"]


@njit(cache=True)
def _everett(table, lo, step, a, b):
    """Bilinear interpolation of the tabulated Everett function, arguments clamped."""
    n = table.shape[0]
    hi = lo + step * (n - 1)
    a = min(max(a, lo), hi)
    b = min(max(b, lo), hi)
    xa = (a - lo) / step
    xb = (b - lo) / step
    ia = min(int(xa), n - 2)
    ib = min(int(xb), n - 2)
    fa = xa - ia
    fb = xb - ib
    return ((1.0 - fa) * ((1.0 - fb) * table[ia, ib] + fb * table[ia, ib + 1])
            + fa * ((1.0 - fb) * table[ia + 1, ib] + fb * table[ia + 1, ib + 1]))


@njit(cache=True)
def _segment(table, lo, step, start, end):
    """Output contributed by a monotone input segment ``start -> end``."""
    if end >= start:
        return _everett(table, lo, step, end, start)
    return -_everett(table, lo, step, start, end)


@njit(cache=True)
def _push(ext, acc, depth, u, table, lo, step):
    """Feed input ``u`` to the staircase memory; return the new depth.

    The caller guarantees room for one more entry (``depth < ext.shape[0]``); every
    entry beyond the first two is a reversal of the input path, and a path that is
    monotone between the ``n`` record samples has at most ``n`` of them.
    """
    last = ext[depth - 1]
    if u == last:
        return depth
    rising = last > ext[depth - 2]
    if (u > last) == rising:
        ext[depth - 1] = u
        # wiping-out: passing the same-type extremum two entries back closes a minor
        # loop; index depth-3 >= 1 keeps the floor ext[0] (it is never passed anyway)
        while depth >= 4 and ((rising and u >= ext[depth - 3])
                              or (not rising and u <= ext[depth - 3])):
            depth -= 2
            ext[depth - 1] = u
        return depth
    acc[depth - 1] = acc[depth - 2] + _segment(table, lo, step, ext[depth - 2], last)
    ext[depth] = u
    return depth + 1


@njit(cache=True)
def _output(ext, acc, depth, table, lo, step):
    return acc[depth - 2] + _segment(table, lo, step, ext[depth - 2], ext[depth - 1])


@njit(cache=True)
def _new_memory(u0, lo, hi, capacity):
    # fixed capacity: growing arrays inside the time loop costs reference counting
    # on every sample, even when no growth happens
    ext = np.empty(capacity)
    acc = np.zeros(capacity)
    ext[0] = lo - 1.0  # floor strictly below every clamped input
    ext[1] = min(max(u0, lo), hi)
    return ext, acc, 2


@njit(cache=True)
def static_path(u, table, lo, step):
    """Preisach output (0/1 relays, virgin state from below) along the input path ``u``.

    Parameters
    ----------
    u : ndarray, shape (n,)
        Input samples [V]; clamped to the tabulated plane.
    table : ndarray, shape (m, m)
        Everett function on the grid ``lo + step * arange(m)`` (rows alpha, cols beta).
    lo, step : float
        Grid origin and spacing [V].

    Returns
    -------
    ndarray, shape (n,)
        Preisach output [um] after each sample (no offset, no linear part).
    """
    hi = lo + step * (table.shape[0] - 1)
    out = np.empty(u.shape[0])
    ext, acc, depth = _new_memory(u[0], lo, hi, u.shape[0] + 3)
    for k in range(u.shape[0]):
        depth = _push(ext, acc, depth, min(max(u[k], lo), hi), table, lo, step)
        out[k] = _output(ext, acc, depth, table, lo, step)
    return out


@njit(cache=True)
def run_chain(t, u, q, t_start, h, n_grid, table, lo, step, offset, gain, hyst_on,
              lag_a, lag_b, lag_c, dyn_on, phi, gam0, gam1):
    """Static hysteresis -> creep lag bank -> second-order dynamics on a uniform grid.

    Parameters
    ----------
    t, u : ndarray, shape (n,)
        Record times [s] (strictly increasing) and input [V]; the input is linear
        between samples and held at ``u[0]`` before ``t[0]``.
    q : ndarray, shape (n,)
        Fractional grid index of each output sample (integer-valued when the sample
        falls on the grid); nondecreasing.
    t_start, h : float
        Input time of grid point 0 [s] and grid step [s].
    n_grid : int
        Number of grid points.
    table : ndarray, shape (m, m)
        Everett table; ``lo``, ``step`` its origin and spacing [V].
    offset : float
        Preisach output subtracted so that the virgin actuator reads 0 at 0 V [um].
    gain : float
        Reversible linear part [um/V].
    hyst_on : bool
        Include the Preisach part.
    lag_a, lag_b, lag_c : ndarray, shape (L,)
        Creep lags ``exp(-h/tau)``, first-order-hold ramp factors
        ``1 - tau (1 - a) / h`` and weights; ``L = 0`` disables creep.
    dyn_on : bool
        Include the second-order dynamics.
    phi : ndarray, shape (2, 2)
        State transition over one grid step (state: position [um], velocity [um/s]).
    gam0, gam1 : ndarray, shape (2,)
        First-order-hold input matrices: a step adds ``gam0 z_prev + gam1 (z - z_prev)``.

    Returns
    -------
    ndarray, shape (n,)
        Displacement at the output samples [um], before drift and noise.
    """
    n = t.shape[0]
    hi = lo + step * (table.shape[0] - 1)
    n_lag = lag_a.shape[0]
    y = np.empty(n)
    x = np.empty(n_lag)
    ext, acc, depth = _new_memory(u[0], lo, hi, n + 3)
    p = 0  # last record sample at or before the current grid time
    i = 0  # next output sample
    w_prev = 0.0
    z_prev = 0.0
    pos = 0.0
    vel = 0.0
    out_prev = 0.0
    for j in range(n_grid):
        tau = t_start + j * h
        # tolerance: grid times carry rounding; a sample within 1e-6 grid steps is reached
        while p + 1 < n and t[p + 1] <= tau + 1e-6 * h:
            p += 1
            if hyst_on:
                # the record's samples are the vertices of the piecewise-linear input:
                # a reversal between grid points must still enter the memory
                depth = _push(ext, acc, depth, min(max(u[p], lo), hi), table, lo, step)
        if tau <= t[p] or p + 1 >= n:
            uj = u[p]
        else:
            uj = u[p] + (u[p + 1] - u[p]) * (tau - t[p]) / (t[p + 1] - t[p])
            # rounding must not step outside the segment: the input stays monotone
            # between record samples, which bounds the memory depth by n
            uj = min(max(uj, min(u[p], u[p + 1])), max(u[p], u[p + 1]))
        w = gain * uj
        if hyst_on:
            depth = _push(ext, acc, depth, min(max(uj, lo), hi), table, lo, step)
            w += _output(ext, acc, depth, table, lo, step) - offset
        z = w
        if j == 0:
            # relaxed start: every lag has settled on the initial displacement
            for m in range(n_lag):
                x[m] = w
        else:
            for m in range(n_lag):
                x[m] = lag_a[m] * x[m] + (1.0 - lag_a[m]) * w_prev + lag_b[m] * (w - w_prev)
        for m in range(n_lag):
            z += lag_c[m] * x[m]
        if dyn_on:
            if j == 0:
                pos = z
                vel = 0.0
            else:
                dz = z - z_prev
                p_new = (phi[0, 0] * pos + phi[0, 1] * vel + gam0[0] * z_prev
                         + gam1[0] * dz)
                vel = phi[1, 0] * pos + phi[1, 1] * vel + gam0[1] * z_prev + gam1[1] * dz
                pos = p_new
            out = pos
        else:
            out = z
        while i < n and q[i] <= j:
            frac = q[i] - (j - 1)
            y[i] = out if frac >= 1.0 else out_prev + frac * (out - out_prev)
            i += 1
        w_prev = w
        z_prev = z
        out_prev = out
    while i < n:  # rounding can leave the last target a hair past the grid
        y[i] = out_prev
        i += 1
    return y


@njit(cache=True)
def ar1(white, phi, rms):
    """Stationary AR(1) sequence ``e_k = phi e_{k-1} + s w_k`` with RMS ``rms``.

    ``white`` (n,) are standard normal draws, ``|phi| < 1``, ``rms`` in um; returns (n,).
    """
    e = np.empty(white.shape[0])
    s = rms * math.sqrt(1.0 - phi * phi)
    prev = 0.0
    for k in range(white.shape[0]):
        # e_0 from the stationary law, so the first sample is not special
        prev = rms * white[k] if k == 0 else phi * prev + s * white[k]
        e[k] = prev
    return e
