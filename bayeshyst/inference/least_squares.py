"""Least-squares steps of the MAP search: residual vectors, batched Jacobians, Gauss–Newton.

The log posterior of a Gaussian or AR(1) likelihood is a sum of squares plus the noise
terms and the priors. :func:`least_squares_point` minimises the sum of squares with
:func:`scipy.optimize.least_squares` over the coordinates the model output depends on
nonlinearly, with

* **variable projection** (Golub & Pereyra 2003) where the posterior has a linear block:
  the residual at nonlinear coordinates ``x`` is the one left after the linear block's
  conditional mean (ridge / GLS, prior included), so the search runs in the few
  nonlinear coordinates only (none at all for a PI model with fixed thresholds);
* **batched central-difference Jacobians**: the ``2k + 1`` perturbed vectors of one
  Jacobian are one batched simulation;
* Gaussian priors in ``z`` (Normal and log-normal parameters) as pseudo-residuals, so the
  minimum is the MAP's, not the likelihood's; other priors enter at the polish that
  follows (:func:`~bayeshyst.inference.optimize.find_map`);
* the noise (``sigma``, AR(1) ``phi``) re-estimated from the residual between rounds.

:func:`gauss_newton_covariance` gives the Laplace covariance at the optimum: ``J^T J``
of the whitened residual in the coordinates that move the output, the noise
coordinates' own curvature, and the priors' curvature, always positive semi-definite.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.posterior import NOISE, Posterior
from bayeshyst.params import (
    Identity,
    LogNormal,
    LogTransform,
    Normal,
)

__all__ = ["gauss_newton_covariance", "least_squares_point", "residual_coordinates"]


def residual_coordinates(post: Posterior, structure: LinearStructure | None) -> np.ndarray:
    """Indices of ``z`` the least squares searches over.

    These are the linear block's design coordinates, or every coordinate but the noise
    when there is no linear block.
    """
    if structure is not None:
        return structure.design_idx
    noise = [i for i, lab in enumerate(post.space.owners) if lab.startswith(NOISE + ".")]
    return np.array([i for i in range(post.ndim) if i not in noise], dtype=int)


def _search_box(post: Posterior, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the least squares in the coordinates ``idx``: bounded ones within saturation.

    Past its transform's ``saturation`` a bounded coordinate is its bound to double
    precision: the residual cannot change there, only the prior's Jacobian does, and a
    search along the flat residual walks off without limit (the Bouc–Wen exponent of an
    MR-damper fit went to z = -1.7e9, its log posterior from -15 495 to -1.7e9).
    """
    lo, hi = np.full(post.ndim, -np.inf), np.full(post.ndim, np.inf)
    for name in post.space.names:
        edge = post.space[name].transform.saturation
        if math.isfinite(edge):
            sl = post.space.slice_of(name)
            lo[sl], hi[sl] = -edge, edge
    return lo[idx], hi[idx]


def _gaussian_prior_rows(post: Posterior, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                      np.ndarray]:
    """Centre and width in ``z`` of the coordinates ``idx`` whose prior is Gaussian there.

    Gaussian in ``z`` means Normal with identity transform or log-normal with log
    transform. Returns the centres and widths (0 and 1 for the other coordinates) and the
    mask of which coordinates they are.
    """
    owners = post.space.owners
    mu, sd, mask = np.zeros(idx.size), np.ones(idx.size), np.zeros(idx.size, dtype=bool)
    for j, i in enumerate(idx):
        p = post.space[owners[i]]
        if isinstance(p.prior, Normal) and isinstance(p.transform, Identity):
            mu[j], sd[j], mask[j] = p.prior.mu, p.prior.sigma, True
        elif isinstance(p.prior, LogNormal) and isinstance(p.transform, LogTransform) \
                and p.transform.lower == 0.0:
            mu[j], sd[j], mask[j] = p.prior.mu, p.prior.sigma, True
    return mu, sd, mask


def _data_residuals(post: Posterior, z: np.ndarray) -> np.ndarray:
    """Whitened residuals ``(y - yhat) / sigma`` over the scored, kept samples (W, n).

    They are simulated (posteriors without a linear block); NaN rows where a simulation
    fails.
    """
    theta = post.space.unpack(z)
    sigma = np.broadcast_to(np.asarray(theta[f"{NOISE}.sigma"], float), (z.shape[0],))
    phi = (np.broadcast_to(np.asarray(theta[f"{NOISE}.phi"], float), (z.shape[0],))
           if post.likelihood.name == "ar1" else None)
    parts = []
    for rec, pred in zip(post._records, post.predict(z), strict=True):
        e = rec["y"][None, :] - pred[:, rec["s0"]:]
        if phi is not None:
            c = np.sqrt(1.0 - phi**2)[:, None]
            e = np.concatenate([e[:, :1], (e[:, 1:] - phi[:, None] * e[:, :-1]) / c], axis=1)
        keep = rec["keep"] if rec["keep"] is not None else np.ones(e.shape[1], dtype=bool)
        parts.append(e[:, keep] / sigma[:, None])
    return np.concatenate(parts, axis=1)


class _Residuals:
    """The residual vector of the least squares as a function of ``z[idx]``, batched."""

    def __init__(self, post: Posterior, structure: LinearStructure | None, z: np.ndarray,
                 idx: np.ndarray) -> None:
        self.post, self.s, self.z, self.idx = post, structure, z.copy(), idx
        self.mu, self.sd, self.mask = _gaussian_prior_rows(post, idx)
        self.evals = 0
        self._last: tuple[bytes, np.ndarray] | None = None

    def batch(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        z = np.repeat(self.z[None, :], x.shape[0], axis=0)
        z[:, self.idx] = x
        self.evals += x.shape[0]
        if self.s is not None:
            r, _, beta = self.s.whitened_rows(z)
            prior_b = (beta - self.s.m0) / self.s.s0
            r = np.concatenate([r, prior_b], axis=1)
        else:
            r = _data_residuals(self.post, z)
        prior_x = ((x - self.mu) / self.sd)[:, self.mask]
        out = np.concatenate([r, prior_x], axis=1)
        # a failed simulation is a large residual, not NaN (the solver cannot take NaN)
        return np.where(np.isfinite(out), out, 1e8)

    def fun(self, x: np.ndarray) -> np.ndarray:
        r = self.batch(x)[0]
        self._last = (np.asarray(x).tobytes(), r)
        return r

    def jac(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        h = 1e-6 * np.maximum(1.0, np.abs(x))
        pts = np.vstack([x + np.diag(h), x - np.diag(h)])
        r = self.batch(pts)
        k = x.size
        return ((r[:k] - r[k:]) / (2.0 * h[:, None])).T


def _update_noise(post: Posterior, structure: LinearStructure | None,
                  z: np.ndarray) -> np.ndarray:
    """``z`` with sigma (and the AR(1) phi) at their maximum-likelihood values given the rest.

    They are left unchanged where they are fixed or the residual is degenerate.
    """
    z = z.copy()
    space = post.space
    names = space.names
    if structure is not None:
        zz = z[None, :]
        _, _, beta = structure.whitened_rows(zz)
        zz[0, structure.lin_idx] = structure.z_of(beta)[0][0]
        z = zz[0]
    theta = space.unpack(z)
    sig_name, phi_name = f"{NOISE}.sigma", f"{NOISE}.phi"
    resid = []
    for rec, pred in zip(post._records, post.predict(z[None, :]), strict=True):
        e = rec["y"] - pred[0, rec["s0"]:]
        keep = rec["keep"] if rec["keep"] is not None else np.ones(e.size, dtype=bool)
        resid.append((e, keep))
    if not all(np.all(np.isfinite(e)) for e, _ in resid):
        return z
    phi = 0.0
    if post.likelihood.name == "ar1" and phi_name in names:
        num = sum(float(np.sum((e[1:] * e[:-1])[k[1:]])) for e, k in resid)
        den = sum(float(np.sum((e[:-1] ** 2)[k[1:]])) for e, k in resid)
        lo, hi = space[phi_name].prior.support
        phi = float(np.clip(num / den, lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo))) \
            if den > 0 else 0.0
        z[space.slice_of(phi_name)] = space[phi_name].transform.forward(np.array([phi]))
    elif post.likelihood.name == "ar1":
        phi = float(theta[phi_name])
    if sig_name in names:
        q, n = 0.0, 0
        for e, k in resid:
            w = np.concatenate([e[:1], (e[1:] - phi * e[:-1]) / math.sqrt(1.0 - phi**2)])
            q += float(np.sum(w[k] ** 2))
            n += int(np.count_nonzero(k))
        if q > 0 and n:
            sigma = math.sqrt(q / n)
            z[space.slice_of(sig_name)] = space[sig_name].transform.forward(np.array([sigma]))
    return z


def least_squares_point(post: Posterior, structure: LinearStructure | None, z0: np.ndarray,
                        *, rounds: int = 3) -> tuple[np.ndarray, int]:
    """A least-squares optimum near ``z0`` (see the module docstring).

    Parameters
    ----------
    post : Posterior
    structure : LinearStructure or None
    z0 : ndarray, shape (ndim,)
        Start.
    rounds : int
        Least-squares / noise re-estimation rounds (stops early once sigma settles).

    Returns
    -------
    z : ndarray, shape (ndim,)
        The optimum (linear block at its conditional mean, noise at its estimate).
    evals : int
        Residual-vector evaluations spent (each one simulation).
    """
    z = np.asarray(z0, dtype=float).copy()
    idx = residual_coordinates(post, structure)
    evals = 0
    sig_slice = (post.space.slice_of(f"{NOISE}.sigma")
                 if f"{NOISE}.sigma" in post.space.names else None)
    lo, hi = _search_box(post, idx)
    # a start past saturation has the same residual at the box's edge
    z[idx] = np.clip(z[idx], lo, hi)
    for _ in range(int(rounds)):
        before = None if sig_slice is None else float(z[sig_slice][0])
        if idx.size:
            obj = _Residuals(post, structure, z, idx)
            with np.errstate(all="ignore"):
                res = optimize.least_squares(obj.fun, z[idx], jac=obj.jac, method="trf",
                                             x_scale="jac", max_nfev=60 * (idx.size + 1),
                                             ftol=1e-10, xtol=1e-10, gtol=1e-10,
                                             bounds=(lo, hi))
            evals += obj.evals
            if np.all(np.isfinite(res.x)):
                z[idx] = res.x
        z = _update_noise(post, structure, z)
        evals += 1
        if before is not None and abs(float(z[sig_slice][0]) - before) < 1e-4:
            break
    return z, evals


def gauss_newton_covariance(post: Posterior, structure: LinearStructure | None,
                            z: np.ndarray) -> tuple[np.ndarray, bool, int]:
    """Laplace covariance of ``z`` at an optimum from the Gauss–Newton curvature.

    ``J^T J`` of the whitened residual (central differences in the coordinates that
    move the output, analytic columns for the linear block), the finite-difference
    curvature of ``-log p`` in the noise coordinates, and the priors' curvature in every
    coordinate. Directions without positive curvature get the broadest variance the
    others identify; the flag says whether that was needed.

    Returns
    -------
    cov : ndarray, shape (ndim, ndim)
    ok : bool
        Whether the curvature was positive definite without regularising.
    evals : int
        Simulations spent.
    """
    n = post.ndim
    z = np.asarray(z, dtype=float)
    hess = np.zeros((n, n))
    owners = post.space.owners
    noise = np.array([i for i in range(n) if owners[i].startswith(NOISE + ".")], dtype=int)
    evals = 0
    if structure is not None:
        x_idx = structure.design_idx
        beta = structure.beta_of(z[None, :])
        h = 1e-6 * np.maximum(1.0, np.abs(z[x_idx]))
        pts = np.repeat(z[None, :], 1 + 2 * x_idx.size, axis=0)
        for j, i in enumerate(x_idx):
            pts[1 + j, i] += h[j]
            pts[1 + x_idx.size + j, i] -= h[j]
        r, design, _ = structure.whitened_rows(pts, np.repeat(beta, pts.shape[0], axis=0))
        evals += pts.shape[0]
        k = x_idx.size
        jx = ((r[1:1 + k] - r[1 + k:]) / (2.0 * h[:, None])).T if k else np.zeros((r.shape[1], 0))
        # the linear coordinates: d resid / d z_b = design * d beta / d z_b
        zb = z[structure.lin_idx][None, :]
        dbdz = np.ones(structure.p)
        start = 0
        for p in structure._lin_params:
            sl = slice(start, start + p.size)
            dbdz[sl] = np.exp(p.transform.log_jacobian(zb[:, sl]))[0]
            start += p.size
        jb = design[0] * dbdz[None, :]
        cols = np.concatenate([x_idx, structure.lin_idx])
        jac = np.concatenate([jx, jb], axis=1)
    else:
        cols = residual_coordinates(post, None)
        h = 1e-6 * np.maximum(1.0, np.abs(z[cols]))
        pts = np.repeat(z[None, :], 1 + 2 * cols.size, axis=0)
        for j, i in enumerate(cols):
            pts[1 + j, i] += h[j]
            pts[1 + cols.size + j, i] -= h[j]
        r = _data_residuals(post, pts)
        evals += pts.shape[0]
        k = cols.size
        jac = ((r[1:1 + k] - r[1 + k:]) / (2.0 * h[:, None])).T
    jac = np.where(np.isfinite(jac), jac, 0.0)
    hess[np.ix_(cols, cols)] += jac.T @ jac
    # noise coordinates: curvature of -log p along them (others held at the optimum)
    if noise.size:
        hn = 1e-3 * np.maximum(1.0, np.abs(z[noise]))
        pts = [z]
        for a in range(noise.size):
            for b in range(a, noise.size):
                for sa, sb in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                    p = z.copy()
                    p[noise[a]] += sa * hn[a]
                    p[noise[b]] += sb * hn[b]
                    pts.append(p)
        f = -post.log_prob_batch(np.asarray(pts))
        evals += len(pts)
        m = 1
        for a in range(noise.size):
            for b in range(a, noise.size):
                pp, pm, mp, mm = f[m:m + 4]
                m += 4
                v = (pp - pm - mp + mm) / (4.0 * hn[a] * hn[b])
                hess[noise[a], noise[b]] = hess[noise[b], noise[a]] = v if np.isfinite(v) else 0.0
    # the priors' curvature in the other coordinates (independent priors: diagonal)
    others = np.array([i for i in range(n) if i not in set(noise)], dtype=int)
    if others.size:
        hp = 1e-4 * np.maximum(1.0, np.abs(z[others]))
        pts = np.repeat(z[None, :], 1 + 2 * others.size, axis=0)
        for j, i in enumerate(others):
            pts[1 + j, i] += hp[j]
            pts[1 + others.size + j, i] -= hp[j]
        lp = np.atleast_1d(post.space.log_prior(pts))
        k = others.size
        curv = -(lp[1:1 + k] - 2.0 * lp[0] + lp[1 + k:]) / hp**2
        hess[others, others] += np.where(np.isfinite(curv), curv, 0.0)
    hess = 0.5 * (hess + hess.T)
    vals, vecs = np.linalg.eigh(hess)
    thresh = 1e-12 * max(float(np.max(np.abs(vals))), 1e-300)
    ok = bool(np.all(vals > thresh))
    if not ok:
        pos = vals[vals > thresh]
        floor = float(pos.min()) if pos.size else 1.0 / float(
            np.max(post.space.prior_scale_z(z) ** 2))
        vals = np.where(vals > thresh, vals, floor)
    cov = (vecs / vals) @ vecs.T
    return 0.5 * (cov + cov.T), ok, evals
