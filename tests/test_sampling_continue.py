"""A longer run that goes on from an earlier run's last walkers (``walkers=``).

The diagnosis samples an unconverged fit again with twice the steps; the longer run
starts each ensemble from where the short one's ended instead of climbing from the start
again. Oracles: the conjugate posterior of the PI weights (the continued run must still
reach it), and the walkers themselves (kept apart, in place, only the ones without
density replaced).
"""

from __future__ import annotations

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
