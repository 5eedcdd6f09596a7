"""Observation models: the density of measured ``y`` given a simulated output.

Each likelihood declares its noise parameters (with priors scaled from the data) and
evaluates, for ``W`` parameter vectors at once, the log-density of the scored samples of
one record as **per-sample terms** ``(W, N)``: the posterior sums them over the record
for the log-likelihood and per cycle for leave-one-cycle-out. For the AR(1) model the
terms are the sequential conditionals ``log p(e_k | e_{k-1})``, so any contiguous block
of them is the exact conditional log-density of that block given the past.

Residuals come from **free-run** simulation of the whole record (not one-step
prediction): that is how a hysteresis model is used for feedforward, and it is what the
posterior must judge.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from scipy import special

from bayeshyst.errors import ModelError
from bayeshyst.params import LogNormal, Param, ParamSpace, Uniform

__all__ = ["AR1", "Gaussian", "Likelihood", "StudentT", "get_likelihood", "likelihood_names"]

_LOG_2PI = math.log(2.0 * math.pi)


def _noise_scale(data: Any) -> tuple[float, str]:
    """A reference noise level (output unit): 1 % of the output span, and the unit.

    Piezo position sensors resolve far better than 1 % of the stroke, and model error
    is typically a few per cent: a log-normal prior centred here with a wide spread
    covers both without favouring either.
    """
    if data is None:
        return 0.01, "um"
    records = list(data) if hasattr(data, "records") else [data]
    ys = np.concatenate([np.asarray(r.y, dtype=float) for r in records])
    span = float(ys.max() - ys.min())
    unit = str(dict(getattr(records[0], "units", None) or {}).get("y", "unknown"))
    return (0.01 * span if span > 0 else 0.01), unit


class Likelihood(ABC):
    """Base class: declared noise parameters and vectorised per-sample log-densities."""

    name: ClassVar[str] = ""

    @abstractmethod
    def param_space(self, data: Any = None) -> ParamSpace:
        """Noise parameters (names without namespace; the posterior adds ``noise.``)."""

    @abstractmethod
    def pointwise(self, resid: np.ndarray, theta: Mapping[str, np.ndarray]) -> np.ndarray:
        """Per-sample log-density terms.

        Parameters
        ----------
        resid : ndarray, shape (W, N)
            Measured minus simulated output over the scored samples of one record.
        theta : mapping
            Noise parameters, each of shape ``(W,)``.

        Returns
        -------
        ndarray, shape (W, N)
            Terms whose sum over the record is its log-likelihood.
        """

    @abstractmethod
    def sample(self, theta: Mapping[str, np.ndarray], n: int,
               rng: np.random.Generator) -> np.ndarray:
        """Noise draws for the noise parameters ``theta``.

        They are what the posterior predictive adds to a simulated output.

        Parameters
        ----------
        theta : mapping
            Noise parameters, each of shape ``(W,)``.
        n : int
            Number of samples per draw.
        rng : numpy.random.Generator
            Source of randomness.

        Returns
        -------
        ndarray, shape (W, n)
            Noise in the output unit.
        """

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True)
class Gaussian(Likelihood):
    """Independent Gaussian errors, ``e_k ~ N(0, sigma^2)``.

    Parameter ``sigma`` (output unit): log-normal prior with median 1 % of the output
    span and a log-scale spread of 1.5 (a factor ~20 at 2 sd either way).
    """

    name: ClassVar[str] = "gaussian"

    def param_space(self, data: Any = None) -> ParamSpace:
        """Noise parameter ``sigma`` (output unit), log-normal prior around 1 % of the span.

        Parameters
        ----------
        data : Record, Dataset or None
            Data whose output span and ``y`` unit set the prior (``None``: median 0.01 um).

        Returns
        -------
        ParamSpace
            The single free parameter ``sigma``.
        """
        scale, unit = _noise_scale(data)
        return ParamSpace((Param("sigma", LogNormal.from_median(scale, 1.5), unit=unit,
                                 description="noise standard deviation"),))

    def pointwise(self, resid: np.ndarray, theta: Mapping[str, np.ndarray]) -> np.ndarray:
        """Per-sample Gaussian log-densities ``log N(e_k; 0, sigma^2)``, shape ``(W, N)``.

        See :meth:`Likelihood.pointwise` for the arguments.
        """
        sigma = np.asarray(theta["sigma"], dtype=float)[:, None]
        return -0.5 * (resid / sigma) ** 2 - np.log(sigma) - 0.5 * _LOG_2PI

    def sample(self, theta, n, rng):
        """Independent ``N(0, sigma^2)`` noise draws, shape ``(W, n)``.

        See :meth:`Likelihood.sample` for the arguments.
        """
        sigma = np.asarray(theta["sigma"], dtype=float)[:, None]
        return sigma * rng.standard_normal((sigma.shape[0], int(n)))


@dataclass(frozen=True)
class StudentT(Likelihood):
    """Independent Student-t errors with scale ``sigma`` and ``nu`` degrees of freedom.

    Robust to outliers (sensor glitches, dropped samples): a residual many ``sigma``
    out costs ``~(nu + 1) log|e|`` instead of ``e^2``. ``nu`` has a log-normal prior
    with median 5 (heavy tails are allowed, ``nu -> inf`` recovers the Gaussian).
    """

    name: ClassVar[str] = "student_t"

    def param_space(self, data: Any = None) -> ParamSpace:
        """Noise parameters ``sigma`` (output unit) and ``nu`` (degrees of freedom).

        Parameters
        ----------
        data : Record, Dataset or None
            Data whose output span and ``y`` unit set the ``sigma`` prior (``None``: median
            0.01 um).

        Returns
        -------
        ParamSpace
            Free parameters ``sigma`` (log-normal, median 1 % of the span, spread 1.5) and
            ``nu`` (log-normal, median 5, spread 1).
        """
        scale, unit = _noise_scale(data)
        return ParamSpace((
            Param("sigma", LogNormal.from_median(scale, 1.5), unit=unit,
                  description="noise scale"),
            Param("nu", LogNormal.from_median(5.0, 1.0), unit="1",
                  description="degrees of freedom (tail heaviness)"),
        ))

    def pointwise(self, resid: np.ndarray, theta: Mapping[str, np.ndarray]) -> np.ndarray:
        """Per-sample Student-t log-densities of scale ``sigma`` and ``nu`` dof, shape ``(W, N)``.

        See :meth:`Likelihood.pointwise` for the arguments.
        """
        sigma = np.asarray(theta["sigma"], dtype=float)[:, None]
        nu = np.asarray(theta["nu"], dtype=float)[:, None]
        const = (special.gammaln(0.5 * (nu + 1.0)) - special.gammaln(0.5 * nu)
                 - 0.5 * np.log(nu * math.pi) - np.log(sigma))
        return const - 0.5 * (nu + 1.0) * np.log1p((resid / sigma) ** 2 / nu)

    def sample(self, theta, n, rng):
        """Independent Student-t noise draws (scale ``sigma``, ``nu`` dof), shape ``(W, n)``.

        See :meth:`Likelihood.sample` for the arguments.
        """
        sigma = np.asarray(theta["sigma"], dtype=float)[:, None]
        nu = np.asarray(theta["nu"], dtype=float)[:, None]
        return sigma * rng.standard_t(nu, size=(sigma.shape[0], int(n)))


@dataclass(frozen=True)
class AR1(Likelihood):
    """Stationary AR(1) Gaussian errors, ``e_k = phi e_{k-1} + eta_k``.

    ``sigma`` is the *marginal* standard deviation (so it compares with the Gaussian's),
    the innovations have variance ``sigma^2 (1 - phi^2)``. The first scored sample of a
    record is marginal ``N(0, sigma^2)``; later ones are conditionals. Dense loop
    residuals are strongly correlated: treating them as independent makes posteriors
    overconfident by a factor ~ sqrt((1 + phi) / (1 - phi)).

    ``phi`` has a uniform prior on (-0.99, 0.999): the upper end allows the
    near-random-walk residuals of heavily oversampled records.
    """

    name: ClassVar[str] = "ar1"

    def param_space(self, data: Any = None) -> ParamSpace:
        """Noise parameters ``sigma`` (marginal sd, output unit) and ``phi`` (lag-1 correlation).

        Parameters
        ----------
        data : Record, Dataset or None
            Data whose output span and ``y`` unit set the ``sigma`` prior (``None``: median
            0.01 um).

        Returns
        -------
        ParamSpace
            Free parameters ``sigma`` (log-normal, median 1 % of the span, spread 1.5) and
            ``phi`` (uniform on (-0.99, 0.999)).
        """
        scale, unit = _noise_scale(data)
        return ParamSpace((
            Param("sigma", LogNormal.from_median(scale, 1.5), unit=unit,
                  description="marginal noise standard deviation"),
            Param("phi", Uniform(-0.99, 0.999), unit="1",
                  description="lag-1 autocorrelation of the noise"),
        ))

    def pointwise(self, resid: np.ndarray, theta: Mapping[str, np.ndarray]) -> np.ndarray:
        """Per-sample AR(1) log-density terms, shape ``(W, N)``.

        The first sample is scored under the marginal ``N(0, sigma^2)``, each later one under
        the conditional ``N(phi e_{k-1}, sigma^2 (1 - phi^2))``. See
        :meth:`Likelihood.pointwise` for the arguments.
        """
        sigma = np.asarray(theta["sigma"], dtype=float)[:, None]
        phi = np.asarray(theta["phi"], dtype=float)[:, None]
        out = np.empty_like(resid)
        out[:, :1] = -0.5 * (resid[:, :1] / sigma) ** 2 - np.log(sigma) - 0.5 * _LOG_2PI
        s_innov = sigma * np.sqrt(1.0 - phi**2)
        innov = resid[:, 1:] - phi * resid[:, :-1]
        out[:, 1:] = -0.5 * (innov / s_innov) ** 2 - np.log(s_innov) - 0.5 * _LOG_2PI
        return out

    def sample(self, theta, n, rng):
        """Stationary AR(1) noise draws, shape ``(W, n)``.

        The first sample is drawn from the marginal ``N(0, sigma^2)``, later ones by the
        recursion with innovations of sd ``sigma sqrt(1 - phi^2)``. See
        :meth:`Likelihood.sample` for the arguments.
        """
        sigma = np.asarray(theta["sigma"], dtype=float)
        phi = np.asarray(theta["phi"], dtype=float)
        w = sigma.shape[0]
        eta = rng.standard_normal((w, int(n)))
        out = np.empty((w, int(n)))
        out[:, 0] = sigma * eta[:, 0]  # stationary start
        s_innov = sigma * np.sqrt(1.0 - phi**2)
        for k in range(1, int(n)):
            out[:, k] = phi * out[:, k - 1] + s_innov * eta[:, k]
        return out


_LIKELIHOODS: dict[str, type[Likelihood]] = {
    cls.name: cls for cls in (Gaussian, StudentT, AR1)
}


def likelihood_names() -> list[str]:
    """Names accepted by :func:`get_likelihood` (and ``--likelihood``)."""
    return sorted(_LIKELIHOODS)


def get_likelihood(name: str | Likelihood) -> Likelihood:
    """A likelihood by name (``"gaussian"``, ``"student_t"``, ``"ar1"``)."""
    if isinstance(name, Likelihood):
        return name
    try:
        return _LIKELIHOODS[name]()
    except KeyError:
        raise ModelError(f"unknown likelihood {name!r}; choose from "
                         f"{', '.join(likelihood_names())}") from None

