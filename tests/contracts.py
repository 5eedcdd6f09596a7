"""The ``simulate`` contract every model keeps, as assertions the model test files share.

Each oracle is the model itself: a run cut into pieces with the state carried across
equals one run; a batch equals its walkers run one by one; prior draws simulate.
"""

from __future__ import annotations

import itertools

import numpy as np


def assert_pieces_match(model, u, t, theta, edges):
    """Run ``u`` in the pieces between ``edges`` (state carried) and compare with one run."""
    whole = model.simulate(u, t, theta)
    state, pieces = None, []
    for a, b in itertools.pairwise(edges):
        traj = model.run(u[a:b], t[a:b], theta, state0=state)
        pieces.append(traj.y)
        state = traj.state
    # to rounding: a new run may re-solve the state at its first instant
    np.testing.assert_allclose(np.concatenate(pieces), whole, rtol=0, atol=1e-12)


def assert_batch_equals_single(model, u, t, space, seed, n=5):
    """``simulate_batch`` of ``n`` prior draws equals each draw simulated alone, bit for bit."""
    z = space.sample_prior(np.random.default_rng(seed), n)
    batch = model.simulate_batch(u, t, space.unpack(z))
    for j in range(n):
        np.testing.assert_array_equal(batch[j], model.simulate(u, t, space.unpack(z[j])))


def assert_prior_draws_simulate(model, u, t, space, seed, n=200):
    """``n`` prior draws all simulate ``u``: none failed, every output finite."""
    z = space.sample_prior(np.random.default_rng(seed), n)
    traj = model.run_batch(u, t, space.unpack(z))
    assert traj.n_failed == 0
    assert np.all(np.isfinite(traj.y))
