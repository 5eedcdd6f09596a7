"""The structured moves' warm-up: the window divergence and when the proposal is frozen."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy import stats

from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.optimize import MAPResult, find_map
from bayeshyst.inference.posterior import EvalCounts, Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inference.warmup import (
    MIN_MOVE_RATE,
    MIN_STUCK_WINDOW,
    SETTLED_KL,
    keep_adapting,
    stuck_walkers,
    window_divergence,
)
from bayeshyst.params.priors import Normal
from bayeshyst.params.space import Param, ParamSpace
from tests.synthetic import pi_data


def _gaussian(rng, n, mean, cov):
    return rng.multivariate_normal(mean, cov, size=n)


def test_window_divergence_is_the_kl_of_the_two_fitted_gaussians():
    # oracle: KL(N1 || N0) by Monte Carlo, E_1[log N1(x) - log N0(x)] with scipy's
    # densities at the two samples' own fitted means and covariances (no closed form)
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 3))
    cov0 = a @ a.T + np.eye(3)
    cov1 = 1.7 * cov0 + 0.3 * np.eye(3)
    old = _gaussian(rng, 20_000, np.zeros(3), cov0)
    new = _gaussian(rng, 20_000, np.array([0.5, -0.2, 0.1]), cov1)
    f1 = stats.multivariate_normal(new.mean(axis=0), np.cov(new.T))
    f0 = stats.multivariate_normal(old.mean(axis=0), np.cov(old.T))
    x = f1.rvs(size=400_000, random_state=rng)
    mc = np.mean(f1.logpdf(x) - f0.logpdf(x))
    se = np.std(f1.logpdf(x) - f0.logpdf(x)) / math.sqrt(x.shape[0])
    assert abs(window_divergence(new, old) - mc) < 5 * se
    # identical samples agree exactly; the divergence is not symmetric
    assert window_divergence(old, old) == pytest.approx(0.0, abs=1e-12)
    assert window_divergence(new, old) != pytest.approx(window_divergence(old, new), rel=0.05)


def test_under_the_null_the_divergence_is_its_sampling_bias_and_short_windows_are_unsettled():
    # two samples of one Gaussian: 2 KL / (1/n1 + 1/n2) is asymptotically chi-square with
    # p = d + d (d + 1) / 2 degrees of freedom (the fitted means and covariances); its
    # mean over 40 seeds has sd sqrt(2 p / 40), and 4 of those is the tolerance
    d, n1, n2 = 4, 4000, 2000
    p = d + d * (d + 1) // 2
    scaled = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        kl = window_divergence(rng.standard_normal((n1, d)), rng.standard_normal((n2, d)))
        scaled.append(2 * kl / (1 / n1 + 1 / n2))
    assert abs(np.mean(scaled) - p) < 4 * math.sqrt(2 * p / 40)
    # so a window with too few draws to tell reads as not settled (the bias alone is
    # p (1/n1 + 1/n2) / 2 = 0.47 nats at 30 + 30 draws): in 40 seeds at most one reads as
    # settled (the chi-square's lower tail at 0.1 nats is below 1e-4)
    settled = sum(window_divergence(np.random.default_rng(s).standard_normal((30, d)),
                                    np.random.default_rng(100 + s).standard_normal((30, d)))
                  < SETTLED_KL for s in range(40))
    assert settled <= 1


def test_draws_that_cannot_give_a_covariance_never_read_as_settled():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((500, 3))
    stuck = x.copy()
    stuck[:, 1] = 0.25  # a coordinate no walker moves
    assert window_divergence(stuck, x) == math.inf
    assert window_divergence(x, stuck) == math.inf
    assert window_divergence(x[:3], x) == math.inf  # fewer draws than coordinates
    assert window_divergence(np.zeros((10, 0)), np.zeros((10, 0))) == 0.0
    # reported in words, not as a number
    chains = [np.repeat(stuck[:200].reshape(200, 1, 3), 4, axis=1)]
    d = keep_adapting(chains, np.arange(3), 50, 100, -math.inf)
    assert d.refit and "inf" not in str(d) and "not measurable" in str(d)


def _chains(rng, steps, walkers, scale_of_step, move_prob=1.0):
    """Walkers drawing N(0, s(t)^2 I) afresh with probability ``move_prob`` per step."""
    out = np.empty((steps, walkers, 2))
    out[0] = rng.standard_normal((walkers, 2)) * scale_of_step(0)
    for t in range(1, steps):
        moved = rng.random(walkers) < move_prob
        fresh = rng.standard_normal((walkers, 2)) * scale_of_step(t)
        out[t] = np.where(moved[:, None], fresh, out[t - 1])
    return out


@pytest.mark.parametrize("seed", range(5))
def test_the_warm_up_goes_on_while_the_ensemble_spreads_and_freezes_once_settled(seed):
    rng = np.random.default_rng(seed)
    idx = np.arange(2)
    # walkers started narrow that keep spreading (width doubling every 100 steps), with
    # a proposal that moves all of them: the old rule froze here at the first extension
    spread = [_chains(rng, 200, 40, lambda t: 0.1 * 2 ** (t / 100)) for _ in range(2)]
    d = keep_adapting(spread, idx, 50, 100, -math.inf)
    assert d.refit and d.divergence > SETTLED_KL and d.move_rate > MIN_MOVE_RATE
    # settled, and the proposal moves most walkers: frozen
    still = [_chains(rng, 200, 40, lambda t: 1.0) for _ in range(2)]
    d = keep_adapting(still, idx, 50, 100, -math.inf)
    assert not d.refit and d.divergence < SETTLED_KL
    assert str(d).startswith("freeze: move rate") and "nats" in str(d)
    # settled but the proposal moves few walkers: go on while a re-fit raised the rate
    slow = [_chains(rng, 400, 40, lambda t: 1.0, move_prob=0.3) for _ in range(2)]
    assert keep_adapting(slow, idx, 100, 200, 0.1).refit
    assert not keep_adapting(slow, idx, 100, 200, 0.28).refit


def test_walkers_started_far_too_narrow_still_reach_the_posterior():
    # oracle: the conjugate posterior of the PI weights at known sigma, tempered
    # (beta = 1/2, so every coordinate is the independence move's and none is drawn
    # exactly; the posterior is the Gaussian one with sigma / sqrt(beta)). The walkers
    # start at 2 % of the posterior sd around its mean, as a candidate's walkers carried
    # from a smaller model start narrower than the larger model's posterior. A proposal
    # fitted to them early and frozen leaves the walkers that reach the tails stuck there
    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    fixed = Posterior(rec, model, beta=0.5).fix("noise.sigma", 0.05)
    exact = conjugate_posterior(Posterior(rec, model).fix("noise.sigma", 0.05 / math.sqrt(0.5)))
    start = find_map(fixed, seed=0, global_search=False, n_screen=64, n_starts=1)
    rng = np.random.default_rng(3)
    chol = np.linalg.cholesky(exact.cov)
    walkers = exact.mean + 0.02 * rng.standard_normal((64, exact.mean.size)) @ chol.T
    res = sample_posterior(fixed, SamplerSettings(seed=4, max_steps=8000, first_chunk=1000),
                           start=start, initial=walkers)
    assert res.converged, res.convergence
    draws = res.flat_z
    se = exact.sd / np.sqrt(res.convergence.ess_bulk_min)
    np.testing.assert_array_less(np.abs(draws.mean(axis=0) - exact.mean), 5 * se)
    np.testing.assert_allclose(draws.std(axis=0, ddof=1), exact.sd, rtol=0.1)


# ------------------------------------------------------------ walkers a frozen proposal holds
def test_a_walker_that_holds_still_is_found_and_free_walkers_are_not():
    idx = np.arange(2)
    for seed in range(5):
        rng = np.random.default_rng(seed)
        free = [_chains(rng, 600, 40, lambda t: 1.0, move_prob=0.4) for _ in range(2)]
        # under the null (every walker moves at 0.4) none is stuck: a quarter of the
        # median is 8 sd below a walker's 240 +- 12 moves in 600 steps
        assert stuck_walkers(free, idx, 0, 600) == []
        slow = _chains(rng, 600, 1, lambda t: 1.0, move_prob=0.05)
        slower = _chains(rng, 600, 1, lambda t: 1.0, move_prob=0.01)
        free[1][:, 7] = slow[:, 0]
        free[0][:, 3] = slower[:, 0]
        found = stuck_walkers(free, idx, 0, 600)
        # both, the slowest first, with every step of the window
        assert len(found) == 2
        np.testing.assert_array_equal(found[0], slower[:, 0])
        np.testing.assert_array_equal(found[1], slow[:, 0])
        # a window shorter than MIN_STUCK_WINDOW cannot tell
        assert stuck_walkers(free, idx, 600 - MIN_STUCK_WINDOW + 1, 600) == []


def test_a_walker_that_moves_but_only_about_one_place_is_trapped_and_free_ones_are_not():
    idx = np.arange(2)
    # the null, over 20 seeds of 2 ensembles: walkers moving at 0.4 have tau = 1.6 / 0.4
    # = 4 steps; the Bonferroni threshold makes a false call 1e-4 per ensemble, so none
    # in 40 but with probability 0.4 %
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        free = [_chains(rng, 600, 40, lambda t: 1.0, move_prob=0.4) for _ in range(2)]
        assert stuck_walkers(free, idx, 0, 600) == []
    # a walker that moves as often as the rest but about a point 0.8 sd off in the second
    # coordinate: its mean is 0.8 / sqrt(4 / 600) = 10 standard errors away
    rng = np.random.default_rng(7)
    free = [_chains(rng, 600, 40, lambda t: 1.0, move_prob=0.4) for _ in range(2)]
    creeping = _chains(rng, 600, 1, lambda t: 0.3, move_prob=0.4)[:, 0] + [0.0, 0.8]
    free[1][:, 5] = creeping
    found = stuck_walkers(free, idx, 0, 600)
    assert len(found) == 1
    np.testing.assert_array_equal(found[0], creeping)


class _Named:
    def __init__(self, name):
        self.name = name


class _TwoModes:
    """``p(z) = 0.75 N(0, I) + 0.25 N(m_B, 0.8^2 I)`` in 8 dimensions, N(0, 100^2) priors.

    A sampling target without a linear block (every coordinate is the independence
    move's and differential evolution's).
    """

    d, w_a, w_b, s_b, s_prior = 8, 0.75, 0.25, 0.8, 100.0
    m_b = np.r_[6.0, 6.0, np.zeros(6)]

    def __init__(self):
        self.space = ParamSpace(tuple(Param(f"x{i}", Normal(0.0, self.s_prior), unit="1",
                                            description="coordinate") for i in range(self.d)))
        self.model, self.likelihood = _Named("two_modes"), _Named("test_density")
        self.beta, self.data, self.held_out = 1.0, (), ()
        self.n = 0

    @property
    def ndim(self):
        return self.d

    @property
    def counts(self):
        return EvalCounts(self.n, 0, 0)

    def log_prob_batch(self, z):
        z = np.atleast_2d(z)
        self.n += z.shape[0]
        c = 0.5 * self.d * math.log(2 * math.pi)
        la = math.log(self.w_a) - 0.5 * np.sum(z**2, axis=1) - c
        lb = (math.log(self.w_b) - 0.5 * np.sum((z - self.m_b) ** 2, axis=1) / self.s_b**2
              - self.d * math.log(self.s_b) - c)
        return np.logaddexp(la, lb) + np.atleast_1d(self.space.log_prior(z))

    def log_prob(self, z):
        return float(self.log_prob_batch(np.asarray(z)[None])[0])

    def weight_b(self):
        # each Gaussian times the Gaussian prior integrates to N(m; 0, (s^2 + s_prior^2) I)
        a = math.log(self.w_a) + stats.multivariate_normal.logpdf(
            np.zeros(self.d), cov=(1 + self.s_prior**2) * np.eye(self.d))
        b = math.log(self.w_b) + stats.multivariate_normal.logpdf(
            self.m_b, cov=(self.s_b**2 + self.s_prior**2) * np.eye(self.d))
        return 1.0 / (1.0 + math.exp(a - b))


@pytest.mark.parametrize("seed", range(4))
def test_a_walker_in_a_mode_the_frozen_proposal_misses_is_anchored_and_the_modes_mix(
        seed, caplog):
    # deliberately built: the proposal is the Laplace one at the main mode and never
    # adapted (no warm-up), and one walker of 34 starts in the second mode (a quarter of
    # the mass, 8.5 sd away). There the posterior outweighs the proposal and the walker
    # holds still. Before anchors the run ended unconverged at 6 000 steps in 6 of 6
    # seeds (R-hat between walkers); with them it converged in 760-3 618 steps
    target = _TwoModes()
    z0 = np.zeros(target.d)
    lp0 = target.log_prob(z0)
    start = MAPResult(z=z0, theta=target.space.unpack(z0), log_prob=lp0,
                      covariance=np.eye(target.d), laplace_ok=True, n_evals=0,
                      candidates=(lp0,), notes=())
    rng = np.random.default_rng(seed)
    walkers = rng.standard_normal((34, target.d))
    walkers[0] = target.m_b + target.s_b * rng.standard_normal(target.d)
    with caplog.at_level(logging.INFO, logger="bayeshyst.inference.sampling"):
        res = sample_posterior(target, SamplerSettings(seed=seed, max_steps=6000, warmup=0,
                                                       n_walkers=34),
                               start=start, initial=walkers)
    assert "held still under the frozen proposal" in caplog.text
    assert res.converged, res.convergence
    # oracle: the second mode's exact posterior mass; the draws' fraction in it (the
    # nearer centre) has sd sqrt(p (1 - p) / ESS)
    x = res.flat_z
    in_b = np.sum((x - target.m_b) ** 2, axis=1) < np.sum(x**2, axis=1)
    p = target.weight_b()
    assert abs(in_b.mean() - p) < 5 * math.sqrt(p * (1 - p) / res.convergence.ess_bulk_min)
