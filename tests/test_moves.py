"""The structured sampler: exact linear-block draws, invariant moves, known posteriors.

Oracles: the conjugate Gaussian posterior of PI weights (closed form, and for AR(1) noise
a dense whitening written here), the marginal posterior of the noise parameters by grid
integration of the exact evidence, and known target densities (a correlated Gaussian,
a banana) for the moves on their own.
"""

from __future__ import annotations

import math

import emcee
import numpy as np
import pytest
from scipy import stats

from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.convergence import integrated_time
from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.moves import ANCHOR_WEIGHT, DifferentialMove, IndependenceMove
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inference.structured_target import MoveStats, StructuredTarget
from bayeshyst.models import get, names
from bayeshyst.threads import single_threaded_blas
from tests.synthetic import pi_data


# ----------------------------------------------------------------------- oracles
def _dense_gls(post: Posterior, sigma: float, phi: float) -> tuple[np.ndarray, np.ndarray,
                                                                   float]:
    """Posterior mean, covariance and log evidence of ``[p0, w, offset]`` for AR(1) noise
    of marginal sd ``sigma`` and coefficient ``phi``, by a dense whitening matrix (slow,
    independent of the library's Gram algebra)."""
    (rec,) = post.data
    s0 = rec.scored.start or 0
    thresholds = dict(post.model_space.fixed)
    x = post.model.regressors(rec.u, rec.t, thresholds)[s0:]
    x = np.column_stack([x, np.ones(x.shape[0])])
    y = rec.y[s0:]
    n = y.size
    # L e is white with unit variance: row 0 = e_0 / sigma, row k = (e_k - phi e_k-1) / s
    s = sigma * math.sqrt(1.0 - phi**2)
    lw = np.zeros((n, n))
    lw[0, 0] = 1.0 / sigma
    for k in range(1, n):
        lw[k, k] = 1.0 / s
        lw[k, k - 1] = -phi / s
    xw, yw = lw @ x, lw @ y
    names = ["p0", "w", "obs.offset"]
    m0 = np.concatenate([np.full(post.space[nm].size, post.space[nm].prior.mu) for nm in names])
    sd0 = np.concatenate([np.full(post.space[nm].size, post.space[nm].prior.sigma)
                          for nm in names])
    prec = np.diag(1 / sd0**2) + xw.T @ xw
    cov = np.linalg.inv(prec)
    mean = cov @ (m0 / sd0**2 + xw.T @ yw)
    # evidence: y ~ N(X m0, Sigma + X S0 X^T), Sigma^-1 = L^T L
    sig_inv = lw.T @ lw
    c = np.linalg.inv(sig_inv) + x @ np.diag(sd0**2) @ x.T
    r = y - x @ m0
    _, logdet = np.linalg.slogdet(c)
    log_ev = -0.5 * (r @ np.linalg.solve(c, r) + logdet + n * math.log(2 * math.pi))
    return mean, cov, float(log_ev)


def _ar1_record(n=500, phi=0.8, sigma=0.05, seed=0):
    model, rec, theta = pi_data(n_ops=2, n=n, sigma=sigma, seed=seed, warmup=50)
    rng = np.random.default_rng(seed + 100)
    e = np.empty(n)
    e[0] = sigma * rng.standard_normal()
    for k in range(1, n):
        e[k] = phi * e[k - 1] + sigma * math.sqrt(1 - phi**2) * rng.standard_normal()
    clean = model.simulate(rec.u, rec.t, theta) + 0.4  # pi_data's offset
    from bayeshyst.data import Record

    return model, Record(t=rec.t, u=rec.u, y=clean + e, name="ar", warmup=50,
                         metadata={"frequency_hz": 3.0})


def _check_moments(draws: np.ndarray, mean: np.ndarray, cov: np.ndarray, ess: float) -> None:
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_array_less(np.abs(draws.mean(axis=0) - mean), 5 * sd / np.sqrt(ess))
    np.testing.assert_allclose(draws.std(axis=0, ddof=1), sd, rtol=0.1)
    corr = np.corrcoef(draws.T)
    np.testing.assert_allclose(corr, cov / np.outer(sd, sd), atol=0.05)


# ----------------------------------------------------------------- the linear block
def test_linear_design_reproduces_every_linear_model_and_composite():
    rng = np.random.default_rng(0)
    t = np.arange(1500) * 1e-3
    u = 75 + 60 * np.sin(2 * np.pi * 2 * t) * np.exp(-0.3 * t)
    from bayeshyst.data import Record

    rec = Record(t=t, u=u, y=0.2 * u, name="x")
    # every registered model that declares a linear group (from the registry, so a new
    # one cannot be missed), then compositions
    linear = [n for n in names() if getattr(get(n), "linear_params", ())]
    assert {"pi_play", "duhem_improved", "maxwell_slip", "bouc_wen"} <= set(linear)
    specs = [*linear, "pi_play(n_operators=3)+second_order", "pi_play+arx",
             "bouc_wen+creep+drift+delay", "pi_play+creep_fractional",
             # a block's own coefficients as the group, last or before an affine block
             "bouc_wen+creep+unexplained", "pi_play(n_operators=3)+unexplained+creep"]
    for spec in specs:
        model = get(spec)
        space = model.param_space(rec)
        theta = space.unpack(space.sample_prior(rng, 4))
        design = model.linear_design(u, t, theta)
        traj = model.run_batch(u, t, theta)
        beta = np.concatenate([np.asarray(theta[n]).reshape(4, -1) for n in design.names],
                              axis=1)
        ok = ~traj.failed
        np.testing.assert_array_equal(design.failed, traj.failed, err_msg=spec)
        scale = np.ptp(traj.y[ok])
        np.testing.assert_allclose(design.predict(beta)[ok], traj.y[ok], rtol=0,
                                   atol=1e-12 * scale, err_msg=spec)
    assert get("bouc_wen+asym_output").linear_params == ()  # an output map is not affine


def test_the_larger_of_the_base_and_a_block_group_is_the_linear_block():
    # the base's group needs every block affine, a block's group every later block; the
    # two are bilinear, so one is chosen: the larger, the base on a tie
    m = get("bouc_wen+creep+unexplained")  # k (1) against 2 x 6 coefficients
    assert m.linear_group == (1, ("unexplained.a", "unexplained.b"))
    m = get("pi_play(n_operators=15)+unexplained")  # p0 + 15 weights against 12
    assert m.linear_group == (-1, ("static.p0", "static.w"))
    m = get("pi_play(n_operators=11)+unexplained")  # 12 against 12: the base
    assert m.linear_group[0] == -1
    m = get("bouc_wen+unexplained+asym_output")  # nothing affine after either
    assert m.linear_group == (None, ()) and m.linear_params == ()


@pytest.mark.parametrize("likelihood", ["gaussian", "ar1"])
@pytest.mark.parametrize("spec", ["pi_play(n_operators=3)", "bouc_wen",
                                  "pi_play(n_operators=2)+second_order",
                                  "bouc_wen+unexplained"])
def test_structure_likelihood_matches_the_simulated_one(spec, likelihood):
    _, rec, _ = pi_data(n_ops=3, n=800)
    post = Posterior(rec, spec, likelihood)
    s = LinearStructure(post)
    z = post.space.sample_prior(np.random.default_rng(1), 8)
    ref = post.log_prob_batch(z) - post.space.log_prior(z)
    ok = np.isfinite(ref)
    assert ok.sum() >= 4
    for point in (None, z[np.flatnonzero(ok)[0]]):  # centred at the prior mean, at a point
        if point is not None:
            s.set_reference(point)
        got = s.log_likelihood(s.stats(z), z)
        np.testing.assert_allclose(got[ok], ref[ok], rtol=1e-9)
        assert np.all(got[~ok] == -np.inf)


@pytest.mark.parametrize("spec, discrepancy", [
    ("pi_play(n_operators=2)+second_order", None), ("bouc_wen", None),
    ("bouc_wen+creep+unexplained", None),
    # with a discrepancy's basis: per-walker designs, and a design shared by the walkers
    ("pi_play(n_operators=2)+second_order", "hsgp"), ("bouc_wen", "hsgp")])
@pytest.mark.parametrize("likelihood", ["gaussian", "ar1"])
def test_structure_statistics_do_not_depend_on_the_batch(spec, discrepancy, likelihood):
    # cached Grams and recomputed ones must agree to the bit (resume identity); Bouc-Wen's
    # design [u, 1] is shared by the walkers (another code path). The sampler computes
    # them with one BLAS thread (sample_posterior), which is what makes them bitwise
    # independent of the batch: a threaded BLAS splits a product by its size (the
    # discrepancy's basis products then differ in the last bits), so the test runs
    # under the same condition, also outside xdist, whose workers are single-threaded.
    _, rec, _ = pi_data(n_ops=2, n=800)
    post = Posterior(rec, spec, likelihood, discrepancy=discrepancy)
    z = post.space.sample_prior(np.random.default_rng(2), 7)
    with single_threaded_blas():
        whole = LinearStructure(post)._compute(z)
        alones = [LinearStructure(post)._compute(z[j:j + 1]) for j in range(7)]
    for j, alone in enumerate(alones):
        for a, b in ((whole.first, alone.first), (whole.lag0, alone.lag0),
                     (whole.cross, alone.cross), (whole.prev, alone.prev)):
            if a is None:  # the lag-one products exist for AR(1) noise only
                assert b is None and likelihood == "gaussian"
                continue
            np.testing.assert_array_equal(a[j], b[0])


def test_walkers_that_overflow_are_failed_quietly_and_the_rest_unchanged():
    # a natural frequency near the float limit (2 pi f_n overflows) and a design whose
    # products overflow: both walkers get -inf, counted as failed, with no numpy warning
    # reaching the user; the other walkers' values are those of a batch without them
    import warnings

    _, rec, _ = pi_data(n_ops=2, n=600)
    post = Posterior(rec, "pi_play(n_operators=2)+second_order")
    z = post.space.sample_prior(np.random.default_rng(5), 4)
    z[1, post.space.slice_of("second_order.f_n")] = 709.5
    s = LinearStructure(post)
    rows, failed = s.designs(z)
    huge = [(phi.copy(), const) for phi, const in rows]
    for phi, _ in huge:
        phi[2] *= 1e300
        phi[2, :, 0] *= -1.0  # opposite signs: inf - inf in the sums, not only inf
    keep = [0, 3]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lp = post.log_prob_batch(z)
        st = s._stats_of(huge, failed.copy())
        lm = s.log_marginal(st, z)
    assert lp[1] == -np.inf and post.counts.failed >= 1
    assert np.all(np.isneginf(lm[[1, 2]]))
    ref = LinearStructure(post)
    np.testing.assert_array_equal(lm[keep], ref.log_marginal(ref.stats(z[keep]), z[keep]))
    assert np.all(np.isfinite(lm[keep]))


def test_statistics_cache_keeps_every_walker_of_a_call_when_it_trims(monkeypatch):
    # more distinct walkers than the cache holds, mixed with cached ones: every lookup
    # must find its walker, and cached values equal a fresh computation
    import bayeshyst.inference.linear as L

    monkeypatch.setattr(L, "_CACHE_SIZE", 4)
    _, rec, _ = pi_data(n_ops=2, n=600)
    post = Posterior(rec, "pi_play(n_operators=2)+second_order")
    s = LinearStructure(post)
    z = post.space.sample_prior(np.random.default_rng(5), 9)
    s.stats(z[:3])
    for batch in (z[[0, 5, 1, 6, 7, 2]], z[[8, 0, 3, 4]], z):
        got = s.stats(batch)
        ref = LinearStructure(post)._compute(batch)
        np.testing.assert_array_equal(got.lag0, ref.lag0)
        assert len(s._cache) <= 4


def test_conditional_and_marginal_are_the_conjugate_posterior():
    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    post = Posterior(rec, model).fix("noise.sigma", 0.05)
    exact = conjugate_posterior(post)
    s = LinearStructure(post)
    z = post.space.sample_prior(np.random.default_rng(3), 1)
    st = s.stats(z)
    cond = s.conditional(st, z)
    np.testing.assert_allclose(cond.mean[0], exact.mean, rtol=0, atol=1e-6 * exact.sd.min())
    cov = np.linalg.inv(cond.chol[0] @ cond.chol[0].T)
    np.testing.assert_allclose(cov, exact.cov, rtol=1e-8, atol=1e-14)
    assert s.log_marginal(st, z)[0] == pytest.approx(exact.log_evidence, rel=1e-10)


def test_ar1_conditional_and_marginal_match_a_dense_whitening():
    model, rec = _ar1_record()
    post = Posterior(rec, model, "ar1").fix("noise.sigma", 0.05).fix("noise.phi", 0.8)
    mean, cov, log_ev = _dense_gls(post, 0.05, 0.8)
    s = LinearStructure(post)
    z = post.space.sample_prior(np.random.default_rng(4), 1)
    st = s.stats(z)
    cond = s.conditional(st, z)
    np.testing.assert_allclose(cond.mean[0], mean, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(cond.chol[0] @ cond.chol[0].T), cov, rtol=1e-6,
                               atol=1e-14)
    assert s.log_marginal(st, z)[0] == pytest.approx(log_ev, rel=1e-9)


# ------------------------------------------------------------ the Gibbs move alone
def test_gibbs_move_alone_reproduces_the_conjugate_posterior_gaussian():
    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    post = Posterior(rec, model).fix("noise.sigma", 0.05)
    exact = conjugate_posterior(post)
    res = sample_posterior(post, SamplerSettings(seed=2, max_steps=2000))
    assert res.converged, res.convergence
    assert set(res.move_acceptance) == {"gibbs_linear"}  # nothing else is free
    _check_moments(res.flat_z, exact.mean, exact.cov, res.convergence.ess_bulk_min)


def test_gibbs_move_alone_reproduces_the_conjugate_posterior_ar1():
    model, rec = _ar1_record()
    post = Posterior(rec, model, "ar1").fix("noise.sigma", 0.05).fix("noise.phi", 0.8)
    mean, cov, _ = _dense_gls(post, 0.05, 0.8)
    res = sample_posterior(post, SamplerSettings(seed=3, max_steps=2000))
    assert res.converged, res.convergence
    assert set(res.move_acceptance) == {"gibbs_linear"}
    _check_moments(res.flat_z, mean, cov, res.convergence.ess_bulk_min)


def _log_evidence_ar1(x: np.ndarray, y: np.ndarray, m0: np.ndarray, sd0: np.ndarray,
                      sigma: float, phi: float) -> float:
    """``log p(y | sigma, phi)`` with ``beta ~ N(m0, diag(sd0^2))`` integrated out, by
    explicit whitening of the rows and the matrix determinant lemma."""
    s = sigma * math.sqrt(1.0 - phi**2)
    xw = np.vstack([x[:1] / sigma, (x[1:] - phi * x[:-1]) / s])
    yw = np.concatenate([y[:1] / sigma, (y[1:] - phi * y[:-1]) / s])
    n = y.size
    log_l = -math.log(sigma) - (n - 1) * math.log(s)  # log |L|
    r = yw - xw @ m0
    a = np.diag(1 / sd0**2) + xw.T @ xw
    b = xw.T @ r
    quad = r @ r - b @ np.linalg.solve(a, b)
    logdet = np.linalg.slogdet(a)[1] + 2 * np.sum(np.log(sd0))
    return float(-0.5 * (quad + logdet + n * math.log(2 * math.pi)) + log_l)


def _grid_moments(logp: np.ndarray, axes: list[np.ndarray]) -> list[tuple[float, float]]:
    w = np.exp(logp - logp.max())
    w /= w.sum()
    out = []
    for d, ax in enumerate(axes):
        marg = w.sum(axis=tuple(i for i in range(len(axes)) if i != d))
        m = float(np.sum(marg * ax))
        out.append((m, float(np.sqrt(np.sum(marg * (ax - m) ** 2)))))
    return out


def test_noise_posterior_matches_grid_integration_of_the_exact_evidence():
    # sigma and phi free, the weights integrated out exactly: the marginal posterior of
    # (sigma, phi) on a grid is the oracle for every move of the structured sampler
    model, rec = _ar1_record(n=400, phi=0.7, sigma=0.05, seed=1)
    post = Posterior(rec, model, "ar1")
    s0 = rec.scored.start or 0
    x = model.regressors(rec.u, rec.t, dict(post.model_space.fixed))[s0:]
    x = np.column_stack([x, np.ones(x.shape[0])])
    names = ["p0", "w", "obs.offset"]
    m0 = np.concatenate([np.full(post.space[nm].size, post.space[nm].prior.mu) for nm in names])
    sd0 = np.concatenate([np.full(post.space[nm].size, post.space[nm].prior.sigma)
                          for nm in names])
    sp, pp = post.space["noise.sigma"], post.space["noise.phi"]
    # the dense oracle agrees with this faster one at a point
    assert _log_evidence_ar1(x, rec.y[s0:], m0, sd0, 0.05, 0.7) == pytest.approx(
        _dense_gls(post, 0.05, 0.7)[2], rel=1e-8)
    sig = np.linspace(0.035, 0.075, 81)
    phi = np.linspace(0.45, 0.9, 81)
    logp = np.array([[_log_evidence_ar1(x, rec.y[s0:], m0, sd0, s_, p_)
                      + float(sp.prior.logpdf(s_)) + float(pp.prior.logpdf(p_))
                      for p_ in phi] for s_ in sig])
    i, j = np.unravel_index(logp.argmax(), logp.shape)
    assert 5 < i < sig.size - 5 and 5 < j < phi.size - 5  # the grid holds the mass
    (ms, ss), (mp, sp_) = _grid_moments(logp, [sig, phi])
    res = sample_posterior(post, SamplerSettings(seed=4, max_steps=4000))
    assert res.converged, res.convergence
    th = res.theta()
    ess = res.convergence.ess_bulk_min
    for v, m, s in ((th["noise.sigma"], ms, ss), (th["noise.phi"], mp, sp_)):
        assert abs(np.mean(v) - m) < 5 * s / math.sqrt(ess)
        assert np.std(v, ddof=1) == pytest.approx(s, rel=0.1)
    assert {"gibbs_linear", "gibbs_sigma", "gibbs_phi", "independence",
            "differential"} <= set(res.move_acceptance)


# ------------------------------------------------------------ moves on known targets
class _Density:
    """A target density with the two things the moves need from a posterior."""

    def __init__(self, ndim, log_density):
        self.ndim = ndim
        self._f = log_density

    def log_prob_batch(self, z):
        return self._f(np.atleast_2d(z))

    def record_counts(self, *args):
        pass


def _run_move(density, move_factory, seed, n_walkers=24, steps=3000, burn=300):
    """Draws of one move on its own, thinned by 3 autocorrelation times (the K-S tests
    assume independent draws; a wider-than-target independence proposal accepts little
    and its chain is correlated over several steps)."""
    target = StructuredTarget(density, None)
    move = move_factory(target)
    sampler = emcee.EnsembleSampler(n_walkers, density.ndim, density.log_prob_batch,
                                    vectorize=True, moves=[(move, 1.0)])
    rng = np.random.default_rng(seed)
    sampler.random_state = np.random.RandomState(seed).get_state()
    p0 = rng.standard_normal((n_walkers, density.ndim))
    sampler.run_mcmc(p0, steps, skip_initial_state_check=True)
    chain = sampler.get_chain()[burn:]
    thin = max(1, math.ceil(3 * float(np.max(integrated_time(chain)))))
    draws = chain[::thin].reshape(-1, density.ndim)
    assert draws.shape[0] >= 1000, f"too few independent draws ({draws.shape[0]})"
    return draws


def _gaussian6():
    rng = np.random.default_rng(7)
    a = rng.standard_normal((6, 6))
    cov = a @ a.T / 6 + 0.2 * np.eye(6)
    mean = np.arange(6.0)
    prec = np.linalg.inv(cov)

    def f(z):
        d = z - mean
        return -0.5 * np.einsum("wi,ij,wj->w", d, prec, d)

    return _Density(6, f), mean, cov


def _banana(a=1.0, b=0.5):
    def f(z):
        x1, x2 = z[:, 0], z[:, 1]
        return -0.5 * (x1 / a) ** 2 - 0.5 * (x2 - b * (x1**2 - a**2)) ** 2

    return _Density(2, f)


def _movers(mean, cov):
    return {
        # a deliberately wrong proposal (shifted by 0.3 sd, 1.3 times too wide, as an
        # adapted one may be): without the MH correction the draws would follow it
        "independence": lambda t: IndependenceMove(
            t, MoveStats(), mean + 0.3 * np.sqrt(np.diag(cov)), cov * 1.3**2),
        "differential": lambda t: DifferentialMove(t, MoveStats()),
    }


@pytest.mark.parametrize("which", ["independence", "differential"])
@pytest.mark.parametrize("seed", [0, 1])
def test_moves_leave_a_correlated_gaussian_invariant(which, seed):
    density, mean, cov = _gaussian6()
    draws = _run_move(density, _movers(mean, cov)[which], seed, steps=8000)
    sd = np.sqrt(np.diag(cov))
    for d in range(6):
        assert stats.kstest((draws[:, d] - mean[d]) / sd[d], "norm").pvalue > 1e-3, d
    # and the correlations (a product of wrong marginals would pass the K-S tests)
    np.testing.assert_allclose(np.corrcoef(draws.T), cov / np.outer(sd, sd), atol=0.08)


@pytest.mark.parametrize("which", ["independence", "differential"])
@pytest.mark.parametrize("seed", [0, 1])
def test_moves_leave_a_banana_invariant(which, seed):
    density = _banana()
    # x1 ~ N(0, 1); x2 - b (x1^2 - a^2) ~ N(0, 1), independent of x1
    mover = _movers(np.zeros(2), np.array([[1.0, 0.0], [0.0, 1.6]]))[which]
    draws = _run_move(density, mover, seed, steps=4000)
    assert stats.kstest(draws[:, 0], "norm").pvalue > 1e-3
    assert stats.kstest(draws[:, 1] - 0.5 * (draws[:, 0] ** 2 - 1.0), "norm").pvalue > 1e-3


def test_stuck_walkers_get_anchor_components_of_their_own_spread():
    density, mean, cov = _gaussian6()
    move = IndependenceMove(StructuredTarget(density, None), MoveStats(), mean, cov)
    rng = np.random.default_rng(5)
    bulk = rng.multivariate_normal(mean, cov, size=4000)
    # one walker that crept about a far point (enough distinct positions for a local
    # covariance), one that never moved (a single position)
    crept = np.repeat(mean + 6.0 + 0.1 * rng.standard_normal((40, 6)), 5, axis=0)
    frozen = np.repeat((mean - 5.0)[None], 200, axis=0)
    move.adapt(bulk)
    n_fit = move.weights.size
    move.adapt(bulk, (crept, frozen))
    assert move.weights.size == n_fit + 2
    np.testing.assert_allclose(move.weights.sum(), 1.0)
    np.testing.assert_allclose(move.weights[-2:], [ANCHOR_WEIGHT / 2] * 2)
    distinct = np.unique(crept, axis=0)
    np.testing.assert_allclose(move.means[-2], distinct.mean(axis=0))
    np.testing.assert_allclose(move.covariances[-2], np.cov(distinct.T)
                               + 0.01 * np.diag(np.diag(np.cov(bulk.T))))
    np.testing.assert_allclose(move.means[-1], mean - 5.0)
    np.testing.assert_allclose(move.covariances[-1], 0.25 * np.cov(bulk.T))
    # the proposal density at the stuck points rose by at least the anchor's own mass
    # there (the oracle: the t component's density at its centre, from scipy)
    t_peak = stats.multivariate_t(loc=mean - 5.0, shape=0.25 * np.cov(bulk.T),
                                  df=move.dof).logpdf(mean - 5.0)
    assert move._log_t((mean - 5.0)[None])[0] >= math.log(ANCHOR_WEIGHT / 2) + t_peak - 1e-9


def test_the_column_logsumexp_is_scipys_including_columns_of_minus_infinity():
    from scipy import special

    from bayeshyst.inference.moves import _logsumexp_columns

    rng = np.random.default_rng(3)
    a = 800 * rng.standard_normal((4, 50))  # far beyond exp's range: the shift matters
    a[:, 3] = -np.inf
    a[:2, 7] = -np.inf
    np.testing.assert_allclose(_logsumexp_columns(a), special.logsumexp(a, axis=0),
                               rtol=1e-14, atol=0)
