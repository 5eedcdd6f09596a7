"""Likelihoods and the posterior density against independent formulas."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import bayeshyst.models as M
from bayeshyst.data import Dataset, Record
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.likelihoods import AR1, Gaussian, StudentT, get_likelihood
from tests.synthetic import pi_data


def _resid(seed=0, w=3, n=50):
    return np.random.default_rng(seed).normal(0.0, 0.3, (w, n))


def test_gaussian_matches_scipy():
    r = _resid()
    sigma = np.array([0.2, 0.3, 1.1])
    pw = Gaussian().pointwise(r, {"sigma": sigma})
    np.testing.assert_allclose(pw, stats.norm.logpdf(r, scale=sigma[:, None]), rtol=1e-12)


def test_student_t_matches_scipy():
    r = _resid(1)
    sigma, nu = np.array([0.2, 0.3, 1.1]), np.array([1.5, 4.0, 30.0])
    pw = StudentT().pointwise(r, {"sigma": sigma, "nu": nu})
    ref = stats.t.logpdf(r, df=nu[:, None], scale=sigma[:, None])
    np.testing.assert_allclose(pw, ref, rtol=1e-10)


def test_ar1_is_the_exact_stationary_gaussian_density():
    # oracle: the joint density of a stationary AR(1) as a multivariate normal with
    # Toeplitz covariance sigma^2 phi^|i-j|
    r = _resid(2, w=3, n=40)
    sigma, phi = np.array([0.3, 0.5, 0.2]), np.array([0.0, 0.7, -0.4])
    pw = AR1().pointwise(r, {"sigma": sigma, "phi": phi})
    lags = np.abs(np.subtract.outer(np.arange(40), np.arange(40)))
    for i in range(3):
        cov = sigma[i] ** 2 * phi[i] ** lags
        ref = stats.multivariate_normal(np.zeros(40), cov).logpdf(r[i])
        assert pw[i].sum() == pytest.approx(ref, rel=1e-10)
    # phi = 0 is the independent Gaussian
    np.testing.assert_allclose(pw[0], Gaussian().pointwise(r[:1], {"sigma": sigma[:1]})[0])


def test_get_likelihood_by_name():
    assert isinstance(get_likelihood("ar1"), AR1)
    with pytest.raises(ModelError, match="unknown likelihood 'ar2'"):
        get_likelihood("ar2")


# ---------------------------------------------------------------- the posterior
def test_log_prob_is_prior_plus_free_run_likelihood():
    model, rec, _ = pi_data()
    post = Posterior(rec, model)
    z = post.space.sample_prior(np.random.default_rng(4), 5)
    lp = post.log_prob_batch(z)
    for i in range(5):
        th = post.space.unpack(z[i])
        model_theta = {k: th[k] for k in ("p0", "w", "r")}
        yhat = model.simulate(rec.u, rec.t, model_theta) + th["obs.offset"]
        ll = stats.norm.logpdf(rec.y[150:], yhat[150:], th["noise.sigma"]).sum()
        assert lp[i] == pytest.approx(post.space.log_prior(z[i]) + ll, rel=1e-10)
        assert post.log_prob(z[i]) == pytest.approx(lp[i], rel=1e-12)


def test_units_partition_the_scored_samples_and_sum_to_the_likelihood():
    model, rec, _ = pi_data()
    post = Posterior(rec, model)
    starts = [u.start for u in post.units]
    stops = [u.stop for u in post.units]
    assert starts[0] == 150 and stops[-1] == rec.n and starts[1:] == stops[:-1]
    assert len(post.units) >= 2
    z = post.space.sample_prior(np.random.default_rng(1), 3)
    units = post.log_likelihood_units(z)
    prior = post.space.log_prior(z)
    np.testing.assert_allclose(units.sum(axis=1) + prior, post.log_prob_batch(z), rtol=1e-10)


def test_log_prob_never_nan_and_failures_counted():
    model, rec, _ = pi_data()
    post = Posterior(rec, model)
    z = np.array([[np.nan] * post.ndim, [1e300] * post.ndim, [0.0] * post.ndim])
    lp = post.log_prob_batch(z)
    assert not np.any(np.isnan(lp))
    assert lp[0] == -np.inf and lp[1] == -np.inf and np.isfinite(lp[2])
    assert post.counts.evaluations == 3 and post.counts.prior_rejected == 2


def test_failed_simulations_are_minus_inf_and_counted():
    # the quadratic generalised play flags non-monotone envelopes as failed
    model = M.get("pi_generalized", n_operators=2, envelope="quadratic")
    t = np.arange(400) * 1e-3
    u = np.sin(2 * np.pi * 5 * t)
    rec = Record(t=t, u=u, y=u + 0.01 * np.cos(2 * np.pi * 5 * t), name="g")
    post = Posterior(rec, model)
    theta = post.space.unpack(np.zeros(post.ndim))
    bad = {**theta, "b_l": 5.0}  # slope 1 + 2 b x < 0 inside the range: fails
    z = post.space.pack({k: v for k, v in bad.items() if k in post.space.names})
    assert post.log_prob(z) == -np.inf
    assert post.counts.failed == 1


def test_beta_zero_is_the_prior_and_runs_no_simulation():
    model, rec, _ = pi_data()
    post = Posterior(rec, model, beta=0.0)
    z = post.space.sample_prior(np.random.default_rng(0), 4)
    np.testing.assert_array_equal(post.log_prob_batch(z), post.space.log_prior(z))
    with pytest.raises(ParameterError, match="beta"):
        Posterior(rec, model, beta=1.5)


def test_offset_added_only_when_the_model_has_none():
    model, rec, _ = pi_data()
    assert "obs.offset" in Posterior(rec, model).space.names
    assert "obs.offset" not in Posterior(rec, model, offset=False).space.names
    # a composite whose base has an offset of its own: the blocks pass a constant on, so
    # a second (observation) offset would be an exact ridge
    for spec in ("preisach+creep", "duhem+second_order", "preisach_density+drift"):
        assert "obs.offset" not in Posterior(rec, spec).space.names, spec
    assert "static.offset" in Posterior(rec, "preisach+creep").space.names
    assert "obs.offset" in Posterior(rec, "pi_play+creep").space.names


def test_posterior_accepts_dataset_and_spec_string_and_pickles():
    import pickle

    _, rec, _ = pi_data()
    post = Posterior(Dataset((rec,), name="d"), "pi_play+arx", "ar1")
    assert "static.w" in post.space.names and "noise.phi" in post.space.names
    clone = pickle.loads(pickle.dumps(post))
    z = post.space.sample_prior(np.random.default_rng(0), 2)
    np.testing.assert_array_equal(clone.log_prob_batch(z), post.log_prob_batch(z))


@pytest.mark.parametrize(("lik", "theta"), [
    (Gaussian(), {"sigma": np.array([0.5])}),
    (StudentT(), {"sigma": np.array([0.5]), "nu": np.array([4.0])}),
    (AR1(), {"sigma": np.array([0.5]), "phi": np.array([0.8])}),
])
def test_noise_draws_follow_the_likelihood(lik, theta):
    # the sampler and the density describe the same distribution: K-S of the draws
    # against the marginal cdf, and for AR(1) the lag-1 autocorrelation
    e = lik.sample(theta, 20_000, np.random.default_rng(0))[0]
    if isinstance(lik, StudentT):
        cdf = stats.t(df=4.0, scale=0.5).cdf
    else:
        cdf = stats.norm(scale=0.5).cdf
    sub = e[::10] if isinstance(lik, AR1) else e  # thin the correlated draws
    assert stats.kstest(sub, cdf).pvalue > 1e-3
    if isinstance(lik, AR1):
        r1 = np.corrcoef(e[:-1], e[1:])[0, 1]
        assert abs(r1 - 0.8) < 3 * (1 - 0.8**2) / np.sqrt(e.size)
