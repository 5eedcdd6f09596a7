"""Fractional-order Duhem model (review §8, Eq. 46 with a fractional rate term, ref. [87]).

Oracles: ``duhem_improved`` bit for bit at order 1; the closed form of a ramp's fractional
derivative, ``D^lam t = t^(1 - lam) / Gamma(2 - lam)``; a full-memory Grünwald–Letnikov sum
on a finely sampled sine; the steady-state gain ``omega^lam`` of ``D^lam``; a slow
pure-Python implementation (RK4 in the input for ``h``, the modes one by one) from a
non-relaxed state on irregular sampling; and the model's properties (state continuation,
batches, rate dependence, failures flagged).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayeshyst.data import Record
from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.base import DataScales
from bayeshyst.models.duhem import ImprovedDuhem
from bayeshyst.models.fractional import FractionalDuhem, derivative_modes
from tests.test_recovery import _check_calibration, _check_coverage, _fit_stats

MODEL = FractionalDuhem()
SCALES = DataScales(0.0, 150.0, 0.0, 40.0)
HYST = settings(max_examples=30, deadline=None)
T_REF = 1e-3
#: only the rate term: y = p t_ref^(1 - lam) D^lam u
RATE_ONLY = {"k": 0.0, "p": 1.0, "alpha": 0.0, "beta": 1.0, "gamma": 0.0, "u_centre": 0.0,
             "u_half": 1.0, "t_ref": T_REF}


def _theta(seed: int, data=SCALES) -> dict:
    space = MODEL.param_space(data)
    return space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])


def _sine(f_hz: float, fs: float = 2000.0, periods: float = 3.0):
    t = np.arange(int(periods * fs / f_hz)) / fs
    return 75.0 - 60.0 * np.cos(2 * np.pi * f_hz * t), t


# ------------------------------------------------------------------ reductions, closed forms


def test_order_one_is_duhem_improved_bit_for_bit():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(2e-4, 1e-3, 400))  # irregular sampling
    u = 75 + 60 * np.sin(2 * np.pi * 3 * t) + rng.normal(0, 5, t.size)
    theta = _theta(2) | {"lam": 1.0}
    base = {k: v for k, v in theta.items() if k not in ("lam", "t_ref")}
    np.testing.assert_array_equal(MODEL.simulate(u, t, theta),
                                  ImprovedDuhem().simulate(u, t, base))


@pytest.mark.parametrize("lam", [0.3, 0.5, 0.8, 0.95])
def test_ramp_from_rest_matches_the_closed_form(lam):
    dt = 1e-5
    t = np.arange(16000) * dt
    start = 10
    u = np.maximum(t - t[start], 0.0)  # at rest, then a ramp: exactly linear between samples
    y = MODEL.simulate(u, t, RATE_ONLY | {"lam": lam})
    tau = t[start + 1:] - t[start]
    exact = T_REF ** (1 - lam) * tau ** (1 - lam) / math.gamma(2 - lam)
    rel = np.abs(y[start + 1:] / exact - 1)
    assert rel.max() < 4e-3  # up to 100 t_ref (class Notes)
    np.testing.assert_array_equal(y[:start + 1], 0.0)


def grunwald_letnikov(u, h, lam):
    """Full-memory Grünwald–Letnikov derivative of samples at rest before ``u[0]``."""
    n = u.size
    w = [1.0]
    for j in range(1, n):
        w.append(w[-1] * (1.0 - (lam + 1.0) / j))
    # the full sum_j w_j x_(k-j) for every k: a convolution (numpy's, not the model's code)
    return np.convolve(np.array(w), u - u[0])[:n] / h**lam


def test_sine_matches_a_grunwald_letnikov_reference():
    # GL is first order in h: the reference runs 20 times finer than the model's samples
    lam, f, fine = 0.6, 50.0, 20
    h = 1e-4
    t_fine = np.arange(1200 * fine) * h / fine
    envelope = np.sin(0.5 * np.pi * np.clip(t_fine / 0.02, 0, 1)) ** 2  # smooth start
    u_fine = envelope * np.sin(2 * np.pi * f * t_fine)
    ref = T_REF ** (1 - lam) * grunwald_letnikov(u_fine, h / fine, lam)[::fine]
    y = MODEL.simulate(u_fine[::fine], t_fine[::fine], RATE_ONLY | {"lam": lam})
    assert np.abs(y - ref).max() < 1e-2 * np.abs(ref).max()


@pytest.mark.parametrize("lam", [0.25, 0.6])
def test_rate_term_gain_grows_as_omega_to_the_order(lam):
    amps = []
    for f in (20.0, 80.0):
        u, t = _sine(f, fs=20000.0, periods=6)
        y = MODEL.simulate(u, t, RATE_ONLY | {"lam": lam})
        last = y[-int(20000 / f):]  # the last period, transients gone
        amps.append(0.5 * np.ptp(last))
        want = 60.0 * T_REF ** (1 - lam) * (2 * np.pi * f) ** lam  # |t_ref^(1-lam) (i w)^lam| A
        assert amps[-1] == pytest.approx(want, rel=0.01)
    assert amps[1] / amps[0] == pytest.approx(4.0 ** lam, rel=0.01)


def test_mode_weights_vanish_and_the_derivative_weight_is_one_at_order_one():
    rates, w, c_inf, ok = derivative_modes([1.0, 0.5, 0.0, 1.2], [T_REF] * 4, 41, 4.0)
    np.testing.assert_array_equal(ok, [True, True, False, False])
    np.testing.assert_array_equal(w[0], 0.0)
    assert c_inf[0] == 1.0
    assert np.all(w[1] > 0) and np.all(np.isnan(rates[2:]))


# ------------------------------------------------------------------ slow oracle


def slow_oracle(u, t, theta, state, n_modes=41, per_decade=4.0, n_rk=200):
    """The model written out: RK4 in s for h, each mode's exact update, sample by sample."""
    k_lin, p, a, b, c = (float(theta[x]) for x in ("k", "p", "alpha", "beta", "gamma"))
    uc, uh = float(theta["u_centre"]), float(theta["u_half"])
    rates, w, c_inf, _ = derivative_modes(theta["lam"], theta["t_ref"], n_modes, per_decade)
    rates, w, c_inf = list(rates[0]), list(w[0]), float(c_inf[0])
    h, u_prev, t_prev = float(state[0]), float(state[1]), float(state[2])
    z = [float(v) for v in state[4:]]
    out = []
    for uk, tk in zip(u, t, strict=True):
        sa, sb = (u_prev - uc) / uh, (uk - uc) / uh
        sg = 1.0 if sb > sa else -1.0

        def dh(s, hh, sg=sg):
            return a - b * sg * hh + c * s

        ds = (sb - sa) / n_rk
        for i in range(n_rk):
            s = sa + i * ds
            k1 = dh(s, h)
            k2 = dh(s + ds / 2, h + ds / 2 * k1)
            k3 = dh(s + ds / 2, h + ds / 2 * k2)
            k4 = dh(s + ds, h + ds * k3)
            h += ds / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        slope = 0.0
        if math.isfinite(t_prev):
            slope = (uk - u_prev) / (tk - t_prev)
            for i, r in enumerate(rates):
                e = math.exp(-r * (tk - t_prev))
                z[i] = e * z[i] + slope * (1 - e) / r
        frac = c_inf * slope + sum(wi * zi for wi, zi in zip(w, z, strict=True))
        out.append(k_lin * uk + p * frac - h)
        u_prev, t_prev = uk, tk
    return np.array(out), h


def test_kernel_matches_a_slow_implementation_from_a_non_relaxed_state():
    rng = np.random.default_rng(3)
    t = 1.0 + np.cumsum(rng.uniform(2e-4, 8e-4, 300))
    u = 75 + 60 * np.sin(2 * np.pi * 4 * t) + rng.normal(0, 4, t.size)
    theta = _theta(4) | {"lam": 0.55, "beta": 2.5}
    s0 = MODEL.initial_state(theta, 70.0)
    s0[0], s0[2], s0[4:] = 3.0, 1.0 - 5e-4, rng.normal(0, 50, MODEL.n_modes)
    s0[1] = 70.0
    traj = MODEL.run(u, t, theta, state0=s0)
    y_ref, h_ref = slow_oracle(u, t, theta, s0)
    np.testing.assert_allclose(traj.y, y_ref, rtol=0, atol=1e-8 * np.abs(y_ref).max())
    assert traj.state[0] == pytest.approx(h_ref, abs=1e-9 * max(1.0, abs(h_ref)))


# ------------------------------------------------------------------ rate dependence


def test_output_depends_on_the_time_base_only_through_the_rate_term():
    u, t = _sine(5.0)
    warped = t + 0.8 * np.sin(2 * np.pi * 5 * t) / (2 * np.pi * 5)  # strictly increasing
    theta = _theta(5) | {"p": 0.01}
    diff = MODEL.simulate(u, t, theta) - MODEL.simulate(u, warped, theta)
    assert np.abs(diff).max() > 1e-3 * np.ptp(MODEL.simulate(u, t, theta))
    still = theta | {"p": 0.0}
    np.testing.assert_array_equal(MODEL.simulate(u, t, still),
                                  MODEL.simulate(u, warped, still))


# ------------------------------------------------------------------ state and batches


@HYST
@given(u=st.lists(st.floats(-100.0, 250.0), min_size=1, max_size=30), data=st.data())
def test_two_pieces_equal_one(u, data):
    u = np.array(u)
    t = np.cumsum(data.draw(st.lists(st.floats(1e-4, 1e-2), min_size=u.size,
                                     max_size=u.size)))
    cuts = sorted(data.draw(st.lists(st.integers(1, max(1, u.size - 1)), max_size=3)))
    bounds = [0, *[c for c in cuts if c < u.size], u.size]
    theta = _theta(9) | {"lam": data.draw(st.floats(0.05, 1.0))}
    whole = MODEL.run(u, t, theta)
    state, parts = MODEL.initial_state(theta, u[0]), []
    for a, b in itertools.pairwise(bounds):
        if a == b:
            continue
        traj = MODEL.run(u[a:b], t[a:b], theta, state0=state)
        parts.append(traj.y)
        state = traj.state
    np.testing.assert_array_equal(np.concatenate(parts), whole.y)
    np.testing.assert_array_equal(state, whole.state)


def test_batched_equals_one_by_one_and_bad_order_is_flagged():
    u, t = _sine(5.0)
    space = MODEL.param_space(SCALES)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(11), 5))
    thetas["lam"][2] = 1.5
    thetas["beta"][4] = -1.0
    batch = MODEL.run_batch(u, t, thetas)
    np.testing.assert_array_equal(batch.failed, [False, False, True, False, True])
    for j in range(5):
        theta = {k: v[j] for k, v in thetas.items()}
        if batch.failed[j]:
            with pytest.raises(SimulationError):
                MODEL.simulate(u, t, theta)
            continue
        one = MODEL.run(u, t, theta)
        np.testing.assert_array_equal(batch.y[j], one.y)
        np.testing.assert_array_equal(batch.state[j], one.state)


@pytest.mark.parametrize("scaled", [True, False], ids=["data_prior", "unit_prior"])
def test_prior_draws_never_give_nan(scaled):
    u, t = _sine(5.0)
    space = MODEL.param_space(SCALES if scaled else None)
    batch = MODEL.run_batch(u, t, space.unpack(space.sample_prior(np.random.default_rng(12),
                                                                  200)))
    assert batch.n_failed == 0
    assert np.all(np.isfinite(batch.y))


def test_regressors_reproduce_the_output():
    u, t = _sine(5.0)
    theta = _theta(14)
    lin = MODEL.linear_params
    phi = MODEL.regressors(u, t, {k: v for k, v in theta.items() if k not in lin})
    y = MODEL.simulate(u, t, theta)
    beta = np.array([float(theta[k]) for k in lin])
    np.testing.assert_allclose(phi @ beta, y, rtol=0, atol=1e-11 * np.abs(y).max())


def test_bad_settings_and_inputs_are_refused():
    with pytest.raises(ModelError):
        FractionalDuhem(n_modes=2)
    for bad in (0.0, -1.0, math.inf):
        with pytest.raises(ModelError, match="per_decade"):
            FractionalDuhem(per_decade=bad)
    theta = _theta(15)
    with pytest.raises(ParameterError, match="strictly increasing"):
        MODEL.simulate([0.0, 1.0, 2.0], [0.0, 1.0, 1.0], theta)
    traj = MODEL.run([0.0, 1.0], [0.0, 1.0], theta)
    with pytest.raises(ParameterError, match="not after"):
        MODEL.run([2.0], [1.0], theta, state0=traj.state)


# ------------------------------------------------------------------ posterior recovery

TRUTH = {"k": 0.3, "p": 0.01, "alpha": 4.0, "beta": 2.0, "gamma": 1.0, "lam": 0.5}
NOISE = 0.05


def _recovery_record(seed, n=1200):
    # two frequencies a decade and a half apart (2 and 40 Hz at 1 kHz) around 1 / (2 pi
    # t_ref): the rate term's gain at both pins its order and size apart
    t = np.arange(n) * 1e-3
    u = 75 - 60 * np.cos(2 * np.pi * 2 * t) + 10 * np.sin(2 * np.pi * 40 * t)
    fixed = dict(MODEL.param_space(Record(t=t, u=u, y=u, name="scales")).fixed)
    y = MODEL.simulate(u, t, TRUTH | fixed) + np.random.default_rng(seed).normal(0, NOISE, n)
    return Record(t=t, u=u, y=y, name=f"frac{seed}", warmup=100)


def _recovery_stats(seeds):
    fits = []
    for seed in seeds:
        post = Posterior(_recovery_record(seed), "duhem_fractional")
        res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000,
                                                     n_walkers=16))
        fits.append(_fit_stats(post, TRUTH | {"obs.offset": 0.0, "noise.sigma": NOISE},
                               seed, res))
    return fits, post.ndim


def test_posterior_is_calibrated_on_one_fit():
    # one fit (~5 s): the truth's squared Mahalanobis distance ~ chi2(d), two-sided 0.1 %
    _check_calibration(*_recovery_stats([0]))


@pytest.mark.slow
def test_90_percent_intervals_cover_at_the_nominal_rate():
    # 20 independent fits: summed Mahalanobis distance of the truth ~ chi2(20 d), and per
    # parameter the 90 % HDI hits ~ Binomial(20, 0.9) (Bonferroni over parameters at 0.1 %)
    fits, ndim = _recovery_stats(range(1, 21))
    _check_calibration(fits, ndim)
    _check_coverage(fits)
