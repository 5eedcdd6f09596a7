"""The GP's kernel, marginal likelihood and conditioned predictor (:mod:`bayeshyst.gp`).

* :func:`make_kernel` -- ``ConstantKernel * ARD-RBF|Matern 5/2 + WhiteKernel`` with
  :data:`BOUNDS`, the estimator's sklearn kernel;
* :func:`log_marginal_likelihood` -- value and analytic gradient in ``O(m^2 d)``
  (sklearn forms an (m, m, d) tensor for the same gradient and is several times slower);
* :func:`maximise_marginal_likelihood` -- L-BFGS-B from several starts, every optimum
  returned (the estimator chooses among them by their free run);
* :class:`Conditioned` -- a GP conditioned on a training set (Cholesky factor), with
  chunked predictive means, variances and joint covariances;
* :func:`blas_limit` / :func:`small_blas` -- single-threaded BLAS for small matrices.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from scipy import linalg, optimize
from scipy.spatial.distance import cdist
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Matern, WhiteKernel

from bayeshyst.errors import DataError, ParameterError
from bayeshyst.threads import single_threaded_blas

__all__ = [
    "BOUNDS",
    "SMALL_BLAS",
    "Conditioned",
    "blas_limit",
    "log_marginal_likelihood",
    "make_kernel",
    "maximise_marginal_likelihood",
    "small_blas",
]

#: Hyperparameter bounds in standardised units (inputs and targets of unit variance):
#: they bound the optimiser and are the support of the hyperparameter prior. A
#: length-scale at its upper bound switches its feature off.
BOUNDS = {"signal_variance": (1e-3, 1e4), "length_scale": (1e-2, 1e3), "noise_level": (1e-8, 1.0)}

#: Largest training-set size whose linear algebra runs with single-threaded BLAS.
SMALL_BLAS = 1000


@contextlib.contextmanager
def blas_limit(m: int) -> Iterator[None]:
    """Single-threaded BLAS while working with ``m x m`` matrices, ``m <= SMALL_BLAS``.

    Threads gain little at that size, and on an oversubscribed machine OpenBLAS's
    spinning threads made these calls up to 100x slower (measured: a 300 x 300 Cholesky
    took 172 ms instead of ~1 ms with another job on both cores). Larger problems keep
    the configured thread count.
    """
    if m > SMALL_BLAS:
        yield
        return
    with single_threaded_blas():
        yield



def small_blas(method: Callable[..., Any]) -> Callable[..., Any]:
    """Run a fitted estimator's method under :func:`blas_limit` of its training-set size.

    The size is ``self._train["y"].size``; before a fit the method runs multi-threaded.
    """
    @functools.wraps(method)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        train = getattr(self, "_train", None)
        with blas_limit(train["y"].size if train is not None else SMALL_BLAS + 1):
            return method(self, *args, **kwargs)
    return wrapper



def _kernel_parts(theta: np.ndarray, kind: str, a: np.ndarray,
                  b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlation ``k`` (without the amplitude) and ``-dk/d(r^2) * 2`` of scaled inputs.

    Both between scaled inputs ``a`` (n, d) and ``b`` (m, d); the second is for the
    gradient with respect to log length-scales.
    """
    sq = cdist(a, b, "sqeuclidean")
    if kind == "rbf":
        k = np.exp(-0.5 * sq)
        return k, k
    r = np.sqrt(5.0 * sq)
    e = np.exp(-r)
    return (1.0 + r + r * r / 3.0) * e, (5.0 / 3.0) * (1.0 + r) * e


def log_marginal_likelihood(theta: np.ndarray, kind: str, z: np.ndarray, y: np.ndarray,
                            gradient: bool = True) -> tuple[float, np.ndarray] | float:
    """Log marginal likelihood of ``c k(z/l) + s2 I`` and its gradient in ``theta``.

    ``theta = log([c, l_1..l_d, s2])`` in the order of sklearn's
    ``ConstantKernel * RBF|Matern(nu=2.5) + WhiteKernel`` (``kernel.theta``). The
    gradient uses ``dlml/dtheta_j = tr(W dK/dtheta_j) / 2``, ``W = a a^T - K^-1``; for
    the length-scales ``sum_ij G_ij (x_ik - x_jk)^2 = 2 (x_k^2)^T G 1 - 2 x_k^T G x_k``
    with ``G = c W o k'``, so no (m, m, d) tensor is formed.

    Parameters
    ----------
    theta : ndarray, shape (d + 2,)
    kind : {"rbf", "matern52"}
    z : ndarray, shape (m, d)
        Standardised training inputs.
    y : ndarray, shape (m,)
        Standardised targets.
    gradient : bool
        Also return the gradient.

    Returns
    -------
    float, or (float, ndarray of shape (d + 2,))
        ``-inf`` (and a zero gradient) when ``K`` is not numerically positive definite.
    """
    c, noise = math.exp(theta[0]), math.exp(theta[-1])
    a = z / np.exp(theta[1:-1])
    k, dk = _kernel_parts(theta, kind, a, a)
    m = y.size
    kmat = c * k
    kmat[np.diag_indices(m)] += noise
    try:
        chol = linalg.cholesky(kmat, lower=True, check_finite=False)
    except linalg.LinAlgError:
        return (-np.inf, np.zeros_like(theta)) if gradient else -np.inf
    alpha = linalg.cho_solve((chol, True), y, check_finite=False)
    lml = float(-0.5 * y @ alpha - np.log(np.diag(chol)).sum() - 0.5 * m * math.log(2 * math.pi))
    if not gradient:
        return lml
    inv, info = linalg.lapack.dpotri(chol, lower=1)
    if info != 0:
        return -np.inf, np.zeros_like(theta)
    inv = np.tril(inv)
    inv += np.tril(inv, -1).T
    # W = a a^T - K^-1 is never formed: its rank-one part goes through matrix-vector
    # products, so the only (m, m) temporary is K^-1 o k' (the m x m passes, not the
    # factorisation, were most of an evaluation at the default 1 000 points)
    grad = np.empty_like(theta)
    k_alpha = k @ alpha
    grad[0] = 0.5 * c * float(alpha @ k_alpha - np.vdot(inv, k))
    grad[-1] = 0.5 * noise * float(alpha @ alpha - np.trace(inv))
    p_mat = inv * dk
    dk_alpha = k_alpha if dk is k else dk @ alpha
    g_sum = c * (alpha * dk_alpha - p_mat.sum(axis=1))
    g_a = c * (alpha[:, None] * (dk @ (alpha[:, None] * a)) - p_mat @ a)
    grad[1:-1] = (a * a).T @ g_sum - np.sum(a * g_a, axis=0)
    return lml, grad



def make_kernel(kind: str, d: int, length_scale: float | np.ndarray, signal_variance: float,
                noise_level: float):
    """The kernel ``ConstantKernel * RBF|Matern(nu=2.5) (ARD, d length-scales) + WhiteKernel``.

    With the initial values given and :data:`BOUNDS`.

    Raises
    ------
    ParameterError
        ``length_scale`` neither a positive number nor ``d`` positive numbers.
    """
    ls = np.asarray(length_scale, dtype=float)
    ok = ls.ndim == 0 or ls.shape == (d,)
    ls = np.broadcast_to(ls, (d,)).copy() if ok else ls
    if not (ok and np.isfinite(ls).all() and (ls > 0).all()):
        raise ParameterError(f"length_scale: expected a positive number or {d} positive "
                             f"numbers (one per feature), found {length_scale!r}")
    corr = (RBF(ls, BOUNDS["length_scale"]) if kind == "rbf"
            else Matern(ls, BOUNDS["length_scale"], nu=2.5))
    return (ConstantKernel(float(signal_variance), BOUNDS["signal_variance"]) * corr
            + WhiteKernel(float(noise_level), BOUNDS["noise_level"]))


def maximise_marginal_likelihood(starts: list[np.ndarray], bounds: np.ndarray, kind: str,
                                 z: np.ndarray, y: np.ndarray,
                                 ) -> list[tuple[np.ndarray, float, bool]]:
    """L-BFGS-B from each start (log hyperparameters within ``bounds`` (p, 2)).

    Returns
    -------
    list of (theta, lml, converged)
        One entry per start whose optimum has a finite log marginal likelihood, best
        (highest ``lml``) first, ties in the order of the starts; ``converged`` is
        whether that run reported success. The caller chooses among them
        (:class:`bayeshyst.gp.GPHysteresis` takes the best one whose free run
        reproduces the training records).

    Raises
    ------
    DataError
        If the kernel matrix was singular everywhere the optimiser went.
    """
    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        lml, grad = log_marginal_likelihood(theta, kind, z, y)
        return -lml, -grad

    runs = [optimize.minimize(objective, th, jac=True, method="L-BFGS-B", bounds=bounds)
            for th in starts]
    optima = sorted(((r.x, float(-r.fun), bool(r.success)) for r in runs if np.isfinite(r.fun)),
                    key=lambda o: -o[1])
    if not optima:
        raise DataError("GP fit: the kernel matrix is not positive definite anywhere the "
                        "optimiser went (duplicate training inputs with conflicting outputs?)")
    return optima



class Conditioned:
    """A zero-mean GP ``c k(z/l) + s2 I`` conditioned on standardised training data.

    Parameters
    ----------
    theta : ndarray, shape (d + 2,)
        Log-hyperparameters (see :func:`log_marginal_likelihood`).
    kind : {"rbf", "matern52"}
    z : ndarray, shape (m, d)
        Standardised training inputs.
    y : ndarray, shape (m,)
        Standardised targets.
    chol, alpha : ndarray, optional
        The Cholesky factor of ``K + s2 I`` and ``(K + s2 I)^-1 y`` when already known
        (sklearn's ``L_`` and ``alpha_``); computed otherwise (Rasmussen & Williams,
        Algorithm 2.1).
    """

    #: Rows of test inputs per chunk: bounds the (rows, m) cross-kernel to ~32 MB.
    CHUNK_ELEMENTS = 1 << 22

    def __init__(self, theta: np.ndarray, kind: str, z: np.ndarray, y: np.ndarray,
                 chol: np.ndarray | None = None, alpha: np.ndarray | None = None) -> None:
        self.theta = np.asarray(theta, dtype=float)
        self.kind = kind
        self.amplitude = math.exp(self.theta[0])
        self.noise = math.exp(self.theta[-1])
        self.scale = np.exp(self.theta[1:-1])
        self.a = z / self.scale
        if chol is None:
            k, _ = _kernel_parts(self.theta, kind, self.a, self.a)
            kmat = self.amplitude * k
            kmat[np.diag_indices(y.size)] += self.noise
            chol = linalg.cholesky(kmat, lower=True, check_finite=False)
            alpha = linalg.cho_solve((chol, True), y, check_finite=False)
        self.chol, self.alpha = chol, alpha

    def cross(self, zs: np.ndarray) -> np.ndarray:
        """Signal covariance between test inputs ``zs`` (n, d) and the training inputs."""
        return self.amplitude * _kernel_parts(self.theta, self.kind, zs / self.scale, self.a)[0]

    def predict(self, zs: np.ndarray, var: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Latent mean and variance (noise excluded) at ``zs`` (n, d), standardised units."""
        n = zs.shape[0]
        step = max(1, self.CHUNK_ELEMENTS // max(1, self.alpha.size))
        mean = np.empty(n)
        out = np.empty(n) if var else None
        for lo in range(0, n, step):
            ks = self.cross(zs[lo:lo + step])
            mean[lo:lo + step] = ks @ self.alpha
            if var:
                v = linalg.solve_triangular(self.chol, ks.T, lower=True, check_finite=False)
                # k(x, x) = c for both kernels; rounding can push tiny variances below 0
                out[lo:lo + step] = np.maximum(self.amplitude - np.einsum("ij,ij->j", v, v), 0.0)
        return mean, out

    def covariance(self, zs: np.ndarray) -> np.ndarray:
        """Joint latent covariance (n, n) at ``zs`` (noise excluded), standardised units."""
        v = linalg.solve_triangular(self.chol, self.cross(zs).T, lower=True, check_finite=False)
        k, _ = _kernel_parts(self.theta, self.kind, zs / self.scale, zs / self.scale)
        return self.amplitude * k - v.T @ v

    def joint_log_density(self, zs: np.ndarray, resid: np.ndarray) -> float:
        """``log N(resid; 0, Sigma + s2 I)`` for standardised residuals at ``zs`` (n, d)."""
        cov = self.covariance(zs)
        cov[np.diag_indices(resid.size)] += self.noise
        chol = linalg.cholesky(cov, lower=True, check_finite=False)
        w = linalg.solve_triangular(chol, resid, lower=True, check_finite=False)
        return float(-0.5 * w @ w - np.log(np.diag(chol)).sum()
                     - 0.5 * resid.size * math.log(2 * math.pi))
