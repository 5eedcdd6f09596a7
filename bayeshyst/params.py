"""Declared parameters: priors, transforms to the real line, and the parameter space.

Every quantity a sampler touches is a :class:`Param`: a name, a prior, a bijective
transform from its support to the real line (with the log-Jacobian of the inverse
map), a shape, a unit and a one-line description. A :class:`ParamSpace` is an ordered
collection of them; it maps the flat unconstrained vector ``z`` that emcee moves in to
the named physical values ``theta`` that models read, and evaluates the prior density
of ``z``::

    log p(z) = sum_i log p_i(x_i(z_i)) + log |dx_i/dz_i|

Fixed parameters stay in ``theta`` (so models always see every name) but leave ``z``.
Namespacing (``"static.w"``) lets composed models concatenate their spaces.

Priors and transforms are vectorised NumPy code: they are evaluated once per walker
per step and are never the bottleneck next to a simulation.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from scipy import special

from bayeshyst.errors import ParameterError

__all__ = [
    "HalfNormal",
    "Identity",
    "LogNormal",
    "LogTransform",
    "LogitTransform",
    "Normal",
    "Param",
    "ParamSpace",
    "Prior",
    "ProbitTransform",
    "Transform",
    "TruncatedNormal",
    "Uniform",
    "UpperLogTransform",
]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def _as_float_array(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{what} must be finite, got {value!r}")
    return arr


# --------------------------------------------------------------------------- transforms


class Transform(ABC):
    """A smooth bijection from a parameter's support to the real line.

    ``forward`` maps a constrained value ``x`` to ``z``; ``inverse`` maps back;
    ``log_jacobian(z)`` is ``log |dx/dz|`` evaluated at ``z`` (elementwise).
    ``saturation`` is the ``|z|`` beyond which ``x`` is its bound to double precision
    (infinite where no bound is reached at a finite ``z``).
    """

    saturation: ClassVar[float] = math.inf

    @abstractmethod
    def forward(self, x: np.ndarray) -> np.ndarray:
        """Map constrained ``x`` to unconstrained ``z`` (elementwise)."""

    @abstractmethod
    def inverse(self, z: np.ndarray) -> np.ndarray:
        """Map unconstrained ``z`` to constrained ``x`` (elementwise)."""

    @abstractmethod
    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """Elementwise ``log |dx/dz|`` at ``z``."""


@dataclass(frozen=True)
class Identity(Transform):
    """``x = z`` for parameters supported on the whole real line."""

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``z = x``, as a float array."""
        return np.asarray(x, dtype=float)

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """``x = z``, as a float array."""
        return np.asarray(z, dtype=float)

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """Zeros shaped like ``z``: the identity has ``dx/dz = 1``."""
        return np.zeros_like(np.asarray(z, dtype=float))


@dataclass(frozen=True)
class LogTransform(Transform):
    """``x = lower + exp(z)`` for a support bounded below by ``lower``.

    Parameters
    ----------
    lower : float
        Lower bound of the support (default 0).
    """

    lower: float = 0.0

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``z = log(x - lower)``; ``-inf`` at ``x = lower`` (no divide warning)."""
        with np.errstate(divide="ignore"):
            return np.log(np.asarray(x, dtype=float) - self.lower)

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """``x = lower + exp(z)``; overflow to ``inf`` is silent."""
        with np.errstate(over="ignore"):
            return self.lower + np.exp(np.asarray(z, dtype=float))

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log |dx/dz| = z``, as a float array."""
        return np.asarray(z, dtype=float)


@dataclass(frozen=True)
class UpperLogTransform(Transform):
    """``x = upper - exp(z)`` for a support bounded above by ``upper``."""

    upper: float = 0.0

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``z = log(upper - x)``; ``-inf`` at ``x = upper`` (no divide warning)."""
        with np.errstate(divide="ignore"):
            return np.log(self.upper - np.asarray(x, dtype=float))

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """``x = upper - exp(z)``; overflow to ``-inf`` is silent."""
        with np.errstate(over="ignore"):
            return self.upper - np.exp(np.asarray(z, dtype=float))

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log |dx/dz| = z``, as a float array."""
        return np.asarray(z, dtype=float)


def _check_bounds(lower: float, upper: float, kind: str) -> None:
    """Finite ``lower < upper`` for a bounded transform, else a ParameterError naming it."""
    if not (math.isfinite(lower) and math.isfinite(upper)):
        raise ParameterError(f"{kind} bounds must be finite, got ({lower}, {upper})")
    if not lower < upper:
        raise ParameterError(f"{kind} bounds need lower < upper, got ({lower}, {upper})")


@dataclass(frozen=True)
class LogitTransform(Transform):
    """``x = lower + (upper - lower) * sigmoid(z)`` for a bounded support.

    Parameters
    ----------
    lower, upper : float
        Bounds of the support, ``lower < upper``.
    """

    lower: float
    upper: float
    #: ``expit(-z) < eps / 2`` beyond it (z ~ 36.7)
    saturation: ClassVar[float] = math.log(2.0 / np.finfo(float).eps)

    def __post_init__(self) -> None:
        _check_bounds(self.lower, self.upper, "logit")

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``z = logit((x - lower) / (upper - lower))``; ``-inf`` / ``inf`` at the bounds."""
        p = (np.asarray(x, dtype=float) - self.lower) / (self.upper - self.lower)
        with np.errstate(divide="ignore"):
            return special.logit(p)

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """``x = lower + (upper - lower) * expit(z)``."""
        return self.lower + (self.upper - self.lower) * special.expit(np.asarray(z, dtype=float))

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log(upper - lower) + log expit(z) + log expit(-z)``.

        Written with ``log_expit`` so that it stays finite for ``|z|`` in the hundreds.
        """
        z = np.asarray(z, dtype=float)
        # log(sigmoid(z) * sigmoid(-z)), written with log_expit so that it stays finite
        # for |z| in the hundreds instead of underflowing to log(0).
        return math.log(self.upper - self.lower) + special.log_expit(z) + special.log_expit(-z)


@dataclass(frozen=True)
class ProbitTransform(Transform):
    """``x = lower + (upper - lower) * Phi(z)`` for a bounded support (``Phi``: normal CDF).

    The logit's alternative for a parameter whose posterior often lies against a bound
    (a Bouc–Wen exponent at ``n = 1``, a delay at 0). Where the likelihood is flat up
    to the bound, the posterior in ``z`` has the tail of ``|dx/dz|``: ``exp(z)`` for the
    logit, a standard normal's ``exp(-z^2 / 2)`` here. An exponential tail sends walkers
    on long excursions that a Gaussian or t proposal fitted to the bulk does not reach
    (the MR damper's base fit at 0.5 A: ``z_n`` down to -10, an autocorrelation time of
    ~280 steps, not converged in 7 000); a Gaussian one is covered.

    Parameters
    ----------
    lower, upper : float
        Bounds of the support, ``lower < upper``.
    """

    lower: float
    upper: float
    #: ``Phi(-z) < eps / 2`` beyond it (z ~ 8.2)
    saturation: ClassVar[float] = float(-special.ndtri(0.5 * np.finfo(float).eps))

    def __post_init__(self) -> None:
        _check_bounds(self.lower, self.upper, "probit")

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``z = Phi^-1((x - lower) / (upper - lower))``; ``-inf`` / ``inf`` at the bounds.

        Computed from the nearer bound, so that a value close to ``upper`` keeps its
        digits (``1 - p`` is not formed).
        """
        x = np.asarray(x, dtype=float)
        w = self.upper - self.lower
        p_lo, p_hi = (x - self.lower) / w, (self.upper - x) / w
        return np.where(p_lo <= 0.5, special.ndtri(p_lo), -special.ndtri(p_hi))

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """``x = lower + (upper - lower) * Phi(z)``, from the nearer bound."""
        z = np.asarray(z, dtype=float)
        w = self.upper - self.lower
        return np.where(z <= 0.0, self.lower + w * special.ndtr(z),
                        self.upper - w * special.ndtr(-z))

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log(upper - lower) - z^2 / 2 - log(2 pi) / 2`` (finite for every finite z)."""
        z = np.asarray(z, dtype=float)
        return math.log(self.upper - self.lower) - 0.5 * z * z - _LOG_SQRT_2PI


def _transform_for_support(lower: float, upper: float) -> Transform:
    if math.isinf(lower) and math.isinf(upper):
        return Identity()
    if math.isinf(upper):
        return LogTransform(lower)
    if math.isinf(lower):
        return UpperLogTransform(upper)
    return LogitTransform(lower, upper)


# ------------------------------------------------------------------------------- priors


class Prior(ABC):
    """A univariate prior applied elementwise (its parameters broadcast to the shape).

    Subclasses give ``logpdf``, ``cdf``, ``sample`` and the ``support`` bounds; the
    default transform follows from the support.
    """

    @property
    @abstractmethod
    def support(self) -> tuple[float, float]:
        """``(lower, upper)`` bounds of the support (may be infinite)."""

    @abstractmethod
    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise log density; ``-inf`` outside the support."""

    @abstractmethod
    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise cumulative distribution function."""

    @abstractmethod
    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Draw an array of the given shape."""

    @abstractmethod
    def scale(self) -> float:
        """A typical width of the prior, used to spread initial points."""

    def default_transform(self) -> Transform:
        """The transform from the support to the real line."""
        return _transform_for_support(*self.support)

    def __str__(self) -> str:
        # short and readable for tables (the dataclass repr keeps full precision)
        args = ", ".join(f"{f.name}={getattr(self, f.name):.4g}" for f in fields(self))
        return f"{type(self).__name__}({args})"

    def _mask(self, x: np.ndarray, values: np.ndarray) -> np.ndarray:
        lo, hi = self.support
        inside = (x >= lo) & (x <= hi)
        return np.where(inside, values, -np.inf)


def _check_positive(value: float, what: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{what} must be a finite positive number, got {value!r}")


@dataclass(frozen=True)
class Uniform(Prior):
    """Uniform on ``[lower, upper]``."""

    lower: float
    upper: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lower) and math.isfinite(self.upper)):
            raise ParameterError(f"Uniform bounds must be finite, got ({self.lower}, {self.upper})")
        if not self.lower < self.upper:
            raise ParameterError(
                f"Uniform needs lower < upper, got lower={self.lower}, upper={self.upper}"
            )

    @property
    def support(self) -> tuple[float, float]:
        """``(lower, upper)``."""
        return (float(self.lower), float(self.upper))

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise log density ``-log(upper - lower)``; ``-inf`` outside the bounds."""
        x = np.asarray(x, dtype=float)
        return self._mask(x, np.full_like(x, -math.log(self.upper - self.lower)))

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise CDF ``(x - lower) / (upper - lower)``, clipped to ``[0, 1]``."""
        return np.clip((np.asarray(x, dtype=float) - self.lower) / (self.upper - self.lower), 0, 1)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Uniform draws on ``[lower, upper)`` of the given shape."""
        return rng.uniform(self.lower, self.upper, size=shape)

    def scale(self) -> float:
        """Standard deviation of the uniform, ``(upper - lower) / sqrt(12)``."""
        return (self.upper - self.lower) / math.sqrt(12.0)


@dataclass(frozen=True)
class Normal(Prior):
    """Normal with mean ``mu`` and standard deviation ``sigma``."""

    mu: float
    sigma: float

    def __post_init__(self) -> None:
        _check_positive(self.sigma, "Normal sigma")
        if not math.isfinite(self.mu):
            raise ParameterError(f"Normal mu must be finite, got {self.mu!r}")

    @property
    def support(self) -> tuple[float, float]:
        """``(-inf, inf)``."""
        return (-math.inf, math.inf)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise normal log density."""
        zs = (np.asarray(x, dtype=float) - self.mu) / self.sigma
        return -0.5 * zs**2 - math.log(self.sigma) - _LOG_SQRT_2PI

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise CDF ``ndtr((x - mu) / sigma)``."""
        return special.ndtr((np.asarray(x, dtype=float) - self.mu) / self.sigma)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Normal draws of the given shape."""
        return rng.normal(self.mu, self.sigma, size=shape)

    def scale(self) -> float:
        """``sigma``."""
        return float(self.sigma)


@dataclass(frozen=True)
class LogNormal(Prior):
    """Log-normal: ``log(x) ~ Normal(mu, sigma)``; the median is ``exp(mu)``."""

    mu: float
    sigma: float

    def __post_init__(self) -> None:
        _check_positive(self.sigma, "LogNormal sigma")
        if not math.isfinite(self.mu):
            raise ParameterError(f"LogNormal mu must be finite, got {self.mu!r}")

    @classmethod
    def from_median(cls, median: float, sigma: float) -> LogNormal:
        """Build from the median (``exp(mu)``) and the log-scale spread ``sigma``."""
        _check_positive(median, "LogNormal median")
        return cls(math.log(median), sigma)

    @property
    def support(self) -> tuple[float, float]:
        """``(0, inf)``."""
        return (0.0, math.inf)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise log-normal log density; ``-inf`` for ``x <= 0``."""
        x = np.asarray(x, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            lx = np.log(np.where(x > 0, x, 1.0))
            val = -0.5 * ((lx - self.mu) / self.sigma) ** 2 - lx - math.log(self.sigma)
        return np.where(x > 0, val - _LOG_SQRT_2PI, -np.inf)

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise CDF ``ndtr((log(x) - mu) / sigma)``; 0 for ``x <= 0``."""
        x = np.asarray(x, dtype=float)
        with np.errstate(divide="ignore"):
            return np.where(x > 0, special.ndtr((np.log(np.maximum(x, 1e-300)) - self.mu)
                                                / self.sigma), 0.0)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Log-normal draws of the given shape."""
        return rng.lognormal(self.mu, self.sigma, size=shape)

    def __str__(self) -> str:
        return f"LogNormal(median={math.exp(self.mu):.4g}, sigma={self.sigma:.4g})"

    def scale(self) -> float:
        """``exp(mu) * sigma``: the median times the log-scale spread."""
        return float(math.exp(self.mu) * self.sigma)


@dataclass(frozen=True)
class HalfNormal(Prior):
    """Half-normal on ``[0, inf)`` with scale ``sigma``."""

    sigma: float

    def __post_init__(self) -> None:
        _check_positive(self.sigma, "HalfNormal sigma")

    @property
    def support(self) -> tuple[float, float]:
        """``(0, inf)``."""
        return (0.0, math.inf)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise half-normal log density; ``-inf`` for ``x < 0``."""
        x = np.asarray(x, dtype=float)
        val = -0.5 * (x / self.sigma) ** 2 - math.log(self.sigma) - _LOG_SQRT_2PI + math.log(2)
        return np.where(x >= 0, val, -np.inf)

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise CDF ``erf(x / (sigma * sqrt(2)))``; 0 for ``x <= 0``."""
        x = np.asarray(x, dtype=float)
        return np.where(x > 0, special.erf(x / (self.sigma * math.sqrt(2.0))), 0.0)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Half-normal draws ``|Normal(0, sigma)|`` of the given shape."""
        return np.abs(rng.normal(0.0, self.sigma, size=shape))

    def scale(self) -> float:
        """``sigma``."""
        return float(self.sigma)


@dataclass(frozen=True)
class TruncatedNormal(Prior):
    """Normal(``mu``, ``sigma``) truncated to ``[lower, upper]`` (either may be infinite)."""

    mu: float
    sigma: float
    lower: float = -math.inf
    upper: float = math.inf

    def __post_init__(self) -> None:
        _check_positive(self.sigma, "TruncatedNormal sigma")
        if not self.lower < self.upper:
            raise ParameterError(
                f"TruncatedNormal needs lower < upper, got ({self.lower}, {self.upper})"
            )
        if self._log_mass() == -math.inf:
            raise ParameterError(
                f"TruncatedNormal({self.mu}, {self.sigma}) has no mass on "
                f"[{self.lower}, {self.upper}]"
            )

    def _std_bounds(self) -> tuple[float, float]:
        return ((self.lower - self.mu) / self.sigma, (self.upper - self.mu) / self.sigma)

    def _log_mass(self) -> float:
        a, b = self._std_bounds()
        # log(Phi(b) - Phi(a)) computed on the side that keeps precision in the tails
        with np.errstate(divide="ignore"):
            if a > 0:
                return float(np.log(special.ndtr(-a) - special.ndtr(-b)))
            return float(np.log(special.ndtr(b) - special.ndtr(a)))

    @property
    def support(self) -> tuple[float, float]:
        """``(lower, upper)`` (either may be infinite)."""
        return (float(self.lower), float(self.upper))

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise log density of the truncated normal; ``-inf`` outside the bounds.

        The normal log density minus the log of the normal's mass on ``[lower, upper]``.
        """
        x = np.asarray(x, dtype=float)
        zs = (x - self.mu) / self.sigma
        val = -0.5 * zs**2 - math.log(self.sigma) - _LOG_SQRT_2PI - self._log_mass()
        return self._mask(x, val)

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Elementwise CDF of the truncated normal: 0 below ``lower``, 1 above ``upper``."""
        a, b = self._std_bounds()
        zs = np.clip((np.asarray(x, dtype=float) - self.mu) / self.sigma, a, b)
        return (special.ndtr(zs) - special.ndtr(a)) / math.exp(self._log_mass())

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Inverse-CDF draws of the given shape, inside ``[lower, upper]``."""
        a, b = self._std_bounds()
        lo, hi = special.ndtr(a), special.ndtr(b)
        p = rng.uniform(lo, hi, size=shape)
        # inverse-CDF sampling; the clip only absorbs ndtri rounding at the bounds
        return np.clip(self.mu + self.sigma * special.ndtri(p), self.lower, self.upper)

    def scale(self) -> float:
        """``sigma``, capped at ``(upper - lower) / sqrt(12)`` when both bounds are finite."""
        width = self.upper - self.lower
        return float(min(self.sigma, width / math.sqrt(12.0)) if math.isfinite(width)
                     else self.sigma)


# ------------------------------------------------------------------------------ Param


@dataclass(frozen=True)
class Param:
    """One declared parameter (scalar or array-valued).

    Parameters
    ----------
    name : str
        Name as models read it from ``theta`` (namespaced as ``"block.name"`` when
        composed).
    prior : Prior
        Prior applied elementwise.
    shape : tuple of int
        ``()`` for a scalar, ``(n,)`` for a vector of ``n`` elements.
    unit : str
        Physical unit of the value, e.g. ``"um/V"``.
    description : str
        One line saying what the parameter means.
    transform : Transform or None
        Map from the support to the real line; ``None`` takes the prior's default.
    """

    name: str
    prior: Prior
    shape: tuple[int, ...] = ()
    unit: str = ""
    description: str = ""
    transform: Transform | None = None

    def __post_init__(self) -> None:
        if not self.name or any(c.isspace() for c in self.name):
            raise ParameterError(f"parameter name must be non-empty without spaces: {self.name!r}")
        shape = tuple(int(s) for s in self.shape)
        if any(s < 1 for s in shape):
            raise ParameterError(f"parameter {self.name!r}: shape entries must be >= 1: {shape}")
        object.__setattr__(self, "shape", shape)
        if self.transform is None:
            object.__setattr__(self, "transform", self.prior.default_transform())

    @property
    def size(self) -> int:
        """Number of scalar elements."""
        return int(np.prod(self.shape, dtype=int)) if self.shape else 1

    def labels(self) -> list[str]:
        """Flat labels of the elements: ``name`` or ``name[0]``, ``name[1]``, ..."""
        if not self.shape:
            return [self.name]
        return [f"{self.name}[{','.join(map(str, idx))}]" for idx in np.ndindex(*self.shape)]

    def check_value(self, value: Any) -> np.ndarray:
        """Validate a physical value (shape and support); return it as a float array."""
        arr = np.asarray(value, dtype=float)
        if arr.shape != self.shape:
            raise ParameterError(
                f"parameter {self.name!r}: expected shape {self.shape}, got {arr.shape}"
            )
        lo, hi = self.prior.support
        bad = ~np.isfinite(arr) | (arr < lo) | (arr > hi)
        if np.any(bad):
            raise ParameterError(
                f"parameter {self.name!r}: value {arr[bad].ravel()[0]!r} outside the prior "
                f"support [{lo}, {hi}]"
            )
        return arr


# -------------------------------------------------------------------------- ParamSpace


@dataclass(frozen=True, eq=False)
class ParamSpace:
    """An ordered set of free parameters plus fixed values.

    Parameters
    ----------
    params : tuple of Param
        The free parameters in the order of the flat vector ``z``.
    fixed : mapping of str to array
        Parameters held at a value: they appear in ``theta`` but not in ``z``.
        Their declarations are kept in ``fixed_params`` so that ``free`` can release
        them again.

    Notes
    -----
    ``unpack`` accepts a single ``z`` of shape ``(ndim,)`` giving scalars / arrays of
    the declared shape, or a batch of shape ``(W, ndim)`` giving arrays with a leading
    ``W`` axis (fixed values are broadcast along it).
    """

    params: tuple[Param, ...] = ()
    fixed: Mapping[str, np.ndarray] = field(default_factory=lambda: MappingProxyType({}))
    fixed_params: tuple[Param, ...] = ()

    def __post_init__(self) -> None:
        params = tuple(self.params)
        object.__setattr__(self, "params", params)
        names = [p.name for p in params] + [p.name for p in self.fixed_params]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ParameterError(f"duplicate parameter names: {dupes}")
        frozen: dict[str, np.ndarray] = {}
        for p in self.fixed_params:
            if p.name not in self.fixed:
                raise ParameterError(f"fixed parameter {p.name!r} has no value")
            arr = p.check_value(self.fixed[p.name]).copy()
            arr.flags.writeable = False
            frozen[p.name] = arr
        extra = set(self.fixed) - set(frozen)
        if extra:
            raise ParameterError(f"fixed values given for undeclared parameters: {sorted(extra)}")
        object.__setattr__(self, "fixed", MappingProxyType(frozen))
        offsets, start = {}, 0
        for p in params:
            offsets[p.name] = (start, start + p.size)
            start += p.size
        object.__setattr__(self, "_offsets", MappingProxyType(offsets))
        object.__setattr__(self, "_ndim", start)

    def __reduce__(self) -> tuple[Any, ...]:
        # MappingProxyType does not pickle; rebuild through __init__ (which re-validates)
        return (ParamSpace, (self.params, dict(self.fixed), self.fixed_params))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ParamSpace):
            return NotImplemented
        return (
            self.params == other.params
            and self.fixed_params == other.fixed_params
            and all(np.array_equal(self.fixed[k], other.fixed[k]) for k in self.fixed)
        )

    __hash__ = None  # type: ignore[assignment]

    # ----------------------------------------------------------------- introspection
    @property
    def names(self) -> tuple[str, ...]:
        """Names of the free parameters, in ``z`` order."""
        return tuple(p.name for p in self.params)

    @property
    def all_names(self) -> tuple[str, ...]:
        """Names of free then fixed parameters (every key of ``theta``)."""
        return self.names + tuple(p.name for p in self.fixed_params)

    @property
    def ndim(self) -> int:
        """Length of the flat unconstrained vector ``z``."""
        return self._ndim  # type: ignore[attr-defined]

    @property
    def labels(self) -> list[str]:
        """One label per element of ``z`` (``w[0]``, ``w[1]``, ...)."""
        return [lab for p in self.params for lab in p.labels()]

    @property
    def declared_transforms(self) -> str:
        """The free parameters whose coordinate is not their prior's default, as text.

        A prior implies its default transform, so the table (``str``) names what is
        sampled up to these; a fit's identity and a checkpoint's fingerprint add them
        (a chain sampled in another coordinate is not the same run). Empty when every
        coordinate is the default.
        """
        return "; ".join(f"{p.name}: {p.transform!r}" for p in self.params
                         if p.transform != p.prior.default_transform())

    def __len__(self) -> int:
        return len(self.params)

    def __iter__(self) -> Iterator[Param]:
        return iter(self.params)

    def __contains__(self, name: object) -> bool:
        return name in self.all_names

    def __getitem__(self, name: str) -> Param:
        for p in self.params + self.fixed_params:
            if p.name == name:
                return p
        raise KeyError(f"no parameter named {name!r}; have {list(self.all_names)}")

    def slice_of(self, name: str) -> slice:
        """The slice of ``z`` that holds free parameter ``name``."""
        if name not in self._offsets:  # type: ignore[attr-defined]
            raise KeyError(f"{name!r} is not a free parameter; free: {list(self.names)}")
        a, b = self._offsets[name]  # type: ignore[attr-defined]
        return slice(a, b)

    def indices(self, names: Iterable[str]) -> np.ndarray:
        """The ``z`` indices (int array, in the given order) of free parameters ``names``."""
        parts = [np.arange(self.ndim)[self.slice_of(n)] for n in names]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=int)

    # ----------------------------------------------------------------- z <-> theta
    def _split(self, z: np.ndarray) -> tuple[np.ndarray, bool]:
        z = np.asarray(z, dtype=float)
        batched = z.ndim == 2
        if z.ndim not in (1, 2) or z.shape[-1] != self.ndim:
            raise ParameterError(
                f"z must have shape ({self.ndim},) or (W, {self.ndim}), got {z.shape}"
            )
        return (z if batched else z[None, :]), batched

    def unpack(self, z: np.ndarray) -> dict[str, Any]:
        """Named physical values from unconstrained ``z``.

        Parameters
        ----------
        z : ndarray, shape (ndim,) or (W, ndim)

        Returns
        -------
        dict
            ``name -> value``: a float (scalar parameter) or an array of the declared
            shape; with a batch, arrays of shape ``(W, *shape)``.
        """
        zz, batched = self._split(z)
        w = zz.shape[0]
        theta: dict[str, Any] = {}
        for p in self.params:
            a, b = self._offsets[p.name]  # type: ignore[attr-defined]
            x = p.transform.inverse(zz[:, a:b]).reshape((w, *p.shape))
            theta[p.name] = x if batched else (float(x[0]) if not p.shape else x[0])
        for p in self.fixed_params:
            v = self.fixed[p.name]
            if batched:
                theta[p.name] = np.broadcast_to(v, (w, *p.shape))
            else:
                theta[p.name] = float(v) if not p.shape else v
        return theta

    def pack(self, theta: Mapping[str, Any]) -> np.ndarray:
        """Unconstrained ``z`` (shape ``(ndim,)``) from named physical values.

        Fixed parameters may be omitted; if given they must equal the fixed value.
        """
        missing = [n for n in self.names if n not in theta]
        if missing:
            raise ParameterError(f"theta is missing parameters {missing}")
        unknown = [n for n in theta if n not in self.all_names]
        if unknown:
            raise ParameterError(f"theta has unknown parameters {unknown}; known "
                                 f"{list(self.all_names)}")
        z = np.empty(self.ndim)
        for p in self.params:
            x = p.check_value(theta[p.name])
            z[self.slice_of(p.name)] = p.transform.forward(x).ravel()
        for p in self.fixed_params:
            if p.name in theta and not np.array_equal(np.asarray(theta[p.name], float),
                                                     self.fixed[p.name]):
                raise ParameterError(
                    f"parameter {p.name!r} is fixed at {self.fixed[p.name]!r}, theta gives "
                    f"{theta[p.name]!r}"
                )
        return z

    def log_prior(self, z: np.ndarray) -> float | np.ndarray:
        """Log prior density of ``z``, Jacobian included.

        Returns a float for ``z`` of shape ``(ndim,)`` and an array ``(W,)`` for a
        batch. The value is finite or ``-inf``, never NaN.
        """
        zz, batched = self._split(z)
        total = np.zeros(zz.shape[0])
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for p in self.params:
                a, b = self._offsets[p.name]  # type: ignore[attr-defined]
                zp = zz[:, a:b]
                x = p.transform.inverse(zp)
                total += np.sum(p.prior.logpdf(x) + p.transform.log_jacobian(zp), axis=1)
        total = np.where(np.isfinite(total), total, -np.inf)
        return total if batched else float(total[0])

    def sample_prior(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Draw ``size`` points of ``z`` from the prior; shape ``(size, ndim)``."""
        if int(size) < 1:
            raise ParameterError(f"size must be >= 1, got {size}")
        out = np.empty((int(size), self.ndim))
        for p in self.params:
            x = p.prior.sample(rng, (int(size), p.size))
            out[:, self.slice_of(p.name)] = p.transform.forward(x)
        return out

    def prior_scale_z(self, z: np.ndarray) -> np.ndarray:
        """Per-element width of the prior in ``z`` near ``z`` (for initial spreads)."""
        z = np.asarray(z, dtype=float)
        out = np.empty(self.ndim)
        for p in self.params:
            sl = self.slice_of(p.name)
            dxdz = np.exp(p.transform.log_jacobian(z[sl]))
            out[sl] = p.prior.scale() / np.maximum(dxdz, 1e-300)
        return out

    # ----------------------------------------------------------------- editing
    def fix(self, name: str, value: Any) -> ParamSpace:
        """A new space with free parameter ``name`` held at ``value``."""
        p = self[name]
        if name not in self.names:
            raise ParameterError(f"parameter {name!r} is already fixed")
        arr = p.check_value(value)
        return ParamSpace(
            tuple(q for q in self.params if q.name != name),
            {**self.fixed, name: arr},
            (*self.fixed_params, p),
        )

    def free(self, name: str) -> ParamSpace:
        """A new space in which fixed parameter ``name`` is sampled again (appended)."""
        if name not in self.fixed:
            raise ParameterError(f"parameter {name!r} is not fixed; fixed: {list(self.fixed)}")
        p = self[name]
        return ParamSpace(
            (*self.params, p),
            {k: v for k, v in self.fixed.items() if k != name},
            tuple(q for q in self.fixed_params if q.name != name),
        )

    def replace(self, name: str, **changes: Any) -> ParamSpace:
        """A new space with parameter ``name`` re-declared (e.g. ``prior=Normal(0, 1)``).

        Accepted fields: ``prior``, ``transform``, ``unit``, ``description``. A new
        prior without an explicit transform gets the prior's default transform.
        """
        allowed = {"prior", "transform", "unit", "description"}
        bad = set(changes) - allowed
        if bad:
            raise ParameterError(f"cannot replace fields {sorted(bad)}; allowed {sorted(allowed)}")
        if "prior" in changes and "transform" not in changes:
            changes["transform"] = None
        old = self[name]
        new = replace(old, **changes)
        if name in self.fixed:
            new.check_value(self.fixed[name])
            return ParamSpace(self.params, self.fixed,
                              tuple(new if q.name == name else q for q in self.fixed_params))
        return ParamSpace(tuple(new if q.name == name else q for q in self.params),
                          self.fixed, self.fixed_params)

    def prefixed(self, namespace: str) -> ParamSpace:
        """The same space with every name written ``namespace.name``."""
        if not namespace or "." in namespace:
            raise ParameterError(f"namespace must be a non-empty name without '.': {namespace!r}")

        def ren(p: Param) -> Param:
            return replace(p, name=f"{namespace}.{p.name}")

        return ParamSpace(
            tuple(ren(p) for p in self.params),
            {f"{namespace}.{k}": v for k, v in self.fixed.items()},
            tuple(ren(p) for p in self.fixed_params),
        )

    @staticmethod
    def concat(spaces: Mapping[str, ParamSpace] | Iterable[ParamSpace]) -> ParamSpace:
        """Join spaces; a mapping ``{namespace: space}`` prefixes each one's names."""
        if isinstance(spaces, Mapping):
            spaces = [s.prefixed(ns) for ns, s in spaces.items()]
        params: list[Param] = []
        fixed: dict[str, np.ndarray] = {}
        fixed_params: list[Param] = []
        for s in spaces:
            params.extend(s.params)
            fixed.update(s.fixed)
            fixed_params.extend(s.fixed_params)
        return ParamSpace(tuple(params), fixed, tuple(fixed_params))

    @staticmethod
    def sub_theta(theta: Mapping[str, Any], namespace: str) -> dict[str, Any]:
        """The entries of ``theta`` under ``namespace.``, with the prefix removed."""
        pre = namespace + "."
        return {k[len(pre):]: v for k, v in theta.items() if k.startswith(pre)}

    def __str__(self) -> str:
        rows = [("name", "shape", "unit", "prior", "description")]
        for p in self.params:
            rows.append((p.name, str(p.shape or "()"), p.unit, str(p.prior), p.description))
        for p in self.fixed_params:
            v = self.fixed[p.name]
            val = f"fixed = {np.array2string(v, precision=4, threshold=6)}"
            rows.append((p.name, str(p.shape or "()"), p.unit, val, p.description))
        widths = [min(max(len(r[i]) for r in rows), 48) for i in range(4)]
        lines = [
            "  ".join(c[:w].ljust(w) for c, w in zip(r[:4], widths, strict=True)) + "  " + r[4]
            for r in rows
        ]
        head = f"ParamSpace: {len(self.params)} free ({self.ndim} in z), {len(self.fixed)} fixed"
        return "\n".join([head, *lines])
