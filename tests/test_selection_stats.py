"""The statistics behind model comparison, each against an independent oracle.

- stacking weights vs a brute-force grid (K = 2) and a constrained SLSQP solve (K = 3);
- the paired elpd difference and its se vs ``arviz.compare``;
- the held-out (leave-one-frequency-out) predictive density vs the analytic Gaussian
  predictive of a linear model under its conjugate posterior;
- ``Posterior.holding_out`` vs the per-cycle log-likelihoods;
- the one ranking (``rank_by_elpd``) vs sums, variances and differences by hand, and the
  study summary's ranking vs the comparison's on the same cycles.
"""

from __future__ import annotations

import math
import re

import arviz as az
import numpy as np
import pytest
from scipy import optimize, stats

import bayeshyst.models as M
from bayeshyst.data import Dataset, Record
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.posterior import Posterior
from bayeshyst.models.base import DataScales
from bayeshyst.selection import (
    check_models,
    paired_difference,
    rank_by_elpd,
    stacking_weights,
)
from bayeshyst.selection.tasks import TaskSpec, heldout_log_density, task_seed


def _objective(w, lpd):
    return -np.sum(np.log(np.exp(lpd) @ w))


def test_stacking_two_models_matches_a_grid():
    rng = np.random.default_rng(1)
    lpd = np.column_stack([rng.normal(-1.0, 0.8, 60), rng.normal(-1.2, 1.0, 60)])
    grid = np.linspace(0.0, 1.0, 100_001)
    vals = [_objective(np.array([g, 1 - g]), lpd) for g in grid]
    g_best = grid[int(np.argmin(vals))]
    w = stacking_weights(lpd)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    assert w[0] == pytest.approx(g_best, abs=2e-4)


def test_stacking_three_models_matches_constrained_optimum():
    rng = np.random.default_rng(2)
    base = rng.normal(-1.0, 0.5, 80)
    lpd = np.column_stack([base + rng.normal(0, 0.4, 80), base + rng.normal(-0.1, 0.6, 80),
                           base + rng.normal(-0.3, 0.3, 80)])
    cons = {"type": "eq", "fun": lambda w: np.sum(w) - 1.0}
    ref = optimize.minimize(_objective, np.full(3, 1 / 3), args=(lpd,), method="SLSQP",
                            bounds=[(0, 1)] * 3, constraints=cons, options={"ftol": 1e-14})
    w = stacking_weights(lpd)
    assert _objective(w, lpd) <= ref.fun + 1e-7
    np.testing.assert_allclose(w, np.clip(ref.x, 0, 1), atol=2e-3)


def test_stacking_dominant_model_and_huge_magnitudes():
    rng = np.random.default_rng(3)
    good = rng.normal(-500.0, 1.0, 30)           # long cycles: elpd in the hundreds
    lpd = np.column_stack([good, good - 40.0])   # model 2 is worse on every cycle
    w = stacking_weights(lpd)
    assert w[0] > 0.999
    assert stacking_weights(lpd[:, :1]).tolist() == [1.0]
    with pytest.raises(ParameterError, match="finite"):
        stacking_weights(np.array([[0.0, -np.inf]]))


@pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::FutureWarning")
def test_paired_difference_equals_arviz_compare():
    rng = np.random.default_rng(4)
    n_units, n_draws = 25, 400
    ll_a = rng.normal(-1.0, 0.05, (1, n_draws, n_units)) + rng.normal(0, 0.3, n_units)
    ll_b = ll_a + rng.normal(-0.2, 0.4, n_units)
    ids = {k: az.from_dict(posterior={"x": rng.normal(size=(1, n_draws))},
                           log_likelihood={"y": v}) for k, v in (("a", ll_a), ("b", ll_b))}
    cmp = az.compare(ids, ic="loo", method="stacking")
    la, lb = (az.loo(ids[k], pointwise=True) for k in ("a", "b"))
    d, se = paired_difference(np.asarray(la.loo_i), np.asarray(lb.loo_i))
    worst = cmp.index[1]
    assert abs(d) == pytest.approx(cmp.loc[worst, "elpd_diff"], rel=1e-10)
    assert se == pytest.approx(cmp.loc[worst, "dse"], rel=1e-10)
    # and the stacking weights agree with arviz's own optimiser
    w = stacking_weights(np.column_stack([np.asarray(la.loo_i), np.asarray(lb.loo_i)]))
    assert w[0] == pytest.approx(cmp.loc["a", "weight"], abs=5e-3)


# ------------------------------------------------------------------ held-out density
def _pi_record(name, freq, u_amp, seed, sigma, model, theta):
    t = np.arange(500) * (1.0 / (100 * freq))
    u = 75 - u_amp * np.cos(2 * np.pi * freq * t)
    y = model.simulate(u, t, theta) + 0.3 + np.random.default_rng(seed).normal(0, sigma, t.size)
    return Record(t=t, u=u, y=y, name=name, warmup=100, metadata={"frequency_hz": freq})


def test_heldout_density_equals_analytic_gaussian_predictive():
    model = M.get("pi_play", n_operators=3)
    sigma = 0.08
    r = model.param_space(DataScales(0.0, 150.0, 0.0, 20.0)).fixed["r"]
    theta = {"p0": 0.1, "w": np.array([0.05, 0.03, 0.02]), "r": r}
    train = Dataset((_pi_record("a", 2.0, 75, 0, sigma, model, theta),
                     _pi_record("b", 5.0, 60, 1, sigma, model, theta)))
    test = Dataset((_pi_record("c", 3.0, 40, 2, sigma, model, theta),))
    post = Posterior(train, model).fix("noise.sigma", sigma)
    conj = conjugate_posterior(post)
    draws = conj.sample(np.random.default_rng(5), 6000)
    z = np.array([post.space.pack({"p0": d[0], "w": d[1:4], "obs.offset": d[4]})
                  for d in draws])
    pw, test_post, zt = heldout_log_density(post, test, z)
    # analytic: y_c ~ N(Phi_c m, Phi_c S Phi_c^T + sigma^2 I), cycle by cycle
    rec = test[0]
    phi = model.regressors(rec.u, rec.t, {"r": post.space.fixed["r"]})
    phi = np.column_stack([phi, np.ones(rec.n)])
    assert len(test_post.units) == pw.size >= 3
    ll = test_post.log_likelihood_units(zt)
    for j, unit in enumerate(test_post.units):
        p, y = phi[unit.start:unit.stop], rec.y[unit.start:unit.stop]
        cov = p @ conj.cov @ p.T + sigma**2 * np.eye(y.size)
        exact = stats.multivariate_normal(p @ conj.mean, cov).logpdf(y)
        # Monte Carlo standard error of log mean exp (delta method)
        wts = np.exp(ll[:, j] - ll[:, j].max())
        mc_se = np.std(wts) / np.mean(wts) / math.sqrt(wts.size)
        assert abs(pw[j] - exact) < 5 * mc_se + 1e-9, (j, pw[j], exact, mc_se)


def test_holding_out_drops_exactly_those_cycles():
    model = M.get("pi_play", n_operators=3)
    r = model.param_space(DataScales(0.0, 150.0, 0.0, 20.0)).fixed["r"]
    theta = {"p0": 0.1, "w": np.array([0.05, 0.03, 0.02]), "r": r}
    data = Dataset((_pi_record("a", 2.0, 75, 0, 0.05, model, theta),
                    _pi_record("b", 5.0, 60, 1, 0.05, model, theta)))
    post = Posterior(data, model)
    z = post.space.sample_prior(np.random.default_rng(0), 16)
    units = post.log_likelihood_units(z)
    lp0 = np.atleast_1d(post.space.log_prior(z))
    for held in ([0], [1, 5], list(range(post.n_units))):
        h = post.holding_out(held)
        keep = np.setdiff1d(np.arange(post.n_units), held)
        np.testing.assert_allclose(h.log_prob_batch(z), lp0 + units[:, keep].sum(axis=1),
                                   rtol=1e-12)
        # the held-out posterior still simulates and scores every cycle on request
        np.testing.assert_allclose(h.log_likelihood_units(z), units, rtol=1e-12)
    np.testing.assert_allclose(post.holding_out([]).log_prob_batch(z), post.log_prob_batch(z))
    with pytest.raises(ParameterError, match="held-out units"):
        post.holding_out([post.n_units])


def test_task_seeds_depend_on_task_not_order():
    a, b = TaskSpec("pi_play", "lofo", 10.0, True), TaskSpec("pi_play", "lofo", 20.0, True)
    assert task_seed(0, a) == task_seed(0, TaskSpec("pi_play", "lofo", 10.0, True))
    assert len({task_seed(0, a), task_seed(0, b), task_seed(1, a)}) == 3
    assert a.key == "pi_play__lofo_10Hz"
    keys = {TaskSpec(m, "joint").key for m in ("pi_play(n_operators=4)+second_order",
                                               "pi_play(n_operators=4)+second-order")}
    assert len(keys) == 2
    assert all(re.fullmatch(r"[A-Za-z0-9._-]+", k) for k in keys)
    assert min(keys).startswith("pi_play-n_operators-4-second")


def test_check_models_messages():
    assert check_models("pi_play(n_operators=4, ), bouc_wen,gp") == (
        "pi_play(n_operators=4, )", "bouc_wen", "gp")
    with pytest.raises(ModelError, match="more than once"):
        check_models(["bouc_wen", "bouc_wen"])
    with pytest.raises(ModelError, match="unknown model 'pi_plya'"):
        check_models("pi_plya")
    with pytest.raises(ModelError, match="non-empty"):
        check_models("pi_play,,bouc_wen")


def test_rank_by_elpd_by_hand():
    """Totals, se = sqrt(n var), paired differences to the best, written out by hand;
    a tie keeps the caller's order; different cycle counts are refused."""
    a = np.array([-1.0, -2.0, -0.5, -1.5])
    b = np.array([-0.5, -1.0, -1.0, -1.0])  # total -3.5, the best
    c = a.copy()                             # ties with a
    ranked = rank_by_elpd({"a": a, "b": b, "c": c}, stacking=True)
    assert [r.model for r in ranked] == ["b", "a", "c"]
    top, second = ranked[0], ranked[1]
    assert top.elpd == pytest.approx(-3.5) and top.delta_elpd == 0.0 and top.delta_se == 0.0
    assert top.se == pytest.approx(math.sqrt(4 * np.var(b)))
    diff = a - b
    assert second.elpd == pytest.approx(-5.0)
    assert second.delta_elpd == pytest.approx(diff.sum())
    assert second.delta_se == pytest.approx(math.sqrt(4 * np.var(diff)))
    assert sum(r.weight for r in ranked) == pytest.approx(1.0)
    assert [r.model for r in rank_by_elpd({"c": c, "a": a})] == ["c", "a"]
    with pytest.raises(ModelError, match="different numbers of cycles"):
        rank_by_elpd({"a": a, "short": b[:3]})
    assert rank_by_elpd({}) == ()


def test_study_summary_ranks_like_the_comparison():
    """One dataset, one frequency: the study's ranking (elpd, Δelpd, se) is the
    comparison's ranking of the same pointwise elpd."""
    from bayeshyst.study.summary import summarise

    rng = np.random.default_rng(3)
    pw = {m: rng.normal(mu, 1.0, 12) for m, mu in (("m1", -2.0), ("m2", -1.0), ("m3", -1.5))}
    rows = [{"likelihood": "gaussian", "dataset": "d", "frequency_hz": 5.0, "n_records": 1,
             "model": m, "status": "ok", "task": m, "nrmse_percent": 1.0, "converged": True}
            for m in pw]
    rankings, summaries = summarise(rows, pw, list(pw))
    expected = rank_by_elpd(pw)
    got = rankings[0].ranking
    assert [g.model for g in got] == [e.model for e in expected] == ["m2", "m3", "m1"]
    for g, e in zip(got, expected, strict=True):
        assert (g.elpd_loo, g.se, g.delta_elpd, g.delta_se) == pytest.approx(
            (e.elpd, e.se, e.delta_elpd, e.delta_se))
    assert [m.model for m in summaries[0].models] == ["m2", "m3", "m1"]
