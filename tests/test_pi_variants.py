"""PI variants (generalised, asymmetric unilateral, rate-dependent play) against oracles.

Oracles: slow pure-Python loops written from the equations (review Eq. 22, 27, 28–30),
the classical ``pi_play`` where an equation reduces to it, and properties (state
continuation, rate independence under time warps, batched == one-by-one).
"""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models.pi import PrandtlIshlinskii
from bayeshyst.models.pi_variants import (
    AsymmetricPrandtlIshlinskii,
    GeneralizedPrandtlIshlinskii,
    RateDependentPrandtlIshlinskii,
    typical_rate,
)

N_OP = 6
MODELS = {
    "gen_cubic": GeneralizedPrandtlIshlinskii(N_OP),
    "gen_quadratic": GeneralizedPrandtlIshlinskii(N_OP, envelope="quadratic"),
    "asym": AsymmetricPrandtlIshlinskii(N_OP),
    "asym_per_op": AsymmetricPrandtlIshlinskii(N_OP, per_operator_slope=True),
    "rate": RateDependentPrandtlIshlinskii(N_OP),
}
HYST = settings(max_examples=40, deadline=None)


def _record(f_hz: float = 2.0, n_per: int = 200, periods: float = 3.0, amp: float = 60.0,
            offset: float = 75.0) -> SimpleNamespace:
    """A unipolar sine record like a piezo drive (0–150 V) with a loop-shaped output."""
    t = np.arange(int(n_per * periods)) / (n_per * f_hz)
    u = offset + amp * np.sin(2 * np.pi * f_hz * t)
    return SimpleNamespace(t=t, u=u, y=0.1 * u + np.sin(2 * np.pi * f_hz * t - 0.3))


def _theta(model, seed: int, data=None) -> dict:
    """A prior draw; for the quadratic envelope a monotone one (|b| <= 0.3 here)."""
    space = model.param_space(data)
    theta = space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])
    if "b_l" in theta and model.envelope == "quadratic":
        theta["b_l"], theta["b_r"] = float(np.tanh(theta["b_l"])) * 0.3, -0.2
    return theta


# ------------------------------------------------------------------ pure-Python oracles


def gamma_oracle(x_u, b, uc, uh, kind):
    x = (x_u - uc) / uh
    if kind == "cubic":
        return x_u + uh * (b * x**2 + b**2 * x**3 / 3.0)
    return x_u + uh * b * x**2


def oracle(name, u, t, theta, v0):
    """Output list and final operator list of one model, one theta, from state v0."""
    p0, w, r = float(theta["p0"]), list(theta["w"]), list(theta["r"])
    n = len(w)
    v = [float(x) for x in v0[:n]]
    up, tp, has = (float(v0[n]), float(v0[n + 1]), v0[n + 2] != 0) if name == "rate" \
        else (0.0, 0.0, False)
    ys = []
    for uk, tk in zip(u, t, strict=True):
        uk, tk = float(uk), float(tk)
        if name.startswith("gen"):
            kind = name.split("_")[1]
            gl = gamma_oracle(uk, theta["b_l"], theta["u_c"], theta["u_h"], kind)
            gr = gamma_oracle(uk, theta["b_r"], theta["u_c"], theta["u_h"], kind)
            lo, hi = [gl - ri for ri in r], [gr + ri for ri in r]
        elif name.startswith("asym"):
            m = np.broadcast_to(theta["m"], (n,))
            lo, hi = [uk - ri for ri in r], [float(m[i]) * uk for i in range(n)]
        else:
            rate = abs(uk - up) / (tk - tp) if has else 0.0
            fac = 1.0 + theta["c"] * math.log(1.0 + rate / theta["udot0"])
            lo, hi = [uk - ri * fac for ri in r], [uk + ri * fac for ri in r]
            up, tp, has = uk, tk, True
        v = [max(lo[i], min(hi[i], v[i])) for i in range(n)]
        ys.append(p0 * uk + sum(w[i] * v[i] for i in range(n)))
    return np.array(ys), np.array(v)


@pytest.mark.parametrize("name", list(MODELS))
def test_kernel_matches_pure_python_oracle(name):
    model = MODELS[name]
    rec = _record()
    theta = _theta(model, 1, rec)
    rng = np.random.default_rng(2)
    u = np.concatenate([rec.u[:300], 75 + 70 * rng.uniform(-1, 1, 150)])
    t = np.arange(u.size) * 1e-3
    s0 = model.initial_state(theta, u[0])
    s0[:N_OP] += rng.normal(0.0, 5.0, N_OP)  # an arbitrary, non-relaxed start
    traj = model.run(u, t, theta, state0=s0)
    y_ref, v_ref = oracle(name, u, t, theta, s0)
    np.testing.assert_allclose(traj.y, y_ref, rtol=0, atol=1e-12 * np.abs(y_ref).max())
    np.testing.assert_allclose(traj.state[:N_OP], v_ref, rtol=0, atol=1e-12 * 150)


def test_default_initial_states_follow_the_documented_relaxed_band_middle():
    gen, asym = MODELS["gen_cubic"], MODELS["asym"]
    th = _theta(gen, 3)
    gl = gamma_oracle(0.4, th["b_l"], th["u_c"], th["u_h"], "cubic")
    gr = gamma_oracle(0.4, th["b_r"], th["u_c"], th["u_h"], "cubic")
    want = [max(gl - ri, min(gr + ri, 0.5 * (gl + gr))) for ri in th["r"]]
    np.testing.assert_allclose(gen.initial_state(th, 0.4), want, atol=1e-15)
    th = _theta(asym, 3) | {"m": 0.5}
    want = [max(0.8 - ri, min(0.4, 0.5 * (0.8 - ri + 0.4))) for ri in th["r"]]
    np.testing.assert_allclose(asym.initial_state(th, 0.8), want, atol=1e-15)
    rate = MODELS["rate"]
    s = rate.initial_state(_theta(rate, 3), 0.7)
    np.testing.assert_array_equal(s, [0.7] * (N_OP + 1) + [0.0, 0.0])


# ------------------------------------------------------------------ reductions to pi_play


def _play_theta(theta, r=None):
    return {"p0": theta["p0"], "w": theta["w"], "r": theta["r"] if r is None else r}


@pytest.mark.parametrize("envelope", ["cubic", "quadratic"])
def test_generalized_with_identity_envelopes_is_pi_play_exactly(envelope):
    model = GeneralizedPrandtlIshlinskii(N_OP, envelope=envelope)
    rec = _record()
    theta = _theta(model, 4, rec) | {"b_l": 0.0, "b_r": 0.0}
    play = PrandtlIshlinskii(N_OP)
    a = model.run(rec.u, rec.t, theta)
    b = play.run(rec.u, rec.t, _play_theta(theta))
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.state, b.state)


def test_asymmetric_with_unit_slope_is_half_threshold_play_minus_offset():
    # m = 1: max(u - r, min(u, v)) = F_{r/2}[u] - r/2 (with v shifted by r/2 initially)
    model = AsymmetricPrandtlIshlinskii(N_OP)
    rec = _record()
    theta = _theta(model, 5, rec) | {"m": 1.0}
    y = model.simulate(rec.u, rec.t, theta)
    y_play = PrandtlIshlinskii(N_OP).simulate(rec.u, rec.t, _play_theta(theta, theta["r"] / 2))
    offset = float(np.dot(theta["w"], theta["r"])) / 2
    np.testing.assert_allclose(y, y_play - offset, rtol=0, atol=1e-12 * np.abs(y).max())
    # and the doubled thresholds make it pi_play's own default placement
    np.testing.assert_allclose(theta["r"] / 2, PrandtlIshlinskii(N_OP).param_space(rec)
                               .fixed["r"], rtol=1e-15)


def test_rate_with_zero_sensitivity_is_pi_play_exactly():
    model = MODELS["rate"]
    rec = _record()
    theta = _theta(model, 6, rec) | {"c": 0.0}
    a = model.run(rec.u, rec.t, theta)
    b = PrandtlIshlinskii(N_OP).run(rec.u, rec.t, _play_theta(theta))
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.state[:N_OP], b.state)


# ------------------------------------------------------------------ loop shape


def _sine(f_hz, n_per=200, periods=2.0):
    t = np.arange(int(n_per * periods) + 1) / (n_per * f_hz)
    return np.sin(2 * np.pi * f_hz * t), t


def _point_asymmetry(model, theta):
    """max |y(t) + y(t + T/2) - 2 mean(y)| over the second period, relative to the span."""
    u, t = _sine(1.0, periods=3.0)
    y = model.simulate(u, t, theta)[200:400]
    y2 = model.simulate(u, t, theta)[300:500]
    return np.abs(y + y2 - 2 * y.mean()).max() / np.ptp(y)


def test_asymmetric_models_give_loops_that_are_not_point_symmetric():
    pos = {"p0": 0.5, "w": np.full(N_OP, 0.3)}
    play = PrandtlIshlinskii(N_OP)
    assert _point_asymmetry(play, pos | {"r": play.param_space().fixed["r"]}) < 1e-12
    asym = MODELS["asym"]
    assert _point_asymmetry(asym, pos | {"m": 1.3, "r": asym.param_space().fixed["r"]}) > 0.02
    gen = MODELS["gen_cubic"]
    th = pos | dict(gen.param_space().fixed) | {"b_l": 0.3, "b_r": 0.3}
    assert _point_asymmetry(gen, th) > 0.02


def test_rate_loop_widens_with_frequency():
    # 1000 samples per period resolve the turning points: the backward difference there
    # is ~ pi u̇_max / 1000, not 0 (with 200 samples at 100 Hz it reaches 1.6 u̇_0 and
    # lowers the top of the saturated operators; see the model's notes)
    model = MODELS["rate"]
    base = {"p0": 0.5, "w": np.full(N_OP, 0.3), "r": model.param_space().fixed["r"],
            "udot0": 2 * np.pi}
    for c, grows in [(0.3, True), (0.0, False)]:
        widths, areas = [], []
        for f in (1.0, 10.0, 100.0):
            u, t = _sine(f, n_per=1000)  # same samples per period: only the rate differs
            y = model.simulate(u, t, base | {"c": c})
            # at u = 0: the falling branch (1.5 periods) minus the rising one (2 periods)
            widths.append(y[1500] - y[2000])
            yc, uc = y[1000:], u[1000:]
            areas.append(-np.sum(0.5 * (yc[1:] + yc[:-1]) * np.diff(uc)))  # ccw > 0
        if grows:
            assert widths[0] > 0 and np.all(np.diff(widths) > 0.02 * widths[0])
            assert areas[0] > 0 and np.all(np.diff(areas) > 0.02 * areas[0])
        else:
            np.testing.assert_array_equal(widths, widths[0])


@HYST
@given(u=st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=40),
       data=st.data())
def test_rate_independent_variants_ignore_a_monotone_time_warp(u, data):
    u = np.array(u)
    dt = np.array(data.draw(st.lists(st.floats(1e-4, 1.0), min_size=u.size,
                                     max_size=u.size)))
    warp = np.array(data.draw(st.lists(st.floats(0.01, 100.0), min_size=u.size,
                                       max_size=u.size)))
    t, t_warped = np.cumsum(dt), np.cumsum(dt * warp)
    play = PrandtlIshlinskii(N_OP)
    models = [play, MODELS["gen_cubic"], MODELS["gen_quadratic"], MODELS["asym"]]
    for model in models:
        theta = _theta(model, 7)
        np.testing.assert_array_equal(model.simulate(u, t, theta),
                                      model.simulate(u, t_warped, theta))


def test_rate_model_changes_under_a_time_warp():
    model = MODELS["rate"]
    theta = _theta(model, 8) | {"c": 0.5, "udot0": 2 * np.pi, "w": np.full(N_OP, 0.3)}
    u, t = _sine(1.0)
    warped = t + 0.3 * np.sin(2 * np.pi * t) / (2 * np.pi)  # strictly increasing
    diff = model.simulate(u, t, theta) - model.simulate(u, warped, theta)
    assert np.abs(diff).max() > 1e-2


# ------------------------------------------------------------------ state and batches


@HYST
@given(u=st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=30), data=st.data())
def test_two_pieces_equal_one(u, data):
    u = np.array(u)
    t = np.cumsum(data.draw(st.lists(st.floats(1e-3, 1.0), min_size=u.size,
                                     max_size=u.size)))
    cuts = sorted(data.draw(st.lists(st.integers(1, max(1, u.size - 1)), max_size=3)))
    bounds = [0, *[c for c in cuts if c < u.size], u.size]
    for name, model in MODELS.items():
        theta = _theta(model, 9)
        if name == "gen_quadratic":
            theta |= {"b_l": 0.1, "b_r": -0.1}  # monotone for |x| <= 5
        whole = model.run(u, t, theta)
        state, parts = None, []
        for a, b in itertools.pairwise(bounds):
            if a == b:
                continue
            if state is None:
                state = model.initial_state(theta, u[0])
            traj = model.run(u[a:b], t[a:b], theta, state0=state)
            parts.append(traj.y)
            state = traj.state
        np.testing.assert_array_equal(np.concatenate(parts), whole.y, err_msg=name)
        np.testing.assert_array_equal(state, whole.state, err_msg=name)


@pytest.mark.parametrize("name", list(MODELS))
def test_samples_one_at_a_time_equal_one_run(name):
    model = MODELS[name]
    rec = _record(periods=0.5)
    theta = _theta(model, 10, rec)
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
    z = space.sample_prior(np.random.default_rng(11), 5)
    if name == "gen_quadratic":  # make one walker violate monotonicity on purpose
        z[2, space.slice_of("b_l")] = 3.0
    batch = model.run_batch(rec.u, rec.t, space.unpack(z))
    for j in range(5):
        theta = space.unpack(z[j])
        if batch.failed[j]:
            assert np.all(np.isnan(batch.y[j]))
            with pytest.raises(SimulationError):
                model.simulate(rec.u, rec.t, theta)
            continue
        one = model.run(rec.u, rec.t, theta)
        np.testing.assert_array_equal(batch.y[j], one.y)
        np.testing.assert_array_equal(batch.state[j], one.state)
    assert batch.failed.sum() == (1 if name == "gen_quadratic" else 0)


@pytest.mark.parametrize("scaled", [True, False], ids=["data_prior", "unit_prior"])
@pytest.mark.parametrize("name", list(MODELS))
def test_prior_draws_never_give_nan(name, scaled):
    model = MODELS[name]
    rec = _record() if scaled else _record(amp=1.0, offset=0.0)
    space = model.param_space(rec if scaled else None)
    z = space.sample_prior(np.random.default_rng(12), 200)
    batch = model.run_batch(rec.u, rec.t, space.unpack(z))
    assert np.all(np.isfinite(batch.y[~batch.failed]))
    n_raised = 0
    for j in range(200):
        theta = space.unpack(z[j])
        try:
            y = model.simulate(rec.u, rec.t, theta)
        except SimulationError:
            n_raised += 1
            continue
        assert np.all(np.isfinite(y))
    assert n_raised == batch.n_failed
    if name == "gen_quadratic":
        # failures are exactly the draws whose slope 1 + 2 b x goes negative on the data
        th = space.unpack(z)
        x = (rec.u[None, :] - th["u_c"][:, None]) / th["u_h"][:, None]
        bad = np.zeros(200, dtype=bool)
        for b in (th["b_l"], th["b_r"]):
            bad |= np.any(1 + 2 * b[:, None] * x < 0, axis=1)
        assert bad.any()
        np.testing.assert_array_equal(batch.failed, bad)
    else:
        assert batch.n_failed == 0


def test_non_monotone_envelope_is_rejected_with_a_reason():
    model = MODELS["gen_quadratic"]
    theta = _theta(model, 13) | {"b_l": 0.8}
    with pytest.raises(SimulationError, match="not monotone"):
        model.simulate(np.linspace(-1, 1, 20), np.arange(20.0), theta)


@pytest.mark.parametrize("name", list(MODELS))
def test_regressors_reproduce_the_output(name):
    model = MODELS[name]
    rec = _record()
    theta = _theta(model, 14, rec)
    phi = model.regressors(rec.u, rec.t, {k: v for k, v in theta.items()
                                          if k not in ("p0", "w")})
    assert phi.shape == (rec.u.size, N_OP + 1)
    np.testing.assert_array_equal(phi[:, 0], rec.u)
    y = model.simulate(rec.u, rec.t, theta)
    np.testing.assert_allclose(phi @ np.r_[theta["p0"], theta["w"]], y, rtol=0,
                               atol=1e-12 * np.abs(y).max())


# ------------------------------------------------------------------ priors and errors


def test_rate_prior_is_scaled_from_the_data_rate():
    rec = _record(f_hz=5.0, n_per=2000)
    # median |d/dt (A sin wt)| = A w median|cos| = A w cos(pi/4) (to the phase grid)
    want = 60 * 2 * np.pi * 5 * math.cos(math.pi / 4)
    assert typical_rate(rec) == pytest.approx(want, rel=0.01)

    class Dataset:  # the Dataset protocol data_scales uses: .records and iteration
        def __init__(self, records):
            self.records = records

        def __iter__(self):
            return iter(self.records)

    # per-record differences: the same record twice has the same typical rate
    assert typical_rate(Dataset([rec, rec])) == pytest.approx(typical_rate(rec), rel=1e-12)
    prior = MODELS["rate"].param_space(rec)["udot0"].prior
    assert math.exp(prior.mu) == pytest.approx(typical_rate(rec))
    assert typical_rate(None) == 4.0


def test_bad_settings_and_inputs_are_refused():
    with pytest.raises(ModelError):
        GeneralizedPrandtlIshlinskii(N_OP, envelope="spline")
    with pytest.raises(ModelError):
        AsymmetricPrandtlIshlinskii(0)
    model = MODELS["rate"]
    theta = _theta(model, 15)
    with pytest.raises(ParameterError, match="strictly increasing"):
        model.simulate([0.0, 1.0, 2.0], [0.0, 1.0, 1.0], theta)
    traj = model.run([0.0, 1.0], [0.0, 1.0], theta)
    with pytest.raises(ParameterError, match="previous sample"):
        model.run([2.0], [1.0], theta, state0=traj.state)
    with pytest.raises(ParameterError, match="missing"):
        model.regressors([0.0, 1.0], [0.0, 1.0], {"r": theta["r"]})
