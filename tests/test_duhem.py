"""Duhem (Coleman–Hodgdon, Eq. 45) and improved Duhem (Eq. 46) against oracles.

Oracles: ``solve_ivp`` integrating the review's equations in *time* (raw variables,
parameters mapped with the documented formulas), closed-form branch solutions, the
incomplete gamma function for the moment kernel. Then properties: state continuation,
batched == one-by-one, rate independence, loop widening, failure flags.
"""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import Polynomial
from scipy import special
from scipy.integrate import solve_ivp

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models import get
from bayeshyst.models._kernels.duhem import exp_moments
from bayeshyst.models.duhem import Duhem, ImprovedDuhem
from tests.contracts import (
    assert_batch_equals_single,
    assert_pieces_match,
    assert_prior_draws_simulate,
)

TOL = 1e-6  # of the stroke, vs solve_ivp at rtol 1e-10


def _inputs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 2.0, 241)
    sine = 60.0 + 55.0 * np.sin(2 * np.pi * 1.5 * t)
    decay = 60.0 + 55.0 * np.exp(-0.8 * t) * np.sin(2 * np.pi * 2.0 * t + 0.3)
    walk = 60.0 + np.cumsum(rng.normal(0.0, 4.0, t.size))
    return {"sine": (sine, t), "decaying": (decay, t), "random_walk": (walk, t)}


INPUTS = _inputs()
DATA = SimpleNamespace(t=np.linspace(0, 1, 201), u=np.linspace(5.0, 115.0, 201),
                       y=np.linspace(0.0, 12.0, 201))


def _piecewise_ivp(rhs, u, t, x0, extra=()):
    """Integrate ``rhs(tau, x, v, vdot)`` interval by interval (input linear between samples)."""
    x = np.atleast_1d(np.asarray(x0, float))
    out = [x.copy()]
    for k in range(1, u.size):
        vdot = (u[k] - u[k - 1]) / (t[k] - t[k - 1])

        def f(tau, xx, k=k, vdot=vdot):
            return rhs(tau, xx, u[k - 1] + vdot * (tau - t[k - 1]), vdot)

        sol = solve_ivp(f, (t[k - 1], t[k]), x, method="DOP853", rtol=1e-10, atol=1e-13)
        x = sol.y[:, -1]
        out.append(x.copy())
    return np.array(out)


def _duhem_theta():
    return {"alpha": 2.5, "f": np.array([6.0, 5.5, 0.4, -0.6]), "g": np.array([1.2, -0.3]),
            "u_centre": 60.0, "u_half": 55.0}


# --------------------------------------------------------------------- moment kernel
@pytest.mark.parametrize("mu", [0.0, 1e-9, 0.37, 1.0, 4.9, 9.0, 9.2, 30.0, 400.0])
def test_exp_moments_match_incomplete_gamma(mu):
    m = 8
    J = np.empty(m + 1)
    exp_moments(mu, m, J)
    k = np.arange(m + 1)
    if mu == 0.0:
        ref = 1.0 / (k + 1)
    else:
        # J_k = gamma(k + 1, mu) / mu^(k + 1), regularised gammainc times k!
        ref = special.gammainc(k + 1, mu) * special.factorial(k) / mu ** (k + 1)
    np.testing.assert_allclose(J, ref, rtol=1e-13)


# --------------------------------------------------------------------- Duhem oracles
@pytest.mark.parametrize("which", list(INPUTS))
def test_duhem_matches_solve_ivp(which):
    u, t = INPUTS[which]
    model = Duhem(3, 1)
    theta = _duhem_theta()
    a_v, f_v, g_v = model.polynomials(theta)  # the review's raw-variable form

    def rhs(tau, w, v, vdot):
        return [a_v * abs(vdot) * (f_v(v) - w[0]) + vdot * g_v(v)]

    ref = _piecewise_ivp(rhs, u, t, f_v(u[0]))[:, 0]
    y = model.simulate(u, t, theta)
    assert np.max(np.abs(y - ref)) <= TOL * np.ptp(ref)


def test_duhem_linear_f_constant_g_closed_form():
    # f(s) = a s, g = b: on a branch w(s) = a s + (b - a)/lam + (w0 - ...) e^{-lam (s - s0)}
    a, b, alpha = 1.7, 0.4, 3.0
    theta = {"alpha": alpha, "f": np.array([0.0, a]), "g": np.array([b]),
             "u_centre": 0.0, "u_half": 1.0}
    model = Duhem(1, 0)
    u = np.concatenate([np.linspace(0, 1, 50), np.linspace(1, -0.6, 70)[1:],
                        np.linspace(-0.6, 0.8, 60)[1:]])
    y = model.simulate(u, u, theta)
    turns = [0, 49, 118, u.size - 1]
    w0 = 0.0  # relaxed: f(0) = 0
    for i0, i1 in itertools.pairwise(turns):
        s = u[i0:i1 + 1]
        lam = alpha * np.sign(s[-1] - s[0])
        c0 = (b - a) / lam
        ref = a * s + c0 + (w0 - a * s[0] - c0) * np.exp(-lam * (s - s[0]))
        np.testing.assert_allclose(y[i0:i1 + 1], ref, rtol=0, atol=1e-13)
        w0 = ref[-1]


def test_duhem_is_linear_in_f_and_g():
    u, t = INPUTS["random_walk"]
    model = Duhem(3, 1)
    theta = _duhem_theta()
    phi = model.regressors(u, u, theta)
    coef = np.concatenate([theta["f"], theta["g"]])
    np.testing.assert_allclose(phi @ coef, model.simulate(u, t, theta), rtol=0, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.01, 10.0), min_size=60, max_size=60))
def test_duhem_rate_independent_under_time_warp(steps):
    u, t = INPUTS["random_walk"]
    u = u[:61]
    warped = np.concatenate([[0.0], np.cumsum(steps)])
    model = Duhem(3, 1)
    theta = _duhem_theta()
    np.testing.assert_array_equal(model.simulate(u, t[:61], theta),
                                  model.simulate(u, warped, theta))


# ------------------------------------------------------------ improved Duhem oracles
def _improved_theta():
    return {"k": 0.11, "p": 2e-3, "alpha": 1.5, "beta": 2.2, "gamma": -0.7,
            "u_centre": 60.0, "u_half": 55.0}


def _backward_derivative(u, t):
    d = np.zeros_like(u)
    d[1:] = np.diff(u) / np.diff(t)
    return d


@pytest.mark.parametrize("which", list(INPUTS))
def test_improved_duhem_matches_solve_ivp(which):
    u, t = INPUTS[which]
    model = ImprovedDuhem()
    theta = _improved_theta()
    pub = model.published_parameters(theta)  # review Eq. 46 in raw variables

    def rhs(tau, h, v, vdot):
        return [pub["a"] * vdot - pub["b"] * abs(vdot) * h[0] + pub["c"] * v * vdot]

    h = _piecewise_ivp(rhs, u, t, 0.0)[:, 0]
    ref = pub["k"] * u + pub["p"] * _backward_derivative(u, t) - h
    y = model.simulate(u, t, theta)
    assert np.max(np.abs(y - ref)) <= TOL * np.ptp(ref)


def test_improved_duhem_sign_pattern():
    """Pins Eq. 46 as ``h' = alpha s' - beta |s'| h + gamma s s'`` and ``y = k u + p u' - h``."""
    model = ImprovedDuhem()
    up = np.linspace(0.0, 1.0, 11)
    down = np.linspace(1.0, 0.0, 11)
    u = np.concatenate([up, down[1:]])
    t = np.arange(u.size) * 0.5
    base = {"k": 0.0, "p": 0.0, "u_centre": 0.0, "u_half": 1.0}
    # beta = 0: no hysteresis, h = alpha s + gamma s^2 / 2 on any path
    y = model.simulate(u, t, {**base, "alpha": 2.0, "beta": 0.0, "gamma": 3.0})
    np.testing.assert_allclose(y, -(2.0 * u + 1.5 * u**2), atol=1e-14)
    # gamma = 0: h relaxes to +alpha/beta rising, to -alpha/beta falling
    y = model.simulate(u, t, {**base, "alpha": 2.0, "beta": 4.0, "gamma": 0.0})
    h_top = 0.5 * (1 - np.exp(-4.0))
    np.testing.assert_allclose(-y[:11], 0.5 * (1 - np.exp(-4.0 * up)), atol=1e-14)
    np.testing.assert_allclose(-y[10:], -0.5 + (h_top + 0.5) * np.exp(-4.0 * (1 - down)),
                               atol=1e-14)
    # k u and p u' with the backward difference (first sample: relaxed, u' = 0)
    y = model.simulate(u, t, {**base, "k": 3.0, "p": 0.25, "alpha": 0.0, "beta": 1.0,
                              "gamma": 0.0})
    np.testing.assert_allclose(y, 3.0 * u + 0.25 * _backward_derivative(u, t), atol=1e-14)


def test_improved_duhem_loop_widens_with_frequency():
    # per period the h-part is the same sample sequence at every frequency, so the
    # signed area sum y du grows by exactly p sum du^2 / dt ~ p pi A^2 omega
    model = ImprovedDuhem()
    theta = _improved_theta()
    amp, n = 50.0, 2000
    areas = []
    for freq in (1.0, 10.0, 40.0):
        t = np.arange(2 * n + 1) / (n * freq)
        u = 60.0 + amp * np.sin(2 * np.pi * freq * t)
        y = model.simulate(u, t, theta)
        areas.append(np.sum(y[n + 1:] * np.diff(u[n:])))
    for i in (1, 2):
        want = theta["p"] * math.pi * amp**2 * 2 * math.pi * ((10.0, 40.0)[i - 1] - 1.0)
        np.testing.assert_allclose(areas[i] - areas[0], want, rtol=1e-5)
    assert areas[0] < areas[1] < areas[2]


# --------------------------------------------------------------------- properties
def _prior_theta(model):
    space = model.param_space(DATA)
    return space.unpack(space.sample_prior(np.random.default_rng(21), 1)[0])


MODELS = [Duhem(3, 1), Duhem(2, 2), ImprovedDuhem()]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.name}{getattr(m, 'f_order', '')}")
@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(1, 80), min_size=1, max_size=6, unique=True))
def test_state_continuation(model, cuts):
    u, t = INPUTS["random_walk"]
    assert_pieces_match(model, u[:81], t[:81], _prior_theta(model), [0, *sorted(cuts), 81])


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_length_one_pieces(model):
    u, t = INPUTS["sine"]
    assert_pieces_match(model, u, t, _prior_theta(model), range(u.size + 1))


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_batched_equals_one_by_one(model):
    u, t = INPUTS["decaying"]
    assert_batch_equals_single(model, u, t, model.param_space(DATA), seed=3)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_prior_draws_never_nan(model):
    u, t = INPUTS["sine"]
    assert_prior_draws_simulate(model, u, t, model.param_space(DATA), seed=11)


def test_failures_are_flagged():
    model = Duhem(3, 1)
    u, t = INPUTS["sine"]
    thetas = {k: np.stack([np.asarray(v, float)] * 3) for k, v in _duhem_theta().items()}
    thetas["alpha"] = np.array([2.5, -1.0, 2.5])
    thetas["f"][2, 0] = 1e308  # overflows to inf within the first steps
    traj = model.run_batch(u, t, thetas)
    np.testing.assert_array_equal(traj.failed, [False, True, True])
    assert np.all(np.isnan(traj.y[1:])) and np.all(np.isfinite(traj.y[0]))
    # a failed walker's (NaN) state stays failed when continued, and does not raise
    thetas["alpha"][1] = 2.5
    more = model.run_batch(u, t, thetas, state0=traj.state)
    np.testing.assert_array_equal(more.failed, [False, True, True])
    with pytest.raises(SimulationError):
        model.simulate(u, t, {**_duhem_theta(), "alpha": -1.0})
    with pytest.raises(SimulationError):
        ImprovedDuhem().simulate(u, t, {**_improved_theta(), "beta": -0.5})


def test_bad_settings_and_time_are_rejected():
    with pytest.raises(ModelError):
        Duhem(f_order=9)
    with pytest.raises(ModelError):
        get("duhem", g_order=-1)
    u, t = INPUTS["sine"]
    with pytest.raises(ParameterError):
        ImprovedDuhem().simulate(u, t[::-1], _improved_theta())


def test_registry_and_priors_scale_with_data():
    assert isinstance(get("duhem", f_order=2), Duhem)
    assert isinstance(get("duhem_improved"), ImprovedDuhem)
    space = Duhem().param_space(DATA)
    assert space.fixed["u_centre"] == pytest.approx(60.0)
    assert space.fixed["u_half"] == pytest.approx(55.0)
    assert space["f"].shape == (4,) and space["g"].shape == (2,)
    # the review's polynomials in V evaluate to the normalised ones
    a_v, f_v, g_v = Duhem().polynomials(_duhem_theta())
    s = (100.0 - 60.0) / 55.0
    assert f_v(100.0) == pytest.approx(Polynomial(_duhem_theta()["f"])(s))
    assert a_v == pytest.approx(2.5 / 55.0)
    assert g_v(100.0) == pytest.approx(Polynomial(_duhem_theta()["g"])(s) / 55.0)


# -------------------------------------------- duhem_improved: posterior recovery
# (its linear group (k, p, alpha, gamma) is drawn exactly by the sampler; beta alone goes
# to the ensemble)
IMPROVED_TRUTH = {"k": 0.3, "p": 0.005, "alpha": 4.0, "beta": 2.0, "gamma": 1.0}
IMPROVED_NOISE = 0.05


def _improved_record(seed, n=1200):
    from bayeshyst.data import Record

    # 2 Hz major loops with a 40 Hz ripple: the rate term p du/dt shows at both rates
    t = np.arange(n) * 1e-3
    u = 75 - 60 * np.cos(2 * np.pi * 2 * t) + 10 * np.sin(2 * np.pi * 40 * t)
    model = ImprovedDuhem()
    fixed = dict(model.param_space(Record(t=t, u=u, y=u, name="scales")).fixed)
    y = model.simulate(u, t, IMPROVED_TRUTH | fixed)
    y = y + np.random.default_rng(seed).normal(0.0, IMPROVED_NOISE, n)
    return Record(t=t, u=u, y=y, name=f"improved{seed}", warmup=100)


def _improved_stats(seeds):
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings
    from tests.test_recovery import _fit_stats

    fits = []
    for seed in seeds:
        post = Posterior(_improved_record(seed), "duhem_improved")
        res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000,
                                                     n_walkers=16))
        fits.append(_fit_stats(post, IMPROVED_TRUTH | {"obs.offset": 0.0,
                                                       "noise.sigma": IMPROVED_NOISE},
                               seed, res))
    return fits, post.ndim


def test_improved_duhem_posterior_is_calibrated_on_one_fit():
    from tests.test_recovery import _check_calibration

    # the truth's squared Mahalanobis distance ~ chi2(d), two-sided 0.1 %
    _check_calibration(*_improved_stats([0]))


@pytest.mark.slow
def test_improved_duhem_90_percent_intervals_cover_at_the_nominal_rate():
    from tests.test_recovery import _check_calibration, _check_coverage

    fits, ndim = _improved_stats(range(1, 21))
    _check_calibration(fits, ndim)
    _check_coverage(fits)
