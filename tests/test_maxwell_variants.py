"""Maxwell-slip variants (asymmetric, ref. [67]; distributed-parameter, ref. [70]) vs oracles.

Oracles: slow pure-Python elasto-slide loops written from review Eq. 36–37 (with the
nonlinear spring, and with log-normal quantile nodes from ``statistics.NormalDist``),
``maxwell_slip`` where a variant reduces to it, and the family's properties (rate
independence, loop orientation and asymmetry, state continuation, batches).
"""

from __future__ import annotations

import itertools
from statistics import NormalDist
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayeshyst.data import Record
from bayeshyst.errors import ModelError, SimulationError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get
from bayeshyst.models.base import DataScales
from bayeshyst.models.maxwell import MaxwellSlip
from bayeshyst.models.maxwell_variants import AsymmetricMaxwellSlip, DistributedMaxwellSlip
from tests.test_recovery import _check_calibration, _check_coverage, _fit_stats

N_EL = 6
MODELS = {
    "asym": AsymmetricMaxwellSlip(N_EL),
    "asym4": AsymmetricMaxwellSlip(N_EL, spring_order=4),
    "dp": DistributedMaxwellSlip(12),
}
HYST = settings(max_examples=40, deadline=None)
SCALES = DataScales(0.0, 150.0, 0.0, 40.0)


def _record(f_hz: float = 2.0, n_per: int = 200, periods: float = 3.0) -> SimpleNamespace:
    """A unipolar sine record like a piezo drive (0–150 V)."""
    t = np.arange(int(n_per * periods)) / (n_per * f_hz)
    u = 75.0 + 60.0 * np.sin(2 * np.pi * f_hz * t)
    return SimpleNamespace(t=t, u=u, y=0.2 * u + np.sin(2 * np.pi * f_hz * t - 0.3))


def _theta(model, seed: int, data=None) -> dict:
    space = model.param_space(data)
    return space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])


# ------------------------------------------------------------------ pure-Python oracles


def elements_oracle(u, k0, k, delta, xs0):
    """Review Eq. 36–37: output list and final slider list."""
    xs = [float(v) for v in xs0]
    ys = []
    for x in u:
        x = float(x)
        force = k0 * x
        for i in range(len(xs)):
            if abs(x - xs[i]) >= delta[i]:  # the spring force reached f_i: the slider moves
                xs[i] = x - delta[i] if x - xs[i] > 0 else x + delta[i]
            force += k[i] * (x - xs[i])
        ys.append(force)
    return ys, xs


def oracle(name, u, theta, xs0):
    if name.startswith("asym"):
        ys, xs = elements_oracle(u, float(theta["k0"]), list(theta["k"]),
                                 list(theta["delta"]), xs0)
        uc, uh = float(theta["u_centre"]), float(theta["u_half"])
        for j, x in enumerate(u):
            s = (float(x) - uc) / uh
            ys[j] += sum(a * s ** (p + 2) for p, a in enumerate(theta["a"]))
        return ys, xs
    n = len(xs0)
    dist = NormalDist()
    delta = [float(theta["delta_med"]) * np.exp(float(theta["sigma"])
                                                * dist.inv_cdf((i + 0.5) / n)) for i in range(n)]
    return elements_oracle(u, float(theta["k0"]), [float(theta["K"]) / n] * n, delta, xs0)


@pytest.mark.parametrize("name", list(MODELS))
def test_kernel_matches_pure_python_oracle(name):
    model = MODELS[name]
    rec = _record()
    theta = _theta(model, 1, rec)
    rng = np.random.default_rng(2)
    u = np.concatenate([rec.u[:300], 75 + 70 * rng.uniform(-1, 1, 150)])
    t = np.arange(u.size) * 1e-3
    s0 = model.initial_state(theta, u[0]) + rng.normal(0.0, 5.0, len(model.initial_state(
        theta, u[0])))  # an arbitrary, non-relaxed start
    traj = model.run(u, t, theta, state0=s0)
    y_ref, xs_ref = oracle(name, u, theta, s0)
    np.testing.assert_allclose(traj.y, y_ref, rtol=0, atol=1e-11 * np.abs(y_ref).max())
    np.testing.assert_allclose(traj.state, xs_ref, rtol=0, atol=1e-12 * 150)


def test_asymmetric_without_spring_is_maxwell_slip_exactly():
    rec = _record()
    model = MODELS["asym"]
    theta = _theta(model, 3, rec) | {"a": np.zeros(2)}
    base = {k: theta[k] for k in ("k0", "k", "delta")}
    np.testing.assert_array_equal(model.simulate(rec.u, rec.t, theta),
                                  MaxwellSlip(N_EL).simulate(rec.u, rec.t, base))


def test_distributed_with_zero_spread_is_one_element_exactly():
    rec = _record()
    theta = {"k0": 0.4, "K": -0.15, "delta_med": 12.0, "sigma": 0.0}
    one = MaxwellSlip(1).simulate(rec.u, rec.t, {"k0": 0.4, "k": [-0.15], "delta": [12.0]})
    y = MODELS["dp"].simulate(rec.u, rec.t, theta)
    np.testing.assert_allclose(y, one, rtol=0, atol=1e-12 * np.abs(one).max())


def test_distributed_approaches_one_element_as_the_spread_narrows():
    # each node's deflection is within delta_med (exp(sigma |z|max) - 1) of the median, and
    # a stop operator's output moves by at most its threshold change: a linear bound
    rec = _record()
    model = MODELS["dp"]
    one = MaxwellSlip(1).simulate(rec.u, rec.t, {"k0": 0.4, "k": [-0.15], "delta": [12.0]})
    zmax = NormalDist().inv_cdf(1 - 0.5 / model.n_nodes)
    gaps = []
    for sigma in (0.2, 0.02, 0.002):
        y = model.simulate(rec.u, rec.t, {"k0": 0.4, "K": -0.15, "delta_med": 12.0,
                                          "sigma": sigma})
        gap = np.abs(y - one).max()
        assert gap <= 0.15 * 12.0 * np.expm1(sigma * zmax) * (1 + 1e-9)
        gaps.append(gap)
    assert gaps[0] > 5 * gaps[1] > 25 * gaps[2] > 0


def test_distributed_quadrature_converges_to_the_continuous_model():
    rec = _record()
    theta = {"k0": 0.4, "K": -0.15, "delta_med": 12.0, "sigma": 0.6}
    ref = DistributedMaxwellSlip(2000).simulate(rec.u, rec.t, theta)
    errs = [np.abs(DistributedMaxwellSlip(n).simulate(rec.u, rec.t, theta) - ref).max()
            for n in (8, 32, 128)]
    assert errs[0] > errs[1] > errs[2]
    assert errs[1] < 0.01 * np.ptp(ref)


# ------------------------------------------------------------------ loop properties


def _loop_area(u, y):
    """Signed area of the last closed cycle in the (u, y) plane (> 0: counter-clockwise)."""
    return 0.5 * float(np.sum(u[:-1] * y[1:] - u[1:] * y[:-1]))


@pytest.mark.parametrize("name", list(MODELS))
def test_negative_element_stiffness_gives_counter_clockwise_loops(name):
    rec = _record(periods=2.0)
    model = MODELS[name]
    theta = _theta(model, 4, rec)
    if name == "dp":
        theta |= {"k0": 0.5, "K": -0.2, "sigma": 0.5}
    else:
        theta |= {"k0": 0.5, "k": np.full(N_EL, -0.05)}
    last = slice(rec.u.size // 2, None)
    area = _loop_area(rec.u[last], model.simulate(rec.u, rec.t, theta)[last])
    assert area > 0
    flipped = theta | ({"K": 0.2} if name == "dp" else {"k": np.full(N_EL, 0.05)})
    assert _loop_area(rec.u[last], model.simulate(rec.u, rec.t, flipped)[last]) < 0


def _point_symmetry_defect(model, theta, rec):
    # a centrosymmetric loop maps onto itself under (u, y) -> (2 uc - u, 2 yc - y):
    # the branch at uc + d going up mirrors the branch at uc - d going down
    half = rec.u.size // 3
    u, y = rec.u[-2 * half:], model.simulate(rec.u, rec.t, theta)[-2 * half:]
    uc, yc = 75.0, 0.5 * (y.max() + y.min())
    up = np.diff(u, append=u[-1]) > 0
    grid = np.linspace(-50, 50, 21)
    order_up, order_dn = np.argsort(u[up]), np.argsort(u[~up])
    y_up = np.interp(uc + grid, u[up][order_up], y[up][order_up])
    y_dn = np.interp(uc - grid, u[~up][order_dn], y[~up][order_dn])
    return np.abs((y_up - yc) + (y_dn - yc)).max() / np.ptp(y)


def test_the_nonlinear_spring_makes_the_loop_asymmetric():
    rec = _record(n_per=400)
    model = MODELS["asym"]
    theta = _theta(model, 5, rec) | {"k0": 0.5, "k": np.full(N_EL, -0.05)}
    assert _point_symmetry_defect(model, theta | {"a": np.zeros(2)}, rec) < 0.01
    assert _point_symmetry_defect(model, theta | {"a": np.array([4.0, 0.0])}, rec) > 0.05
    # odd powers alone keep the loop centrosymmetric: the asymmetry is the even part
    assert _point_symmetry_defect(model, theta | {"a": np.array([0.0, 4.0])}, rec) < 0.01


@HYST
@given(u=st.lists(st.floats(-100.0, 250.0), min_size=2, max_size=40), data=st.data())
def test_rate_independent_under_a_monotone_time_warp(u, data):
    u = np.array(u)
    dt = np.array(data.draw(st.lists(st.floats(1e-4, 1.0), min_size=u.size, max_size=u.size)))
    warp = np.array(data.draw(st.lists(st.floats(0.01, 100.0), min_size=u.size,
                                       max_size=u.size)))
    t, t_warped = np.cumsum(dt), np.cumsum(dt * warp)
    for model in MODELS.values():
        theta = _theta(model, 7, SCALES)
        np.testing.assert_array_equal(model.simulate(u, t, theta),
                                      model.simulate(u, t_warped, theta))


# ------------------------------------------------------------------ state and batches


@HYST
@given(u=st.lists(st.floats(-100.0, 250.0), min_size=1, max_size=30), data=st.data())
def test_two_pieces_equal_one(u, data):
    u = np.array(u)
    t = np.arange(u.size) * 1e-3
    cuts = sorted(data.draw(st.lists(st.integers(1, max(1, u.size - 1)), max_size=3)))
    bounds = [0, *[c for c in cuts if c < u.size], u.size]
    for name, model in MODELS.items():
        theta = _theta(model, 9, SCALES)
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
def test_batched_equals_one_by_one(name):
    model = MODELS[name]
    rec = _record()
    space = model.param_space(rec)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(11), 5))
    if name == "dp":  # one walker with a negative spread: flagged, not NaN
        thetas["sigma"][2] = -0.5
    batch = model.run_batch(rec.u, rec.t, thetas)
    for j in range(5):
        theta = {k: v[j] for k, v in thetas.items()}
        if batch.failed[j]:
            with pytest.raises(SimulationError):
                model.simulate(rec.u, rec.t, theta)
            continue
        one = model.run(rec.u, rec.t, theta)
        np.testing.assert_array_equal(batch.y[j], one.y)
        np.testing.assert_array_equal(batch.state[j], one.state)
    assert batch.failed.sum() == (1 if name == "dp" else 0)


@pytest.mark.parametrize("scaled", [True, False], ids=["data_prior", "unit_prior"])
@pytest.mark.parametrize("name", list(MODELS))
def test_prior_draws_never_give_nan(name, scaled):
    model = MODELS[name]
    rec = _record()
    space = model.param_space(rec if scaled else None)
    z = space.sample_prior(np.random.default_rng(12), 200)
    batch = model.run_batch(rec.u, rec.t, space.unpack(z))
    assert batch.n_failed == 0
    assert np.all(np.isfinite(batch.y))


@pytest.mark.parametrize("name", list(MODELS))
def test_regressors_reproduce_the_output(name):
    model = MODELS[name]
    rec = _record()
    theta = _theta(model, 14, rec)
    lin = model.linear_params
    phi = model.regressors(rec.u, rec.t, {k: v for k, v in theta.items() if k not in lin})
    beta = np.concatenate([np.ravel(theta[k]) for k in lin])
    y = model.simulate(rec.u, rec.t, theta)
    np.testing.assert_allclose(phi @ beta, y, rtol=0, atol=1e-11 * np.abs(y).max())


def test_bad_settings_are_refused():
    for bad in (1, 7, 2.5, True):
        with pytest.raises(ModelError, match="spring_order"):
            AsymmetricMaxwellSlip(4, spring_order=bad)
    with pytest.raises(ModelError):
        AsymmetricMaxwellSlip(0)
    with pytest.raises(ModelError):
        DistributedMaxwellSlip(0)
    theta = {"k0": 0.4, "K": -0.15, "delta_med": -1.0, "sigma": 0.3}
    with pytest.raises(SimulationError):
        MODELS["dp"].simulate([0.0, 1.0], [0.0, 1.0], theta)


# ------------------------------------------------------------------ posterior recovery

RECOVERY = {
    "maxwell_slip_dp": {"k0": 0.35, "K": -0.12, "delta_med": 20.0, "sigma": 0.6},
    "maxwell_slip_asym(n_elements=4)": {"k0": 0.35, "k": [-0.05, -0.04, -0.03, -0.02],
                                        "a": [3.0, -1.0]},
}
NOISE = 0.05


def _recovery_record(spec, seed, n=1200):
    """A 2 Hz sine with a faster minor-loop component, simulated from the truth plus noise."""
    t = np.arange(n) * 1e-3
    u = 75 - 60 * np.cos(2 * np.pi * t / 0.5) + 10 * np.sin(2 * np.pi * t / 0.09)
    model = get(spec)
    # the fixed settings (thresholds, normalisation) are those a fit derives from the input
    fixed = dict(model.param_space(Record(t=t, u=u, y=u, name="scales")).fixed)
    y = model.simulate(u, t, {**RECOVERY[spec], **fixed})
    y = y + np.random.default_rng(seed).normal(0.0, NOISE, n)
    return Record(t=t, u=u, y=y, name=f"{spec}-{seed}", warmup=100)


def _recovery_stats(spec, seeds):
    out = []
    for seed in seeds:
        post = Posterior(_recovery_record(spec, seed), spec)
        res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000, n_walkers=16))
        out.append(_fit_stats(post, {**RECOVERY[spec], "obs.offset": 0.0,
                                     "noise.sigma": NOISE}, seed, res))
    return out, post.ndim


def test_distributed_posterior_is_calibrated_on_one_fit():
    # one fit (~7 s): the truth's squared Mahalanobis distance ~ chi2(d), two-sided 0.1 %
    fits, ndim = _recovery_stats("maxwell_slip_dp", [0])
    _check_calibration(fits, ndim)


@pytest.mark.slow
@pytest.mark.parametrize("spec", list(RECOVERY))
def test_90_percent_intervals_cover_at_the_nominal_rate(spec):
    # 20 independent fits: summed Mahalanobis ~ chi2(20 d), and per parameter the 90 % HDI
    # hits ~ Binomial(20, 0.9) (Bonferroni over parameters at 0.1 %)
    fits, ndim = _recovery_stats(spec, range(1, 21))
    _check_calibration(fits, ndim)
    _check_coverage(fits)
