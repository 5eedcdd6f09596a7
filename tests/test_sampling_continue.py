"""A longer run that goes on from an earlier run's last walkers (``walkers=``).

The diagnosis samples an unconverged fit again with twice the steps; the longer run
starts each ensemble from where the short one's ended instead of climbing from the start
again. Oracles: the conjugate posterior of the PI weights (the continued run must still
reach it), and the walkers themselves (kept apart, in place, only the ones without
density replaced).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bayeshyst.errors import ParameterError
from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inference.starts import initial_positions
from tests.synthetic import pi_data


@pytest.fixture(scope="module")
def tempered():
    # tempered (beta = 1/2) so that the structured moves have no exact linear block and
    # the weights are theirs to move; at known sigma the posterior is the Gaussian with
    # sigma / sqrt(beta)
    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    post = Posterior(rec, model, beta=0.5).fix("noise.sigma", 0.05)
    exact = conjugate_posterior(Posterior(rec, model).fix("noise.sigma", 0.05 / math.sqrt(0.5)))
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    return post, exact, start


def test_a_run_continued_from_a_short_ones_walkers_reaches_the_conjugate_posterior(tempered):
    post, exact, start = tempered
    # every walker 30 sd off: 60 steps do not get there
    rng = np.random.default_rng(1)
    far = exact.mean + (30.0 + rng.standard_normal((64, exact.mean.size))) * exact.sd
    short = sample_posterior(post, SamplerSettings(seed=2, max_steps=60, first_chunk=60),
                             start=start, initial=far)
    assert not short.converged
    assert short.last_walkers.shape == (2, short.chains.shape[2], post.ndim)
    longer = sample_posterior(post, SamplerSettings(seed=3, max_steps=4000),
                              start=short.start, walkers=short.last_walkers)
    assert longer.converged, longer.convergence
    flat = longer.flat_z
    se = exact.sd / np.sqrt(longer.convergence.ess_bulk_min)
    assert np.all(np.abs(flat.mean(axis=0) - exact.mean) < 5 * se)
    np.testing.assert_allclose(flat.std(axis=0, ddof=1), exact.sd, rtol=0.1)


def test_the_given_walkers_are_kept_per_ensemble_and_only_those_without_density_replaced(
        tempered):
    post, exact, start = tempered
    rng = np.random.default_rng(0)
    walkers = exact.mean + rng.standard_normal((2, 24, exact.mean.size)) * exact.sd
    walkers[1, 5] = np.nan  # no density: replaced by a Laplace draw
    rngs = [np.random.default_rng(s) for s in (1, 2)]
    got = initial_positions(post, start, None, 2, 24, rngs, walkers)
    np.testing.assert_array_equal(got[0], walkers[0])
    keep = np.arange(24) != 5
    np.testing.assert_array_equal(got[1][keep], walkers[1][keep])
    assert np.all(np.isfinite(got[1][5]))
    assert np.isfinite(post.log_prob_batch(got[1][5:6])[0])


def test_walkers_must_match_the_runs_ensembles_and_not_come_with_a_pool(tempered):
    post, exact, start = tempered
    settings = SamplerSettings(seed=0, max_steps=20, first_chunk=20, n_walkers=24)
    good = np.broadcast_to(exact.mean, (2, 24, exact.mean.size)).copy()
    with pytest.raises(ParameterError, match=r"walkers must have shape .*\(2, 24, "):
        sample_posterior(post, settings, start=start, walkers=good[:, :20])
    with pytest.raises(ParameterError, match="not both"):
        sample_posterior(post, settings, start=start, walkers=good, initial=good[0])


def _below_the_mode(post, start, nats):
    """``start`` moved along its first Laplace axis to ``nats`` below the mode."""
    vals, vecs = np.linalg.eigh(start.covariance)
    z = start.z + math.sqrt(2.0 * nats * vals[-1]) * vecs[:, -1]
    return dataclasses.replace(start, z=z, log_prob=float(post.log_prob(z)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_continued_run_restarts_only_when_most_of_its_walkers_lie_above_the_start(
        tempered, seed):
    # oracle: the posterior is Gaussian (a tempered linear model at known sigma), so a
    # draw's log density lies chi2_d / 2 below the mode (d = 5 here). Against a start
    # 1.5 nats below the mode, a draw lies more than a nat above the start with
    # probability P(chi2_5 < 1) = 0.04 (many of the 64 walkers x 50 warm-up steps do),
    # but the median draw lies below the start (P(chi2_5 < 3) = 0.30): a fresh run's
    # warm-up restarts on one walker, a run going on from draws does not. Against a
    # start 6 nats below (P(chi2_5 < 12) = 0.97) most draws lie above, and it restarts
    post, _, start = tempered
    assert post.ndim == 5
    rng = np.random.default_rng(seed)
    chol = np.linalg.cholesky(start.covariance)
    draws = start.z + rng.standard_normal((2, 32, post.ndim)) @ chol.T
    settings = SamplerSettings(seed=seed, max_steps=200, first_chunk=100, n_walkers=32)

    def restarted(res):
        return any("restart 1" in n for n in res.start.notes)

    near = _below_the_mode(post, start, 1.5)
    assert restarted(sample_posterior(post, settings, start=near, initial=draws))
    assert not restarted(sample_posterior(post, settings, start=near, walkers=draws))
    far = _below_the_mode(post, start, 6.0)
    assert restarted(sample_posterior(post, settings, start=far, walkers=draws))
