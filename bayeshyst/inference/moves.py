"""emcee moves that use the posterior's structure.

They are exact Gibbs draws of the linear block, an adaptive independence proposal and
differential evolution on the rest.

Each move is an :class:`emcee.moves.Move`: emcee stays the sampler (its state, random
state, backend, checkpoints and resume are unchanged) and picks one move per step from
the weighted list :func:`structured_moves` returns. Every move leaves the posterior
invariant on its own:

* :class:`LinearGibbsMove` draws the linear block ``beta`` of every walker from its
  exact conditional Gaussian given the other coordinates ``z_n``
  (:class:`~bayeshyst.inference.linear.LinearStructure`), then the noise scale from
  ``sigma^2 ~ InvGamma(n/2, Q/2)`` (the likelihood's own shape in ``sigma``) and the
  AR(1) coefficient from its regression on the lagged residual, each accepted with the
  exact Metropolis–Hastings ratio (for the conjugate parts that ratio is the prior's,
  near one). Where a linear parameter's prior is not Normal its Gaussian stand-in is an
  independence proposal corrected the same way.
* :class:`IndependenceMove` proposes ``z_n`` from a multivariate t distribution fitted
  to the posterior (started from the MAP and its Laplace covariance, re-fitted to the
  ensemble during warm-up by :meth:`IndependenceMove.adapt` and frozen afterwards, so
  the kept chain is a plain MH chain) and completes the proposal with an exact draw of
  ``beta`` given the proposed ``z_n``: the acceptance ratio is then the ratio of the
  *marginal* posterior of ``z_n`` (``beta`` integrated out) to the proposal, and a
  low-dimensional, nearly Gaussian marginal is accepted most of the time.
* :class:`DifferentialMove` is the red-blue differential-evolution move of ter Braak
  (2006) and Nelson et al. (2013) on ``z_n``, completed the same way: it follows curved
  ridges and, with its occasional unit step, jumps between modes.

Without a linear block (Student-t noise, a tempered likelihood) the last two act on the
whole of ``z`` and evaluate the posterior by simulation.

The target the moves share and their acceptance counts per move are in
:mod:`bayeshyst.inference.structured_target` (:class:`StructuredTarget`,
:class:`MoveStats`).
"""

from __future__ import annotations

import math
from typing import Any

import emcee
import numpy as np
from emcee.state import State
from scipy import special

from bayeshyst.inference.noise_proposals import phi_proposal, sigma_proposal
from bayeshyst.inference.structured_target import MoveStats, StructuredTarget

__all__ = ["ANCHOR_WEIGHT", "DifferentialMove", "IndependenceMove", "LinearGibbsMove",
           "structured_moves"]


def _accept(log_ratio: np.ndarray, random: np.random.RandomState) -> np.ndarray:
    u = random.rand(log_ratio.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(u) < np.where(np.isnan(log_ratio), -np.inf, log_ratio)


class _StructuredMove(emcee.moves.Move):
    """Shared bookkeeping: a target, a name and acceptance counts."""

    name = "move"

    def __init__(self, target: StructuredTarget, stats: MoveStats) -> None:
        self.target = target
        self.stats = stats


class LinearGibbsMove(_StructuredMove):
    """Exact draws of the linear block, then of ``sigma`` and the AR(1) ``phi``.

    Parameters
    ----------
    target : StructuredTarget
        With a linear structure.
    stats : MoveStats
        Where acceptances are counted (``gibbs_linear``, ``gibbs_sigma``,
        ``gibbs_phi``).
    """

    name = "gibbs"

    def __init__(self, target: StructuredTarget, stats: MoveStats) -> None:
        if target.structure is None:
            raise ValueError("the Gibbs move needs a posterior with a linear block")
        super().__init__(target, stats)

    def propose(self, model: Any, state: State) -> tuple[State, np.ndarray]:
        """One Gibbs sweep over every walker: the linear block, then ``sigma`` and ``phi``.

        The linear block is drawn from its conditional Gaussian (every draw is taken when
        the conditional is exact; with stand-in priors the exact MH ratio decides), then
        ``sigma`` and the AR(1) ``phi`` are updated by MH when they are free.

        Parameters
        ----------
        model : emcee model
            The sampler's interface to the moves; only its ``random`` state is used.
        state : emcee.State
            Current coordinates (W, ndim) and log posteriors (W,).

        Returns
        -------
        state : emcee.State
            The new coordinates and log posteriors.
        accepted : ndarray of bool, shape (W,)
            Walkers that moved in any of the steps.
        """
        s = self.target.structure
        random = model.random
        z = np.array(state.coords, dtype=float)
        lp = np.array(state.log_prob, dtype=float)
        w = z.shape[0]
        st = s.stats(z)
        cond = s.conditional(st, z)
        beta_old = s.beta_of(z)
        beta = cond.draw(random)
        zb, logjac = s.z_of(beta)
        z_new = z.copy()
        good = cond.ok & np.all(np.isfinite(zb), axis=1)
        z_new[:, s.lin_idx] = np.where(good[:, None], zb, z[:, s.lin_idx])
        lp_new = self.target.log_prob(z_new, st)
        if s.exact:
            # the conditional is exact: the MH ratio is one (to rounding), take every draw
            acc = good & np.isfinite(lp_new)
        else:
            _, logjac_old = s.z_of(beta_old)
            log_r = (lp_new - lp + (cond.log_density(beta_old) - logjac_old)
                     - (cond.log_density(beta) - logjac))
            acc = good & _accept(log_r, random)
        self.stats.add("gibbs_linear", w, int(np.count_nonzero(acc)))
        z = np.where(acc[:, None], z_new, z)
        lp = np.where(acc, lp_new, lp)
        accepted = acc.copy()
        beta = s.beta_of(z)
        if s.sigma_free:
            z, lp, a = self._noise_step(z, lp, st, beta, random, "sigma")
            accepted |= a
        if s.phi_free:
            z, lp, a = self._noise_step(z, lp, st, beta, random, "phi")
            accepted |= a
        return State(z, log_prob=lp, blobs=None, random_state=state.random_state), accepted

    def _noise_step(self, z: np.ndarray, lp: np.ndarray, st: Any, beta: np.ndarray,
                    random: np.random.RandomState, which: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """MH update of ``sigma`` (given the rest) or of the AR(1) ``phi``.

        ``phi`` moves along the curve of constant innovation scale, moving ``sigma`` with
        it when it is free.
        """
        s = self.target.structure
        space = self.target.post.space
        sig_p, sig_sl = space[s.sigma_name], space.slice_of(s.sigma_name).start
        z_new = z.copy()
        if which == "sigma":
            new, lq_new, lq_old = sigma_proposal(s, st, z, beta, random)
            with np.errstate(divide="ignore", invalid="ignore"):
                z_new[:, sig_sl] = sig_p.transform.forward(new)
            correction = lq_new - lq_old  # in the z coordinate already
        else:
            # sigma is the marginal scale: near phi = 1 it is tied to phi along
            # s = sigma sqrt(1 - phi^2), the innovation scale the data pin down, so phi
            # moves with s held (sigma follows), where its regression is the proposal
            phi_p, phi_sl = space[s.phi_name], space.slice_of(s.phi_name).start
            sigma, phi = s.noise(z)
            new, lq_new, lq_old = phi_proposal(s, st, z, beta, random)
            lo, hi = phi_p.prior.support
            inside = (new > lo) & (new < hi)
            new = np.where(inside, new, phi)
            with np.errstate(divide="ignore", invalid="ignore"):
                z_new[:, phi_sl] = phi_p.transform.forward(new)
                # density of (phi, s) from that of the z coordinates: divide by the
                # transforms' Jacobians and by d sigma / d s = 1 / sqrt(1 - phi^2)
                lj_old = phi_p.transform.log_jacobian(z[:, phi_sl])
                lj_new = phi_p.transform.log_jacobian(z_new[:, phi_sl])
                corr_old = lj_old + 0.5 * np.log1p(-phi**2)
                corr_new = lj_new + 0.5 * np.log1p(-new**2)
                if s.sigma_free:
                    sig_new = sigma * np.sqrt((1.0 - phi**2) / (1.0 - new**2))
                    z_new[:, sig_sl] = sig_p.transform.forward(sig_new)
                    corr_old = corr_old + sig_p.transform.log_jacobian(z[:, sig_sl])
                    corr_new = corr_new + sig_p.transform.log_jacobian(z_new[:, sig_sl])
                else:
                    corr_old = lj_old
                    corr_new = lj_new
            lq_new = np.where(inside, lq_new, -np.inf)
            correction = (lq_new + corr_new) - (lq_old + corr_old)
        good = np.all(np.isfinite(z_new), axis=1) & np.isfinite(correction)
        z_new = np.where(good[:, None], z_new, z)
        lp_new = self.target.log_prob(z_new, st)
        with np.errstate(invalid="ignore"):
            log_r = lp_new - lp - correction
        acc = good & _accept(log_r, random)
        self.stats.add(f"gibbs_{which}", z.shape[0], int(np.count_nonzero(acc)))
        return (np.where(acc[:, None], z_new, z), np.where(acc, lp_new, lp), acc)


def _logsumexp_columns(a: np.ndarray) -> np.ndarray:
    """``log(sum(exp(a), axis=0))`` of a (k, M) array (k small); ``-inf`` for a column of -inf.

    One pass per row of ``a``, along the long axis; scipy's ``logsumexp`` costs three
    times as much per call on these arrays, and the proposal calls it on every density
    evaluation and EM step.
    """
    top = np.max(a, axis=0)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return top + np.log(np.sum(np.exp(a - top), axis=0))


def _fit_mixture(x: np.ndarray, k: int, iterations: int = 60
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """Gaussian mixture of ``k`` components fitted to ``x`` (M, d) by EM.

    Deterministic: the centres start at the point farthest from the mean and then at
    the points farthest from those already chosen (no random restarts, so a resumed run
    refits the same proposal). Returns weights (k,), means (k, d), covariances
    (k, d, d) and the log-likelihood, or None when a component collapses.
    """
    m, d = x.shape
    centres = [x[int(np.argmax(np.sum((x - x.mean(axis=0)) ** 2, axis=1)))]]
    while len(centres) < k:
        dist = np.min([np.sum((x - c) ** 2, axis=1) for c in centres], axis=0)
        centres.append(x[int(np.argmax(dist))])
    mu = np.array(centres)
    base = np.cov(x.T).reshape(d, d)
    ridge = 1e-6 * np.diag(np.diag(base)) + 1e-300 * np.eye(d)
    cov = np.repeat(base[None], k, axis=0)
    w = np.full(k, 1.0 / k)
    prev = -np.inf
    ll = -np.inf
    const = 0.5 * d * math.log(2 * math.pi)
    xt = np.ascontiguousarray(x.T)                                      # (d, M)
    for _ in range(iterations):
        # component-major (k, M) and (d, M): every reduction runs along the long axis
        # (numpy's sums across a short last axis cost several times more)
        logp = np.empty((k, m))
        for j in range(k):
            try:
                c = np.linalg.cholesky(cov[j] + ridge)
            except np.linalg.LinAlgError:
                return None
            # whitened by the inverse factor (d x d, once per component) rather than a
            # general solve against the (d, M) block
            r = np.linalg.inv(c) @ (xt - mu[j][:, None])
            logp[j] = (math.log(w[j]) - 0.5 * np.sum(r * r, axis=0)
                       - np.sum(np.log(np.diag(c))) - const)
        norm = _logsumexp_columns(logp)
        ll = float(np.sum(norm))
        resp = np.exp(logp - norm)
        nk = resp.sum(axis=1)
        if np.any(nk < d + 2):
            return None
        w = nk / m
        mu = (resp @ x) / nk[:, None]
        for j in range(k):
            dx = xt - mu[j][:, None]
            cov[j] = (dx * resp[j]) @ dx.T / nk[j] + ridge
        if ll - prev < 1e-6 * abs(ll):
            break
        prev = ll
    return w, mu, cov, ll


#: Weight and width (sd multiple) of the independence proposal's defensive component,
#: the global fit widened: without it a walker that reaches the tails, where the
#: posterior outweighs the fitted components, can sit there for hundreds of steps and
#: keep R-hat across walkers above 1.01 (Bouc–Wen on the bundled five-frequency record:
#: 3 000 steps unconverged, tau 18; with 0.1 at twice the width: 487-608 steps).
DEFENSIVE = 0.1
DEFENSIVE_SCALE = 2.0

#: Total weight of the anchors (one component on each walker the frozen proposal left
#: stuck, :func:`~bayeshyst.inference.warmup.stuck_walkers`), and how many there are at
#: most. Small: an anchor covers a tail or a late-found mode the fitted components miss,
#: where a walker's importance ratio p / q is large; it need not match that region's
#: mass, only bound the ratio, and the bulk keeps nine tenths of the proposal.
ANCHOR_WEIGHT = 0.05
MAX_ANCHORS = 8


def _anchor(draws: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre and scale of a component on one stuck walker's draws ``draws`` (M, d).

    The mean and covariance of its distinct positions when it has enough to give one,
    else its last position with a quarter of the ensemble's covariance ``cov``.
    """
    d = draws.shape[1]
    distinct = np.unique(draws, axis=0)
    if distinct.shape[0] >= 2 * d + 2:
        local = np.cov(distinct.T).reshape(d, d)
        if np.all(np.isfinite(local)) and np.linalg.matrix_rank(local) == d:
            # a hundredth of the ensemble's variances keeps a walker that crept along a
            # narrow ridge from giving a component thinner than the ridge's own width
            return distinct.mean(axis=0), local + 0.01 * np.diag(np.diag(cov))
    return draws[-1].copy(), 0.25 * cov


class IndependenceMove(_StructuredMove):
    """Adaptive independence proposal on ``z_n`` (a mixture of multivariate t).

    ``beta`` is drawn exactly.

    The proposal is one t distribution at the start (the MAP and its Laplace
    covariance); each adaptation re-fits it to the ensemble's draws as a mixture of up
    to three components (chosen by BIC: curved ridges, such as Bouc–Wen's ``beta``–
    ``gamma``–``n`` one on short or misfitting records, are covered by a few ellipsoids
    where one accepts little), plus a defensive component (:data:`DEFENSIVE`): the single
    global fit at twice its width, which keeps the proposal's tails wider than the
    draws'.

    Parameters
    ----------
    target : StructuredTarget
    stats : MoveStats
    mean : ndarray, shape (d,)
        Initial centre (the MAP's ``z_n``).
    cov : ndarray, shape (d, d)
        Initial scale matrix (the Laplace covariance of ``z_n``).
    dof : float
        Degrees of freedom of the t components: heavier tails than the posterior keep
        the importance ratio bounded (a walker is not left stuck where the posterior
        outweighs the proposal). On Bouc–Wen (6 000 samples, 24 walkers) 10 accepted
        82 % (tau 1.9 steps), 30 accepted 87 % (tau 1.4), 200 89 % (tau 1.6); 25 keeps
        most of that gain with tails still well beyond a Gaussian's.
    max_components : int
        Largest number of mixture components an adaptation may choose.
    """

    name = "independence"

    def __init__(self, target: StructuredTarget, stats: MoveStats, mean: np.ndarray,
                 cov: np.ndarray, dof: float = 25.0, max_components: int = 5) -> None:
        super().__init__(target, stats)
        self.dof = float(dof)
        self.max_components = int(max_components)
        self._initial = (np.asarray(mean, float).copy(), np.asarray(cov, float).copy())
        self.set_proposal(*self._initial)

    @staticmethod
    def _factor(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        d = cov.shape[0]
        cov = 0.5 * (cov + cov.T)
        vals, vecs = np.linalg.eigh(cov)
        floor = max(float(vals.max()) * 1e-10, 1e-300) if d else 1.0
        vals = np.maximum(vals, floor)
        chol = np.linalg.cholesky((vecs * vals) @ vecs.T) if d else np.zeros((0, 0))
        # the inverse factor once here: a triangular solve per step costs more in call
        # overhead than the d x d product does in arithmetic
        return chol, (np.linalg.inv(chol) if d else np.zeros((0, 0))), float(np.sum(np.log(vals)))

    def set_proposal(self, mean: np.ndarray, cov: np.ndarray,
                     weights: np.ndarray | None = None) -> None:
        """Set the proposal: one t component or a mixture.

        One component takes ``mean`` (d,) and ``cov`` (d, d); a mixture ``mean`` (K, d),
        ``cov`` (K, d, d) and ``weights`` (K,). Scales are regularised to be positive
        definite.
        """
        means = np.atleast_2d(np.asarray(mean, dtype=float))
        covs = np.asarray(cov, dtype=float).reshape(means.shape[0], means.shape[1],
                                                    means.shape[1])
        self.weights = (np.ones(1) if weights is None
                        else np.asarray(weights, dtype=float) / np.sum(weights))
        self.means = means.copy()
        self.covariances = covs.copy()
        factors = [self._factor(c) for c in covs]
        self.chols = np.array([f[0] for f in factors])
        self._chol_invs = np.array([f[1] for f in factors])
        self._logdets = np.array([f[2] for f in factors])
        self.mean = self.means[int(np.argmax(self.weights))]

    def adapt(self, samples: np.ndarray, stuck: tuple[np.ndarray, ...] = ()) -> None:
        """Re-fit the proposal to posterior draws ``samples`` (M, ndim) of the ensemble.

        Mixtures of 1..``max_components`` Gaussians (1 for d = 1; k only with at least
        ten draws per parameter) are fitted by EM and the one with the lowest BIC is
        kept (components then get t tails), plus the defensive component, plus an anchor
        on each of the first :data:`MAX_ANCHORS` walkers in ``stuck`` (weight
        :data:`ANCHOR_WEIGHT` between them). With fewer than ``2 d + 2`` distinct draws
        the proposal stays as it is.

        Parameters
        ----------
        samples : ndarray, shape (M, ndim)
        stuck : tuple of ndarray, shape (M_i, ndim) each
            The draws of walkers the current proposal held in one place (still or
            trapped, :func:`~bayeshyst.inference.warmup.stuck_walkers`).
        """
        x = np.asarray(samples, float)[:, self.target.other_idx]
        m, d = x.shape
        if m < 2 * d + 2 or not np.all(np.isfinite(x)):
            return
        cov = np.cov(x.T).reshape(d, d)
        if not np.all(np.isfinite(cov)) or np.linalg.matrix_rank(cov) < d:
            return
        best = (np.ones(1), x.mean(axis=0)[None], cov[None])
        n_par = d + d * (d + 1) // 2
        best_bic = math.inf
        for k in range(1, self.max_components + 1 if d >= 2 else 2):
            if m < 10 * k * n_par:
                break
            fit = _fit_mixture(x, k)
            if fit is None:
                continue
            w, mu, cv, ll = fit
            bic = -2.0 * ll + (k * n_par + k - 1) * math.log(m)
            if bic < best_bic:
                best_bic, best = bic, (w, mu, cv)
        w, mu, cv = best
        # defensive component: the global fit, twice as wide (a walker in the tails, where
        # the posterior outweighs the fitted components, is reached and left again)
        anchors = [_anchor(np.asarray(a, float)[:, self.target.other_idx], cov)
                   for a in stuck[:MAX_ANCHORS]]
        share = ANCHOR_WEIGHT if anchors else 0.0
        w = np.concatenate([(1.0 - DEFENSIVE - share) * w, [DEFENSIVE],
                            np.full(len(anchors), share / max(len(anchors), 1))])
        mu = np.vstack([mu, x.mean(axis=0), *[a[0][None] for a in anchors]])
        cv = np.concatenate([cv, (DEFENSIVE_SCALE**2 * cov)[None],
                             *[a[1][None] for a in anchors]])
        self.set_proposal(mu, cv, w)

    def _log_t(self, x: np.ndarray) -> np.ndarray:
        d = self.means.shape[1]
        nu = self.dof
        const = (special.gammaln(0.5 * (nu + d)) - special.gammaln(0.5 * nu)
                 - 0.5 * d * math.log(nu * math.pi))
        parts = []
        for wk, mk, ci, ld in zip(self.weights, self.means, self._chol_invs, self._logdets,
                                  strict=True):
            r = (x - mk) @ ci.T
            m = np.sum(r * r, axis=1)
            parts.append(math.log(wk) + const - 0.5 * ld - 0.5 * (nu + d) * np.log1p(m / nu))
        return _logsumexp_columns(np.array(parts))

    def propose(self, model: Any, state: State) -> tuple[State, np.ndarray]:
        """One independence proposal per walker, completed with an exact draw of ``beta``.

        ``z_n`` is drawn from the t mixture, the linear block from its conditional given the
        proposed ``z_n``; the MH ratio includes both proposal densities.

        Parameters
        ----------
        model : emcee model
            The sampler's interface to the moves; only its ``random`` state is used.
        state : emcee.State
            Current coordinates (W, ndim) and log posteriors (W,).

        Returns
        -------
        state : emcee.State
            The new coordinates and log posteriors.
        accepted : ndarray of bool, shape (W,)
            Walkers that moved.
        """
        random = model.random
        z = np.array(state.coords, dtype=float)
        lp = np.array(state.log_prob, dtype=float)
        w, d = z.shape[0], self.means.shape[1]
        comp = (np.searchsorted(np.cumsum(self.weights), random.rand(w) * self.weights.sum())
                if self.weights.size > 1 else np.zeros(w, dtype=int))
        comp = np.minimum(comp, self.weights.size - 1)
        g = random.standard_normal((w, d))
        chi = random.chisquare(self.dof, size=w)
        step = np.einsum("wij,wj->wi", self.chols[comp], g)
        x = self.means[comp] + step / np.sqrt(chi / self.dof)[:, None]
        z_prop = z.copy()
        z_prop[:, self.target.other_idx] = x
        z_new, lp_new, lq_new = self.target.complete(z_prop, random)
        lq_old = self.target.log_q_current(z)
        with np.errstate(invalid="ignore"):  # -inf - -inf: a rejected proposal (NaN)
            log_r = (lp_new - lp + lq_old - lq_new
                     + self._log_t(z[:, self.target.other_idx]) - self._log_t(x))
        acc = _accept(log_r, random) & np.isfinite(lp_new)
        self.stats.add(self.name, w, int(np.count_nonzero(acc)))
        z = np.where(acc[:, None], z_new, z)
        lp = np.where(acc, lp_new, lp)
        return State(z, log_prob=lp, blobs=None, random_state=state.random_state), acc


class DifferentialMove(_StructuredMove):
    """Differential evolution on ``z_n`` (red-blue halves), ``beta`` drawn exactly.

    Parameters
    ----------
    target : StructuredTarget
    stats : MoveStats
    jump : float
        Probability of a unit step ``gamma = 1`` (a jump between modes) instead of
        ``gamma = 2.38 / sqrt(2 d)``.
    """

    name = "differential"

    def __init__(self, target: StructuredTarget, stats: MoveStats, jump: float = 0.1) -> None:
        super().__init__(target, stats)
        self.jump = float(jump)

    def propose(self, model: Any, state: State) -> tuple[State, np.ndarray]:
        """One differential-evolution step per walker, completed with an exact draw of ``beta``.

        The walkers are split into two random halves; each walker of one half moves by
        ``gamma`` times the difference of two distinct walkers of the other half
        (``gamma = 1`` with probability ``jump``), then the other half moves the same way.

        Parameters
        ----------
        model : emcee model
            The sampler's interface to the moves; only its ``random`` state is used.
        state : emcee.State
            Current coordinates (W, ndim) and log posteriors (W,).

        Returns
        -------
        state : emcee.State
            The new coordinates and log posteriors.
        accepted : ndarray of bool, shape (W,)
            Walkers that moved.
        """
        random = model.random
        z = np.array(state.coords, dtype=float)
        lp = np.array(state.log_prob, dtype=float)
        w = z.shape[0]
        idx = self.target.other_idx
        d = idx.size
        g0 = 2.38 / math.sqrt(2.0 * max(d, 1))
        halves = np.arange(w) % 2
        random.shuffle(halves)
        accepted = np.zeros(w, dtype=bool)
        for half in (0, 1):
            act = np.flatnonzero(halves == half)
            comp = np.flatnonzero(halves != half)
            if act.size == 0 or comp.size < 2:
                continue
            a = random.randint(comp.size, size=act.size)
            b = (a + 1 + random.randint(comp.size - 1, size=act.size)) % comp.size
            gamma = np.where(random.rand(act.size) < self.jump, 1.0,
                             g0 * (1.0 + 1e-5 * random.randn(act.size)))
            diff = z[comp[a]][:, idx] - z[comp[b]][:, idx]
            z_prop = z[act].copy()
            z_prop[:, idx] += gamma[:, None] * diff
            z_new, lp_new, lq_new = self.target.complete(z_prop, random)
            lq_old = self.target.log_q_current(z[act])
            with np.errstate(invalid="ignore"):  # -inf - -inf: a rejected proposal (NaN)
                log_r = lp_new - lp[act] + lq_old - lq_new
            acc = _accept(log_r, random) & np.isfinite(lp_new)
            z[act] = np.where(acc[:, None], z_new, z[act])
            lp[act] = np.where(acc, lp_new, lp[act])
            accepted[act] = acc
        self.stats.add(self.name, w, int(np.count_nonzero(accepted)))
        return State(z, log_prob=lp, blobs=None, random_state=state.random_state), accepted


def structured_moves(target: StructuredTarget, stats: MoveStats, mean: np.ndarray,
                     cov: np.ndarray) -> tuple[list[tuple[emcee.moves.Move, float]],
                                               IndependenceMove | None]:
    """The weighted move list of one ensemble, and its adaptive independence move.

    With a linear block whose design depends on the proposed coordinates (a simulation
    per proposal): Gibbs 0.05, independence 0.85, differential evolution 0.1 — every
    accepted independence or differential-evolution proposal draws the block afresh,
    so the Gibbs move only refreshes it and the noise between them, at no simulation
    cost. With a constant design (PI weights with fixed thresholds: no move simulates)
    the Gibbs move's noise updates are as cheap as the others and mix the noise scale
    and AR(1) coefficient along their ridge: Gibbs 0.5, independence 0.35, differential
    evolution 0.15. Without a linear block: independence 0.75, differential evolution
    0.25. The Gibbs move alone when nothing but the linear block is free.

    Parameters
    ----------
    target : StructuredTarget
    stats : MoveStats
        Shared by the ensemble's moves.
    mean, cov : ndarray
        Initial centre (d,) and scale (d, d) of the independence proposal on ``z_n``.
    """
    s = target.structure
    if target.n_other == 0:
        return [(LinearGibbsMove(target, stats), 1.0)], None
    indep = IndependenceMove(target, stats, mean, cov)
    de = DifferentialMove(target, stats)
    if s is None:
        return [(indep, 0.75), (de, 0.25)], indep
    gibbs = LinearGibbsMove(target, stats)
    if s.design_idx.size == 0:
        return [(gibbs, 0.5), (indep, 0.35), (de, 0.15)], indep
    return [(gibbs, 0.05), (indep, 0.85), (de, 0.1)], indep
