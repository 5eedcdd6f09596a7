"""Kernel of the asymmetric Maxwell-slip model (review §7.2, ref. [67]).

The elasto-slide elements are the Maxwell-slip kernel of
:mod:`bayeshyst.models._kernels.operators` (written once); this kernel adds the
nonlinear spring ``g`` in parallel, a polynomial in the normalised input
``s = (x - u_centre) / u_half`` without constant and linear terms (those are the
output offset and the linear spring ``k0``).
"""

from __future__ import annotations

from numba import njit, prange

from bayeshyst.models._kernels import batch_kernel
from bayeshyst.models._kernels.operators import _maxwell_one

__all__ = ["asym_maxwell_batch"]


@njit(cache=True)
def _spring(x, a, uc, uh, y):
    # Horner on s: g(s) = s^2 (a_0 + a_1 s + ... ), added to the elements' force
    m = a.shape[0]
    for t in range(x.shape[0]):
        s = (x[t] - uc) / uh
        acc = 0.0
        for j in range(m - 1, -1, -1):
            acc = acc * s + a[j]
        y[t] += acc * s * s


@njit(cache=True, parallel=True)
def _asym_par(x, k0, k, delta, a, uc, uh, state, y):
    """``y = k0 x + sum_i k_i (x - x_i) + g(s)`` for W parameter vectors.

    ``k0`` (W,), ``k``, ``delta`` (W, n) element stiffnesses and slip deflections,
    ``a`` (W, m) coefficients of ``s^2 .. s^(m + 1)`` in ``g``, ``uc``, ``uh`` (W,) the
    input normalisation; ``state`` (W, n) slider positions, updated in place; ``y``
    (W, N), written.
    """
    for j in prange(k.shape[0]):
        _maxwell_one(x, k0[j], k[j], delta[j], state[j], y[j])
        _spring(x, a[j], uc[j], uh[j], y[j])


@njit(cache=True)
def _asym_ser(x, k0, k, delta, a, uc, uh, state, y):
    for j in range(k.shape[0]):
        _maxwell_one(x, k0[j], k[j], delta[j], state[j], y[j])
        _spring(x, a[j], uc[j], uh[j], y[j])


asym_maxwell_batch = batch_kernel(_asym_par, _asym_ser, work_arg=-1,
                                  name="asym_maxwell_batch")
