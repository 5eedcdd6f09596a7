"""Hammerstein forms of review §10: additive cascaded dynamics [107], fractional order [111].

Oracles: ``creep_vibration`` against a slow pure-Python simulation (exact ZOH lags written
out, the stage by ``solve_ivp`` with the input linear between samples), its reduction to
``second_order`` at ``c = 0`` and the exact identity ``series - additive = sum_j c_j
L_j[G_v[w] - w]`` (the series cascade ``creep+second_order`` as the other side);
``bouc_wen_fractional`` against a Grünwald–Letnikov solution of ``τ^λ D^λ x + x = w`` on a
grid 50 times finer than the samples, its reduction at ``λ = 1`` to the integer-order
``bouc_wen+creep(n_terms=1)``, and its identity with ``bouc_wen+creep_fractional``.
Properties: continuation, batched == one-by-one, prior draws never NaN, affinity, rate
dependence, creep after a step, refused settings, posterior recovery.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special

from bayeshyst.data.record import Record
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models.blocks import block_class
from bayeshyst.models.hammerstein import CreepVibration, FractionalHammerstein
from bayeshyst.models.registry import get
from tests.test_bouc_wen_variants import ivp_stage

CV = {"c": np.array([0.04, 0.03, 0.02]), "tau": np.array([0.01, 0.05, 0.25]),
      "f_n": 80.0, "zeta": 0.15}


def _signal(n=300, seed=2):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.7e-3, 1.3e-3, n))
    t -= t[0]
    w = 10.0 + 8.0 * np.sin(2 * np.pi * 12 * t) + np.where(t > 0.15, 5.0, 0.0)
    return t, w + rng.normal(0.0, 0.2, n)


def slow_creep_vibration(t, w, c, tau, f_n, zeta):
    """Exact ZOH lags and the FOH stage (solve_ivp), from rest at ``w[0]``, added."""
    x = np.full(len(c), w[0])
    lags = np.empty(w.size)
    for k in range(w.size):
        if k:
            x = w[k - 1] + np.exp(-(t[k] - t[k - 1]) / tau) * (x - w[k - 1])
        lags[k] = np.dot(c, x)
    return (1.0 - c.sum()) * ivp_stage(t, w, f_n, zeta) + lags


def test_creep_vibration_matches_slow_python():
    t, w = _signal()
    y = CreepVibration().apply(w, t, CV).y
    y_ref = slow_creep_vibration(t, w, CV["c"], CV["tau"], CV["f_n"], CV["zeta"])
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-8 * np.ptp(y_ref))


def test_creep_vibration_without_creep_is_second_order():
    t, w = _signal()
    y = CreepVibration().apply(w, t, {**CV, "c": np.zeros(3)}).y
    ref = block_class("second_order")().apply(w, t, {"f_n": CV["f_n"], "zeta": CV["zeta"]}).y
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.ptp(ref))


def test_additive_differs_from_the_series_cascade_by_the_bypassing_creep():
    # series G_c G_v w minus additive (1 - sum c) G_v w + sum c L w is sum c L (G_v w - w);
    # the discrete blocks commute when the sampling is uniform (time-invariant)
    t, w = _signal()
    t = np.arange(t.size) * 1e-3
    creep = block_class("creep")()
    stage = block_class("second_order")()
    cth = {"c": CV["c"], "tau": CV["tau"]}
    sth = {"f_n": CV["f_n"], "zeta": CV["zeta"]}
    series = stage.apply(creep.apply(w, t, cth).y, t, sth).y
    additive = CreepVibration().apply(w, t, CV).y
    z = stage.apply(w, t, sth).y - w
    lag_z = creep.apply(z, t, cth).y - (1.0 - CV["c"].sum()) * z  # sum c_j L_j[z]
    np.testing.assert_allclose(series - additive, lag_z, rtol=0, atol=1e-10 * np.ptp(w))
    assert np.max(np.abs(lag_z)) > 1e-3 * np.ptp(w)  # and the difference is not nil


def test_creep_vibration_is_affine_and_continues_exactly():
    t, w = _signal()
    b = CreepVibration()
    w2 = np.cos(np.arange(w.size) / 7.0)
    lhs = b.apply(2.0 * w - 0.5 * w2, t, CV).y
    rhs = 2.0 * b.apply(w, t, CV).y - 0.5 * b.apply(w2, t, CV).y
    np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-10 * np.ptp(lhs))
    one = b.apply(w, t, CV)
    a = b.apply(w[:111], t[:111], CV)
    c = b.apply(w[111:], t[111:], CV, state0=a.state)
    np.testing.assert_array_equal(np.r_[a.y, c.y], one.y)


def test_creep_vibration_settings_are_checked_by_its_parts():
    with pytest.raises(ModelError, match="n_terms"):
        CreepVibration(n_terms=0)
    with pytest.raises(ModelError, match="hold"):
        CreepVibration(hold="cubic")


# ------------------------------------------------------------------ fractional order


def gl_fractional_lag(t_fine, w_fine, tau, lam):
    """``τ^λ D^λ x + x = w`` (Caputo, at rest) by the implicit Grünwald–Letnikov scheme."""
    d = t_fine[1] - t_fine[0]
    m = t_fine.size
    om = np.empty(m)
    om[0] = 1.0
    for j in range(1, m):
        om[j] = om[j - 1] * (1.0 - (lam + 1.0) / j)
    c = (tau / d) ** lam
    x = np.empty(m)
    x[0] = w_fine[0]
    for i in range(1, m):
        s = np.dot(om[1:i + 1], x[i - 1::-1] - x[0])
        x[i] = (w_fine[i] + c * x[0] - c * s) / (1.0 + c)
    return x


FH = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3, "gain": 0.5,
      "tau": 0.02, "lam": 0.6}


def _drive(n=200, dt=1e-3):
    t = np.arange(n) * dt
    return t, 75.0 - 60.0 * np.cos(2 * np.pi * 7.0 * t) + np.where(t > 0.12, 10.0, 0.0)


def test_fractional_hammerstein_matches_grunwald_letnikov():
    t, u = _drive()
    y = FractionalHammerstein().simulate(u, t, FH)
    w = get("bouc_wen").simulate(u, t, {k: FH[k] for k in ("k", "alpha", "beta", "gamma",
                                                            "n")})
    sub = 50
    t_fine = np.arange((t.size - 1) * sub + 1) * (t[1] / sub)
    # the input held between samples: on (t_(k-1), t_k] the fine grid sees w_(k-1)
    w_fine = np.r_[w[0], np.repeat(w[:-1], sub)]
    x = gl_fractional_lag(t_fine, w_fine, FH["tau"], FH["lam"])[::sub]
    y_ref = (1.0 - FH["gain"]) * w + FH["gain"] * x
    # GL is first order in its step and the diffusive grid is ~1e-3 accurate
    assert np.max(np.abs(y - y_ref)) <= 3e-3 * np.ptp(y_ref)


def test_fractional_hammerstein_at_order_one_is_the_integer_order_lead_lag():
    t, u = _drive()
    y = FractionalHammerstein().simulate(u, t, {**FH, "lam": 1.0})
    ref = get("bouc_wen+creep(n_terms=1)").simulate(u, t, {
        **{f"static.{k}": FH[k] for k in ("k", "alpha", "beta", "gamma", "n")},
        "creep.c": [FH["gain"]], "creep.tau": [FH["tau"]]})
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.ptp(ref))


def test_fractional_hammerstein_is_bouc_wen_plus_creep_fractional():
    t, u = _drive()
    y = FractionalHammerstein().simulate(u, t, FH)
    ref = get("bouc_wen+creep_fractional").simulate(u, t, {
        **{f"static.{k}": FH[k] for k in ("k", "alpha", "beta", "gamma", "n")},
        **{f"creep_fractional.{k}": FH[k] for k in ("gain", "tau", "lam")}})
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.ptp(ref))


def _ml_series(lam, z, terms=80):
    k = np.arange(terms)
    return np.sum((-z[:, None]) ** k / special.gamma(lam * k + 1), axis=1)


def test_fractional_hammerstein_creeps_after_a_step_as_mittag_leffler():
    # alpha -> 0: w = k u; after a step of u the output creeps by g (1 - E_lam(-(t/tau)^lam))
    t = np.r_[0.0, np.arange(1, 400) * 1e-3]
    u = np.r_[0.0, np.full(399, 100.0)]
    th = {**FH, "alpha": 1e-12}
    y = FractionalHammerstein().simulate(u, t, th)
    x = (t[1:] - t[1]) / th["tau"]
    small = x ** th["lam"] < 1.2
    expected = 30.0 * (1.0 - th["gain"] * _ml_series(th["lam"], x[small] ** th["lam"]))
    np.testing.assert_allclose(y[1:][small], expected, atol=2e-3 * 30.0)
    assert np.all(np.diff(y[1:]) >= -1e-12)  # creep never reverses


def test_fractional_hammerstein_is_rate_dependent():
    m = FractionalHammerstein()
    spans = []
    for f in (0.5, 40.0):
        t = np.arange(0, 3.0 / f, 1.0 / (400 * f))
        y = m.simulate(75 - 60 * np.cos(2 * np.pi * f * t), t, FH)
        spans.append(np.ptp(y[t >= 2.0 / f]))
    assert spans[1] < 0.9 * spans[0]


# ---------------------------------------------------------------- shared properties

MODELS = {"bouc_wen_fractional": FH,
          "pi_play(n_operators=4)+creep_vibration": None}


def _theta(name, rec):
    m = get(name)
    if MODELS[name] is not None:
        return m, {k: np.array([v]) for k, v in MODELS[name].items()}
    space = m.param_space(rec)
    return m, space.unpack(space.sample_prior(np.random.default_rng(5), 1))


@pytest.mark.parametrize("name", list(MODELS))
def test_pieces_batches_and_prior_draws(name):
    t, u = _drive(300)
    rec = Record(t=t, u=u, y=0.3 * u, name="r")
    m, theta = _theta(name, rec)
    one = m.run_batch(u, t, theta)
    a = m.run_batch(u[:123], t[:123], theta)
    b = m.run_batch(u[123:], t[123:], theta, state0=a.state)
    # Bouc–Wen recomputes |h|^n at the start of a run: pieces agree to rounding
    np.testing.assert_allclose(np.c_[a.y, b.y], one.y, rtol=1e-12, atol=0)
    space = m.param_space(rec)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(1), 30))
    traj = m.run_batch(u, t, thetas)
    ok = ~traj.failed
    assert ok.sum() >= 20 and np.all(np.isfinite(traj.y[ok]))
    assert np.all(np.isnan(traj.y[traj.failed]))
    for j in np.flatnonzero(ok)[:3]:
        single = m.run_batch(u, t, {k: v[j:j + 1] for k, v in thetas.items()})
        np.testing.assert_array_equal(single.y[0], traj.y[j])


def test_fractional_hammerstein_linear_design_reproduces_the_output():
    t, u = _drive()
    m = FractionalHammerstein()
    theta = {k: np.array([v]) for k, v in FH.items()}
    design = m.linear_design(u, t, theta)
    y = m.run_batch(u, t, theta).y
    np.testing.assert_allclose(design.predict(theta["k"][:, None]), y, rtol=0,
                               atol=1e-10 * np.ptp(y))


def test_fractional_hammerstein_refuses_bad_settings_and_times():
    with pytest.raises(ModelError, match="n_modes"):
        FractionalHammerstein(n_modes=1)
    with pytest.raises(ModelError, match="per_decade"):
        FractionalHammerstein(per_decade=-1.0)
    t, u = _drive(20)
    with pytest.raises(ParameterError, match="strictly increasing"):
        FractionalHammerstein().simulate(u, t[::-1], FH)


def test_tau_prior_spans_sampling_period_to_record_length():
    t = np.arange(10_000) * 1e-4
    rec = Record(t=t, u=np.sin(t), y=np.sin(t), name="r")
    prior = FractionalHammerstein().param_space(rec)["tau"].prior
    lo, hi = math.exp(prior.mu - 2 * prior.sigma), math.exp(prior.mu + 2 * prior.sigma)
    assert lo == pytest.approx(1e-4, rel=1e-3) and hi == pytest.approx(t[-1], rel=1e-3)


# ------------------------------------------------------------------ posterior recovery

FH_TRUTH = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3, "gain": 0.3,
            "tau": 0.05, "lam": 0.6}


def fh_record(seed, n=1500, sigma=0.05):
    """A 2 Hz sine, a held step (creep), then a 10 Hz sine, at 1 kHz."""
    t = np.arange(n) * 1e-3
    u = np.where(t < 0.5, 75.0 - 75.0 * np.cos(2 * np.pi * 2.0 * t), 110.0)
    u = np.where(t >= 1.0, 75.0 - 35.0 * np.cos(2 * np.pi * 10.0 * (t - 1.0)), u)
    y = FractionalHammerstein().simulate(u, t, FH_TRUTH)
    y = y + np.random.default_rng(seed).normal(0.0, sigma, n)
    return Record(t=t, u=u, y=y, name=f"fh{seed}", warmup=150)


def _fh_stats(seeds):
    from bayeshyst.inference.posterior import Posterior
    from tests.test_recovery import _fit_stats

    out = []
    for seed in seeds:
        post = Posterior(fh_record(seed), "bouc_wen_fractional")
        out.append(_fit_stats(post, {**FH_TRUTH, "obs.offset": 0.0, "noise.sigma": 0.05},
                              seed))
    return out, post.ndim


@pytest.mark.slow
def test_fractional_hammerstein_posterior_is_calibrated():
    # oracle: the truth's squared Mahalanobis distances over independent fits ~ chi2
    from tests.test_recovery import _check_calibration

    fits, ndim = _fh_stats(range(5))
    _check_calibration(fits, ndim)


CV_SPEC = "pi_play(n_operators=4)+creep_vibration(n_terms=2)"


def cv_record(seed, n=2000, sigma=0.05):
    """Truth drawn from the prior (PI weights kept positive, creep gains a few percent)."""
    model = get(CV_SPEC)
    t = np.arange(n) * 5e-4
    u = np.where(t < 0.4, 75.0 - 75.0 * np.cos(2 * np.pi * 5.0 * t), 100.0)
    u = np.where(t >= 0.6, 75.0 - 40.0 * np.cos(2 * np.pi * 60.0 * (t - 0.6)), u)
    rec0 = Record(t=t, u=u, y=0.3 * u, name="scale")
    space = model.param_space(rec0)
    theta = space.unpack(space.sample_prior(np.random.default_rng(100 + seed), 1))
    theta["static.w"] = np.abs(theta["static.w"])
    theta["static.p0"] = np.abs(theta["static.p0"])
    theta["creep_vibration.c"] = np.array([[0.03, 0.02]])
    theta["creep_vibration.f_n"] = np.array([150.0])
    theta["creep_vibration.zeta"] = np.array([0.2])
    y = model.run_batch(u, t, theta).y[0] + np.random.default_rng(seed).normal(0, sigma, n)
    truth = {k: v[0] for k, v in theta.items() if k in space.names}
    return Record(t=t, u=u, y=y, name=f"cv{seed}", warmup=200), truth


@pytest.mark.slow
def test_additive_hammerstein_posterior_is_calibrated():
    from bayeshyst.inference.posterior import Posterior
    from tests.test_recovery import _check_calibration, _fit_stats

    fits = []
    for seed in range(5):
        rec, truth = cv_record(seed)
        post = Posterior(rec, CV_SPEC)
        fits.append(_fit_stats(post, {**truth, "obs.offset": 0.0, "noise.sigma": 0.05},
                               seed))
    _check_calibration(fits, post.ndim)
