"""PI operator variants (right/left play, dead-zone MPI, one-side-play MPI and MRPI) vs oracles.

Oracles: slow pure-Python loops written from the equations in the models' docstrings
(review Eq. 23–27, refs. [56] [62] [63] [106]); the classical ``pi_play`` where a model
reduces to it; analytic branches of a full cycle; the reflection identity between the
right and the left play; properties (rate independence under a time warp and its
failure for the MRPI, state continuation, batched == one-by-one, the linear design);
the numerical inverse's round trip; posterior recovery on data from each model (quick
chi2 calibration for the one-side-play MPI, slow coverage over 20 seeds for all four).
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayeshyst.data import Record
from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.numerical import invert
from bayeshyst.models import get
from bayeshyst.models.pi import PrandtlIshlinskii
from bayeshyst.models.pi_operators import (
    DeadZonePrandtlIshlinskii,
    OneSidePlayPrandtlIshlinskii,
    RateDependentOneSidePlayPI,
    RightLeftPrandtlIshlinskii,
    dead_zone_thresholds,
)
from bayeshyst.models.pi_variants import typical_rate
from tests.test_recovery import _check_calibration, _check_coverage, _fit_stats

N_OP = 5
MODELS = {
    "right_left": RightLeftPrandtlIshlinskii(N_OP),
    "deadzone": DeadZonePrandtlIshlinskii(N_OP, n_deadzones=3),
    "osp": OneSidePlayPrandtlIshlinskii(N_OP),
    "osp_rate": RateDependentOneSidePlayPI(N_OP),
}
STATIC = ["right_left", "deadzone", "osp"]
HYST = settings(max_examples=40, deadline=None)


def _record(f_hz: float = 2.0, n_per: int = 200, periods: float = 3.0, amp: float = 60.0,
            offset: float = 75.0) -> SimpleNamespace:
    """A unipolar sine record like a piezo drive (0–150 V) with a loop-shaped output."""
    t = np.arange(int(n_per * periods)) / (n_per * f_hz)
    u = offset + amp * np.sin(2 * np.pi * f_hz * t)
    return SimpleNamespace(t=t, u=u, y=0.1 * u + np.sin(2 * np.pi * f_hz * t - 0.3))


def _theta(model, seed: int, data=None) -> dict:
    space = model.param_space(data)
    return space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])


def _irregular(seed: int):
    """Sine with reversals, then random jumps, on irregular strictly increasing times."""
    rec = _record()
    rng = np.random.default_rng(seed)
    u = np.concatenate([rec.u[:300], 75 + 70 * rng.uniform(-1, 1, 150)])
    t = np.cumsum(rng.uniform(2e-4, 3e-3, u.size))
    return u, t


# ------------------------------------------------------------------ pure-Python oracles


def oracle(name, u, t, theta, s0):
    """Output list and final state of one model, one theta, from the state ``s0``."""
    s = [float(x) for x in s0]
    n = N_OP
    ys = []
    for uk, tk in zip(u, t, strict=True):
        uk, tk = float(uk), float(tk)
        if name == "right_left":
            lo_u, span = float(theta["u_lo"]), float(theta["u_span"])
            y = float(theta["p0"]) * uk
            for i in range(n):
                rr, rl = float(theta["r_right"][i]), float(theta["r_left"][i])
                rise = lo_u + (uk - lo_u - rr) * (span / (span - rr))
                fall = lo_u + (uk - lo_u) * (span / (span - rl))
                s[i] = max(rise, min(uk, s[i]))
                s[n + i] = min(fall, max(uk, s[n + i]))
                y += float(theta["w_right"][i]) * s[i] + float(theta["w_left"][i]) * s[n + i]
        elif name == "deadzone":
            z = float(theta["p0"]) * uk
            for i in range(n):
                r = float(theta["r"][i])
                s[i] = max(uk - r, min(uk + r, s[i]))
                z += float(theta["w"][i]) * s[i]
            y = z
            for g, d in zip(theta["g"], theta["d"], strict=True):
                dz = max(z - d, 0.0) if d > 0 else (min(z - d, 0.0) if d < 0 else z)
                y += float(g) * dz
        else:
            x = (uk - float(theta["u_c"])) / float(theta["u_h"])
            y = float(theta["p0"]) * uk + float(theta["u_h"]) * (
                float(theta["a2"]) * x**2 + float(theta["a3"]) * x**3)
            if name == "osp":
                for i in range(n):
                    s[i] = max(uk - float(theta["r"][i]), min(uk, s[i]))
                    y += float(theta["w"][i]) * s[i]
            else:
                up, tp, q, has = s[n], s[n + 1], s[n + 2], s[n + 3] != 0.0
                for i in range(n):
                    if uk > up:  # a rising step can only raise the operator
                        s[i] = max(uk - float(theta["tau_l"]) * abs(q) - float(theta["r"][i]),
                                   s[i])
                    elif uk < up:
                        s[i] = min(uk + float(theta["tau_r"]) * abs(q), s[i])
                    y += float(theta["w"][i]) * s[i]
                s[n + 2] = (uk - up) / (tk - tp) if has else 0.0
                s[n], s[n + 1], s[n + 3] = uk, tk, 1.0
        ys.append(y)
    return np.array(ys), np.array(s)


@pytest.mark.parametrize("start", ["default", "perturbed"])
@pytest.mark.parametrize("name", list(MODELS))
def test_kernel_matches_pure_python_oracle(name, start):
    model = MODELS[name]
    theta = _theta(model, 1, _record())
    if name == "osp_rate":  # rate shifts that matter on this input (~1e4 V/s)
        theta |= {"tau_l": 2e-3, "tau_r": 5e-4}
    u, t = _irregular(2)
    s0 = model.initial_state(theta, u[0])
    if start == "perturbed":  # an arbitrary, non-relaxed start
        k = 2 * N_OP if name == "right_left" else N_OP
        s0[:k] += np.random.default_rng(3).normal(0.0, 5.0, k)
        if name == "osp_rate":  # and a previous sample with its own rate
            s0[N_OP:] = [u[0] - 1.5, t[0] - 1e-3, 800.0, 1.0]
    traj = model.run(u, t, theta, state0=s0)
    y_ref, s_ref = oracle(name, u, t, theta, s0)
    np.testing.assert_allclose(traj.y, y_ref, rtol=0, atol=1e-12 * np.abs(y_ref).max())
    np.testing.assert_allclose(traj.state, s_ref, rtol=1e-13, atol=1e-12 * 150)


def test_default_initial_states_are_the_documented_band_middles():
    rl = MODELS["right_left"]
    th = _theta(rl, 4, _record())
    lo, span = th["u_lo"], th["u_span"]
    u0 = 40.0
    rise = lo + (u0 - lo - th["r_right"]) * span / (span - th["r_right"])
    fall = lo + (u0 - lo) * span / (span - th["r_left"])
    np.testing.assert_allclose(rl.initial_state(th, u0),
                               np.r_[0.5 * (rise + u0), 0.5 * (fall + u0)], rtol=1e-15)
    osp = MODELS["osp"]
    th = _theta(osp, 4)
    np.testing.assert_allclose(osp.initial_state(th, 0.3), 0.3 - th["r"] / 2, rtol=1e-15)
    s = MODELS["osp_rate"].initial_state(_theta(MODELS["osp_rate"], 4), 0.3)
    np.testing.assert_array_equal(s[N_OP:], [0.3, 0.0, 0.0, 0.0])


# ------------------------------------------------------------------ reductions


def _play(theta, r=None):
    return {"p0": theta["p0"], "w": theta["w"], "r": theta["r"] if r is None else r}


def test_deadzone_with_zero_weights_is_pi_play_exactly():
    model = MODELS["deadzone"]
    u, t = _irregular(5)
    theta = _theta(model, 5, _record()) | {"g": np.zeros(3)}
    a = model.run(u, t, theta)
    b = PrandtlIshlinskii(N_OP).run(u, t, _play(theta))
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.state, b.state)


def test_deadzone_at_zero_thresholds_is_a_scaled_pi_play():
    # Kuhnen's d = 0 operator is the identity: y = (1 + sum g) z
    model = MODELS["deadzone"]
    u, t = _irregular(6)
    g = np.array([0.3, -0.1, 0.45])
    theta = _theta(model, 6, _record()) | {"g": g, "d": np.zeros(3)}
    z = PrandtlIshlinskii(N_OP).simulate(u, t, _play(theta))
    np.testing.assert_allclose(model.simulate(u, t, theta), (1 + g.sum()) * z, rtol=1e-14,
                               atol=1e-13 * np.abs(z).max())


def test_deadzone_output_is_the_piecewise_linear_map_of_the_play_output():
    # y(z): slope 1, plus 0.5 below d = -3, minus 0.4 above 4, plus 0.8 above 9
    model = MODELS["deadzone"]
    u, t = _irregular(7)
    u = u - 75.0  # bipolar, so that z visits both signs
    theta = _theta(model, 7, _record()) | {"g": np.array([0.5, -0.4, 0.8]),
                                           "d": np.array([-3.0, 4.0, 9.0]),
                                           "p0": 0.2, "w": np.full(N_OP, 0.05)}
    z = PrandtlIshlinskii(N_OP).simulate(u, t, _play(theta))
    assert z.min() < -3.0 and z.max() > 9.0  # every piece is visited
    want = z + 0.5 * np.minimum(z + 3.0, 0) - 0.4 * np.maximum(z - 4.0, 0) \
        + 0.8 * np.maximum(z - 9.0, 0)
    np.testing.assert_allclose(model.simulate(u, t, theta), want, rtol=0,
                               atol=1e-12 * np.abs(z).max())


def test_deadzone_non_monotone_draw_is_simulated_and_its_inverse_says_so():
    # g = [0.3, -1.6, 0.2] at d = [15.75, 26.25, 36.75]: slope 1 + 0.3 - 1.6 < 0 between
    # the second and third dead zone. The prior (Normal(0, 0.5)) allows such draws; like
    # pi_play's negative partial sums they are simulated, not failed (g is linear)
    model = DeadZonePrandtlIshlinskii(N_OP, n_deadzones=3)
    fs = 2000.0
    t = np.arange(700) / fs
    u = 75.0 - 60.0 * np.cos(2 * np.pi * 10.0 * t)
    base = dict(model.param_space(Record(t=t, u=u, y=0.35 * u, name="r")).fixed) | {
        "p0": 0.2, "w": np.full(N_OP, 0.03)}
    np.testing.assert_allclose(base["d"], [15.75, 26.25, 36.75])
    folds = base | {"g": np.array([0.3, -1.6, 0.2])}
    rises = base | {"g": np.array([0.3, -0.6, 0.2])}  # partial sums 1.3, 0.7, 0.9 > 0
    against = {}
    for name, theta in (("folds", folds), ("rises", rises)):
        traj = model.run(u, t, theta)
        assert not traj.failed
        against[name] = np.sum(np.diff(traj.y) * np.sign(np.diff(u)) < 0)
    assert against["rises"] == 0 and against["folds"] > 10
    # the inverse of the folding draw cannot meet a target it has no branch for, and says so
    y_d = model.simulate(u, t, rises)
    inv = invert(model, y_d, t, {k: np.asarray(v)[None] for k, v in folds.items()},
                 u_limits=(-100.0, 250.0))
    assert inv.n_nonmonotone > 0 and inv.max_error > 0.1 * np.ptp(y_d)


def test_osp_without_polynomial_is_half_threshold_play_minus_offset():
    model = MODELS["osp"]
    rec = _record()
    u, t = _irregular(8)
    theta = _theta(model, 8, rec) | {"a2": 0.0, "a3": 0.0}
    r_play = PrandtlIshlinskii(N_OP).param_space(rec).fixed["r"]
    np.testing.assert_allclose(theta["r"] / 2, r_play, rtol=1e-15)
    y = model.simulate(u, t, theta)
    y_play = PrandtlIshlinskii(N_OP).simulate(u, t, _play(theta, r_play))
    offset = float(np.dot(theta["w"], theta["r"])) / 2
    np.testing.assert_allclose(y, y_play - offset, rtol=0, atol=1e-12 * np.abs(y).max())


def test_mrpi_with_zero_rate_coefficients_is_osp_exactly():
    u, t = _irregular(9)
    theta = _theta(MODELS["osp_rate"], 9, _record()) | {"tau_l": 0.0, "tau_r": 0.0}
    a = MODELS["osp_rate"].run(u, t, theta)
    b = MODELS["osp"].run(u, t, {k: v for k, v in theta.items() if not k.startswith("tau")})
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.state[:N_OP], b.state)


def _sides(theta, right, left):
    return theta | {"p0": 0.0, "w_right": right, "w_left": left}


def test_left_play_is_the_right_play_reflected_through_the_range_centre():
    model = MODELS["right_left"]
    rec = _record()
    theta = _theta(model, 10, rec)
    u, t = _irregular(10)
    centre = float(theta["u_lo"] + theta["u_span"] / 2)
    w = np.abs(theta["w_right"])
    y_right = model.simulate(2 * centre - u, t, _sides(theta, w, 0 * w))
    y_left = model.simulate(u, t, _sides(theta, 0 * w, w))
    np.testing.assert_allclose(y_left, 2 * centre * w.sum() - y_right, rtol=0,
                               atol=1e-12 * 150 * w.sum())


def test_right_play_full_cycle_follows_the_documented_branches():
    # after the range's bottom: rise flat at u_lo until u_lo + r, then along R(u);
    # after the top: fall along u (the full-range chord)
    model = RightLeftPrandtlIshlinskii(1)
    space = model.param_space(_record())
    theta = dict(space.fixed) | {"p0": 0.0, "w_right": [1.0], "w_left": [0.0]}
    lo, span, r = float(theta["u_lo"]), float(theta["u_span"]), float(theta["r_right"][0])
    up = np.linspace(lo, lo + span, 301)
    u = np.concatenate([np.linspace(lo + span / 2, lo, 50), up, up[::-1]])
    y = model.simulate(u, np.arange(u.size), theta)
    rise = np.maximum(lo + (up - lo - r) * span / (span - r), lo)
    np.testing.assert_allclose(y[50:351], rise, rtol=1e-14, atol=1e-12 * span)
    np.testing.assert_allclose(y[351:], up[::-1], rtol=1e-14, atol=1e-12 * span)


# ------------------------------------------------------------------ loop shape


def _sine(f_hz, n_per=200, periods=3.0, centre=0.0):
    t = np.arange(int(n_per * periods) + 1) / (n_per * f_hz)
    return centre + np.sin(2 * np.pi * f_hz * t), t


def _point_asymmetry(model, theta, centre=0.0):
    """max |y(t) + y(t + T/2) - 2 mean(y)| over the second period, relative to the span."""
    u, t = _sine(1.0, centre=centre)
    y = model.simulate(u, t, theta)
    return np.abs(y[200:400] + y[300:500] - 2 * y[200:400].mean()).max() / np.ptp(y[200:400])


def test_loops_are_asymmetric_exactly_where_the_model_is():
    w = np.full(N_OP, 0.3)
    rl = MODELS["right_left"]
    unit = dict(rl.param_space().fixed)  # range [-1, 1], centre 0
    assert _point_asymmetry(rl, unit | {"p0": 0.5, "w_right": w, "w_left": w}) < 1e-12
    assert _point_asymmetry(rl, unit | {"p0": 0.5, "w_right": w, "w_left": 0.2 * w}) > 0.02
    dz = MODELS["deadzone"]
    base = {"p0": 0.5, "w": w, "r": dz.param_space().fixed["r"], "d": np.array([0.4, 0.8, 1.2])}
    assert _point_asymmetry(dz, base | {"g": np.zeros(3)}) < 1e-12
    assert _point_asymmetry(dz, base | {"g": np.array([0.5, 0.5, 0.5])}) > 0.02
    osp = MODELS["osp"]
    th = dict(osp.param_space().fixed) | {"p0": 0.5, "w": w, "a3": 0.0}
    assert _point_asymmetry(osp, th | {"a2": 0.0}) < 1e-12
    assert _point_asymmetry(osp, th | {"a2": 0.3}) > 0.02


def test_mrpi_loop_widens_with_frequency():
    model = MODELS["osp_rate"]
    base = dict(model.param_space().fixed) | {"p0": 0.5, "w": np.full(N_OP, 0.3),
                                              "a2": 0.0, "a3": 0.0}
    for tau, grows in [(2e-3, True), (0.0, False)]:
        areas = []
        for f in (1.0, 10.0, 100.0):
            u, t = _sine(f, n_per=1000, periods=2.0)  # same samples per period
            y = model.simulate(u, t, base | {"tau_l": tau, "tau_r": tau})
            yc, uc = y[1000:], u[1000:]
            areas.append(-np.sum(0.5 * (yc[1:] + yc[:-1]) * np.diff(uc)))  # ccw > 0
        if grows:
            assert areas[0] > 0 and np.all(np.diff(areas) > 0.02 * areas[0]), areas
        else:
            # the samples differ only by rounding (sin(2 pi f k / (1000 f)))
            np.testing.assert_allclose(areas, areas[0], rtol=1e-12)


def test_mrpi_output_follows_the_input_direction_at_any_rate_lag():
    # per monotone step: with non-negative weights and a monotone polynomial the output
    # never moves against the input, however large tau (the clamp form would)
    model = MODELS["osp_rate"]
    u, t = _irregular(20)
    theta = dict(model.param_space(_record()).fixed) | {
        "p0": 0.2, "a2": 0.0, "a3": 0.0, "w": np.full(N_OP, 0.1)}
    for tau in (0.0, 1e-3, 1e-2, 1.0):
        y = model.simulate(u, t, theta | {"tau_l": tau, "tau_r": 2 * tau})
        assert np.all(np.diff(y) * np.sign(np.diff(u)) >= -1e-12 * np.ptp(y)), tau
    # and the rate does act here: the lag changes the output
    assert np.abs(y - model.simulate(u, t, theta | {"tau_l": 0.0, "tau_r": 0.0})).max() > 1.0


@HYST
@given(u=st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=40), data=st.data())
def test_rate_independent_models_ignore_a_monotone_time_warp(u, data):
    u = np.array(u)
    dt = np.array(data.draw(st.lists(st.floats(1e-4, 1.0), min_size=u.size, max_size=u.size)))
    warp = np.array(data.draw(st.lists(st.floats(0.01, 100.0), min_size=u.size,
                                       max_size=u.size)))
    t, t_warped = np.cumsum(dt), np.cumsum(dt * warp)
    for name in STATIC:
        model = MODELS[name]
        theta = _theta(model, 11)
        np.testing.assert_array_equal(model.simulate(u, t, theta),
                                      model.simulate(u, t_warped, theta), err_msg=name)


def test_mrpi_changes_under_a_time_warp():
    model = MODELS["osp_rate"]
    theta = _theta(model, 12) | {"tau_l": 0.02, "tau_r": 0.01, "w": np.full(N_OP, 0.3)}
    u, t = _sine(1.0)
    warped = t + 0.3 * np.sin(2 * np.pi * t) / (2 * np.pi)  # strictly increasing
    diff = model.simulate(u, t, theta) - model.simulate(u, warped, theta)
    assert np.abs(diff).max() > 1e-2


# ------------------------------------------------------------------ state and batches


@HYST
@given(u=st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=30), data=st.data())
def test_two_pieces_equal_one(u, data):
    u = np.array(u)
    t = np.cumsum(data.draw(st.lists(st.floats(1e-3, 1.0), min_size=u.size, max_size=u.size)))
    cuts = sorted(data.draw(st.lists(st.integers(1, max(1, u.size - 1)), max_size=3)))
    bounds = [0, *[c for c in cuts if c < u.size], u.size]
    for name, model in MODELS.items():
        theta = _theta(model, 13)
        if name == "osp_rate":
            theta |= {"tau_l": 0.3, "tau_r": 0.1}
        whole = model.run(u, t, theta)
        state, parts = model.initial_state(theta, u[0]), []
        for a, b in itertools.pairwise(bounds):
            if a == b:
                continue
            traj = model.run(u[a:b], t[a:b], theta, state0=state)
            parts.append(traj.y)
            state = traj.state
        np.testing.assert_array_equal(np.concatenate(parts), whole.y, err_msg=name)
        np.testing.assert_array_equal(state, whole.state, err_msg=name)


@pytest.mark.parametrize("name", list(MODELS))
def test_samples_one_at_a_time_equal_one_run(name):
    model = MODELS[name]
    rec = _record(periods=0.5)
    theta = _theta(model, 14, rec)
    whole = model.run(rec.u, rec.t, theta)
    state = model.initial_state(theta, rec.u[0])
    ys = []
    for k in range(rec.u.size):
        traj = model.run(rec.u[k:k + 1], rec.t[k:k + 1], theta, state0=state)
        ys.append(traj.y[0])
        state = traj.state
    np.testing.assert_array_equal(ys, whole.y)


@pytest.mark.parametrize("name", list(MODELS))
def test_batched_equals_one_by_one(name):
    model = MODELS[name]
    rec = _record()
    space = model.param_space(rec)
    z = space.sample_prior(np.random.default_rng(15), 5)
    batch = model.run_batch(rec.u, rec.t, space.unpack(z))
    assert batch.n_failed == 0
    for j in range(5):
        one = model.run(rec.u, rec.t, space.unpack(z[j]))
        np.testing.assert_array_equal(batch.y[j], one.y)
        np.testing.assert_array_equal(batch.state[j], one.state)


@pytest.mark.parametrize("scaled", [True, False], ids=["data_prior", "unit_prior"])
@pytest.mark.parametrize("name", list(MODELS))
def test_prior_draws_never_give_nan(name, scaled):
    model = MODELS[name]
    rec = _record() if scaled else _record(amp=1.0, offset=0.0)
    space = model.param_space(rec if scaled else None)
    batch = model.run_batch(rec.u, rec.t, space.unpack(
        space.sample_prior(np.random.default_rng(16), 300)))
    assert batch.n_failed == 0
    assert np.all(np.isfinite(batch.y)) and np.all(np.isfinite(batch.state))


@pytest.mark.parametrize("name", list(MODELS))
def test_linear_design_reproduces_the_output(name):
    # the contract of LinearInParams: affine in the linear group from the relaxed state
    model = MODELS[name]
    u, t = _irregular(17)
    space = model.param_space(_record())
    theta = space.unpack(space.sample_prior(np.random.default_rng(17), 4))
    design = model.linear_design(u, t, theta)
    beta = np.concatenate([np.asarray(theta[n]).reshape(4, -1) for n in design.names], axis=1)
    y = model.run_batch(u, t, theta).y
    np.testing.assert_allclose(design.predict(beta), y, rtol=0, atol=1e-11 * np.ptp(y))
    assert design.names == model.linear_params


# ------------------------------------------------------------------ priors and errors


def test_fixed_placements_are_scaled_from_the_data():
    rec = _record()
    y_lo, y_hi = rec.y.min(), rec.y.max()
    np.testing.assert_allclose(MODELS["deadzone"].param_space(rec).fixed["d"],
                               y_lo + np.arange(1, 4) * (y_hi - y_lo) / 4, rtol=1e-14)
    sc = get("pi_play").param_space(rec)  # the same data_scales
    assert sc.fixed["r"].shape == (10,)
    np.testing.assert_allclose(dead_zone_thresholds(1, SimpleNamespace(
        y_min=-2.0, y_span=4.0)), [0.0])
    fixed = MODELS["right_left"].param_space(rec).fixed
    assert float(fixed["u_lo"]) == pytest.approx(rec.u.min())
    assert float(fixed["u_span"]) == pytest.approx(np.ptp(rec.u))
    tau = MODELS["osp_rate"].param_space(rec)["tau_l"].prior
    assert tau.sigma == pytest.approx(0.1 * np.ptp(rec.u) / typical_rate(rec))


def test_bad_settings_and_inputs_are_refused():
    with pytest.raises(ModelError):
        DeadZonePrandtlIshlinskii(4, n_deadzones=0)
    with pytest.raises(ModelError):
        RightLeftPrandtlIshlinskii(0)
    rl = MODELS["right_left"]
    rec = _record()
    theta = _theta(rl, 18, rec)
    theta["r_left"] = theta["r_left"] * 0 + float(theta["u_span"])  # band would be infinite
    assert rl.run_batch(rec.u, rec.t, {k: np.asarray(v)[None] for k, v in theta.items()}
                        ).failed[0]
    with pytest.raises(SimulationError):
        rl.simulate(rec.u, rec.t, theta)
    model = MODELS["osp_rate"]
    theta = _theta(model, 19) | {"tau_r": -1e-3}
    with pytest.raises(SimulationError):
        model.simulate(rec.u, rec.t, theta)
    theta["tau_r"] = 1e-3
    with pytest.raises(ParameterError, match="strictly increasing"):
        model.simulate([0.0, 1.0, 2.0], [0.0, 1.0, 1.0], theta)
    traj = model.run([0.0, 1.0], [0.0, 1.0], theta)
    with pytest.raises(ParameterError, match="previous sample"):
        model.run([2.0], [1.0], theta, state0=traj.state)


# ------------------------------------------------------------------ inverse of the MRPI


def _mrpi_inverse_case(tau_over_dt):
    fs = 2000.0
    t = np.arange(700) / fs
    u = 75.0 - 60.0 * np.cos(2 * np.pi * 10.0 * t) + 8.0 * np.sin(2 * np.pi * 30.0 * t)
    model = MODELS["osp_rate"]
    theta = dict(model.param_space(_record()).fixed) | {
        "p0": 0.2, "a2": 0.02, "a3": 0.01, "w": np.linspace(0.1, 0.02, N_OP),
        "tau_l": tau_over_dt / fs, "tau_r": 0.7 * tau_over_dt / fs}
    y_d = model.simulate(u, t, theta)
    inv = invert(model, y_d, t, {k: np.asarray(v)[None] for k, v in theta.items()},
                 u_limits=(-100.0, 250.0))
    return model, theta, u, t, y_d, inv


def test_mrpi_inverse_is_exact_for_rate_lags_up_to_the_sample_period():
    model, theta, u, t, y_d, inv = _mrpi_inverse_case(0.9)
    y = model.simulate(inv.u, t, theta)
    assert np.max(np.abs(y - y_d)) <= 1e-6 * np.ptp(y_d)
    np.testing.assert_allclose(inv.u, u, atol=1e-6 * 150)


def test_mrpi_inverse_failure_for_long_rate_lags_is_reported_not_hidden():
    # tau = 20 samples: the non-minimum-phase branch makes the causal inverse diverge
    model, theta, _, t, y_d, inv = _mrpi_inverse_case(20.0)
    y = model.simulate(inv.u, t, theta)
    err = np.max(np.abs(y - y_d))
    assert err > 1e-2 * np.ptp(y_d)
    assert inv.max_error == pytest.approx(err, rel=1e-6)


# ------------------------------------------------------------------ posterior recovery
# The checks of tests/test_recovery.py: the truth's squared Mahalanobis distance summed
# over independent fits is ~ chi2(S d) (two-sided 0.1 % test), and (slow) each 90 % HDI
# covers the truth at the binomial rate (Bonferroni over parameters).

SIGMA = 0.05
RECOVERY = {
    # pi_osp: linear in all its weights; only the offset and the noise are not
    "osp": ("pi_osp(n_operators=4)",
            {"p0": 0.15, "w": np.array([0.08, 0.06, 0.04, 0.02]), "a2": 0.03, "a3": -0.02}),
    # pi_right_left: linear in all its weights
    "right_left": ("pi_right_left(n_operators=3)",
                   {"p0": 0.15, "w_right": np.array([0.06, 0.04, 0.03]),
                    "w_left": np.array([0.02, 0.05, 0.01])}),
    # pi_osp_rate: the same linear block plus the rate lags (fitted on two frequencies)
    "osp_rate": ("pi_osp_rate(n_operators=4)",
                 {"p0": 0.15, "w": np.array([0.08, 0.06, 0.04, 0.02]), "a2": 0.03,
                  "a3": -0.02, "tau_l": 2e-3, "tau_r": 1e-3}),
    # pi_deadzone: g is the linear block, p0 and w are sampled by the ensemble
    "deadzone": ("pi_deadzone(n_operators=4, n_deadzones=2)",
                 {"p0": 0.15, "w": np.array([0.08, 0.06, 0.04, 0.02]),
                  "g": np.array([0.4, -0.3])}),
}


def _recovery_post(kind, seed):
    """(posterior, truth) of data simulated from the model + noise."""
    spec, truth = RECOVERY[kind]
    model = get(spec)
    if kind == "osp_rate":  # 2 Hz, then 12 Hz: the loop width changes with the rate
        t = np.arange(1500) * 1e-3
        u = 75.0 - 70.0 * np.cos(2 * np.pi * np.cumsum(np.where(t < 0.75, 2.0, 12.0)) * 1e-3)
    else:
        t = np.arange(1200) * 1e-3
        u = 75.0 - 70.0 * np.cos(2 * np.pi * 2.0 * t) * np.exp(-0.4 * t)  # minor loops
    # priors and fixed placements (dead-zone thresholds) from a proxy record with the
    # same input and output ranges, so that truth and fit share the fixed values
    space = model.param_space(Record(t=t, u=u, y=0.35 * u, name="proxy"))
    y = model.simulate(u, t, dict(space.fixed) | truth)
    rec = Record(t=t, u=u, y=y + np.random.default_rng(seed).normal(0.0, SIGMA, t.size),
                 name=f"{kind}{seed}", warmup=200)
    post = Posterior(rec, model, space=space)
    return post, truth | {"obs.offset": 0.0, "noise.sigma": SIGMA}


def _recovery_fit(kind, seed):
    """(posterior, result, truth) of one fit to data simulated from the model + noise."""
    post, truth = _recovery_post(kind, seed)
    settings = SamplerSettings(seed=seed, max_steps=8000, n_walkers=16)
    # the dead-zone MPI's posterior has a minor mode (play part scaled up against the
    # offset and a negative first dead-zone weight) that the screen's local searches can
    # both land in; the model declares it, so the default path searches globally too
    res = sample_posterior(post, settings)
    return post, res, truth


def _recovery_stats(kind, seeds):
    out = []
    for seed in seeds:
        post, res, truth = _recovery_fit(kind, seed)
        out.append(_fit_stats(post, truth, seed, res))
    return out, post.ndim


def test_osp_mpi_posterior_is_calibrated():
    fits, ndim = _recovery_stats("osp", range(3))
    _check_calibration(fits, ndim)


@pytest.mark.slow
def test_right_left_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _recovery_stats("right_left", range(20))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_osp_mpi_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _recovery_stats("osp", range(3, 23))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_mrpi_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _recovery_stats("osp_rate", range(20))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_deadzone_mpi_posterior_is_calibrated_and_covers_at_the_nominal_rate():
    fits, ndim = _recovery_stats("deadzone", range(20))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_deadzone_default_map_search_finds_the_major_mode():
    # oracle: the MAP of a search that always runs the global differential evolution;
    # before pi_deadzone declared multimodal_posterior, the default search ended in the
    # minor mode (noise sigma ~0.36 against 0.05) for 3 of 6 seeds, both starts agreeing
    for seed in range(6):
        post, _ = _recovery_post("deadzone", seed)
        default = find_map(post, seed=seed)
        forced = find_map(post, seed=seed, global_search=True)
        assert default.log_prob >= forced.log_prob - 0.5, (seed, default.log_prob,
                                                           forced.log_prob)
