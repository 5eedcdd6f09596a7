"""The MAP search: least squares with variable projection, Gauss–Newton Laplace, fallback.

Oracles: the conjugate posterior of PI weights (its mode and covariance are the MAP and
the Laplace covariance exactly), a known truth on simulated Bouc–Wen data, and a
posterior built with two basins (a delay aliased by one period of the drive).
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data import Record
from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.least_squares import gauss_newton_covariance
from bayeshyst.inference.optimize import find_map, laplace_covariance
from bayeshyst.inference.posterior import Posterior
from bayeshyst.models import get
from tests.synthetic import pi_data


def test_map_and_laplace_of_a_linear_model_are_the_conjugate_posterior():
    model, rec, _ = pi_data(n_ops=3, sigma=0.05)
    post = Posterior(rec, model).fix("noise.sigma", 0.05)
    exact = conjugate_posterior(post)
    for seed in (0, 1):
        m = find_map(post, seed=seed)
        # Normal priors, identity transforms: z is the value; the posterior is Gaussian
        np.testing.assert_allclose(m.z, exact.mean, rtol=0, atol=1e-6 * exact.sd.min())
        np.testing.assert_allclose(m.covariance, exact.cov, rtol=1e-6,
                                   atol=1e-9 * float(np.max(np.abs(exact.cov))))
        assert m.laplace_ok and m.notes == ()


def test_gauss_newton_matches_the_finite_difference_hessian_at_a_bouc_wen_map():
    t = np.arange(3000) * 5e-4
    u = 75.0 - 75.0 * np.cos(2 * np.pi * t) * np.exp(-0.3 * t)
    truth = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3}
    y = get("bouc_wen").simulate(u, t, truth) + np.random.default_rng(0).normal(0, 0.05, t.size)
    post = Posterior(Record(t=t, u=u, y=y, name="bw", warmup=200), "bouc_wen")
    m = find_map(post, seed=0)
    theta = m.theta
    sd = np.sqrt(np.diag(m.covariance))
    for k, v in truth.items():  # the truth within 4 Laplace sd of the MAP (z coordinates)
        z_true = post.space[k].transform.forward(np.asarray(v))
        i = post.space.slice_of(k).start
        assert abs(float(z_true) - m.z[i]) < 4 * sd[i], (k, theta[k], v)
    gn, ok, _ = gauss_newton_covariance(post, None, m.z)
    fd, ok_fd = laplace_covariance(post, m.z)
    assert ok and ok_fd
    # near the optimum of a well-fitted model the residual curvature is small: the two
    # agree on every marginal sd to 10 %
    np.testing.assert_allclose(np.sqrt(np.diag(gn)), np.sqrt(np.diag(fd)), rtol=0.1)
    np.testing.assert_allclose(np.sqrt(np.diag(m.covariance)), np.sqrt(np.diag(fd)), rtol=0.1)


def _aliased_delay():
    """A sine through a delay: ``d`` and ``d`` + one period fit all but the first period,
    so the posterior has two basins, the true one deeper."""
    fs, f = 2000.0, 20.0
    t = np.arange(1200) / fs
    u = 75.0 + 60.0 * np.sin(2 * np.pi * f * t)
    model = get("pi_play(n_operators=2)+delay(max_delay_samples=160)")
    space = model.param_space(Record(t=t, u=u, y=0.3 * u, name="x"))
    theta = {"static.p0": 0.2, "static.w": np.array([0.05, 0.03]),
             "static.r": space.fixed["static.r"], "delay.d": 0.2 / f}
    y = model.simulate(u, t, theta) + np.random.default_rng(1).normal(0, 0.02, t.size)
    return model, Record(t=t, u=u, y=y, name="delay", warmup=0), 1.0 / f


def test_starts_in_different_basins_are_settled_and_say_so():
    model, rec, period = _aliased_delay()
    post = Posterior(rec, model)
    good = find_map(post, seed=0, global_search=False)
    d_good = good.theta["delay.d"]
    assert abs(d_good - 0.2 * period) < 0.01 * period
    # an extra start one period later: least squares stays in that basin, the starts
    # disagree; more starts from the screen reach the deeper basin twice
    theta = dict(good.theta)
    theta["delay.d"] = d_good + period
    x0 = post.space.pack({k: v for k, v in theta.items() if k in post.space.names})
    res = find_map(post, seed=0, x0=x0, n_starts=2)
    assert any("different optima" in n for n in res.notes), res.notes
    assert abs(res.theta["delay.d"] - 0.2 * period) < 0.01 * period
    assert len(res.candidates) >= 2 and res.candidates[0] - res.candidates[1] > 0.5
    # with a screen of one draw there are no more starts to ask: the global search runs
    one = find_map(post, seed=0, x0=x0, n_starts=2, n_screen=1)
    assert any("differential evolution" in n for n in one.notes), one.notes
    assert abs(one.theta["delay.d"] - 0.2 * period) < 0.01 * period
    # with the fallback off the disagreement is not searched (and not claimed to be)
    alone = find_map(post, seed=0, x0=x0, n_starts=2, n_screen=1, global_search=False)
    assert not any("differential evolution" in n for n in alone.notes)


def _resonance_in_the_prior_tail(seeds=(0, 1, 2)):
    """PI + second order at 10 kHz whose resonance sits 4.5 prior sd below the prior
    median of f_n (fs / 20 = 500 Hz, log-sd 1): 5.6 Hz, lightly damped, driven at 2 Hz."""
    fs = 10_000.0
    t = np.arange(8000) / fs
    u = 75.0 - 75.0 * np.cos(2 * np.pi * 2.0 * t)
    model = get("pi_play(n_operators=2)+second_order")
    space = model.param_space(Record(t=t, u=u, y=0.3 * u, name="x"))
    f_n = 500.0 * np.exp(-4.5)
    theta = {"static.p0": 0.2, "static.w": np.array([0.05, 0.03]),
             "static.r": space.fixed["static.r"], "second_order.f_n": f_n,
             "second_order.zeta": 0.1}
    y = model.simulate(u, t, theta) + np.random.default_rng(0).normal(0, 0.05, t.size)
    return model, Record(t=t, u=u, y=y, name="tail", warmup=0), f_n


def test_global_search_reaches_a_mode_far_in_the_prior_tail():
    # the data put f_n 4.5 prior sd from the median, beyond the prior's central 99.99 %;
    # the profiled differential evolution must search there (over three seeds)
    from bayeshyst.inference.linear import LinearStructure
    from bayeshyst.inference.optimize import _global_search

    model, rec, f_n = _resonance_in_the_prior_tail()
    post = Posterior(rec, model)
    structure = LinearStructure.of(post)
    for seed in (0, 1, 2):
        rng = np.random.default_rng(seed)
        cand = post.space.sample_prior(rng, 64)
        f = -post.log_prob_batch(cand)
        f = np.where(np.isfinite(f), f, 1e300)
        z = _global_search(post, rng, cand, f, 40, structure)
        found = post.space.unpack(z)["second_order.f_n"]
        assert abs(found / f_n - 1.0) < 0.05, (seed, found, f_n)


def _offset_mode_missed():
    """pi_play(2) data, its MAP, and a "MAP" 30 posterior sd off in the offset with its
    own (much lower) density: a start that is not the mode."""
    from dataclasses import replace

    _, rec, _ = pi_data(n_ops=2, n=600)
    post = Posterior(rec, get("pi_play", n_operators=2))
    true_map = find_map(post, seed=0)
    z = true_map.z.copy()
    j = int(np.arange(post.ndim)[post.space.slice_of("obs.offset")][0])
    z[j] += 30 * np.sqrt(true_map.covariance[j, j])
    wrong = replace(true_map, z=z, log_prob=float(post.log_prob(z)),
                    theta=post.space.unpack(z), notes=())
    return post, true_map, wrong, j


def test_walkers_above_the_map_restart_the_run_from_the_better_mode(tmp_path):
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings

    post, true_map, wrong, j = _offset_mode_missed()
    settings = SamplerSettings(seed=2, max_steps=2000)
    # from the real MAP no walker exceeds its density by more than the polish tolerance
    ok = sample_posterior(post, settings.replace(max_steps=200), start=true_map)
    assert not any("restarted" in n for n in ok.start.notes)
    # from the wrong one the walkers climb past it: the run restarts from the polished
    # optimum, says so, and samples the posterior around the real mode
    res = sample_posterior(post, settings, start=wrong)
    assert any("restarted" in n for n in res.start.notes), res.start.notes
    assert res.start.log_prob > true_map.log_prob - 0.1
    assert res.converged
    sd = np.sqrt(true_map.covariance[j, j])
    assert abs(np.mean(res.flat_z[:, j]) - true_map.z[j]) < 0.5 * sd
    # the restart is a fixed function of the chain: with a checkpoint the same draws,
    # and the finished checkpoint read back gives them again
    ck = settings.replace(checkpoint=tmp_path / "run.h5")
    first = sample_posterior(post, ck, start=wrong)
    again = sample_posterior(post, ck, start=wrong)
    np.testing.assert_array_equal(first.chains, res.chains)
    np.testing.assert_array_equal(again.chains, res.chains)


def test_a_run_out_of_restarts_names_the_missed_mode(monkeypatch):
    from bayeshyst.inference import sampling
    from bayeshyst.inference.settings import SamplerSettings

    post, _, wrong, _ = _offset_mode_missed()
    monkeypatch.setattr(sampling, "MAX_RESTARTS", 0)
    res = sampling.sample_posterior(post, SamplerSettings(seed=2, max_steps=20, first_chunk=20,
                                                          warmup=6), start=wrong)
    assert not res.converged
    assert any("missed the main mode" in r for r in res.convergence.reasons)


def _inert_exponent():
    """Bouc–Wen with ``beta`` and ``gamma`` held at ~0: the loop is ``k u + alpha u``,
    the exponent ``n`` moves the output by a negligible amount and its posterior is its
    prior."""
    t = np.arange(1500) * 1e-3
    u = 50.0 * np.sin(2 * np.pi * t)
    y = 0.4 * u + np.random.default_rng(3).normal(0, 0.05, t.size)
    rec = Record(t=t, u=u, y=y, name="inert", warmup=100)
    return (Posterior(rec, "bouc_wen").fix("beta", 1e-15).fix("gamma", 0.0)
            .fix("noise.sigma", 0.05))


def test_least_squares_stays_where_a_flat_bounded_coordinate_still_means_something():
    from bayeshyst.inference.least_squares import least_squares_point

    post = _inert_exponent()
    i = post.space.slice_of("n").start
    # the exponent's own coordinate (probit since dfad011: 8.2; the logit's was 36.7)
    edge = post.space["n"].transform.saturation
    for seed in range(4):  # starts anywhere in the prior, and one far past saturation
        z0 = post.space.sample_prior(np.random.default_rng(seed), 1)[0]
        z0[i] = (-1.0, 2.0, -1e4, 1e4)[seed]
        z, _ = least_squares_point(post, None, z0)
        assert np.all(np.isfinite(z))
        # beyond it n is its bound to double precision: nothing there to search for
        assert abs(z[i]) <= edge


def test_the_map_of_an_inert_bounded_coordinate_is_its_prior_mode_in_z():
    """Oracle: with ``n`` inert its posterior in ``z`` is prior times Jacobian, whose
    mode a scalar search finds independently; the MAP search must land there and
    never below an explicit start (it once returned a point 1.7e9 nats below it)."""
    from scipy import optimize as sopt

    post = _inert_exponent()
    p = post.space["n"]
    i = post.space.slice_of("n").start

    def neg(zn):
        return -float(p.prior.logpdf(p.transform.inverse(np.asarray(zn)))
                      + p.transform.log_jacobian(np.asarray(zn)))

    mode = sopt.minimize_scalar(neg, bounds=(-30.0, 30.0), method="bounded",
                                options={"xatol": 1e-9}).x
    for seed in (0, 1):
        start = find_map(post, seed=seed)
        assert abs(start.z[i] - mode) < 1e-3, (start.z[i], mode)
        x0 = start.z.copy()
        x0[i] = -8.0  # a walker far out in the prior's tail
        m = find_map(post, seed=seed, x0=x0, n_screen=16, n_starts=1, global_search=False)
        assert m.log_prob >= float(post.log_prob(x0))
        assert abs(m.z[i] - mode) < 1e-3, (m.z[i], mode)


def _bouc_wen_record(seed=0):
    t = np.arange(3000) * 5e-4
    u = 75.0 - 75.0 * np.cos(2 * np.pi * t) * np.exp(-0.3 * t)
    truth = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3}
    y = get("bouc_wen").simulate(u, t, truth) + np.random.default_rng(seed).normal(0, 0.05,
                                                                                    t.size)
    return Record(t=t, u=u, y=y, name="bw", warmup=200)


def _gradient(post, z, h=1e-5):
    """Central-difference gradient of log p, one coordinate at a time (the slow oracle)."""
    g = np.empty(z.size)
    for i in range(z.size):
        e = np.zeros(z.size)
        e[i] = h * max(1.0, abs(z[i]))
        g[i] = (post.log_prob(z + e) - post.log_prob(z - e)) / (2 * e[i])
    return g


@pytest.mark.parametrize("shift", [-8.0, 5.0, 12.0])
def test_the_profiled_search_climbs_from_far_below_to_the_joint_mode(shift):
    from bayeshyst.inference.linear import LinearStructure
    from bayeshyst.inference.profile import profile_mode

    post = Posterior(_bouc_wen_record(), "bouc_wen")
    m = find_map(post, seed=0)
    sd = np.sqrt(np.diag(m.covariance))
    # the nonlinear coordinates moved `shift` Laplace sd along the posterior's ridge
    # direction and beyond it, the linear gain left where it was: hundreds of nats down
    z0 = m.z.copy()
    structure = LinearStructure(post, reference=m.z)
    other = structure.other_idx
    z0[other] += shift * sd[other] * np.where(np.arange(other.size) % 2 == 0, 1.0, -0.5)
    assert post.log_prob(z0) < m.log_prob - 50
    lp, z = profile_mode(post, structure, z0)
    assert lp == pytest.approx(post.log_prob(z), abs=1e-9)
    # the joint mode: as high as the full search's (within its tolerance) and at it
    assert lp > m.log_prob - 0.01
    assert np.all(np.abs(z - m.z) < 0.05 * sd), (z - m.z) / sd
    # and stationary in every coordinate, the block's included (the slow oracle)
    g = _gradient(post, z)
    assert np.all(np.abs(g * sd) < 0.05), g * sd


def test_a_start_on_another_fits_discrepancy_is_the_joint_mode():
    from scipy import optimize

    from bayeshyst.inference.discrepancy_fit import attach_discrepancy
    from bayeshyst.inference.linear import LinearStructure

    # the diagnosis' pattern: a candidate (Bouc-Wen with drift) on the shape correction
    # of the fit it augments (Bouc-Wen alone), on data with dynamics neither has. The
    # correction is orthogonal to the smaller model's sensitivities only: the candidate's
    # mode with it lies tens of nats above the candidate's own MAP carried over
    rec = _bouc_wen_record()
    truth = {"static.k": 0.3, "static.alpha": 0.12, "static.beta": 0.004,
             "static.gamma": 0.001, "static.n": 1.3, "second_order.f_n": 40.0,
             "second_order.zeta": 0.3}
    y = get("bouc_wen+second_order").simulate(rec.u, rec.t, truth)
    y = y + np.random.default_rng(1).normal(0, 0.05, rec.t.size)
    data = Record(t=rec.t, u=rec.u, y=y, name="bw2", warmup=200)
    smaller = Posterior(data, "bouc_wen")
    disc = attach_discrepancy(smaller, find_map(smaller, seed=0), "hsgp")[0].discrepancy
    cand = Posterior(data, "bouc_wen+drift")
    m = find_map(cand, seed=0)
    post, _, start = attach_discrepancy(cand, m, disc)
    assert start.log_prob == pytest.approx(post.log_prob(start.z), abs=1e-9)
    # the carried point: the candidate's MAP, the coefficients at their conditional mean
    carried = post.space.sample_prior(np.random.default_rng(0), 1)[0]
    for n in cand.space.names:
        if n in post.space.names:
            carried[post.space.slice_of(n)] = m.z[cand.space.slice_of(n)]
    structure = LinearStructure(post, reference=carried)
    cond = structure.conditional(structure.stats(carried[None]), carried[None])
    carried[structure.lin_idx] = structure.z_of(cond.mean)[0][0]
    assert start.log_prob > post.log_prob(carried) + 20
    # a local optimum: a derivative-free search over every coordinate gains nothing
    # (from the carried point it gains 0.24 nats and stops 35 below the start)
    best = optimize.minimize(lambda z: -post.log_prob(z), start.z, method="Powell",
                             options={"maxiter": 20_000, "maxfev": 200_000})
    assert -best.fun < start.log_prob + 0.05, (start.log_prob, -best.fun)




class _Stored:
    """What _bulk_above reads of an emcee sampler: its stored log densities."""

    def __init__(self, lp):
        self._lp = lp

    def get_log_prob(self):
        return self._lp


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_after_the_warm_up_only_the_bulk_of_the_draws_above_the_start_restarts(seed):
    from bayeshyst.inference.sampling import MAP_SLACK, _bulk_above

    # exact draws of a 20-dimensional Gaussian: log p = mode - chi2_20 / 2, whose median
    # lies 9.67 nats below the mode (scipy.stats.chi2(20).median() / 2)
    rng = np.random.default_rng(seed)
    mode = 100.0
    lp = [mode - 0.5 * rng.chisquare(20, size=(2000, 32)) for _ in range(2)]
    samplers = [[_Stored(x), None] for x in lp]
    # a start 3 nats below the mode: some walker passes it by more than the slack (a
    # restart before), but the draws sample its region: no restart after the warm-up
    assert max(float(x.max()) for x in lp) > mode - 3.0 + MAP_SLACK
    assert not _bulk_above(samplers, 2000, mode - 3.0)
    # a start 15 nats below: most draws lie above it, it is not their region's mode
    assert _bulk_above(samplers, 2000, mode - 15.0)
