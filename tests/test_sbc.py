"""Simulation-based calibration of the structured sampler (Talts et al. 2018).

Each replicate draws every parameter (weights or Bouc–Wen shape, offset, noise) from a
fixed prior, simulates a short record from it, and samples the posterior with the
default engine (MAP, least squares, structured moves). If the sampler draws from the
posterior, the rank of the true value among ``L`` posterior draws is uniform on
``0..L``, whatever the prior or the data: a chi-square test of the ranks over the
replicates is the oracle. Ranks are taken in ``z`` (the unconstrained coordinates), to
which the physical values are monotone.

Statistics: each parameter's chi-square test is at level 1e-3 (Bonferroni over the
parameters keeps a correct sampler's family-wise failure rate below 1 % per model).
The default suite runs 20 replicates per model into 4 rank bins (5 expected per bin);
``-m slow`` runs 100 into 10 bins.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from bayeshyst.data import Record
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get

N_DRAWS = 99  # ranks 0..99: 100 equally likely values
# short records from prior draws make wide, curved posteriors (Bouc-Wen: tau of 20-70
# steps for beta, gamma, n); 2 000 steps keep ~20 independent draws per walker
MAX_STEPS = 2000


def _design(n: int = 400):
    t = np.arange(n) * 2.5e-3
    u = 75.0 - 70.0 * np.cos(2 * np.pi * t / 0.5) * np.exp(-0.4 * t)
    return t, u


def _reference(spec: str) -> Posterior:
    """The fixed prior: the model's default priors for a typical 0-150 V / 0-40 um loop."""
    t, u = _design()
    y = 40.0 * (u - u.min()) / np.ptp(u)  # only its range matters (prior scales)
    return Posterior(Record(t=t, u=u, y=y, name="reference", warmup=40), get(spec))


def _replicate(ref: Posterior, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(ranks of the truth, shape (ndim,)) for one replicate; the truth, too."""
    rng = np.random.default_rng(seed)
    space = ref.space
    t, u = ref.data[0].t, ref.data[0].u
    for _ in range(50):  # a prior draw whose simulation succeeds (the support's edge)
        z_true = space.sample_prior(rng, 1)[0]
        theta = space.unpack(z_true)
        mt = {k: theta[k] for k in ref.model_space.all_names}
        traj = ref.model.run_batch(u, t, {k: np.asarray(v)[None] for k, v in mt.items()})
        if not traj.failed[0] and np.all(np.isfinite(traj.y)):
            break
    y = (traj.y[0] + theta["obs.offset"]
         + theta["noise.sigma"] * rng.standard_normal(t.size))
    post = Posterior(Record(t=t, u=u, y=y, name="sbc", warmup=40), ref.model).with_priors(space)
    res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=MAX_STEPS))
    draws = res.draws(N_DRAWS, seed=seed)
    return np.sum(draws < z_true[None, :], axis=0), z_true


def _check_uniform(ranks: np.ndarray, bins: int, labels: list[str]) -> None:
    edges = np.linspace(0, N_DRAWS + 1, bins + 1)
    for j, lab in enumerate(labels):
        counts, _ = np.histogram(ranks[:, j], bins=edges)
        p = stats.chisquare(counts).pvalue
        assert p > 1e-3, f"{lab}: rank histogram {counts.tolist()} not uniform (p = {p:.2g})"


def _run(spec: str, replicates: int, bins: int) -> None:
    ref = _reference(spec)
    ranks = np.array([_replicate(ref, 1000 + i)[0] for i in range(replicates)])
    _check_uniform(ranks, bins, ref.space.labels)


# Bouc-Wen's replicates are in tests/test_sbc_bouc_wen.py: a file runs whole on one
# worker, and the two models together were the suite's longest file by far
def test_sbc_ranks_are_uniform():
    _run("pi_play(n_operators=4)", replicates=20, bins=4)


@pytest.mark.slow
def test_sbc_ranks_are_uniform_100_replicates():
    _run("pi_play(n_operators=4)", replicates=100, bins=10)
