"""The structured moves' warm-up: the window divergence and when the proposal is frozen."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inference.warmup import (
    MIN_MOVE_RATE,
    SETTLED_KL,
    keep_adapting,
    window_divergence,
)
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
