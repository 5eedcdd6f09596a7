"""Weighted PI models (polynomial input, rate-dependent weights, covariate) against oracles.

Oracles: slow pure-Python loops written from the equations (review Eq. 20, 28–32, §3,
§10 ref. [106]); ``pi_play`` and ``pi_rate`` where the equations reduce to them; the
analytic constant-covariate case (``pi_play`` with scaled weights and thresholds);
properties (time warps, loop widening, state continuation, batches); recovery of the
parameters from data simulated by the models.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from bayeshyst.data import Record
from bayeshyst.errors import DataError, ModelError, ParameterError
from bayeshyst.inference.conjugate import conjugate_posterior
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inverse.numerical import invert
from bayeshyst.models import get
from bayeshyst.models.pi import PrandtlIshlinskii
from bayeshyst.models.pi_variants import RateDependentPrandtlIshlinskii
from bayeshyst.models.pi_weighted import CovariatePI, PolynomialInputPI, RateWeightedPI

N_OP = 5
COL = "temperature_c"
MODELS = {
    "poly": PolynomialInputPI(N_OP, degree=4),
    "rate_w": RateWeightedPI(N_OP),
    "rate_wt": RateWeightedPI(N_OP, rate_thresholds=True),
    "cov": CovariatePI(N_OP, column=COL),
}


def _irregular(n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Irregular times, an input with reversals of every size, and a wandering column."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(2e-4, 3e-3, n))
    u = 75.0 + 60.0 * np.sin(2 * np.pi * 3.0 * t) * np.cos(2 * np.pi * 0.7 * t) \
        + rng.normal(0.0, 4.0, n)
    c = 30.0 + np.cumsum(rng.normal(0.0, 0.4, n))
    return t, u, c


def _data(t, u, c=None) -> Record:
    y = 0.2 * u + np.sin(t)
    return Record(t=t, u=u, y=y, name="r", covariates={} if c is None else {COL: c})


def _theta(model, seed: int, data=None) -> dict:
    space = model.param_space(data)
    return space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])


def _play(theta, **scale) -> dict:
    return {"p0": theta["p0"], "w": theta["w"], "r": theta["r"]} | scale


# ------------------------------------------------------------------ pure-Python oracles


def _clamp(lo, hi, v):
    return max(lo, min(hi, v))


def oracle(name, u, t, cov, theta, s0):
    """Output list and final state of one model for one theta, from state ``s0``."""
    p0, w, r = float(theta["p0"]), [float(x) for x in theta["w"]], list(theta["r"])
    n = len(w)
    v = [float(x) for x in s0[:n]]
    up, tp, has = (float(s0[n]), float(s0[n + 1]), s0[n + 2] != 0) \
        if name.startswith("rate") else (0.0, 0.0, False)
    ys = []
    for k, (uk, tk) in enumerate(zip(u, t, strict=True)):
        uk, tk = float(uk), float(tk)
        gain, f, ops_factor, lin_factor, extra = 1.0, 1.0, 1.0, 1.0, 0.0
        if name == "poly":
            x = (uk - theta["u_c"]) / theta["u_h"]
            extra = sum(float(g) * x ** (j + 2) for j, g in enumerate(theta["g"]))
        elif name.startswith("rate"):
            rate = (uk - up) / (tk - tp) if has else 0.0
            x = (uk - theta["u_c"]) / theta["u_h"]
            q = rate / theta["udot_ref"]
            lin_factor = math.exp(theta["m1"] * q + theta["m2"] * x)
            ops_factor = math.exp(theta["s1"] * q + theta["s2"] * x)
            if name == "rate_wt":
                f = 1.0 + theta["c"] * math.log(1.0 + abs(rate) / theta["udot0"])
            up, tp, has = uk, tk, True
        elif cov is not None:
            dc = float(cov[k]) - theta["c0"]
            gain, f = 1.0 + theta["a"] * dc, 1.0 + theta["b"] * dc
        acc = lin_factor * p0 * uk
        for i in range(n):
            v[i] = _clamp(uk - r[i] * f, uk + r[i] * f, v[i])
            acc += ops_factor * w[i] * v[i]
        ys.append(gain * (acc + extra))
    state = v + ([up, tp, 1.0] if name.startswith("rate") else [])
    return np.array(ys), np.array(state)


def _cov_arg(name, c):
    return {COL: c} if name == "cov" else None


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("relaxed", [True, False], ids=["relaxed", "given_state"])
def test_kernel_matches_pure_python_oracle(name, relaxed):
    model = MODELS[name]
    t, u, c = _irregular()
    rec = _data(t, u, c)
    theta = _theta(model, 1, rec)
    if name.startswith("rate"):
        # exponents large enough to matter on this input, small enough not to overflow
        theta |= {"m1": 0.3, "m2": -0.2, "s1": -0.25, "s2": 0.15}
    if name == "cov":
        theta |= {"a": 0.01, "b": 0.03}
    s0 = model.initial_state(theta, u[0])
    if not relaxed:
        s0 = s0.copy()
        s0[:N_OP] = u[0] + np.linspace(-1.0, 1.0, N_OP) * theta["r"]  # inside each band
        if name.startswith("rate"):
            s0[N_OP:] = [u[0] - 3.0, t[0] - 1e-3, 1.0]  # a previous sample: u̇_0 != 0
    traj = model.run(u, t, theta, state0=s0, covariates=_cov_arg(name, c))
    y_ref, s_ref = oracle(name, u, t, c if name == "cov" else None, theta, s0)
    np.testing.assert_allclose(traj.y, y_ref, rtol=1e-12, atol=1e-12 * np.abs(y_ref).max())
    np.testing.assert_allclose(traj.state, s_ref, rtol=1e-12, atol=1e-9)


# ------------------------------------------------------------------ reductions


def test_polynomial_of_degree_one_is_pi_play_exactly():
    t, u, _ = _irregular()
    model = PolynomialInputPI(N_OP, degree=1)
    theta = _theta(model, 2, _data(t, u))
    assert "g" not in theta and model.linear_params == ("p0", "w")
    a = model.run(u, t, theta)
    b = PrandtlIshlinskii(N_OP).run(u, t, _play(theta))
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.state, b.state)


def test_polynomial_adds_exactly_its_memoryless_polynomial():
    t, u, _ = _irregular()
    model = MODELS["poly"]
    theta = _theta(model, 3, _data(t, u))
    x = (u - theta["u_c"]) / theta["u_h"]
    poly = sum(g * x ** (j + 2) for j, g in enumerate(theta["g"]))
    play = PrandtlIshlinskii(N_OP).simulate(u, t, _play(theta))
    np.testing.assert_allclose(model.simulate(u, t, theta), play + poly, rtol=0,
                               atol=1e-12 * np.abs(play).max())


@pytest.mark.parametrize("thresholds", [False, True])
def test_rate_weights_with_zero_exponents_reduce_exactly(thresholds):
    # pi_play without the threshold law, pi_rate (Eq. 28-30) with it
    t, u, _ = _irregular()
    model = RateWeightedPI(N_OP, rate_thresholds=thresholds)
    theta = _theta(model, 4, _data(t, u)) | {"m1": 0.0, "m2": 0.0, "s1": 0.0, "s2": 0.0}
    a = model.run(u, t, theta)
    if thresholds:
        ref = RateDependentPrandtlIshlinskii(N_OP)
        b = ref.run(u, t, _play(theta, c=theta["c"], udot0=theta["udot0"]))
        np.testing.assert_array_equal(a.state, b.state)
    else:
        b = PrandtlIshlinskii(N_OP).run(u, t, _play(theta))
        np.testing.assert_array_equal(a.state[:N_OP], b.state)
    np.testing.assert_array_equal(a.y, b.y)


def test_covariate_without_sensitivity_or_column_is_pi_play_exactly():
    t, u, c = _irregular()
    model = MODELS["cov"]
    theta = _theta(model, 5, _data(t, u, c))
    play = PrandtlIshlinskii(N_OP).simulate(u, t, _play(theta))
    flat = theta | {"a": 0.0, "b": 0.0}
    np.testing.assert_array_equal(model.simulate(u, t, flat, covariates={COL: c}), play)
    # without the column: nominal conditions c = c0, whatever a and b
    np.testing.assert_array_equal(model.simulate(u, t, theta | {"a": 0.02, "b": 0.05}), play)


def test_constant_covariate_is_pi_play_with_scaled_weights_and_thresholds():
    t, u, c = _irregular()
    model = MODELS["cov"]
    theta = _theta(model, 6, _data(t, u, c)) | {"a": 0.012, "b": -0.02}
    level = float(theta["c0"]) + 7.5
    dc = level - float(theta["c0"])
    y = model.simulate(u, t, theta, covariates={COL: np.full(u.size, level)})
    g, f = 1 + 0.012 * dc, 1 - 0.02 * dc
    play = PrandtlIshlinskii(N_OP).simulate(
        u, t, {"p0": g * theta["p0"], "w": g * theta["w"], "r": f * theta["r"]})
    np.testing.assert_allclose(y, play, rtol=1e-13, atol=1e-13 * np.abs(play).max())


# ------------------------------------------------------------------ loop shape


def _sine(f_hz, n_per=1000, periods=2.0):
    t = np.arange(int(n_per * periods) + 1) / (n_per * f_hz)
    return 75.0 - 60.0 * np.cos(2 * np.pi * f_hz * t), t


def _area(u, y):
    return -np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(u))  # counter-clockwise > 0


def test_rate_weights_widen_the_loop_with_frequency_for_negative_exponents():
    # m1, s1 < 0: rising branches weighted less than falling ones, more so the faster
    model = MODELS["rate_w"]
    theta = _theta(model, 7) | {"p0": 0.2, "w": np.full(N_OP, 0.05), "m2": 0.0, "s2": 0.0,
                                "udot_ref": 60.0 * 2 * np.pi * 10.0}
    theta["r"] = np.linspace(5.0, 40.0, N_OP)
    for m, grows in [(-0.1, True), (0.0, False)]:
        areas = []
        for f in (1.0, 10.0, 100.0):
            u, t = _sine(f)  # same samples per period: only the rate differs
            y = model.simulate(u, t, theta | {"m1": m, "s1": m})
            areas.append(_area(u[1000:], y[1000:]))
        if grows:
            assert areas[0] > 0 and np.all(np.diff(areas) > 0.05 * areas[0])
        else:  # the inputs agree to rounding only (2 pi f t at different f)
            np.testing.assert_allclose(areas, areas[0], rtol=1e-12)


def test_rate_weights_change_under_a_time_warp_and_not_without_rate_exponents():
    model = MODELS["rate_w"]
    u, t = _sine(1.0, n_per=400)
    warped = t + 0.3 * np.sin(2 * np.pi * t) / (2 * np.pi)  # strictly increasing
    theta = _theta(model, 8, _data(t, u)) | {"m1": 0.2, "s1": -0.2, "m2": 0.3, "s2": -0.3}
    assert np.abs(model.simulate(u, t, theta) - model.simulate(u, warped, theta)).max() > 1e-2
    static = theta | {"m1": 0.0, "s1": 0.0}
    np.testing.assert_array_equal(model.simulate(u, t, static), model.simulate(u, warped, static))


def test_covariate_changes_slope_and_width_of_the_loop():
    model = MODELS["cov"]
    u, t = _sine(2.0)
    theta = _theta(model, 9) | {"p0": 0.2, "w": np.full(N_OP, 0.05), "c0": 25.0}
    # below half the amplitude (also x 1.2): a wider operator there adds loop area
    theta["r"] = np.linspace(2.0, 20.0, N_OP)

    def loop(level, a, b):
        y = model.simulate(u, t, theta | {"a": a, "b": b},
                           covariates={COL: np.full(u.size, level)})
        return np.ptp(y[1000:]) / np.ptp(u[1000:]), _area(u[1000:], y[1000:])

    slope0, area0 = loop(25.0, 0.01, 0.02)
    slope_hot, _ = loop(35.0, 0.01, 0.0)
    _, area_wide = loop(35.0, 0.0, 0.02)
    assert slope_hot == pytest.approx(1.1 * slope0, rel=1e-12)  # weights x (1 + 0.01 * 10)
    assert area_wide > 1.1 * area0  # thresholds x 1.2: a wider loop


def test_rate_weights_output_moves_against_the_input_near_reversals():
    # the documented reason pi_rate_weights is not invertible over its range (Eq. 31)
    model = MODELS["rate_w"]
    u, t = _sine(10.0, n_per=200)
    theta = _theta(model, 10) | {"p0": 0.2, "w": np.full(N_OP, 0.05), "m2": 0.0, "s2": 0.0,
                                 "s1": 0.0, "udot_ref": 3000.0}
    for m1 in (0.1, -0.1):
        y = model.simulate(u, t, theta | {"m1": m1})
        du, dy = np.diff(u), np.diff(y)
        against = np.flatnonzero(dy * np.sign(du) < 0)
        assert against.size > 0
        # only near reversals (the top at u = 135 V or the bottom at 15 V)
        assert np.all(np.abs(du[against]) < 0.2 * np.abs(du).max())
    y0 = model.simulate(u, t, theta | {"m1": 0.0})
    assert np.all(np.diff(y0) * np.sign(np.diff(u)) >= 0)


def test_rate_independent_rate_weights_invert_numerically():
    model = MODELS["rate_w"]
    u, t = _sine(10.0, n_per=200, periods=1.5)
    theta = {k: np.asarray(v)[None, ...] for k, v in (_theta(model, 11, _data(t, u)) | {
        "p0": 0.2, "w": np.full(N_OP, 0.05), "m1": 0.0, "s1": 0.0, "m2": 0.2,
        "s2": -0.2}).items()}
    y_d = model.run_batch(u, t, theta).y[0]
    inv = invert(model, y_d, t, theta, u_limits=(-100.0, 250.0))
    np.testing.assert_allclose(inv.u, u, atol=1e-6 * 150)
    assert inv.n_saturated == 0


def test_covariate_inverse_designs_for_nominal_conditions():
    # the inverse has no column (a command for a future run): it inverts at c = c0
    model = MODELS["cov"]
    u, t = _sine(10.0, n_per=200, periods=1.5)
    theta = {k: np.asarray(v)[None, ...] for k, v in (_theta(model, 12, _data(t, u)) | {
        "p0": 0.2, "w": np.full(N_OP, 0.05), "a": 0.01, "b": 0.03, "c0": 25.0}).items()}
    y_d = model.run_batch(u, t, theta).y[0]
    inv = invert(model, y_d, t, theta, u_limits=(-100.0, 250.0))
    np.testing.assert_allclose(inv.u, u, atol=1e-6 * 150)
    hot = model.run_batch(inv.u, t, theta, covariates={COL: np.full(u.size, 35.0)}).y[0]
    assert np.abs(hot - y_d).max() > 0.05 * np.ptp(y_d)  # off-nominal: the command misses


@pytest.mark.parametrize("spec", ["cov", "conditioned", "aux_creep"])
def test_inverse_at_the_measured_column_recovers_the_input(spec):
    # oracle: the input that made the reference. Given the temperature the command will
    # run at (a 20 K ramp), the inverse of a column-reading model -- the PI itself, any
    # model conditioned on the column, an aux block before a creep block -- returns that
    # input and meets the reference at that temperature; at nominal it does not
    from bayeshyst.models import get as get_model

    u, t = _sine(10.0, n_per=200, periods=1.5)
    ramp = np.linspace(15.0, 35.0, u.size)
    model = {"cov": MODELS["cov"],
             "conditioned": get_model(f"conditioned(pi_play(n_operators={N_OP}), "
                                      f"column='{COL}')"),
             "aux_creep": get_model(f"pi_play(n_operators={N_OP})+aux(column='{COL}')+creep"),
             }[spec]
    space = model.param_space(_data(t, u, ramp))
    theta = space.unpack(space.sample_prior(np.random.default_rng(3), 1))
    linear = {"p0": 0.2, "w": np.full(N_OP, 0.05)}
    for name, value in linear.items():  # a monotone loop: positive weights
        for key in (name, f"static.{name}"):
            if key in theta:
                theta[key] = np.asarray(value, dtype=float)[None, ...]
    cov = {COL: ramp}
    y_d = model.run_batch(u, t, theta, covariates=cov).y[0]
    inv = invert(model, y_d, t, theta, u_limits=(-100.0, 250.0), covariates=cov)
    assert inv.n_nonmonotone == 0 and inv.n_saturated == 0
    np.testing.assert_allclose(inv.u, u, atol=1e-5 * 150)
    met = model.run_batch(inv.u, t, theta, covariates=cov).y[0]
    assert np.abs(met - y_d).max() <= 1e-6 * np.ptp(y_d)
    nominal = invert(model, y_d, t, theta, u_limits=(-100.0, 250.0))
    assert np.abs(nominal.u - u).max() > 1e-2 * np.ptp(u)  # the column mattered
    with pytest.raises(ModelError, match=COL):
        invert(model, y_d, t, theta, covariates={"other": ramp})


# ------------------------------------------------------------------ state and batches


@pytest.mark.parametrize("name", list(MODELS))
def test_pieces_and_single_samples_equal_one_run(name):
    model = MODELS[name]
    t, u, c = _irregular(120)
    theta = _theta(model, 13, _data(t, u, c))
    whole = model.run(u, t, theta, covariates=_cov_arg(name, c))
    for bounds in ([0, 37, 38, 90, u.size], list(range(u.size + 1))):
        s, ys = None, []
        for a, b in itertools.pairwise(bounds):
            tr = model.run(u[a:b], t[a:b], theta, state0=s, covariates=_cov_arg(name, c[a:b]))
            ys.append(tr.y)
            s = tr.state
        np.testing.assert_array_equal(np.concatenate(ys), whole.y)
        np.testing.assert_array_equal(s, whole.state)


@pytest.mark.parametrize("name", list(MODELS))
def test_batched_equals_one_by_one(name):
    model = MODELS[name]
    t, u, c = _irregular(200)
    rec = _data(t, u, c)
    space = model.param_space(rec)
    z = space.sample_prior(np.random.default_rng(14), 7)
    batch = model.run_batch(u, t, space.unpack(z), covariates=_cov_arg(name, c))
    for j in range(z.shape[0]):
        one = model.run_batch(u, t, space.unpack(z[j:j + 1]), covariates=_cov_arg(name, c))
        np.testing.assert_array_equal(one.y[0], batch.y[j])
        assert one.failed[0] == batch.failed[j]


@pytest.mark.parametrize("name", list(MODELS))
def test_prior_draws_never_give_nan(name):
    model = MODELS[name]
    t, u, c = _irregular(400)
    rec = _data(t, u, c)
    space = model.param_space(rec)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(15), 300))
    if name.startswith("rate"):
        thetas["m1"] = thetas["m1"] * 200.0  # some walkers overflow exp(): flagged
    if name == "cov":
        thetas["a"] = thetas["a"] * 8.0  # some slopes turn negative over the column
    traj = model.run_batch(u, t, thetas, covariates=_cov_arg(name, c))
    ok = ~traj.failed
    assert np.all(np.isfinite(traj.y[ok])) and np.all(np.isnan(traj.y[~ok]))
    assert ok.sum() > 100
    if name != "poly":
        assert traj.failed.any()


@pytest.mark.parametrize("name", list(MODELS))
def test_design_reproduces_the_output(name):
    model = MODELS[name]
    t, u, c = _irregular(150)
    rec = _data(t, u, c)
    theta = _theta(model, 16, rec)
    cov = _cov_arg(name, c)
    lin = model.linear_params
    phi = model.regressors(u, t, {k: v for k, v in theta.items() if k not in lin},
                           covariates=cov)
    beta = np.concatenate([np.ravel(theta[k]) for k in lin])
    y = model.simulate(u, t, theta, covariates=cov)
    np.testing.assert_allclose(phi @ beta, y, rtol=1e-10, atol=1e-10 * np.abs(y).max())
    design = model.linear_design(u, t, {k: np.asarray(v)[None, ...] for k, v in theta.items()},
                                 covariates=cov)
    np.testing.assert_allclose(design.predict(beta[None, :])[0], y, rtol=1e-10,
                               atol=1e-10 * np.abs(y).max())


# ------------------------------------------------------------------ the measured column


def test_covariate_model_names_its_column_and_refuses_data_without_it():
    model = CovariatePI(N_OP, column="load_n")
    assert model.covariates == ("load_n",)
    t, u, c = _irregular(100)
    theta = _theta(model, 17)
    with pytest.raises(ModelError, match="load_n"):
        model.run(u, t, theta, covariates={COL: c})
    with pytest.raises(DataError, match="load_n"):
        Posterior(_data(t, u, c), model)


def test_a_composite_passes_the_column_to_its_base():
    model = get(f"pi_covariate(n_operators={N_OP})+creep")
    assert model.covariates == (COL,)
    t, u, c = _irregular(200)
    rec = _data(t, u, c)
    space = model.param_space(rec)
    theta = space.unpack(space.sample_prior(np.random.default_rng(18), 1)[0])
    theta["creep.c"] = np.zeros_like(theta["creep.c"])  # creep off: the base alone
    base_theta = {k.split(".", 1)[1]: v for k, v in theta.items() if k.startswith("static.")}
    theta["static.a"], base_theta["a"] = 0.02, 0.02
    np.testing.assert_allclose(
        model.simulate(u, t, theta, covariates={COL: c}),
        MODELS["cov"].simulate(u, t, base_theta, covariates={COL: c}), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("spec", ["pi_covariate(n_operators=4)",
                                  "pi_covariate(n_operators=4)+creep"])
def test_the_samplers_linear_block_sees_the_column(spec):
    # oracle: the model's own simulation with the column; the design the exact linear
    # draws use must reproduce it (at nominal conditions it would not: a, b != 0)
    from bayeshyst.inference.linear import LinearStructure

    t, u, c = _irregular(300)
    post = Posterior(_data(t, u, c), spec)
    lin = LinearStructure.of(post)
    assert lin is not None and lin.model_names
    z = post.space.sample_prior(np.random.default_rng(22), 3)
    sens = [i for i, n in enumerate(post.space.names) if n.endswith(("a", "b"))
            and n.rsplit(".", 1)[-1] in ("a", "b")]
    z[:, [post.space.slice_of(post.space.names[i]).start for i in sens]] = [0.02, 0.04]
    (phi, const), = lin.designs(z)[0]
    beta = lin.beta_of(z)
    pred = (phi @ beta[:, :, None])[:, :, 0] + const
    theta, _, off = post._split_theta(post.space.unpack(z))
    y = post.model.run_batch(u, t, theta, covariates={COL: c}).y + np.reshape(off, (-1, 1))
    np.testing.assert_allclose(pred, y, rtol=1e-9, atol=1e-9 * np.abs(y).max())
    nominal = post.model.run_batch(u, t, theta).y + np.reshape(off, (-1, 1))
    assert np.abs(nominal - y).max() > 1e-3


@pytest.mark.parametrize("spec", ["pi_play(n_operators=4)+aux(column='temperature_c')+creep",
                                  "pi_covariate(n_operators=4)+creep"])
def test_composite_blocks_rest_at_the_first_samples_column(spec):
    # a block after a column-reading part starts at rest at that part's output with the
    # column's first value; the linear design assumes the same (before, the run rested
    # at nominal conditions and the two disagreed by a creep transient)
    model = get(spec)
    t, u, c = _irregular(300)
    space = model.param_space(_data(t, u, c))
    th = space.unpack(space.sample_prior(np.random.default_rng(23), 2))
    for k, v in (("aux.g", 0.2), ("aux.h", 0.5), ("static.a", 0.02), ("static.b", 0.04)):
        if k in th:
            th[k] = np.full_like(th[k], v)
    names = model.linear_group[1]
    design = model.linear_design(u, t, th, covariates={COL: c})
    beta = np.concatenate([np.reshape(th[n], (2, -1)) for n in names], axis=1)
    y = model.run_batch(u, t, th, covariates={COL: c}).y
    np.testing.assert_allclose(design.predict(beta), y, rtol=1e-10, atol=1e-10 * np.abs(y).max())


def test_conjugate_posterior_reads_the_column():
    model = MODELS["cov"]
    t, u, c = _irregular(300)
    truth = _theta(model, 19, _data(t, u, c)) | {"a": 0.03, "b": 0.05}
    y = model.simulate(u, t, truth, covariates={COL: c})
    rec = Record(t=t, u=u, y=y + np.random.default_rng(0).normal(0, 0.01, u.size), name="r",
                 covariates={COL: c})
    post = Posterior(rec, model)
    fixed = {"a": 0.03, "b": 0.05, "noise.sigma": 0.01}
    cp = conjugate_posterior(post, fixed)
    phi = model.regressors(u, t, {"a": 0.03, "b": 0.05, "r": truth["r"], "c0": truth["c0"]},
                           covariates={COL: c})
    nominal = model.regressors(u, t, {"a": 0.03, "b": 0.05, "r": truth["r"],
                                      "c0": truth["c0"]})
    x = np.column_stack([phi, np.ones(u.size)])
    ls = np.linalg.lstsq(x, rec.y, rcond=None)[0]
    # weak priors: the posterior mean is the least-squares fit on the column's design
    np.testing.assert_allclose(cp.mean, ls, rtol=1e-3, atol=1e-3)
    assert np.abs(phi - nominal).max() > 1e-3


def test_bad_settings_and_inputs_are_refused():
    with pytest.raises(ModelError, match="degree"):
        PolynomialInputPI(N_OP, degree=0)
    with pytest.raises(ModelError, match="n_operators"):
        RateWeightedPI(0)
    with pytest.raises(ModelError, match="rate_thresholds"):
        RateWeightedPI(N_OP, rate_thresholds=1)
    with pytest.raises(ModelError, match="column"):
        CovariatePI(N_OP, column="a=b")
    model = MODELS["rate_w"]
    theta = _theta(model, 20)
    with pytest.raises(ParameterError, match="strictly increasing"):
        model.run([0.0, 1.0, 2.0], [0.0, 1.0, 1.0], theta)
    s = model.run([0.0, 1.0], [0.0, 1.0], theta).state
    with pytest.raises(ParameterError, match="not after"):
        model.run([2.0], [1.0], theta, state0=s)
    with pytest.raises(ModelError, match="temperature_c"):
        MODELS["cov"].run([0.0, 1.0], [0.0, 1.0], _theta(MODELS["cov"], 21),
                          covariates={COL: [1.0]})


# ------------------------------------------------------------------ posterior recovery

RECOVERY = {
    # a temperature ramp 20 -> 40 °C: slope +8 %, width +20 % over the record
    "pi_covariate": (CovariatePI(4), {"a": 0.004, "b": 0.01}),
    "pi_poly": (PolynomialInputPI(4, degree=3), {"g": np.array([-1.0, 0.5])}),
    # negative rate exponents: the loop widens with the rate (counter-clockwise)
    "pi_rate_weights": (RateWeightedPI(4), {"m1": -0.1, "m2": 0.1, "s1": -0.15, "s2": -0.1}),
}
SIGMA = 0.02


def recovery_record(name: str, seed: int, n: int = 2000) -> tuple[Record, dict]:
    """Data simulated by the model (noise sd 0.02 µm on a ~30 µm stroke) and the truth."""
    model, extra = RECOVERY[name]
    t = np.arange(n) * 1e-3
    u = 75.0 - 60.0 * np.cos(2 * np.pi * 2.0 * t) + 10.0 * np.sin(2 * np.pi * 5.0 * t)
    cov = {COL: 20.0 + 20.0 * t / t[-1]}
    # the fixed values (thresholds, c0, scalings) are those the fit will use
    fixed = model.param_space(Record(t=t, u=u, y=0.2 * u, name="x", covariates=cov)).fixed
    truth = dict(fixed) | {"p0": 0.15, "w": np.array([0.05, 0.04, 0.03, 0.02])} | extra
    y = model.simulate(u, t, truth, covariates=cov if model.covariates else None)
    y = y + np.random.default_rng(seed).normal(0.0, SIGMA, n)
    rec = Record(t=t, u=u, y=y, name=f"{name}{seed}", warmup=250, covariates=cov,
                 metadata={"frequency_hz": 2.0})
    free = {k: v for k, v in truth.items() if k not in fixed}
    return rec, free | {"obs.offset": 0.0, "noise.sigma": SIGMA}


def _recovery_stats(name: str, seeds, n: int = 2000):
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings
    from tests.test_recovery import _fit_stats

    out = []
    for seed in seeds:
        rec, truth = recovery_record(name, seed, n)
        post = Posterior(rec, RECOVERY[name][0])
        res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000, n_walkers=24))
        out.append(_fit_stats(post, truth, seed, res))
    return out, post.ndim


def test_covariate_posterior_under_a_temperature_ramp_is_calibrated():
    # one fit: the truth's squared Mahalanobis distance ~ chi2(d), two-sided 0.1 %
    # (tests/test_recovery.py's check); many seeds and the other models: the slow test
    from scipy import stats

    fits, ndim = _recovery_stats("pi_covariate", [0], 1200)
    p = stats.chi2.sf(fits[0][0], ndim)
    assert 1e-3 / 2 < p < 1 - 1e-3 / 2, (fits[0][0], ndim, p)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RECOVERY))
def test_90_percent_intervals_cover_the_truth_at_the_nominal_rate(name):
    # 20 independent noise draws: calibration (chi2) and each parameter's HDI coverage
    # (binomial, Bonferroni over parameters), a and b of the temperature ramp included
    from tests.test_recovery import _check_calibration, _check_coverage

    fits, ndim = _recovery_stats(name, range(1, 21))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


def test_structural_settings_round_trip_through_the_model_spec():
    # a saved fit rebuilds its model from this string
    from bayeshyst.models import model_spec

    for model in (CovariatePI(4, column="load_n"), RateWeightedPI(3, rate_thresholds=True),
                  PolynomialInputPI(2, degree=5)):
        assert get(model_spec(model)) == model
    assert get(model_spec(CovariatePI(4, column="load_n"))).covariates == ("load_n",)
