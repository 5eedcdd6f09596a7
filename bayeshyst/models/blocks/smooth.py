"""Structure no physical block explains: a smooth function of one observed feature.

When the residual of a model depends on something observed -- the time since the record
started, a measured column -- and no block of the catalogue explains that dependence, the
closed loop (:mod:`bayeshyst.diagnosis`) still has to say how much of the error it is.
:class:`Unexplained` is that term: a gain and an offset that change smoothly with the
feature, with a reduced-rank Gaussian-process prior (Solin & Särkkä 2020), so it can
follow any slow dependence, not one chosen shape. It is the model-discrepancy term
``delta`` of Kennedy & O'Hagan (2001) restricted to one feature
(:mod:`bayeshyst.discrepancy` holds the one over the loop's own coordinates, and shares
the basis below).

**Reduced rank.** On ``[-L, L]`` a squared-exponential kernel of unit variance and
length ``l`` is ``k(z, z') ~ sum_j S(w_j) phi_j(z) phi_j(z')`` with
``phi_j(z) = L^-1/2 sin(w_j (z + L))``, ``w_j = pi j / 2L`` and
``S(w) = sqrt(2 pi) l exp(-l^2 w^2 / 2)`` (:func:`sine_basis`, :func:`log_se_spectrum`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from bayeshyst.errors import ModelError
from bayeshyst.models.base import check_count, data_scales
from bayeshyst.models.blocks.base import EffectBlock, param_columns, register_block
from bayeshyst.params import LogNormal, Normal, Param, ParamSpace

__all__ = ["BASIS_HALF_WIDTH", "TIME", "Unexplained", "log_se_spectrum", "sine_basis"]

#: Half-width ``L`` of the basis domain over a feature scaled to [-1, 1]: a boundary
#: closer to the data depresses the prior variance near its ends.
BASIS_HALF_WIDTH = 2.5
#: The feature name that means "time since the record started".
TIME = "time"
#: Prior standard deviation of the gain change, and of the offset change as a fraction
#: of the output span (as for the auxiliary-input block).
GAIN_PRIOR = 0.05
OFFSET_PRIOR = 0.05

_FEATURE = re.compile(r"^[^\s=+(),'\"]+(?: [^=+(),'\"]+)*$")


def sine_basis(z: Any, m: int, half_width: float = BASIS_HALF_WIDTH
               ) -> tuple[np.ndarray, np.ndarray]:
    """Laplacian eigenfunctions on ``[-L, L]`` and their square-root eigenvalues.

    Parameters
    ----------
    z : array_like, shape (...)
        Points (scaled feature, dimensionless).
    m : int
        Number of eigenfunctions.
    half_width : float
        ``L``.

    Returns
    -------
    phi : ndarray, shape (..., m)
        ``L^-1/2 sin(w_j (z + L))``.
    w : ndarray, shape (m,)
        ``pi j / 2L``, ``j = 1..m``.
    """
    w = math.pi * np.arange(1, m + 1) / (2.0 * half_width)
    z = np.asarray(z, dtype=float)
    return np.sin(w * (z[..., None] + half_width)) / math.sqrt(half_width), w


def log_se_spectrum(w: np.ndarray, length: Any) -> np.ndarray:
    """``log S(w)`` of the unit-variance 1-D squared-exponential kernel.

    Parameters
    ----------
    w : ndarray, shape (m,)
        Angular frequencies (per unit of the scaled feature).
    length : float or ndarray, shape (W,)
        Length-scales (scaled feature units).

    Returns
    -------
    ndarray, shape (W, m)
    """
    ell = np.atleast_1d(np.asarray(length, dtype=float))[:, None]
    return 0.5 * math.log(2.0 * math.pi) + np.log(ell) - 0.5 * (ell * w[None, :]) ** 2


def feature_range(data: Any, feature: str) -> tuple[float, float]:
    """Centre and half-range of ``feature`` over ``data`` (``(0, 1)`` without data).

    Time is the time since each record's first sample; a column is read from the
    records' covariates (a record lacking it: no data to scale to).
    """
    if data is None:
        return 0.0, 1.0
    records = list(data) if hasattr(data, "records") else [data]
    if feature == TIME:
        lo, hi = 0.0, max(float(r.t[-1] - r.t[0]) for r in records)
    else:
        cols = [getattr(r, "covariates", {}).get(feature) for r in records]
        if any(c is None for c in cols):
            return 0.0, 1.0
        values = np.concatenate([np.asarray(c, float) for c in cols])
        lo, hi = float(values.min()), float(values.max())
    half = 0.5 * (hi - lo)
    return 0.5 * (hi + lo), (half if half > 0 else 1.0)


@register_block
@dataclass(frozen=True)
class Unexplained(EffectBlock):
    """A gain and an offset that change smoothly with one observed feature.

    ``y = (1 + g(z)) w + h(z)``, ``z = (x - x_ref) / x_half``, where ``x`` is the time
    since the record started (``feature="time"``) or a measured column (any other
    name), scaled to [-1, 1] over the fitted data, and ``g``, ``h`` are independent
    zero-mean Gaussian processes, squared-exponential with length ``length`` (scaled
    units) and standard deviations 0.05 (gain) and 0.05 of the output span (offset), in
    reduced-rank form: ``g(z) = sum_j 0.05 sqrt(S(w_j)) phi_j(z) a_j``, likewise ``h``
    with ``b_j``, and ``a_j, b_j ~ Normal(0, 1)``. Kennedy & O'Hagan's discrepancy
    restricted to one feature (see module notes); the closed loop adds it when the
    residual depends on the feature and no physical block explains it.

    Parameters
    ----------
    feature : str
        ``"time"`` or the name of a data column (``Record.covariates``).
    n_basis : int
        Basis functions per process, at least 6.

    Notes
    -----
    The length is fixed at ``1.75 L / n_basis`` (L = 2.5), the shortest the basis
    resolves (Riutort-Mayol et al. 2023): 0.73 of the half-range for 6 functions, so the
    term follows slow changes -- two or three swings over the record -- and nothing on
    the time scale of a loop. ``x_ref`` and ``x_half`` are fixed parameters from the
    data. Simulated on a record without the column (a feedforward command), the block is
    the identity; over time it extrapolates its fitted trend, so feedforward should be
    designed without it.
    """

    name: ClassVar[str] = "unexplained"
    affine: ClassVar[bool] = True
    #: given its input, the output is linear in the coefficients: the sampler draws them
    #: exactly instead of leaving twelve coordinates to the ensemble
    linear_params: ClassVar[tuple[str, ...]] = ("a", "b")
    rate_dependent: ClassVar[bool] = True
    equation: ClassVar[str] = "y = (1 + g(z)) w + h(z), g, h ~ GP over z = scaled feature"
    example: ClassVar[Mapping[str, Any]] = MappingProxyType({"feature": "time"})
    feature: str = TIME
    n_basis: int = 6

    def __post_init__(self) -> None:
        if not isinstance(self.feature, str) or not _FEATURE.match(self.feature):
            raise ModelError(f"unexplained: feature must be 'time' or name a data column (no "
                             f"'=', '+', parentheses, commas or quotes), got {self.feature!r}")
        # the fixed length 1.75 L / m must also stay below L / 3.2 (the boundary's
        # reach), which needs m >= 6 at L = 2.5 (Riutort-Mayol et al. 2023)
        check_count(self.n_basis, "unexplained n_basis", minimum=6)

    @property
    def length(self) -> float:
        """The fixed length-scale (scaled feature units)."""
        return 1.75 * BASIS_HALF_WIDTH / self.n_basis

    @property
    def covariates(self) -> tuple[str, ...]:
        """The column the block reads (none for time)."""
        return () if self.feature == TIME else (self.feature,)

    @property
    def state_size(self) -> int:
        """1: the time the record started (so a record applied in pieces is one call)."""
        return 1

    def param_space(self, data: Any = None) -> ParamSpace:
        """Standardised coefficients ``a`` (gain), ``b`` (offset), each (n_basis,)."""
        sc = data_scales(data)
        ref, half = feature_range(data, self.feature)
        m, f = self.n_basis, self.feature
        unit = "s" if f == TIME else f
        return ParamSpace(
            (Param("a", Normal(0.0, 1.0), shape=(m,), unit="1",
                   description=f"standardised coefficients of the gain's change with {f}"),
             Param("b", Normal(0.0, 1.0), shape=(m,), unit="1",
                   description=f"standardised coefficients of the offset's change with {f}")),
            fixed={"x_ref": ref, "x_half": half, "y_span": sc.y_span},
            fixed_params=(
                Param("x_ref", Normal(ref, half), unit=unit,
                      description=f"centre of {f} over the data (fixed)"),
                Param("x_half", LogNormal.from_median(half, 1.0), unit=unit,
                      description=f"half-range of {f} over the data (fixed)"),
                Param("y_span", LogNormal.from_median(sc.y_span, 1.0), unit=sc.y_unit,
                      description="output span of the data (fixed: the offset's scale)")),
        )

    def _initial_state(self, theta, w0, t0):
        # NaN: the start is the first sample of the first call
        return np.full((w0.shape[0], 1), float(t0))

    def _scales(self) -> np.ndarray:
        _, w = sine_basis(np.zeros(1), self.n_basis)
        return np.exp(0.5 * log_se_spectrum(w, self.length))[0]        # (m,)

    def _apply(self, w, t, theta, state):
        if self.feature != TIME:  # nominal conditions: no column, no change
            return (np.array(w, dtype=np.float64), np.array(state, dtype=np.float64),
                    ~np.all(np.isfinite(w), axis=1))
        return self._apply_with(w, t, theta, state, None)

    def _apply_with(self, w, t, theta, state, covariates):
        t = np.asarray(t, float)
        width = w.shape[0]
        start = np.array(state, dtype=np.float64).reshape(width, 1)
        start[~np.isfinite(start)] = t[0]
        if self.feature == TIME:
            x = t[None, :] - start                                        # (W, N)
        elif covariates is None:
            return self._apply(w, t, theta, start)
        else:
            x = np.asarray(covariates[self.feature], float)[None, :]
        ref = np.asarray(theta["x_ref"], float).reshape(width, 1)
        half = np.asarray(theta["x_half"], float).reshape(width, 1)
        span = np.asarray(theta["y_span"], float).reshape(width, 1)
        s = self._scales()
        a = param_columns(theta, "a", width) * s                          # (W, m)
        b = param_columns(theta, "b", width) * s
        phi = self._basis(x, ref, half)
        if phi.ndim == 2:  # one basis for every walker
            g = GAIN_PRIOR * (a @ phi.T)
            h = OFFSET_PRIOR * span * (b @ phi.T)
        else:
            g = GAIN_PRIOR * np.einsum("wnm,wm->wn", phi, a)
            h = OFFSET_PRIOR * span * np.einsum("wnm,wm->wn", phi, b)
        with np.errstate(over="ignore", invalid="ignore"):
            out = w * (1.0 + g) + h
        failed = ~np.all(np.isfinite(out), axis=1)
        return np.ascontiguousarray(out), start, failed

    def _basis(self, x: np.ndarray, ref: np.ndarray, half: np.ndarray) -> np.ndarray:
        """The sine basis at the scaled feature ``(x - ref) / half``.

        ``x`` (W or 1, N), ``ref`` and ``half`` (W or 1, 1). (N, m) when every row has
        the same feature and scaling (the usual case: the scaling is fixed and every
        signal starts with the record; evaluating the sines per walker was half the
        cost of a sampler step), else (W, N, m).
        """
        if _same_rows(x) and _same_rows(ref) and _same_rows(half):
            return sine_basis((x[0] - ref[0, 0]) / half[0, 0], self.n_basis)[0]
        return sine_basis((x - ref) / half, self.n_basis)[0]

    def _linear_columns(self, w, t, theta, names, covariates):
        # d out / d a_j = 0.05 s_j phi_j(z) w and d out / d b_j = 0.05 span s_j phi_j(z):
        # P + 1 applications of the block to unit coefficient vectors made ~13 (W, N)
        # temporaries per column block, most of a sampler step on the unexplained
        # candidates of the diagnosis
        if set(names) != {"a", "b"} or len(names) != 2:
            return None  # one of the two held fixed: the generic path
        w = np.asarray(w, dtype=np.float64)
        width, n = w.shape
        m = self.n_basis
        if self.feature == TIME:
            x = np.asarray(t, float) - float(np.asarray(t, float)[0])
        elif covariates is None:  # nominal conditions: the identity, no columns
            return (np.zeros((width, n, 2 * m)), w.copy(), ~np.all(np.isfinite(w), axis=1))
        else:
            x = np.asarray(covariates[self.feature], float)
        ref = np.asarray(theta["x_ref"], float).reshape(-1, 1)
        half = np.asarray(theta["x_half"], float).reshape(-1, 1)
        span = np.broadcast_to(np.asarray(theta["y_span"], float).reshape(-1), (width,))
        phi = np.broadcast_to(self._basis(x[None, :], ref, half) * self._scales(),
                              (width, n, m))
        gain = GAIN_PRIOR * phi * w[:, :, None]
        offset = OFFSET_PRIOR * span[:, None, None] * phi
        cols = {"a": gain, "b": offset}
        out = np.concatenate([cols[nm] for nm in names], axis=2)
        failed = ~np.all(np.isfinite(w), axis=1)
        return out, w.copy(), failed


def _same_rows(x: np.ndarray) -> bool:
    """Whether every row of ``x`` (W, ...) equals the first (exactly)."""
    return x.shape[0] <= 1 or bool(np.all(x == x[:1]))
