"""InferenceData conversion, netCDF persistence, PSIS-LOO/WAIC wrappers."""

from __future__ import annotations

import functools

import arviz as az
import numpy as np
import pytest

import bayeshyst.models as M
from bayeshyst import diagnostics as D
from bayeshyst.data import Record
from bayeshyst.data.dataset import Dataset
from bayeshyst.errors import ParameterError
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.base import DataScales

SIGMA = 0.05
DRAWS = 10
N_PRED = 200


@functools.lru_cache(maxsize=1)
def two_record_fit():
    """A quick (unconverged) fit of a 2-operator PI model to a 5 Hz and a 10 Hz record.

    Shared with ``tests/test_plotting.py`` (cached: built once per session).
    """
    model = M.get("pi_play", n_operators=2)
    r = model.param_space(DataScales(5.0, 145.0, 0.0, 20.0)).fixed["r"]
    theta = {"p0": 0.1, "w": np.array([0.05, 0.02]), "r": r}
    rng = np.random.default_rng(0)
    recs = []
    for f, n in ((5.0, 900), (10.0, 500)):
        t = np.arange(n) * 1e-3
        u = 75 + 70 * np.sin(2 * np.pi * f * t - np.pi / 2)
        y = model.simulate(u, t, theta) + 0.4 + rng.normal(0.0, SIGMA, n)
        recs.append(Record(t=t, u=u, y=y, name=f"f{f:g}", warmup=100,
                           metadata={"frequency_hz": f}))
    post = Posterior(Dataset(tuple(recs), name="two"), model)
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    res = sample_posterior(post, SamplerSettings(seed=5, max_steps=400, first_chunk=100),
                           start=start)
    return post, res


@pytest.fixture(scope="module")
def fit():
    return two_record_fit()


@pytest.fixture(scope="module")
def idata(fit):
    post, res = fit
    return D.to_inference_data(post, res, draws_per_chain=DRAWS, n_predictive=N_PRED, seed=3)


def _z_of_draws(res, idata):
    """The z of every (chain, draw) of ``idata``, rebuilt from the chains."""
    thin = np.asarray(idata.sample_stats.attrs["kept_step_index"])
    e_idx = idata.posterior["ensemble"].values
    w_idx = idata.posterior["walker"].values
    return res.chains[e_idx[:, None], thin[None, :], w_idx[:, None]]  # (chain, draw, ndim)


def test_groups_dims_and_shapes(fit, idata):
    post, res = fit
    n_ens, n_steps, n_walk, _ = res.chains.shape
    assert set(idata.groups()) == {"posterior", "sample_stats", "log_likelihood",
                                   "posterior_predictive", "observed_data", "constant_data"}
    pos = idata.posterior
    assert dict(pos.sizes) == {"chain": n_ens * n_walk, "draw": DRAWS, "w_dim_0": 2}
    assert set(pos.data_vars) == set(post.space.names)
    assert pos["w"].dims == ("chain", "draw", "w_dim_0")
    assert pos["noise.sigma"].attrs["unit"] == "um"
    np.testing.assert_array_equal(pos["ensemble"], np.repeat(np.arange(n_ens), n_walk))
    assert pos["draw"].values[0] == res.convergence.burn
    assert pos["draw"].values[-1] == res.convergence.burn + n_steps - 1
    assert idata.sample_stats["lp"].shape == (n_ens * n_walk, DRAWS)
    attrs = idata.sample_stats.attrs
    assert attrs["converged"] == int(res.converged)
    assert attrs["rhat_max"] == res.convergence.rhat_max
    assert attrs["model"] == "pi_play" and attrs["likelihood"] == "gaussian"
    assert attrs["seed"] == 5 and attrs["evaluations"] == res.counts.evaluations

    ll = idata.log_likelihood
    assert ll["y"].dims == ("chain", "draw", "cycle")
    assert ll["y"].shape == (n_ens * n_walk, DRAWS, post.n_units)
    assert list(ll["cycle_record"].values) == [u.record for u in post.units]
    assert list(ll["cycle_index"].values) == [u.index for u in post.units]
    assert list(ll["cycle_frequency_hz"].values) == [u.frequency_hz for u in post.units]

    n_obs = sum(r.n for r in post.data)
    assert idata.posterior_predictive["y"].shape == (1, N_PRED, n_obs)
    np.testing.assert_array_equal(idata.observed_data["y"],
                                  np.concatenate([r.y for r in post.data]))
    assert list(idata.observed_data["obs_record"].values[[0, -1]]) == ["f5", "f10"]
    const = idata.constant_data
    np.testing.assert_array_equal(const["u"], np.concatenate([r.u for r in post.data]))
    assert const["scored"].dtype == bool
    assert int(const["scored"].sum()) == sum(r.n_scored for r in post.data)
    cycle = const["cycle"].values
    assert np.all((cycle == -1) == ~const["scored"].values)  # the cycles partition scoring
    offsets = {"f5": 0, "f10": post.data[0].n}
    for j, unit in enumerate(post.units):
        np.testing.assert_array_equal(
            np.flatnonzero(cycle == j), offsets[unit.record] + np.arange(unit.start, unit.stop))
    assert np.all(const["record"].values[cycle == post.n_units - 1] == 1)


def test_posterior_values_are_the_chain_draws(fit, idata):
    post, res = fit
    thin = np.asarray(idata.sample_stats.attrs["kept_step_index"])
    n_walk = res.chains.shape[2]
    for e, w, d in [(0, 0, 0), (1, 5, 3), (1, n_walk - 1, DRAWS - 1), (0, n_walk - 2, 7)]:
        z = res.chains[e, thin[d], w]
        theta = res.space.unpack(z)
        chain = e * n_walk + w
        for name in post.space.names:
            np.testing.assert_array_equal(
                idata.posterior[name].isel(chain=chain, draw=d).values, theta[name])
        assert idata.sample_stats["lp"].isel(chain=chain, draw=d) == res.log_prob[e, thin[d], w]


def test_cycle_log_likelihood_plus_prior_is_the_log_posterior(fit, idata):
    post, res = fit
    z = _z_of_draws(res, idata)
    prior = post.space.log_prior(z.reshape(-1, z.shape[-1])).reshape(z.shape[:2])
    total = idata.log_likelihood["y"].sum("cycle").values + prior
    np.testing.assert_allclose(total, idata.sample_stats["lp"].values, rtol=0, atol=1e-8)


def test_thinning_keeps_every_step_when_asked_for_more(fit):
    post, res = fit
    small = D.to_inference_data(post, res, draws_per_chain=10_000, n_predictive=2)
    assert small.posterior.sizes["draw"] == res.chains.shape[1]


@pytest.mark.filterwarnings("ignore:Estimated shape parameter of Pareto")
def test_loo_and_waic_leave_out_cycles(fit, idata):
    post, res0 = fit
    # PI weights and the offset form a linear block: loo uses the Rao-Blackwellised
    # cycle terms (block integrated out), which arviz's PSIS-LOO must reproduce
    assert res0.linear_block and D.GIVEN_REST in idata.log_likelihood
    ref = az.loo(idata, pointwise=True, var_name=D.GIVEN_REST)
    assert int(ref.n_data_points) == post.n_units
    res = D.loo(idata)
    assert res.method == "loo" and res.n_units == post.n_units
    assert res.n_samples == idata.posterior.sizes["chain"] * DRAWS
    assert res.elpd == pytest.approx(float(ref.elpd_loo))
    assert res.pareto_k.shape == res.pointwise.shape == (post.n_units,)
    assert res.pointwise.sum() == pytest.approx(res.elpd)
    assert "elpd_loo" in str(res) and "nan" not in str(res)
    w = D.waic(idata)
    assert w.pareto_k is None and w.n_units == post.n_units
    assert w.elpd == pytest.approx(res.elpd, rel=1e-3)
    # an unconverged run says so in every number derived from it
    if not fit[1].converged:
        assert any("did not converge" in m for m in res.warnings + w.warnings)


def test_large_pareto_k_is_reported(idata):
    bad = idata.copy()
    rng = np.random.default_rng(0)
    # the cycle terms loo reads (the Rao-Blackwellised ones where there is a linear block)
    var = D.GIVEN_REST if D.GIVEN_REST in bad.log_likelihood else "y"
    y = bad.log_likelihood[var].values.copy()
    y[..., 1] += 40.0 * rng.standard_exponential(y.shape[:2])  # a few draws dominate
    bad.log_likelihood[var].values[:] = y
    res = D.loo(bad)
    assert res.pareto_k[1] > D.PARETO_K_BAD
    msg = [m for m in res.warnings if "Pareto k > 0.7" in m]
    assert msg and "f5#1" in msg[0]
    assert not res.reliable and "warning" in str(res)


def test_elpd_by_group_sums_the_cycles(fit, idata):
    post, _ = fit
    total = D.loo(idata)
    groups = D.elpd_by_group(idata, result=total)
    assert [g.value for g in groups] == [5.0, 10.0]
    assert [g.n_units for g in groups] == [
        sum(u.frequency_hz == f for u in post.units) for f in (5.0, 10.0)]
    assert sum(g.elpd for g in groups) == pytest.approx(total.elpd)
    first = total.pointwise[: groups[0].n_units]
    assert groups[0].se == pytest.approx(np.sqrt(first.size * np.var(first)))
    by_record = D.elpd_by_group(idata, "cycle_record", result=total)
    assert [g.value for g in by_record] == ["f5", "f10"]
    assert "cycle_record = f5" in str(by_record[0])
    with pytest.raises(ParameterError, match="'frequency'"):
        D.elpd_by_group(idata, "frequency")


def test_posterior_predictive_noise_has_the_noise_sd(fit, idata):
    post, res = fit
    z = res.draws(N_PRED, seed=3)  # the draws to_inference_data(seed=3) used
    pred = np.concatenate(post.predict(z), axis=1)
    noise = idata.posterior_predictive["y"].values[0] - pred
    sigma = post.space.unpack(z)["noise.sigma"][:, None]
    std = noise / sigma
    assert abs(std.mean()) < 5 / np.sqrt(std.size)
    assert std.std() == pytest.approx(1.0, abs=0.01)
    assert noise.std() == pytest.approx(SIGMA, rel=0.05)  # and near the simulated truth
    # another seed: other noise
    other = D.to_inference_data(post, res, draws_per_chain=2, n_predictive=N_PRED, seed=4)
    assert not np.allclose(other.posterior_predictive["y"], idata.posterior_predictive["y"])


def test_netcdf_round_trip_is_exact_and_atomic(idata, tmp_path, monkeypatch):
    path = tmp_path / "out" / "posterior.nc"
    assert D.save_netcdf(idata, path) == path
    assert sorted(p.name for p in path.parent.iterdir()) == ["posterior.nc"]
    back = D.load_netcdf(path)
    assert set(back.groups()) == set(idata.groups())
    for group in idata.groups():
        assert back[group].identical(idata[group]), group
    assert D.loo(back).elpd == D.loo(idata).elpd
    # a write that fails half-way leaves the previous file untouched and no temp file
    before = path.read_bytes()

    def broken(self, filename, **kwargs):
        with open(filename, "wb") as fh:
            fh.write(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(az.InferenceData, "to_netcdf", broken)
    with pytest.raises(OSError, match="disk full"):
        D.save_netcdf(idata, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == ["posterior.nc"]
    with pytest.raises(FileNotFoundError):
        D.load_netcdf(tmp_path / "missing.nc")


def test_bad_input_is_refused(fit, idata):
    post, res = fit
    with pytest.raises(ParameterError, match="draws_per_chain"):
        D.to_inference_data(post, res, draws_per_chain=0)
    with pytest.raises(ParameterError, match="n_predictive"):
        D.to_inference_data(post, res, n_predictive=1.5)
    with pytest.raises(ParameterError, match="not sampled from this posterior"):
        D.to_inference_data(post.fix("noise.sigma", SIGMA), res)
    with pytest.raises(ParameterError, match="InferenceData"):
        D.loo(res)
    with pytest.raises(ParameterError, match="log_likelihood"):
        D.loo(az.InferenceData(posterior=idata.posterior))
