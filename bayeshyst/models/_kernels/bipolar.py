"""Kernels of the bipolar (butterfly) models: polarisation by a saturated play, strain by P².

Equations (MODELS.md §9)::

    v_k = max(E_k - E_c, min(E_k + E_c, v_{k-1}))     play of half-width E_c (review Eq. 11)
    P_k = (1 - eta) tanh(v_k / w) + eta tanh(E_k / w_r)   polarisation, |P| < 1
    S_k = Q P_k^2 + d E_k                              strain (electrostriction + linear)

``P = tanh(F_{E_c}[E] / w)`` is a Preisach model (review Eq. 3) whose ±1 relays all have
the half-width ``E_c`` and whose centres ``c`` are logistic with scale ``w / 2``: relay
``(c + E_c, c - E_c)`` is up exactly when ``v > c``, so the relay sum is the logistic
distribution function of ``v``, ``(1 + tanh(v / w)) / 2``, rescaled to ±1. The optional
reversible part (weight ``eta``, 0 without it) is the same on the diagonal ``E_c = 0``:
relays without hysteresis, logistic centres of scale ``w_r / 2``. The play keeps the
whole memory in one number, so a sample costs a max, a min and one or two ``tanh``.

State of one walker: ``[v]`` (input unit), the play's output. Each kernel is a
one-walker function plus a loop over walkers that runs in parallel for large batches
and serially otherwise (:func:`bayeshyst.models._kernels.batch_kernel`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel

__all__ = ["butterfly_batch", "butterfly_one"]


@njit(cache=True)
def butterfly_one(u, e_c, width, eta, w_rev, q, d, polar, state, y):
    """One walker of :func:`butterfly_batch`; returns True if it failed.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Field (input unit).
    e_c, width : float
        Coercive field and switching width (input unit).
    eta, w_rev : float
        Reversible fraction (1, in ``[0, 1)``; 0 skips the term) and its width (input
        unit).
    q, d : float
        ``Q`` (output unit) and ``d`` (output unit per input unit).
    polar : bool
        Write the polarisation ``P`` instead of the strain (``q`` and ``d`` unused).
    state : ndarray, shape (1,)
        ``[v]``, updated in place.
    y : ndarray, shape (N,)
        Strain (or polarisation), written.
    """
    if not (e_c >= 0.0 and width > 0.0 and 0.0 <= eta < 1.0 and w_rev > 0.0
            and math.isfinite(e_c + width + w_rev + q + d)):
        return True
    v = state[0]
    if not math.isfinite(v):
        return True
    inv_w = 1.0 / width
    inv_wr = 1.0 / w_rev
    keep = 1.0 - eta
    for k in range(u.shape[0]):
        uk = u[k]
        # the play: v stays unless the field pushes it by more than E_c
        v = max(uk - e_c, min(uk + e_c, v))
        p = math.tanh(v * inv_w)
        if eta != 0.0:
            p = keep * p + eta * math.tanh(uk * inv_wr)
        y[k] = p if polar else q * p * p + d * uk
    state[0] = v
    return False


@njit(cache=True, parallel=True)
def _butterfly_par(u, e_c, width, eta, w_rev, q, d, polar, state, y, failed):
    """Butterfly strain ``S = Q P^2 + d E`` for W walkers (module docstring).

    Parameters
    ----------
    u : (N,) field (input unit); e_c, width, eta, w_rev, q, d : (W,) parameters (eta = 0:
    no reversible part); polar : bool, write
    ``P`` instead of ``S``; state : (W, 1)
    ``[v]``, updated in place; y : (W, N) strain, written (NaN rows for failed walkers);
    failed : (W,) bool, written: parameters outside ``E_c >= 0, w > 0, 0 <= eta < 1,
    w_r > 0`` or not finite.
    """
    for j in prange(e_c.shape[0]):
        bad = butterfly_one(u, e_c[j], width[j], eta[j], w_rev[j], q[j], d[j], polar,
                            state[j], y[j])
        failed[j] = bad
        if bad:
            y[j, :] = np.nan


@njit(cache=True)
def _butterfly_ser(u, e_c, width, eta, w_rev, q, d, polar, state, y, failed):
    for j in range(e_c.shape[0]):
        bad = butterfly_one(u, e_c[j], width[j], eta[j], w_rev[j], q[j], d[j], polar,
                            state[j], y[j])
        failed[j] = bad
        if bad:
            y[j, :] = np.nan


butterfly_batch = batch_kernel(_butterfly_par, _butterfly_ser, work_arg=-2,
                               name="butterfly_batch")
