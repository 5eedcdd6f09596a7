"""The time loop of the bipolar virtual actuator (:mod:`bayeshyst.data.virtual_bipolar`).

Private and independent of :mod:`bayeshyst.models` (the data layer sits below it): the
polarisation here is an explicit ensemble of ±1 relays, each switched by itself, not a
play operator, so a fit of the ``butterfly`` model to these data compares two different
codes and two different hysteresis laws.

One step of the loop, for field ``E_k`` (kV/mm) after a step ``h_k`` (s)::

    relay i:  +1 if E_k >= alpha_i,  -1 if E_k <= beta_i,  else unchanged
    P_sw    = mean of the relays
    m_j     = a_j m_j + (1 - a_j) s(E_k) P_sw,   a_j = exp(-h_k / tau_j)
    P       = P_sw + chi E_k - sum_j kappa_j m_j,   s(E) = max(0, 1 - |E| / E_c)
    S       = Q P^2 + d E_k

``m_j`` are the relaxing parts of the remanent polarisation: driven only while the field
is below the coercive field (``s``), strongest at zero field, so during a hold at zero
field ``P`` relaxes from ``P_sw`` towards ``(1 - sum kappa) P_sw`` with the time
constants ``tau_j``, and a strong field re-stabilises it (``m_j`` decay to 0). The lag
update holds ``s P_sw`` constant over the step (exact for a hold).
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["bipolar_path"]


@njit(cache=True)
def bipolar_path(t, u, alpha, beta, relays, m, taus, kappas, e_c, chi, q, d, y, p_out):
    """Strain along a sampled field path; updates ``relays`` and ``m`` in place.

    Parameters
    ----------
    t, u : ndarray, shape (N,)
        Times (s, strictly increasing) and field (kV/mm).
    alpha, beta : ndarray, shape (R,)
        Up- and down-switching fields of the relays (kV/mm), ``alpha > beta``.
    relays : ndarray, shape (R,)
        Relay states ±1 before ``t[0]``, updated.
    m : ndarray, shape (J,)
        Relaxing polarisation parts before ``t[0]``, updated.
    taus, kappas : ndarray, shape (J,)
        Relaxation time constants (s) and fractions (1).
    e_c, chi, q, d : float
        Coercive field (kV/mm), reversible susceptibility (per kV/mm), strain at
        saturation (um), linear term (um per kV/mm).
    y, p_out : ndarray, shape (N,)
        Strain (um) and polarisation (units of the relays' saturation), written.
    """
    n_relays = alpha.shape[0]
    total = 0.0
    for i in range(n_relays):
        total += relays[i]
    t_prev = t[0]
    for k in range(u.shape[0]):
        e = u[k]
        for i in range(n_relays):
            if e >= alpha[i]:
                if relays[i] < 0.0:
                    relays[i] = 1.0
                    total += 2.0
            elif e <= beta[i] and relays[i] > 0.0:
                relays[i] = -1.0
                total -= 2.0
        p_sw = total / n_relays
        drive = max(0.0, 1.0 - abs(e) / e_c) * p_sw
        h = t[k] - t_prev
        p = p_sw + chi * e
        for j in range(m.shape[0]):
            a = math.exp(-h / taus[j])
            m[j] = a * m[j] + (1.0 - a) * drive
            p -= kappas[j] * m[j]
        t_prev = t[k]
        p_out[k] = p
        y[k] = q * p * p + d * e
