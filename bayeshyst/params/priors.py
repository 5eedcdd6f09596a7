"""Univariate priors, applied elementwise to a parameter's values.

Each gives its log density, CDF, sampler, support and a typical width; the support
fixes the default transform to the real line (:mod:`bayeshyst.params.transforms`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

import numpy as np
from scipy import special

from bayeshyst.errors import ParameterError
from bayeshyst.params.transforms import LOG_SQRT_2PI, Transform, transform_for_support

__all__ = ["HalfNormal", "LogNormal", "Normal", "Prior", "TruncatedNormal", "Uniform"]


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
        return transform_for_support(*self.support)

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
        return -0.5 * zs**2 - math.log(self.sigma) - LOG_SQRT_2PI

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
        return np.where(x > 0, val - LOG_SQRT_2PI, -np.inf)

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
        val = -0.5 * (x / self.sigma) ** 2 - math.log(self.sigma) - LOG_SQRT_2PI + math.log(2)
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
        val = -0.5 * zs**2 - math.log(self.sigma) - LOG_SQRT_2PI - self._log_mass()
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
