"""Posterior recovery on data from the Preisach variants themselves.

Data are simulated from each model with Gaussian noise and refitted with the default
priors; the checks are those of ``tests/test_recovery.py`` (whose helpers are reused):
the sum over independent fits of the truth's squared Mahalanobis distance under each
posterior is ~ chi2(S d) (two-sided 0.1 % test, every run) and, slow, each parameter's
90 % HDI covers the truth at the nominal rate over 20 seeds (binomial test, Bonferroni
over parameters, so a calibrated posterior fails with probability < 0.1 %).
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data import Dataset, Record
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.preisach_variants import DiagonalPreisach, PreisachRate
from tests.test_recovery import _check_calibration, _check_coverage, _labels_and_truth

SIGMA = 0.05
# 3 levels over 0-150 V: six cells, positive weights (a counter-clockwise loop)
MU = np.array([1.2, 0.8, 0.6, 0.5, 0.4, 1.0])
DIAGONAL_TRUTH = {"offset": 0.5, "mu": MU}
RATE_TRUTH = {"offset": 0.5, "mu": MU, "c": 0.6, "udot0": 800.0}


def _drive(f_hz, n_per=300, periods=3):
    """A decaying sine over 0–150 V (minor loops inside the major one)."""
    k = np.arange(n_per * periods)
    t = k / (n_per * f_hz)
    envelope = 1.0 - 0.5 * k / k.size
    return t, 75.0 - 74.0 * envelope * np.cos(2 * np.pi * f_hz * t)


def _records(model, truth, seed, freqs):
    """Noisy records from the model at ``freqs``, with the fixed values the fit will use."""
    rng = np.random.default_rng(seed)
    drives = [(f_hz, *_drive(f_hz)) for f_hz in freqs]
    # the fit places the fixed levels / bounds from the data's input range: so does the truth
    inputs = Dataset(tuple(Record(t=t, u=u, y=u, name=f"f{f_hz:g}")
                           for f_hz, t, u in drives))
    theta = {**truth, **model.param_space(inputs).fixed}
    recs = []
    for f_hz, t, u in drives:
        y = model.simulate(u, t, theta) + rng.normal(0.0, SIGMA, u.size)
        recs.append(Record(t=t, u=u, y=y, name=f"f{f_hz:g}", warmup=50,
                           metadata={"frequency_hz": f_hz}))
    return Dataset(tuple(recs), name=f"seed{seed}")


def _fit(model, truth, seed, freqs):
    """(squared Mahalanobis distance of the truth in z, label -> covered by the 90 % HDI)."""
    data = _records(model, truth, seed, freqs)
    post = Posterior(data, model)
    res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000,
                                                 n_walkers=2 * post.ndim + 2))
    assert res.converged, res.convergence
    full = {**truth, "noise.sigma": SIGMA}
    zt = post.space.pack(full)
    z = res.flat_z
    d = zt - z.mean(axis=0)
    d2 = float(d @ np.linalg.solve(np.cov(z.T), d))
    summ = {s.label: s for s in res.summary(0.9)}
    hits = {lab: summ[lab].hdi_lo <= v <= summ[lab].hdi_hi
            for lab, v in _labels_and_truth(post.space, full).items()}
    return d2, hits, post.ndim


def _stats(model, truth, seeds, freqs):
    out = [_fit(model, truth, seed, freqs) for seed in seeds]
    return [(d2, hits) for d2, hits, _ in out], out[0][2]


def test_diagonal_posterior_is_calibrated():
    fits, ndim = _stats(DiagonalPreisach(3), DIAGONAL_TRUTH, range(3), (2.0,))
    _check_calibration(fits, ndim)


@pytest.mark.slow
def test_diagonal_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _stats(DiagonalPreisach(3), DIAGONAL_TRUTH, range(3, 23), (2.0,))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_rate_posterior_is_calibrated():
    # two drive frequencies (peak rates ~0.7 and ~14 kV/s around udot0 = 0.8 kV/s), so
    # that c and udot0 are both identified
    fits, ndim = _stats(PreisachRate(3), RATE_TRUTH, range(3), (1.0, 20.0))
    _check_calibration(fits, ndim)


@pytest.mark.slow
def test_rate_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _stats(PreisachRate(3), RATE_TRUTH, range(3, 23), (1.0, 20.0))
    _check_calibration(fits, ndim)
    _check_coverage(fits)
