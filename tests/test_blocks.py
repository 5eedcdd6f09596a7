"""Effect blocks against independent oracles.

Oracles: ``scipy.signal.lfilter`` (ARX), the analytic step responses of a second-order
system (under-, critically, over-damped) and of a first-order lag bank, the
Mittag-Leffler function (closed form ``erfcx`` for order 1/2, its power series for small
arguments, the exponential for order 1), a shift for an integer delay, and the
polynomials of drift and output map written out directly. Then properties: two pieces
(down to one sample) equal one run, batched equals one-by-one.
"""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal, special

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models import _kernels as kernels
from bayeshyst.models.blocks import (
    ARX,
    DEFAULT_DT,
    AsymmetricOutput,
    Creep,
    Delay,
    Drift,
    EffectBlock,
    FractionalCreep,
    SecondOrder,
    block_class,
    block_names,
    time_scales,
)

DT = 1e-3


def _record(n: int = 400, dt: float = DT, jitter: float = 0.0, seed: int = 0):
    """A record-like object: times with optional jitter, a unipolar drive, a loop output."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(dt * (1.0 + jitter * rng.uniform(-1, 1, n))) - dt
    u = 75.0 + 60.0 * np.sin(2 * np.pi * 3.0 * t)
    return SimpleNamespace(t=t, u=u, y=0.12 * u + 0.5 * np.cos(2 * np.pi * 3.0 * t))


REC = _record()
BLOCKS = {
    "arx": ARX(2, 3, 1),
    "arx_fir": ARX(0, 2, 2),
    "second_order": SecondOrder(),
    "creep": Creep(4),
    "creep_fractional": FractionalCreep(n_modes=15),
    "drift": Drift(2),
    "delay": Delay(6),
    "asym_output": AsymmetricOutput(3),
}


def _theta(block: EffectBlock, seed: int, data=REC, width: int | None = None) -> dict:
    space = block.param_space(data)
    z = space.sample_prior(np.random.default_rng(seed), width or 1)
    return space.unpack(z if width else z[0])


def _step(n: int, dt: float = DT, jitter: float = 0.0, seed: int = 1):
    """Times and a unit step that the held input takes at ``t[1]``."""
    rng = np.random.default_rng(seed)
    t = 5.0 + np.cumsum(dt * (1.0 + jitter * rng.uniform(-1, 1, n)))
    w = np.ones(n)
    w[0] = 0.0
    return t, w


# ------------------------------------------------------------------------------- ARX


@pytest.mark.parametrize(("na", "nb", "nk"),
                         [(0, 1, 0), (1, 1, 0), (2, 2, 0), (2, 3, 1), (4, 2, 3), (0, 3, 2)])
def test_arx_matches_lfilter_from_a_steady_start(na, nb, nk):
    block = ARX(na, nb, nk)
    rng = np.random.default_rng(na * 100 + nb * 10 + nk)
    w = np.cumsum(rng.normal(size=300)) + 3.0
    for seed in range(5):
        theta = _theta(block, seed)
        a, b = block.polynomials(theta)
        bb = np.r_[np.zeros(nk), b]
        zi = signal.lfilter_zi(bb, a) * w[0] if max(len(a), len(bb)) > 1 else np.zeros(0)
        ref = signal.lfilter(bb, a, w, zi=zi)[0] if zi.size else signal.lfilter(bb, a, w)
        np.testing.assert_allclose(block.apply(w, np.arange(w.size), theta).y, ref,
                                   rtol=1e-11, atol=1e-11)
        # every draw: unit DC gain and all poles inside the unit circle
        assert b.sum() / a.sum() == pytest.approx(1.0, abs=1e-13)
        if na:
            assert np.max(np.abs(np.roots(a))) < 1.0


def test_reflection_coefficients_give_exactly_the_stable_polynomials():
    rng = np.random.default_rng(3)
    for na in range(1, 7):
        block = ARX(na, 1)
        for _ in range(50):
            a, _ = block.polynomials({"kappa": rng.uniform(-0.999, 0.999, na)})
            assert np.max(np.abs(np.roots(a))) < 1.0
    # the map is onto: a stable A built from its roots comes back from its kappa
    a = np.real(np.poly([0.9, -0.5, 0.3 + 0.6j, 0.3 - 0.6j]))
    kappa, cur = [], a.copy()
    for m in range(4, 0, -1):  # step-down recursion
        k = cur[m]
        kappa.append(k)
        cur = (cur[: m + 1] - k * cur[: m + 1][::-1]) / (1 - k * k)
    np.testing.assert_allclose(ARX(4, 1).polynomials({"kappa": kappa[::-1]})[0], a,
                               atol=1e-12)
    with pytest.raises(ParameterError):
        ARX(1, 1).polynomials({"kappa": [1.0]})
    traj = ARX(1, 1).apply_batch(np.ones(5), np.arange(5.0), {"kappa": [[0.5], [1.0]]})
    assert traj.failed.tolist() == [False, True] and np.all(np.isnan(traj.y[1]))


# ---------------------------------------------------------------------- second order


def _second_order_step(t, fn, zeta):
    wn = 2 * np.pi * fn
    if zeta < 1:
        s, wd = zeta * wn, wn * math.sqrt(1 - zeta * zeta)
        return 1 - np.exp(-s * t) * (np.cos(wd * t) + s / wd * np.sin(wd * t))
    if zeta == 1:
        return 1 - np.exp(-wn * t) * (1 + wn * t)
    p1, p2 = wn * (zeta - math.sqrt(zeta**2 - 1)), wn * (zeta + math.sqrt(zeta**2 - 1))
    return 1 - (p2 * np.exp(-p1 * t) - p1 * np.exp(-p2 * t)) / (p2 - p1)


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.3, 1.0 - 1e-6, 1.0, 1.0 + 1e-6, 2.5, 40.0])
@pytest.mark.parametrize("jitter", [0.0, 0.6])
def test_second_order_step_response_is_exact(zeta, jitter):
    t, w = _step(600, jitter=jitter)
    theta = {"f_n": 7.0, "zeta": zeta}
    y = SecondOrder(hold="zoh").apply(w, t, theta).y
    assert y[0] == 0.0
    np.testing.assert_allclose(y[1:], _second_order_step(t[1:] - t[1], 7.0, zeta), atol=2e-10)


def _ramp_response(tau, fn, zeta, n=400_001):
    """Response to a unit ramp: the step response integrated (trapezoid, fine grid)."""
    grid = np.linspace(0.0, float(np.max(tau)), n)
    s = _second_order_step(grid, fn, zeta)
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (s[1:] + s[:-1]) * np.diff(grid))])
    return np.interp(tau, grid, integral)


@pytest.mark.parametrize("zeta", [0.05, 0.3, 1.0, 2.5])
def test_second_order_first_order_hold_is_exact(zeta):
    # sampled step 0 -> 1 between t[k0-1] and t[k0]: with a first-order hold the drive is
    # a ramp over that interval, i.e. (ramp(t - t_a) - ramp(t - t_b)) / (t_b - t_a)
    t, w = _step(600, jitter=0.6)
    k0 = int(np.argmax(w > 0.5))
    ta, tb = t[k0 - 1], t[k0]
    y = SecondOrder().apply(w, t, {"f_n": 7.0, "zeta": zeta}).y
    tau_a, tau_b = np.maximum(t - ta, 0.0), np.maximum(t - tb, 0.0)
    exact = (_ramp_response(tau_a, 7.0, zeta) - _ramp_response(tau_b, 7.0, zeta)) / (tb - ta)
    np.testing.assert_allclose(y, exact, atol=1e-8)


def test_second_order_holds_differ_by_the_one_sample_lag():
    # oracle: the continuous-time response to the exact sine (lsim on a 50x finer grid);
    # FOH tracks it to O(h^2), ZOH tracks it delayed by half a sample
    from scipy import signal

    h, fn, zeta = 1e-3, 200.0, 0.5
    t = np.arange(2000) * h
    w = np.sin(2 * np.pi * t)
    wn = 2 * np.pi * fn
    fine = np.arange(0, t[-1] + h / 100, h / 50)
    system = signal.lti([wn**2], [1.0, 2 * zeta * wn, wn**2])
    _, y_fine, _ = signal.lsim(system, np.sin(2 * np.pi * fine), fine)
    y_cont = np.interp(t, fine, y_fine)
    y_half = np.interp(t - h / 2, fine, y_fine)
    theta = {"f_n": fn, "zeta": zeta}
    y_foh = SecondOrder().apply(w, t, theta).y
    y_zoh = SecondOrder(hold="zoh").apply(w, t, theta).y
    assert np.max(np.abs(y_foh[200:] - y_cont[200:])) < 1e-5
    # (the staircase equals a half-sample delay only to first order: 1.8e-5 measured)
    assert np.max(np.abs(y_zoh[200:] - y_half[200:])) < 1e-4
    # and the ZOH lag is far larger than either
    assert np.max(np.abs(y_zoh[200:] - y_cont[200:])) > 2e-3
    with pytest.raises(ModelError, match="hold"):
        SecondOrder(hold="linear")


def test_second_order_prior_sits_below_nyquist():
    space = SecondOrder().param_space(_record(dt=1e-4))
    assert space["f_n"].prior.cdf(np.array(5000.0)) > 0.98  # Nyquist of 10 kHz data
    assert math.exp(space["f_n"].prior.mu) == pytest.approx(500.0)
    assert SecondOrder().param_space()["f_n"].prior.mu == pytest.approx(math.log(0.05 / DEFAULT_DT))


# ----------------------------------------------------------------------------- creep


def test_creep_step_matches_the_closed_form_for_any_sampling():
    t, w = _step(500, dt=0.01, jitter=0.7)
    theta = {"c": np.array([0.02, -0.01, 0.03]), "tau": np.array([0.05, 0.4, 3.0])}
    y = Creep(3).apply(w, t, theta).y
    ref = 1 - np.sum(theta["c"][:, None] * np.exp(-(t[1:] - t[1]) / theta["tau"][:, None]),
                     axis=0)
    np.testing.assert_allclose(y[1:], ref, atol=1e-13)
    assert y[0] == 0.0


def test_creep_bank_climbs_logarithmically_over_three_decades():
    gamma = 0.015  # creep per decade of time
    block = Creep(11, tau_min=1e-2, tau_max=1e3)  # two lags per decade over five decades
    theta = {"c": np.full(11, gamma * 0.5), "tau": block.time_constants()}
    t = np.r_[0.0, np.logspace(-3, 4, 701)]
    w = np.r_[0.0, np.ones(701)]
    y = block.apply(w, t, theta).y[1:]
    tt = t[1:] - t[1]
    inner = (tt > 0.03) & (tt < 30.0)  # three decades, clear of the ends of the bank
    slope = np.gradient(y[inner], np.log10(tt[inner]))
    assert np.all(np.abs(slope / gamma - 1.0) < 0.03)
    assert (y[inner][-1] - y[inner][0]) / gamma == pytest.approx(3.0, rel=0.01)


def test_creep_time_constants_follow_the_data():
    rec = _record(n=20001, dt=1e-3)  # 20 s at 1 kHz
    tau = Creep(3).time_constants(rec)
    np.testing.assert_allclose(tau, [0.2, 2.0, 20.0])
    np.testing.assert_allclose(Creep(3).time_constants(_record(n=500)), [0.01, 0.0706399, 0.499],
                               rtol=1e-4)  # short record: no lag faster than 10 samples
    assert Creep(3, tau_min=1.0, tau_max=100.0).time_constants()[1] == pytest.approx(10.0)
    ts = time_scales(rec)
    assert ts.dt == pytest.approx(1e-3) and ts.duration == pytest.approx(20.0)


# ----------------------------------------------------------------- fractional creep


def _ml_series(lam, x, terms=120):
    """``E_lam(-x)`` by its power series (accurate for the small x used here)."""
    k = np.arange(terms)
    return np.sum((-x[:, None]) ** k / special.gamma(lam * k + 1), axis=1)


def test_fractional_order_one_is_the_first_order_lag():
    t, w = _step(400, dt=0.01, jitter=0.5)
    y = FractionalCreep().apply(w, t, {"gain": 0.3, "tau": 0.7, "lam": 1.0}).y
    lag = Creep(1).apply(w, t, {"c": [0.3], "tau": [0.7]}).y
    np.testing.assert_allclose(y, lag, atol=1e-13)


@pytest.mark.parametrize("lam", [0.3, 0.5, 0.8])
def test_fractional_step_follows_mittag_leffler(lam):
    tau, gain = 2.0, 0.4
    t = np.r_[0.0, 1e-3, 1e-3 + np.logspace(-3, 3.3, 400) * tau]
    w = np.r_[0.0, np.ones(t.size - 1)]
    y = FractionalCreep().apply(w, t, {"gain": gain, "tau": tau, "lam": lam}).y
    x = (t[1:] - t[1]) / tau
    e = (1 - y[1:]) / gain  # the block's relaxation function
    if lam == 0.5:
        np.testing.assert_allclose(e, special.erfcx(np.sqrt(x)), atol=6e-4)
    small = x**lam < 1.2
    np.testing.assert_allclose(e[small], _ml_series(lam, x[small] ** lam), atol=2e-3)
    assert np.all(np.diff(e) <= 1e-15)  # completely monotone: creep never reverses


def test_fractional_weights_are_a_probability_and_bad_orders_fail():
    _, wts, ok = FractionalCreep().modes([1.0, 1.0, 1.0, -1.0], [0.2, 1.0, 0.0, 0.5])
    assert ok.tolist() == [True, True, False, False]
    np.testing.assert_allclose(wts[ok].sum(axis=1), 1.0, atol=1e-14)
    assert np.all(wts >= 0)
    traj = FractionalCreep().apply_batch(np.ones(4), np.arange(4.0),
                                         {"gain": [0.1, 0.1], "tau": [1.0, 1.0],
                                          "lam": [0.5, 1.5]})
    assert traj.failed.tolist() == [False, True]


# --------------------------------------------------------------- drift, delay, map


def test_drift_is_the_polynomial_in_normalised_time_from_the_first_sample():
    t = 3.0 + np.linspace(0, 8.0, 50)
    w = np.sin(t)
    theta = {"g": np.array([0.1, -0.05]), "d": np.array([0.3, 0.2]), "t_scale": 4.0}
    s = (t - 3.0) / 4.0
    ref = (1 + 0.1 * s - 0.05 * s**2) * w + 0.3 * s + 0.2 * s**2
    traj = Drift(2).apply(w, t, theta)
    np.testing.assert_allclose(traj.y, ref, atol=1e-14)
    assert traj.state.tolist() == [3.0]
    assert Drift(2).param_space(_record(n=1001))["t_scale"].name == "t_scale"
    assert float(Drift(2).param_space(_record(n=1001)).fixed["t_scale"]) == pytest.approx(1.0)


@pytest.mark.parametrize("m", [0, 1, 3, 6])
def test_integer_delay_is_a_shift_held_at_the_start(m):
    rng = np.random.default_rng(m)
    w = rng.normal(size=60)
    t = np.arange(60) * DT
    y = Delay(6).apply(w, t, {"d": m * DT}).y
    ref = np.r_[np.full(m, w[0]), w[: 60 - m]]
    np.testing.assert_allclose(y, ref, atol=1e-12)


def test_fractional_delay_interpolates_and_too_long_a_delay_fails():
    t = np.r_[0.0, 1.0, 3.0, 4.0, 8.0]
    w = np.array([1.0, 2.0, 6.0, 0.0, 4.0])
    y = Delay(3).apply(w, t, {"d": 1.5}).y
    np.testing.assert_allclose(y, [1.0, 1.0, 3.0, 5.0, 2.5])  # w(t - 1.5), w held before t0
    traj = Delay(1).apply_batch(w, np.arange(5.0), {"d": [1.9, 2.5]})
    assert traj.failed.tolist() == [False, True]  # 2 stored samples cover 2 steps, not 2.5
    assert Delay(10).param_space(REC)["d"].prior.upper == pytest.approx(10 * DT)


def test_output_map_is_the_normalised_polynomial_and_must_be_monotone():
    block = AsymmetricOutput(3)
    theta = {"a2": 0.2, "a3": -0.1, "centre": 5.0, "half_span": 2.0}
    w = np.linspace(2.0, 8.0, 31)
    x = (w - 5.0) / 2.0
    ref = 5.0 + 2.0 * (x + 0.2 * x**2 - 0.1 * x**3)
    np.testing.assert_allclose(block.apply(w, w, theta).y, ref, atol=1e-13)
    # P'(x) = 1 + 2 a2 x > 0 on [-1, 1] iff |a2| < 1/2
    order2 = AsymmetricOutput(2)
    traj = order2.apply_batch(w, w, {"a2": [0.49, -0.49, 0.51, -0.6], "centre": [5.0] * 4,
                                     "half_span": [2.0] * 4})
    assert traj.failed.tolist() == [False, False, True, True]
    space = block.param_space(REC)
    assert float(space.fixed["centre"]) == pytest.approx((REC.y.min() + REC.y.max()) / 2)
    assert block.rate_dependent is False


# --------------------------------------------------------------------- properties


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from(sorted(BLOCKS)), seed=st.integers(0, 10_000),
       cuts=st.lists(st.integers(1, 39), max_size=5))
def test_two_pieces_equal_one_run(name, seed, cuts):
    block = BLOCKS[name]
    rec = _record(n=40, jitter=0.04, seed=seed)
    theta = _theta(block, seed)
    w = np.random.default_rng(seed).normal(size=40).cumsum()
    whole = block.apply(w, rec.t, theta)
    state, parts = None, []
    bounds = [0, *sorted(set(cuts)), 40]
    for a, b in itertools.pairwise(bounds):
        traj = block.apply(w[a:b], rec.t[a:b], theta,
                           state0=block.initial_state(theta, w[0]) if state is None else state)
        parts.append(traj.y)
        state = traj.state
    np.testing.assert_array_equal(np.concatenate(parts), whole.y)
    np.testing.assert_array_equal(state, whole.state)


@pytest.mark.parametrize("name", sorted(BLOCKS))
def test_one_sample_at_a_time_equals_one_run(name):
    block = BLOCKS[name]
    theta = _theta(block, 11)
    w = REC.y[:80]
    whole = block.apply(w, REC.t[:80], theta).y
    state = block.initial_state(theta, w[0])
    steps = []
    for k in range(80):
        traj = block.apply(w[k:k + 1], REC.t[k:k + 1], theta, state0=state)
        steps.append(traj.y[0])
        state = traj.state
    np.testing.assert_array_equal(steps, whole)


@pytest.mark.parametrize("threads", ["parallel", "serial"])
@pytest.mark.parametrize("name", sorted(BLOCKS))
def test_batched_equals_one_by_one(name, threads):
    # the batch runs the prange kernel or its serial twin; single runs are serial
    block = BLOCKS[name]
    thetas = _theta(block, 5, width=5)
    w = np.vstack([REC.y * (1 + 0.1 * i) for i in range(5)])
    with kernels.kernel_parallelism(0 if threads == "parallel" else None):
        traj = block.apply_batch(w, REC.t, thetas)
    assert not traj.failed.any()
    for i in range(5):
        one = block.apply(w[i], REC.t, {k: v[i] for k, v in thetas.items()})
        np.testing.assert_array_equal(traj.y[i], one.y)
        np.testing.assert_array_equal(traj.state[i], one.state)


@pytest.mark.parametrize("name", sorted(BLOCKS))
def test_constant_input_stays_at_rest(name):
    block = BLOCKS[name]
    theta = _theta(block, 2)
    if name == "drift":
        theta = {**theta, "g": np.zeros(2), "d": np.zeros(2)}
    y = block.apply(np.full(50, 3.0), REC.t[:50], theta).y
    np.testing.assert_allclose(y, y[0], rtol=1e-13)


def test_parameters_are_declared_with_units_and_descriptions():
    assert set(block_names()) == {"arx", "second_order", "creep", "creep_fractional",
                                  "drift", "delay", "asym_output", "aux", "change_point",
                                  "disturbance", "unexplained", "creep_vibration"}
    for name in block_names():
        cls = block_class(name)
        space = cls(**cls.example).param_space(REC)
        for p in (*space.params, *space.fixed_params):
            assert p.unit and p.description, (name, p.name)


def test_bad_settings_and_names_are_refused():
    for make in (lambda: ARX(nb=0), lambda: ARX(na=-1), lambda: ARX(na=1.5),
                 lambda: Creep(0), lambda: Creep(3, tau_min=2.0, tau_max=1.0),
                 lambda: Creep(2, tau_min=-1.0), lambda: FractionalCreep(per_decade=0.0),
                 lambda: Drift(0), lambda: Delay(0), lambda: AsymmetricOutput(1)):
        with pytest.raises(ModelError):
            make()
    with pytest.raises(ModelError, match="valid blocks: arx"):
        block_class("creeep")
    with pytest.raises(ParameterError, match="missing"):
        SecondOrder().apply(np.ones(3), np.arange(3.0), {"f_n": 1.0})
    with pytest.raises(SimulationError):
        SecondOrder().apply(np.ones(3), np.arange(3.0), {"f_n": 1.0, "zeta": -0.1})
    traj = SecondOrder().apply_batch(np.ones(3), np.array([0.0, 2.0, 1.0]),
                                     {"f_n": [1.0], "zeta": [0.5]})
    assert traj.failed[0]  # time going backwards is a failure, not a silent result
