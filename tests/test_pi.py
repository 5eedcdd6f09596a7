"""Play/stop PI and Maxwell-slip: analytic identities and an independent slow oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bayeshyst.models as M
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models._kernels.operators import play_operator, stop_operator
from bayeshyst.models.pi import play_pi_inverse


# ------------------------------------------------------------------ slow oracles
def slow_play(u, r, v_prev):
    """Play operator written from its definition, sample by sample, in pure Python."""
    out = []
    for x in u:
        v_prev = max(x - r, min(x + r, v_prev))
        out.append(v_prev)
    return np.array(out), v_prev


def slow_stop(u, r, e_prev, u_prev):
    out = []
    for x in u:
        e_prev = min(r, max(-r, e_prev + x - u_prev))
        u_prev = x
        out.append(e_prev)
    return np.array(out)


def slow_pi_play(u, p0, w, r):
    y = p0 * np.asarray(u, float)
    for wi, ri in zip(w, r, strict=True):
        y = y + wi * slow_play(u, ri, u[0])[0]
    return y


def slow_elasto_slide(x, k, f):
    """One Maxwell-slip element as review Eq. 36 states it (force saturation form)."""
    xs = x[0]
    out = []
    for xt in x:
        force = k * (xt - xs)
        if abs(force) >= f:
            s = np.sign(force)
            force = f * s
            xs = xt - (f / k) * s
        out.append(force)
    return np.array(out)


def random_input(rng, n=400):
    kind = rng.integers(3)
    t = np.linspace(0.0, 1.0, n)
    if kind == 0:
        return np.cumsum(rng.normal(0.0, 0.1, n))
    if kind == 1:
        return np.sin(2 * np.pi * 4 * t) * np.exp(-3 * t) + 0.2 * np.sin(2 * np.pi * 23 * t)
    return rng.uniform(-1.0, 1.0, n)


def pi_theta(rng, n, scales=None):
    space = M.get("pi_play", n_operators=n).param_space(scales)
    return {"p0": rng.uniform(0.2, 1.0), "w": rng.uniform(0.01, 0.5, n), "r": space.fixed["r"]}


# ------------------------------------------------------------------ identities
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 2.0))
@settings(max_examples=50, deadline=None)
def test_play_plus_stop_is_identity(seed, r):
    # review Eq. 17, with initial states v_{-1} + e_{-1} = u_{-1}
    rng = np.random.default_rng(seed)
    u = random_input(rng)
    v = np.empty_like(u)
    e = np.empty_like(u)
    v0 = rng.uniform(-0.5, 0.5)
    e0 = rng.uniform(-r, r)  # an admissible stop state, |e| <= r
    play_operator(u, r, v0, v)
    stop_operator(u, r, e0, v0 + e0, e)  # u_{-1} = v_{-1} + e_{-1}
    np.testing.assert_allclose(v + e, u, atol=1e-12)


@given(st.integers(0, 2**31 - 1), st.integers(1, 25))
@settings(max_examples=60, deadline=None)
def test_play_pi_inverse_is_identity(seed, n):
    rng = np.random.default_rng(seed)
    model = M.get("pi_play", n_operators=n)
    th = pi_theta(rng, n)
    u = random_input(rng)
    t = np.arange(u.size, dtype=float)
    y = model.simulate(u, t, th)
    np.testing.assert_allclose(model.inverse(y, t, th), u, atol=1e-9)
    # and the other way round: forward(inverse(y_d)) = y_d
    y_d = random_input(rng) * 2.0
    np.testing.assert_allclose(model.simulate(model.inverse(y_d, t, th), t, th), y_d, atol=1e-9)


def test_inverse_with_negative_weights_and_continued_state():
    # weights may be negative (saturating loops) as long as every partial sum is positive
    rng = np.random.default_rng(11)
    n = 6
    model = M.get("pi_play", n_operators=n)
    th = {"p0": 1.0, "w": np.array([0.3, -0.2, 0.25, -0.3, 0.1, -0.1]),
          "r": np.linspace(0.1, 0.6, n)}
    u = random_input(rng, 600)
    t = np.arange(u.size, dtype=float)
    first = model.run(u[:250], t[:250], th)
    y2 = model.simulate(u[250:], t[250:], th, state0=first.state)
    u_back = model.inverse(y2, t[250:], th, state0=first.state, u_prev=u[249])
    np.testing.assert_allclose(u_back, u[250:], atol=1e-9)


def test_stop_form_of_inverse_equals_play_form():
    rng = np.random.default_rng(5)
    n = 8
    th = pi_theta(rng, n)
    inv = play_pi_inverse(th["p0"], th["w"], th["r"])
    y = random_input(rng) * 3
    t = np.arange(y.size, dtype=float)
    u_play = M.get("pi_play", n_operators=n).simulate(y, t, inv.play_theta)
    state = np.concatenate([np.zeros(n), [y[0]]])
    u_stop = M.get("pi_stop", n_operators=n).simulate(y, t, inv.stop_theta, state0=state)
    np.testing.assert_allclose(u_stop, u_play, atol=1e-12)


def test_non_invertible_pi_is_refused():
    with pytest.raises(ParameterError, match="partial sum"):
        play_pi_inverse(1.0, [0.5, -2.0], [0.1, 0.2])
    with pytest.raises(ParameterError, match="increasing"):
        play_pi_inverse(1.0, [0.5, 0.2], [0.2, 0.1])


# ------------------------------------------------------------------ oracles
@given(st.integers(0, 2**31 - 1), st.integers(1, 12))
@settings(max_examples=40, deadline=None)
def test_play_pi_matches_slow_oracle(seed, n):
    rng = np.random.default_rng(seed)
    th = pi_theta(rng, n)
    th["w"] = rng.normal(0.0, 0.5, n)
    u = random_input(rng)
    y = M.get("pi_play", n_operators=n).simulate(u, np.arange(u.size, dtype=float), th)
    np.testing.assert_allclose(y, slow_pi_play(u, th["p0"], th["w"], th["r"]), atol=1e-12)


def test_stop_pi_matches_slow_oracle():
    rng = np.random.default_rng(2)
    n = 7
    th = pi_theta(rng, n)
    u = random_input(rng)
    y = M.get("pi_stop", n_operators=n).simulate(u, np.arange(u.size, dtype=float), th)
    ref = th["p0"] * u + sum(w * slow_stop(u, r, 0.0, u[0])
                             for w, r in zip(th["w"], th["r"], strict=True))
    np.testing.assert_allclose(y, ref, atol=1e-12)


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=40, deadline=None)
def test_maxwell_slip_equals_stop_pi_and_eq36(seed):
    rng = np.random.default_rng(seed)
    n = 5
    k0 = rng.uniform(0.1, 1.0)
    k = rng.uniform(0.1, 2.0, n) * rng.choice([-1.0, 1.0], n)
    delta = np.sort(rng.uniform(0.05, 0.8, n))
    x = random_input(rng)
    t = np.arange(x.size, dtype=float)
    model = M.get("maxwell_slip", n_elements=n)
    y = model.simulate(x, t, {"k0": k0, "k": k, "delta": delta})
    y_stop = M.get("pi_stop", n_operators=n).simulate(x, t, {"p0": k0, "w": k, "r": delta})
    np.testing.assert_allclose(y, y_stop, atol=1e-12)
    # and each element as review Eq. 36 writes it, for positive stiffness
    kp = np.abs(k)
    f = model.breakaway_forces({"k": kp, "delta": delta})
    ref = k0 * x + sum(slow_elasto_slide(x, ki, fi) for ki, fi in zip(kp, f, strict=True))
    np.testing.assert_allclose(model.simulate(x, t, {"k0": k0, "k": kp, "delta": delta}), ref,
                               atol=1e-12)


def test_regressors_reproduce_simulation():
    rng = np.random.default_rng(4)
    model = M.get("pi_play", n_operators=9)
    th = pi_theta(rng, 9)
    u = random_input(rng)
    phi = model.regressors(u, np.arange(u.size, dtype=float), th)
    y = model.simulate(u, np.arange(u.size, dtype=float), th)
    np.testing.assert_allclose(phi @ np.concatenate([[th["p0"]], th["w"]]), y, atol=1e-12)


# ------------------------------------------------------------------ properties
MODELS = [("pi_play", {"n_operators": 6}), ("pi_stop", {"n_operators": 6}),
          ("maxwell_slip", {"n_elements": 6})]


@pytest.mark.parametrize(("name", "settings_"), MODELS)
@given(seed=st.integers(0, 2**31 - 1), cut=st.integers(1, 399))
@settings(max_examples=25, deadline=None)
def test_state_continuation(name, settings_, seed, cut):
    rng = np.random.default_rng(seed)
    model = M.get(name, **settings_)
    space = model.param_space()
    th = space.unpack(space.sample_prior(rng, 1)[0])
    u = random_input(rng)
    t = np.arange(u.size, dtype=float)
    whole = model.simulate(u, t, th)
    a = model.run(u[:cut], t[:cut], th)
    b = model.run(u[cut:cut + 1], t[cut:cut + 1], th, state0=a.state)  # a one-sample step
    c = model.simulate(u[cut + 1:], t[cut + 1:], th, state0=b.state) if cut + 1 < u.size else []
    np.testing.assert_array_equal(np.concatenate([a.y, b.y, c]), whole)


@pytest.mark.parametrize(("name", "settings_"), MODELS)
@given(seed=st.integers(0, 2**31 - 1))
@settings(max_examples=20, deadline=None)
def test_rate_independence_under_time_warp(name, settings_, seed):
    rng = np.random.default_rng(seed)
    model = M.get(name, **settings_)
    space = model.param_space()
    th = space.unpack(space.sample_prior(rng, 1)[0])
    u = random_input(rng)
    t = np.arange(u.size, dtype=float)
    warped = np.cumsum(rng.uniform(0.01, 5.0, u.size))  # any strictly increasing times
    np.testing.assert_array_equal(model.simulate(u, t, th), model.simulate(u, warped, th))


@pytest.mark.parametrize(("name", "settings_"), MODELS)
def test_batched_equals_one_by_one(name, settings_):
    rng = np.random.default_rng(9)
    model = M.get(name, **settings_)
    space = model.param_space()
    z = space.sample_prior(rng, 5)
    u = random_input(rng)
    t = np.arange(u.size, dtype=float)
    batch = model.simulate_batch(u, t, space.unpack(z))
    for i in range(5):
        np.testing.assert_array_equal(batch[i], model.simulate(u, t, space.unpack(z[i])))


@pytest.mark.parametrize(("name", "settings_"), MODELS)
def test_prior_draws_never_nan(name, settings_):
    rng = np.random.default_rng(1)
    model = M.get(name, **settings_)
    space = model.param_space()
    u = random_input(rng, 2000)
    thetas = space.unpack(space.sample_prior(rng, 200))
    traj = model.run_batch(u, np.arange(u.size, dtype=float), thetas)
    assert traj.n_failed == 0 and np.all(np.isfinite(traj.y))


def test_play_pi_loop_is_counter_clockwise_and_closes():
    # one full period after the first: the loop closes exactly (rate-independent memory)
    # and the rising branch lies below the falling one (counter-clockwise)
    n = 10
    model = M.get("pi_play", n_operators=n)
    th = pi_theta(np.random.default_rng(0), n)
    k = np.arange(3 * 400)
    u = np.sin(2 * np.pi * k / 400)
    y = model.simulate(u, k.astype(float), th)
    np.testing.assert_allclose(y[400:800], y[800:1200], atol=1e-12)
    # at u = 0: rising (k = 800) below falling (k = 1000)
    assert y[800] < y[1000]


def test_registry_errors_are_clear():
    with pytest.raises(ModelError, match="unknown model 'pi_plya'"):
        M.get("pi_plya")
    with pytest.raises(ModelError, match="no setting"):
        M.get("pi_play", n_operator=3)
    with pytest.raises(ModelError, match="integer >= 1"):
        M.get("pi_play", n_operators=0)


def test_theta_validation_names_the_parameter():
    model = M.get("pi_play", n_operators=3)
    th = model.param_space().unpack(np.zeros(4))
    with pytest.raises(ParameterError, match=r"theta\['w'\] has shape"):
        model.simulate([0.0, 1.0], [0.0, 1.0], {**th, "w": np.zeros(2)})
    with pytest.raises(ParameterError, match="missing"):
        model.simulate([0.0, 1.0], [0.0, 1.0], {"p0": 1.0})
