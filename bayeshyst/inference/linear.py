"""The posterior's linear block: exact conditionals, marginals and fast likelihoods.

Most hysteresis models are linear in a block of their parameters once the others are
fixed: the weights of every PI-type model, the Preisach grid, Maxwell-slip, Duhem's
``f, g`` given ``alpha``, Bouc–Wen's ``k``, and the observation offset of any model —
and they stay so behind linear dynamics, creep, delay or drift (the Hammerstein
structure, :meth:`~bayeshyst.models.compose.Composite.linear_design`). Write the
scored output as ``y = Phi(z_n) beta + c(z_n)``, with ``z_n`` the other coordinates
(nonlinear model parameters and noise). With Gaussian or AR(1) noise and Normal priors
on ``beta``, the conditional posterior of ``beta`` given ``z_n`` is Gaussian and the
marginal ``p(z_n | y)`` is available in closed form (MODELS.md §2)::

    Lambda = S0^-1 + M_pp / sigma^2,   h = S0^-1 (m0 - b) + M_pr / sigma^2
    delta | z_n ~ N(Lambda^-1 h, Lambda^-1),          beta = b + delta

where ``M = [[M_pp, M_pr], [M_rp, M_rr]]`` is the (AR(1)-whitened) Gram matrix of
``[Phi, y - c - Phi b]`` over the scored samples and ``b`` a reference point (the MAP)
that keeps the quadratic forms free of cancellation. For AR(1) noise the whitened Gram
is a rational function of ``phi`` assembled from three lagged Grams, so ``phi`` and
``sigma`` move without touching the data again.

:class:`LinearStructure` holds that algebra for one :class:`Posterior`; the sampler's
moves (:mod:`bayeshyst.inference.moves`) use it to draw ``beta`` exactly (Gibbs), to
propose ``z_n`` with ``beta`` integrated out, and to evaluate the log posterior of a
proposal from the Grams instead of a new simulation. A linear parameter whose prior is
not Normal gets a moment-matched Gaussian stand-in, and the moves then correct with the
exact Metropolis–Hastings ratio (:attr:`LinearStructure.exact` is False).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np

from bayeshyst.discrepancy import DISC
from bayeshyst.inference._grams import BasisGrams, Grams, grams, grams_shared, stacked
from bayeshyst.inference.conditional import (
    LOG_2PI,
    Conditional,
    LinearStats,
    one_for_all,
    triangular,
)
from bayeshyst.inference.posterior import NOISE, OBS, Posterior
from bayeshyst.models.base import LinearDesign
from bayeshyst.params import Identity, Normal

__all__ = ["Conditional", "LinearStats", "LinearStructure"]

#: walkers whose Grams are kept (keyed by their design-determining coordinates)
_CACHE_SIZE = 512


class LinearStructure:
    """The linear block of a posterior (see the module docstring).

    Parameters
    ----------
    post : Posterior
        With a Gaussian or AR(1) likelihood at full power (``beta == 1``).
    reference : ndarray, shape (ndim,), optional
        A point whose linear coordinates centre the Grams (the MAP); default the prior
        means.

    Raises
    ------
    ValueError
        If the posterior has no linear block (use :meth:`of`, which returns None).
    """

    def __init__(self, post: Posterior, reference: np.ndarray | None = None) -> None:
        kind = post.likelihood.name
        if kind not in ("gaussian", "ar1") or post.beta != 1.0:
            raise ValueError(f"no linear block for likelihood {kind!r} at power {post.beta}")
        space = post.space
        model = post.model
        model_lin = tuple(getattr(model, "linear_params", ()))
        free = set(space.names)
        self.model_names = tuple(n for n in model_lin if n in free)
        offset = f"{OBS}.offset"
        self.has_offset = post.offset and offset in free
        xi = f"{DISC}.xi"
        #: the discrepancy's basis columns join the block (last) when its xi is free
        self.has_basis = post.discrepancy is not None and xi in free
        names = (self.model_names + ((offset,) if self.has_offset else ())
                 + ((xi,) if self.has_basis else ()))
        if not names:
            raise ValueError(f"{post!r} has no free linear parameter")
        if self.model_names and not hasattr(model, "linear_design"):
            raise ValueError(f"{model.name} declares no linear design")
        self.post = post
        self.kind = kind
        self.names = names
        self.lin_idx = space.indices(names)
        mask = np.ones(space.ndim, dtype=bool)
        mask[self.lin_idx] = False
        #: coordinates the moves propose (everything but the linear block)
        self.other_idx = np.flatnonzero(mask)
        noise_free = {n for n in space.names if n.startswith(NOISE + ".")}
        #: coordinates the design depends on (the model's free nonlinear parameters); the
        #: discrepancy's amplitudes and lengths only scale its fixed basis columns, so they
        #: rescale cached Grams instead of asking for a new simulation
        owner = space.owners
        self.design_idx = np.array([i for i in self.other_idx
                                    if not owner[i].startswith((NOISE + ".", DISC + "."))
                                    and owner[i] != offset], dtype=int)
        self.m_basis = post.discrepancy.size if self.has_basis else 0
        self.sigma_name = f"{NOISE}.sigma"
        self.phi_name = f"{NOISE}.phi"
        self.sigma_free = self.sigma_name in noise_free
        self.phi_free = kind == "ar1" and self.phi_name in noise_free
        # priors of the linear block: exact Normals, or moment-matched stand-ins
        m0, s0, exact = [], [], True
        self._lin_params = []
        for n in names:
            p = space[n]
            if isinstance(p.prior, Normal) and isinstance(p.transform, Identity):
                m0.append(np.full(p.size, p.prior.mu))
                s0.append(np.full(p.size, p.prior.sigma))
            else:
                exact = False
                x = p.prior.sample(np.random.default_rng(0), (4000,))
                m0.append(np.full(p.size, float(np.mean(x))))
                s0.append(np.full(p.size, float(np.std(x)) or p.prior.scale()))
            self._lin_params.append(p)
        self.m0 = np.concatenate(m0)
        self.s0 = np.concatenate(s0)
        #: whether the conditional Gaussian is the exact conditional posterior
        self.exact = exact
        self.p = self.m0.size
        #: columns of the simulated design (model, offset); the basis follows them
        self.p_design = self.p - self.m_basis
        self.lagged = kind == "ar1"
        self._records = post._records
        self._basis_grams = BasisGrams(self._records, self.p_design, self.p, self.lagged)
        self._composite_base = None
        self._constant: LinearStats | None = None
        self._cache: OrderedDict[bytes, tuple] = OrderedDict()
        self.beta_ref = self.m0.copy()
        if reference is not None:
            self.set_reference(reference)
        self._base_designs = self._cached_base_designs()
        self._shared_design = self._design_is_shared()

    # ------------------------------------------------------------------ construction
    @classmethod
    def of(cls, post: Posterior, reference: np.ndarray | None = None) -> LinearStructure | None:
        """The posterior's linear structure, or None when it has none.

        It has none with Student-t noise, a tempered likelihood or no free linear
        parameter.
        """
        try:
            return cls(post, reference)
        except ValueError:
            return None

    def set_reference(self, z: np.ndarray) -> None:
        """Centre the Grams at the linear coordinates of ``z`` (ndim,) (clears caches)."""
        beta = self.beta_of(np.asarray(z, dtype=float)[None, :])[0]
        if np.all(np.isfinite(beta)):
            # the basis coefficients stay referenced at 0 (their prior mean): the
            # reference residual must not depend on the basis' scales
            beta[self.p_design:] = 0.0
            self.beta_ref = beta
        self._cache.clear()
        self._constant = None

    def _design_is_shared(self) -> bool:
        """Whether the design's columns are the same for every walker.

        They are for Bouc–Wen's ``[u, 1]`` or an offset alone: then the Grams take the
        shared path whatever the batch size (the path is a property of the model, so a
        walker's values never depend on the batch it is computed in).
        """
        if self.design_idx.size == 0:
            return True
        z = self.post.space.sample_prior(np.random.default_rng(0), 2)
        if self.p_design == 0:
            return True
        rows, _ = self.designs(z)
        return all(phi.shape[0] == 1 for phi, _ in rows)

    def _cached_base_designs(self) -> list[LinearDesign] | None:
        """Base designs of a composite whose base has no free nonlinear parameter."""
        from bayeshyst.models.compose import STATIC, Composite

        model = self.post.model
        if not isinstance(model, Composite) or not self.model_names or self.design_idx.size == 0 \
                or model.linear_group[0] != -1:  # a block's coefficients: no base design
            return None
        if model.base.covariates:  # its design depends on each record's measured column
            return None
        owner = self.post.space.owners
        owners = {owner[i] for i in self.design_idx}
        if any(o.startswith(STATIC + ".") for o in owners):
            return None
        theta = self._model_theta(self.post.space.sample_prior(np.random.default_rng(0), 1))
        base_theta, _ = model._split(theta)
        names = tuple(n[len(STATIC) + 1:] for n in self.model_names)
        return [model.base.linear_design(rec["u"], rec["t"], base_theta, names)
                for rec in self._records]

    # ------------------------------------------------------------------ coordinates
    def beta_of(self, z: np.ndarray) -> np.ndarray:
        """Linear parameters in physical units (W, P) from ``z`` (W, ndim)."""
        out = np.empty((z.shape[0], self.p))
        start = 0
        for p, name in zip(self._lin_params, self.names, strict=True):
            sl = self.post.space.slice_of(name)
            with np.errstate(over="ignore", invalid="ignore"):
                out[:, start:start + p.size] = p.transform.inverse(z[:, sl])
            start += p.size
        return out

    def z_of(self, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``z`` coordinates (W, P) of linear values ``beta`` and ``log |dbeta/dz|`` (W,).

        Values outside a parameter's support give NaN coordinates.
        """
        zb = np.empty_like(beta)
        logjac = np.zeros(beta.shape[0])
        start = 0
        for p in self._lin_params:
            sl = slice(start, start + p.size)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                zb[:, sl] = p.transform.forward(beta[:, sl])
                logjac += np.sum(p.transform.log_jacobian(zb[:, sl]), axis=1)
            start += p.size
        return zb, np.where(np.isfinite(logjac), logjac, -np.inf)

    def noise(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``sigma`` (W,) and ``phi`` (W,; zeros for Gaussian noise) at ``z``."""
        w = z.shape[0]
        return (self._scalar_value(z, self.sigma_name, w),
                self._scalar_value(z, self.phi_name, w) if self.kind == "ar1" else np.zeros(w))

    def _scalar_value(self, z: np.ndarray, name: str, w: int) -> np.ndarray:
        # one scalar parameter's column through its transform, or its fixed value (this
        # runs several times per move: a full unpack of every parameter would cost more
        # than the algebra it feeds)
        space = self.post.space
        if name in space.fixed:
            return np.full(w, float(space.fixed[name]))
        with np.errstate(over="ignore"):
            return np.asarray(space[name].transform.inverse(z[:, space.slice_of(name).start]),
                              dtype=float).copy()

    def _model_theta(self, z: np.ndarray) -> dict[str, Any]:
        theta, _ = self.post.model_draws(z)
        return theta

    # ------------------------------------------------------------------ statistics
    def designs(self, z: np.ndarray) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
        """Design of every record over its scored samples, for the walkers ``z`` (W, ndim).

        Returns a list (one per record) of ``(phi, const)`` with ``phi`` (1 or W, N, P)
        (the offset column included) and ``const`` (W, N), and the failed walkers (W,).
        """
        w = z.shape[0]
        failed = np.zeros(w, dtype=bool)
        theta = self._model_theta(z)
        model = self.post.model
        out = []
        for i, rec in enumerate(self._records):
            if self.model_names:
                cov = rec["covariates"]
                if self._base_designs is not None:
                    d = model.apply_blocks_to_design(self._base_designs[i], rec["t"], theta,
                                                     self.model_names, covariates=cov)
                else:  # cov: the columns a model (or a block) reads, else None
                    d = model.linear_design(rec["u"], rec["t"], theta, self.model_names,
                                            covariates=cov)
                phi, const = d.phi, d.const
                failed |= np.broadcast_to(d.failed, (w,))
            else:
                traj = model.run_batch(rec["u"], rec["t"], theta, covariates=rec["covariates"])
                phi = np.zeros((1, traj.y.shape[1], 0))
                const = traj.y
                failed |= traj.failed
            s0 = rec["s0"]
            phi = phi[:, s0:]
            const = np.broadcast_to(const, (w, const.shape[1]))[:, s0:]
            if self.has_offset:
                phi = np.concatenate([phi, np.ones((phi.shape[0], phi.shape[1], 1))], axis=2)
            out.append((phi, const))
        return out, failed

    def _reference_residual(self, rec: dict, phi: np.ndarray, const: np.ndarray) -> np.ndarray:
        # einsum without BLAS: every walker's residual is summed in the same order
        # whatever the batch, so cached and recomputed Grams agree to the bit
        with np.errstate(invalid="ignore", over="ignore"):
            ref = self.beta_ref[:self.p_design]
            if self._shared_design:  # one product for every walker
                return (rec["y"] - np.einsum("np,p->n", phi[0], ref,
                                             optimize=False))[None, :] - const
            fit = np.einsum("wnp,p->wn", phi, ref, optimize=False)
            return rec["y"][None, :] - const - fit

    def _compute(self, z: np.ndarray) -> LinearStats:
        """Grams of the walkers ``z`` (W, ndim) (no cache)."""
        rows, failed = self.designs(z)
        return self._stats_of(rows, failed)

    def _stats_of(self, rows: list[tuple[np.ndarray, np.ndarray]],
                  failed: np.ndarray) -> LinearStats:
        w = failed.shape[0]
        q = self.p + 1
        first, lag0 = np.zeros((w, q, q)), np.zeros((w, q, q))
        cross = np.zeros((w, q, q)) if self.lagged else None
        prev = np.zeros((w, q, q)) if self.lagged else None
        n = n_first = 0
        for i, (rec, (phi, const)) in enumerate(zip(self._records, rows, strict=True)):
            r = self._reference_residual(rec, phi, const)
            failed |= ~np.all(np.isfinite(r), axis=1)
            keep = rec["keep"] if rec["keep"] is not None else np.ones(r.shape[1], dtype=bool)
            # a walker far out in its prior can give a finite design whose products
            # overflow: its Grams turn non-finite and _factor flags it failed (counted)
            with np.errstate(over="ignore", invalid="ignore"):
                if self.has_basis:
                    f, l0, c, pv = self._grams_with_basis(i, phi, r, keep)
                elif self._shared_design and np.all(np.isfinite(phi)):
                    f, l0, c, pv = grams_shared(phi[0], r, keep, self.lagged)
                else:
                    f, l0, c, pv = grams(
                        stacked(np.broadcast_to(phi, (w, *phi.shape[1:])), r),
                        keep, self.lagged)
                first += f
                lag0 += l0
                if self.lagged:
                    cross += c
                    prev += pv
            n += int(np.count_nonzero(keep))
            n_first += int(keep[0])
        return LinearStats(first, lag0, cross, prev, n, n_first, failed)

    def whitened_rows(self, z: np.ndarray, beta: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened residuals and design rows over the kept samples of every record.

        Parameters
        ----------
        z : ndarray, shape (W, ndim)
        beta : ndarray, shape (W, P), optional
            Linear block; default the conditional mean given the rest of ``z`` (the
            variable-projection residual of least squares).

        Returns
        -------
        resid : ndarray, shape (W, n)
            ``(y - yhat)`` whitened by the noise model and divided by ``sigma`` (NaN
            rows for failed walkers).
        design : ndarray, shape (W, n, P)
            ``d resid / d beta`` (the whitened design divided by ``-sigma``).
        beta : ndarray, shape (W, P)
            The linear block used.
        """
        sigma, phi_ar = self.noise(z)
        rows, failed = self.designs(z)
        if beta is None:
            # Grams from the same designs (no second simulation): the projected beta
            beta = self.conditional(self._stats_of(rows, failed.copy()), z).mean
        res_parts, des_parts = [], []
        scale = self.column_scale(z) if self.has_basis else None
        for rec, (phi, const) in zip(self._records, rows, strict=True):
            if scale is not None:  # the scaled basis columns complete the design
                basis = rec["basis"][rec["s0"]:]
                phi = np.concatenate([np.broadcast_to(phi, (z.shape[0], *phi.shape[1:])),
                                      basis[None, :, :] * scale[:, None, self.p_design:]],
                                     axis=2)
            with np.errstate(invalid="ignore", over="ignore"):
                e = rec["y"][None, :] - const - np.einsum("wnp,wp->wn", np.broadcast_to(
                    phi, (z.shape[0], *phi.shape[1:])), beta)
            d = -np.broadcast_to(phi, (z.shape[0], *phi.shape[1:]))
            keep = rec["keep"] if rec["keep"] is not None else np.ones(e.shape[1], dtype=bool)
            if self.lagged:
                c = np.sqrt(1.0 - phi_ar**2)[:, None]
                e = np.concatenate([e[:, :1], (e[:, 1:] - phi_ar[:, None] * e[:, :-1]) / c],
                                   axis=1)
                d = np.concatenate([d[:, :1], (d[:, 1:] - phi_ar[:, None, None] * d[:, :-1])
                                    / c[:, :, None]], axis=1)
            res_parts.append(e[:, keep] / sigma[:, None])
            des_parts.append(d[:, keep] / sigma[:, None, None])
        resid = np.concatenate(res_parts, axis=1)
        resid[failed] = np.nan
        return resid, np.concatenate(des_parts, axis=1), beta

    def stats(self, z: np.ndarray) -> LinearStats:
        """Grams of the walkers ``z`` (W, ndim), cached by their design coordinates.

        Walkers whose design-determining coordinates were seen before are served from the
        cache (values identical to a recomputation).
        """
        z = np.atleast_2d(np.asarray(z, dtype=float))
        if self.design_idx.size == 0:
            if self._constant is None:
                self._constant = self._compute(z[:1])
            return self._constant_for(z)
        keys = [z[j, self.design_idx].tobytes() for j in range(z.shape[0])]
        todo = [j for j, k in enumerate(keys) if k not in self._cache]
        # one entry per distinct key (DE proposals can repeat a point)
        uniq: dict[bytes, int] = {}
        for j in todo:
            uniq.setdefault(keys[j], j)
        fresh: dict[bytes, tuple] = {}
        if uniq:
            rows = np.array(list(uniq.values()))
            new = self._compute(z[rows])
            for i, k in enumerate(uniq):
                fresh[k] = (new.first[i], new.lag0[i],
                            None if new.cross is None else new.cross[i],
                            None if new.prev is None else new.prev[i],
                            bool(new.failed[i]), new.n, new.n_first)
        entries = [fresh[k] if k in fresh else self._cache[k] for k in keys]
        # store and refresh, then trim: the walkers of this call are the newest entries
        for k in keys:
            if k in fresh:
                self._cache[k] = fresh[k]
            self._cache.move_to_end(k)
        while len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return self._scaled(LinearStats(
            np.stack([e[0] for e in entries]), np.stack([e[1] for e in entries]),
            None if not self.lagged else np.stack([e[2] for e in entries]),
            None if not self.lagged else np.stack([e[3] for e in entries]),
            entries[0][5], entries[0][6], np.array([e[4] for e in entries])), z)

    def _constant_for(self, z: np.ndarray) -> LinearStats:
        """The design-free Grams of the walkers ``z``, read-only.

        When every walker's columns have the same scale (no basis, or its scales held
        fixed, as a fitted discrepancy's are) the Grams are one matrix for all of them:
        it is scaled once and broadcast, not copied and scaled per walker (copying and
        scaling ~100 x 100 Grams for every walker was a quarter of a play-PI fit with a
        discrepancy).
        """
        w = z.shape[0]
        c = self._constant
        scale = self.column_scale(z) if self.has_basis else None
        if scale is None or np.all(scale == scale[:1]):
            one = self._scaled(c, z[:1])

            def wide(a: np.ndarray | None) -> np.ndarray | None:
                return None if a is None else np.broadcast_to(a[:1], (w, *a.shape[1:]))

            return LinearStats(wide(one.first), wide(one.lag0), wide(one.cross),
                               wide(one.prev), one.n, one.n_first,
                               np.broadcast_to(one.failed[:1], (w,)).copy())
        return self._scaled(c.take(np.zeros(w, dtype=int)), z)

    # ------------------------------------------------------------------ discrepancy basis
    def column_scale(self, z: np.ndarray) -> np.ndarray:
        """Scale of every linear column (W, P): 1, and the basis' spectral scales."""
        out = np.ones((z.shape[0], self.p))
        if self.has_basis:
            theta = {name[len(DISC) + 1:]: self._scalar_value(z, name, z.shape[0])
                     for name in self.post._disc_names if name != f"{DISC}.xi"}
            out[:, self.p_design:] = self.post.discrepancy.column_scale(theta)
        return out

    def _scaled(self, st: LinearStats, z: np.ndarray) -> LinearStats:
        """Grams of the unscaled basis turned into those of the scaled one."""
        if not self.has_basis:
            return st
        s = np.concatenate([self.column_scale(z), np.ones((z.shape[0], 1))], axis=1)
        bad = ~np.all(np.isfinite(s), axis=1)
        s = np.where(bad[:, None], 1.0, s)
        outer = s[:, :, None] * s[:, None, :]
        return LinearStats(st.first * outer, None if st.lag0 is None else st.lag0 * outer,
                           None if st.cross is None else st.cross * outer,
                           None if st.prev is None else st.prev * outer,
                           st.n, st.n_first, st.failed | bad)

    def _grams_with_basis(self, rec_index: int, phi: np.ndarray, r: np.ndarray,
                          keep: np.ndarray) -> Grams:
        """Grams of ``[phi, B, r]`` with the discrepancy's basis ``B`` unscaled (W, Q, Q)."""
        return self._basis_grams.grams(rec_index, phi, r, keep, self._shared_design)

    def whitened(self, st: LinearStats, phi: np.ndarray) -> np.ndarray:
        """The whitened Gram ``M`` (W, Q, Q) at AR coefficients ``phi`` (W,)."""
        if not self.lagged:
            if st.lag0 is None:
                return st.first
            with np.errstate(over="ignore", invalid="ignore"):  # overflowed walkers: failed
                return st.first + st.lag0
        ph = phi[:, None, None]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inner = (st.lag0 - ph * (st.cross + st.cross.transpose(0, 2, 1))
                     + ph * ph * st.prev) / (1.0 - ph * ph)
        return st.first + inner

    # ------------------------------------------------------------------ densities
    def _noise_ok(self, sigma: np.ndarray, phi: np.ndarray) -> np.ndarray:
        return np.isfinite(sigma) & (sigma > 0) & np.isfinite(phi) & (np.abs(phi) < 1)

    def conditional(self, st: LinearStats, z: np.ndarray) -> Conditional:
        """``beta | z_n`` for the walkers ``z`` (their noise) with Grams ``st``."""
        chol, half, ok = self._factor(st, z)
        mean = self.beta_ref + triangular(chol, half, transpose=True)
        return Conditional(mean, chol, ok & np.all(np.isfinite(mean), axis=1))

    def _factor(self, st: LinearStats, z: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lambda's lower factor ``L`` (W, P, P), ``L^-1 h`` (W, P) and the walkers' ``ok``.

        ``Lambda^-1 h`` is then one more triangular solve: a general (LU) solve of the
        same system cost 5x the factorisation (measured, 106 coefficients) and was most
        of the discrepancy's held-out scale search.
        """
        sigma, phi = self.noise(z)
        w = z.shape[0]
        if w > 1 and one_for_all(st) and np.all(sigma == sigma[0]) and np.all(phi == phi[0]):
            # every walker has the same Grams (broadcast by _constant_for) and noise: one
            # factorisation serves them all
            chol, half, ok = self._factor(st.take(np.zeros(1, dtype=int)), z[:1])
            return (np.broadcast_to(chol, (w, *chol.shape[1:])),
                    np.broadcast_to(half, (w, half.shape[1])), np.repeat(ok, w))
        ok = ~st.failed & self._noise_ok(sigma, phi)
        m = self.whitened(st, np.where(ok, phi, 0.0))
        s2 = np.where(ok, sigma, 1.0) ** 2
        p = self.p
        # a walker whose Grams overflowed has a non-finite precision (inf - inf in the
        # sum): it is flagged here, so the arithmetic's warnings are not the user's
        with np.errstate(over="ignore", invalid="ignore"):
            prec = m[:, :p, :p] / s2[:, None, None]
            diag = np.arange(p)
            prec[:, diag, diag] += 1.0 / self.s0**2  # the prior precision, in place
            h = m[:, :p, p] / s2[:, None] + ((self.m0 - self.beta_ref) / self.s0**2)[None]
            ok &= np.isfinite(prec.sum(axis=(1, 2))) & np.all(np.isfinite(h), axis=1)
        if not ok.all():
            prec[~ok] = np.eye(p)
            h = np.where(ok[:, None], h, 0.0)
        # stacked LAPACK calls: each walker's factor is computed on its own, so the
        # values do not depend on the batch (cached and recomputed ones agree)
        try:
            chol = np.linalg.cholesky(prec)
        except np.linalg.LinAlgError:
            chol = np.empty_like(prec)
            for j in range(prec.shape[0]):
                try:
                    chol[j] = np.linalg.cholesky(prec[j])
                except np.linalg.LinAlgError:
                    ok[j] = False
                    chol[j] = np.eye(p)
        half = triangular(chol, h, transpose=False)
        return chol, half, ok

    def log_likelihood(self, st: LinearStats, z: np.ndarray,
                       beta: np.ndarray | None = None) -> np.ndarray:
        """Log-likelihood (W,) at ``z``, its linear block replaced by ``beta`` if given.

        -inf for failed designs or noise outside its support.
        """
        sigma, phi = self.noise(z)
        beta = self.beta_of(z) if beta is None else beta
        ok = ~st.failed & self._noise_ok(sigma, phi) & np.all(np.isfinite(beta), axis=1)
        m = self.whitened(st, np.where(ok, phi, 0.0))
        v = np.concatenate([-(np.where(ok[:, None], beta, self.beta_ref) - self.beta_ref),
                            np.ones((z.shape[0], 1))], axis=1)
        quad = np.einsum("wi,wij,wj->w", v, m, v)
        s = np.where(ok, sigma, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ll = (-st.n * np.log(s) - 0.5 * (st.n - st.n_first) * np.log1p(-phi * phi)
                  - 0.5 * st.n * LOG_2PI - 0.5 * quad / s**2)
        return np.where(ok & np.isfinite(ll), ll, -np.inf)

    def log_marginal(self, st: LinearStats, z: np.ndarray, *,
                     conditional: bool = False) -> np.ndarray | tuple[np.ndarray, Conditional]:
        """``log p(y | z_n)`` with the linear block integrated over its (Gaussian) prior (W,).

        Exact for Normal priors; with stand-in priors it is the stand-in's marginal.
        With ``conditional``, also ``beta | z_n`` (as :meth:`conditional`) from the same
        factorisation.
        """
        chol, half, ok_factor = self._factor(st, z)
        out = self._marginal_value(st, z, chol, half, ok_factor)
        if not conditional:
            return out
        mean = self.beta_ref + triangular(chol, half, transpose=True)
        return out, Conditional(mean, chol, ok_factor & np.all(np.isfinite(mean), axis=1))

    def _marginal_value(self, st: LinearStats, z: np.ndarray, chol: np.ndarray,
                        half: np.ndarray, ok_factor: np.ndarray) -> np.ndarray:
        sigma, phi = self.noise(z)
        ok = ~st.failed & self._noise_ok(sigma, phi)
        ok &= ok_factor & np.all(np.isfinite(half), axis=1)
        m = self.whitened(st, np.where(ok, phi, 0.0))
        p = self.p
        s = np.where(ok, sigma, 1.0)
        mu0 = (self.m0 - self.beta_ref) / self.s0
        # 1/2 h^T Lambda^-1 h = 1/2 |L^-1 h|^2
        half_quad = 0.5 * np.sum(half**2, axis=1)
        logdet_lam = 2.0 * np.sum(np.log(np.abs(np.diagonal(chol, axis1=1, axis2=2))), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = (-st.n * np.log(s) - 0.5 * (st.n - st.n_first) * np.log1p(-phi * phi)
                   - 0.5 * st.n * LOG_2PI - 0.5 * m[:, p, p] / s**2
                   - 0.5 * float(mu0 @ mu0) - float(np.sum(np.log(self.s0)))
                   - 0.5 * logdet_lam + half_quad)
        return np.where(ok & np.isfinite(out), out, -np.inf)

    def __repr__(self) -> str:
        return (f"LinearStructure({', '.join(self.names)}: {self.p} linear, "
                f"{self.other_idx.size} other coordinates, design "
                f"{'constant' if self.design_idx.size == 0 else 'per walker'}, "
                f"{self.kind}{'' if self.exact else ', stand-in priors'})")
