"""Rate-dependent Bouc–Wen variants (review Eq. 49 as printed; ref. [95]) against oracles.

Oracles: ``solve_ivp`` (DOP853, rtol 1e-11) on the review's equations in *time*, with
the input linear between samples, stopped and restarted at the kinks ``h = 0`` (the
kernels integrate in the input travel, per interval); the reductions ``δ = 0`` ->
``bouc_wen`` and ``τ = 0`` -> ``bouc_wen_asym_sgn+second_order`` (and
``bouc_wen+second_order`` at ``δ = 0``); the lag's analytic amplitude
``1/sqrt(1 + (ωτ)²)``. Properties: rate dependence (a time warp changes the output
unless ``δ = 0``), loops that change with frequency, state continuation, batched ==
one-by-one, prior draws never NaN, the linear design, refused settings.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bayeshyst.data.record import Record
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models.bouc_wen import BoucWen
from bayeshyst.models.bouc_wen_variants import (
    AsymmetricBoucWenSgn,
    FrequencyFactorBoucWen,
    input_rate,
)
from bayeshyst.models.registry import get

RTOL = 1e-11


def _irregular(n: int = 260, seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Irregular times (steps 0.5-1.5 ms) and an input with reversals, holds, slow parts."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    t -= t[0]
    u = 60.0 + 50.0 * np.sin(2 * np.pi * 8.0 * t) * np.cos(2 * np.pi * 3.0 * t)
    u += rng.normal(0.0, 1.5, n)
    u[n // 6:n // 6 + 6] = u[n // 6]  # a hold: h must not move
    return t, u


def _sgn_rhs(alpha, beta, gamma, n, delta, ua, r, ta, sh):
    s = math.copysign(1.0, r)

    def rhs(tt, hh):
        uu = ua + r * (tt - ta)
        return [r * (alpha - (beta * s * sh + gamma) * abs(hh[0]) ** n) + delta * uu * s]
    return rhs


def ivp_h(t, u, alpha, beta, gamma, n, delta, h0=0.0):
    """``h`` of review Eq. 49 as printed, by solve_ivp in time, interval by interval."""
    out = np.empty(u.size)
    out[0] = h = h0
    for i in range(u.size - 1):
        ta, tb = t[i], t[i + 1]
        r = (u[i + 1] - u[i]) / (tb - ta)
        while r != 0.0 and ta < tb:
            if h == 0.0:  # leave h = 0 on the branch that dh/dt points to
                uu = u[i] + r * (ta - t[i])
                h = 1e-300 * math.copysign(1.0, r * alpha + delta * uu * math.copysign(1, r))
            sh = math.copysign(1.0, h)

            def event(tt, hh):
                return hh[0]
            event.terminal = True
            sol = solve_ivp(_sgn_rhs(alpha, beta, gamma, n, delta, u[i] + r * (ta - t[i]), r,
                                     ta, sh), (ta, tb), [h], method="DOP853", rtol=RTOL,
                            atol=1e-13, events=event)
            if sol.status == 1 and sol.t_events[0][0] > ta:
                ta, h = sol.t_events[0][0], 0.0
                continue
            h = float(sol.y[0, -1])
            break
        out[i + 1] = h
    return out


# (alpha, beta, gamma, n, delta): delta > 0, < 0, strong enough that the drive per unit
# travel turns negative on the slow parts (the reflected frame), n != 1
SGN_THETAS = {
    "n1_pos": (0.3, 0.02, 0.01, 1.0, 2.0),
    "n1.5_neg": (0.3, 0.01, -0.004, 1.5, -1.5),
    "strong_neg": (0.2, 0.02, 0.005, 1.2, -40.0),
}


@pytest.mark.parametrize("h0", [0.0, 3.0])
@pytest.mark.parametrize("case", list(SGN_THETAS))
def test_asym_sgn_matches_solve_ivp_in_time(case, h0):
    t, u = _irregular()
    a, b, g, n, d = SGN_THETAS[case]
    th = {"k": 0.4, "alpha": a, "beta": b, "gamma": g, "n": n, "delta": d}
    model = AsymmetricBoucWenSgn()
    y = model.simulate(u, t, th, state0=np.array([h0, u[0], t[0]]))
    y_ref = 0.4 * u - ivp_h(t, u, a, b, g, n, d, h0)
    assert np.max(np.abs(y - y_ref)) <= 1e-7 * np.ptp(y_ref)
    if case == "strong_neg":
        # the case does reach a negative drive alpha + delta' u somewhere
        du, dt = np.diff(u), np.diff(t)
        moving = du != 0
        drive = a + d * dt[moving] / np.abs(du[moving]) * u[:-1][moving]
        assert drive.min() < 0


def test_asym_sgn_at_delta_zero_is_bouc_wen():
    t, u = _irregular()
    th = {"k": 0.4, "alpha": 0.3, "beta": 0.02, "gamma": 0.01, "n": 1.3}
    y0 = BoucWen().simulate(u, t, th)
    y = AsymmetricBoucWenSgn().simulate(u, t, {**th, "delta": 0.0})
    np.testing.assert_allclose(y, y0, rtol=0, atol=1e-12 * np.ptp(y0))


def test_asym_sgn_is_rate_dependent_only_through_delta():
    t, u = _irregular()
    warp = t[-1] * (t / t[-1]) ** 1.7  # a monotone time warp
    th = {"k": 0.4, "alpha": 0.3, "beta": 0.02, "gamma": 0.01, "n": 1.3, "delta": -3.0}
    m = AsymmetricBoucWenSgn()
    assert np.max(np.abs(m.simulate(u, t, th) - m.simulate(u, warp, th))) > 1e-3
    th["delta"] = 0.0
    np.testing.assert_allclose(m.simulate(u, t, th), m.simulate(u, warp, th), rtol=0,
                               atol=1e-12)


def _loop_asymmetry(model, th, f):
    t = np.arange(0, 3.0 / f, 1.0 / (400 * f))
    u = 60.0 + 50.0 * np.sin(2 * np.pi * f * t)
    y = model.simulate(u, t, th)
    last = t >= 2.0 / f
    up = np.gradient(u)[last] > 0
    uu, yy = u[last], y[last]
    # vertical loop opening at the two ends of the input range (near 20 % and 80 %)
    out = []
    for level in (30.0, 90.0):
        rise = np.interp(level, uu[up][np.argsort(uu[up])], yy[up][np.argsort(uu[up])])
        fall = np.interp(level, uu[~up][np.argsort(uu[~up])], yy[~up][np.argsort(uu[~up])])
        out.append(fall - rise)
    return np.array(out)


def test_asym_sgn_loop_changes_with_frequency_and_stays_counter_clockwise():
    th = {"k": 0.4, "alpha": 0.3, "beta": 0.02, "gamma": 0.01, "n": 1.0, "delta": -0.3}
    m = AsymmetricBoucWenSgn()
    slow, fast = _loop_asymmetry(m, th, 1.0), _loop_asymmetry(m, th, 20.0)
    assert np.all(slow > 0) and np.all(fast > 0)  # counter-clockwise: falling above rising
    # the asymmetry (ratio of the openings at the two ends) depends on the drive rate;
    # without delta it does not
    assert abs(slow[1] / slow[0] - fast[1] / fast[0]) > 0.05
    th["delta"] = 0.0
    s0, f0 = _loop_asymmetry(m, th, 1.0), _loop_asymmetry(m, th, 20.0)
    np.testing.assert_allclose(s0, f0, rtol=1e-6)


# ------------------------------------------------------------------ frequency factor


def ivp_lag(t, u, tau):
    """``τ v̇ = u - v`` with ``u`` linear between samples, by solve_ivp, from ``v = u_0``."""
    out = np.empty(u.size)
    out[0] = v = u[0]
    for i in range(u.size - 1):
        r = (u[i + 1] - u[i]) / (t[i + 1] - t[i])
        sol = solve_ivp(lambda tt, z, i=i, r=r: [(u[i] + r * (tt - t[i]) - z[0]) / tau],
                        (t[i], t[i + 1]), [v], method="DOP853", rtol=RTOL, atol=1e-12)
        out[i + 1] = v = float(sol.y[0, -1])
    return out


def ivp_stage(t, w, fn, zeta):
    """``x`` of ``ẍ + 2ζω ẋ + ω² x = ω² w`` with ``w`` linear between samples, at rest."""
    wn = 2 * np.pi * fn
    out = np.empty(w.size)
    out[0] = w[0]
    z = [w[0], 0.0]
    for i in range(w.size - 1):
        r = (w[i + 1] - w[i]) / (t[i + 1] - t[i])

        def rhs(tt, zz, i=i, r=r):
            return [zz[1], wn * wn * (w[i] + r * (tt - t[i]) - zz[0]) - 2 * zeta * wn * zz[1]]
        sol = solve_ivp(rhs, (t[i], t[i + 1]), z, method="DOP853", rtol=RTOL, atol=1e-12)
        z = list(sol.y[:, -1])
        out[i + 1] = z[0]
    return out


FREQ = {"f_n": 150.0, "zeta": 0.2, "gain": 0.4, "alpha": 0.3, "beta": 0.02, "gamma": 0.01,
        "n": 1.4, "delta": -1.0, "tau": 2e-3}


def test_frequency_factor_matches_solve_ivp_in_time():
    t, u = _irregular(200)
    y = FrequencyFactorBoucWen().simulate(u, t, FREQ)
    p = FREQ
    # the three parts by solve_ivp: h (Eq. 49 in time), the lag, and the stage driven by
    # w = gain v - h sampled and held linear between samples (the kernel's convention)
    h = ivp_h(t, u, p["alpha"], p["beta"], p["gamma"], p["n"], p["delta"])
    w = p["gain"] * ivp_lag(t, u, p["tau"]) - h
    y_ref = ivp_stage(t, w, p["f_n"], p["zeta"])
    assert np.max(np.abs(y - y_ref)) <= 1e-7 * np.ptp(y_ref)


@pytest.mark.parametrize("delta", [0.0, -1.0])
def test_frequency_factor_neutral_value_is_the_existing_composition(delta):
    t, u = _irregular()
    th = {**FREQ, "tau": 0.0, "delta": delta}
    y = FrequencyFactorBoucWen().simulate(u, t, th)
    spec = "bouc_wen+second_order" if delta == 0 else "bouc_wen_asym_sgn+second_order"
    ref = {"static.k": th["gain"], "static.alpha": th["alpha"], "static.beta": th["beta"],
           "static.gamma": th["gamma"], "static.n": th["n"], "second_order.f_n": th["f_n"],
           "second_order.zeta": th["zeta"]}
    if delta:
        ref["static.delta"] = delta
    y_ref = get(spec).simulate(u, t, ref)
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-12 * np.ptp(y_ref))


@pytest.mark.parametrize("f", [2.0, 20.0, 60.0])
def test_frequency_factor_attenuates_the_linear_drive_as_a_first_order_lag(f):
    # alpha -> 0: no hysteresis; a stage far above the drive: the output amplitude is the
    # lag's, gain A / sqrt(1 + (2 pi f tau)^2)
    tau = 4e-3
    t = np.arange(0, 8.0 / f, 1.0 / (2000 * f))
    u = 50.0 * np.sin(2 * np.pi * f * t)
    th = {**FREQ, "alpha": 1e-12, "delta": 0.0, "tau": tau, "f_n": 5e4, "zeta": 0.7}
    y = FrequencyFactorBoucWen().simulate(u, t, th)
    amp = 0.5 * np.ptp(y[t >= 6.0 / f])
    expected = 0.4 * 50.0 / math.sqrt(1 + (2 * np.pi * f * tau) ** 2)
    assert abs(amp - expected) <= 2e-3 * expected


def test_frequency_factor_loop_changes_with_frequency():
    m = FrequencyFactorBoucWen()
    th = {**FREQ, "f_n": 5e3}
    spans = []
    for f in (1.0, 30.0):
        t = np.arange(0, 3.0 / f, 1.0 / (400 * f))
        y = m.simulate(60 + 50 * np.sin(2 * np.pi * f * t), t, th)
        spans.append(np.ptp(y[t >= 2.0 / f]))
    assert spans[1] < 0.97 * spans[0]  # the lag lowers the stroke at 30 Hz (tau = 2 ms)


# ---------------------------------------------------------------- shared properties

MODELS = {"bouc_wen_asym_sgn": {k: FREQ[k] for k in ("alpha", "beta", "gamma", "n", "delta")}
          | {"k": 0.4},
          "bouc_wen_freq": FREQ}


@pytest.mark.parametrize("name", list(MODELS))
def test_two_pieces_equal_one_run(name):
    t, u = _irregular()
    m = get(name)
    one = m.run(u, t, MODELS[name])
    a = m.run(u[:97], t[:97], MODELS[name])
    b = m.run(u[97:], t[97:], MODELS[name], state0=a.state)
    np.testing.assert_array_equal(np.r_[a.y, b.y], one.y)


@pytest.mark.parametrize("name", list(MODELS))
def test_batched_equals_one_by_one_and_prior_draws_never_nan(name):
    t, u = _irregular()
    m = get(name)
    rec = Record(t=t, u=u, y=0.4 * u, name="r")
    space = m.param_space(rec)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(1), 40))
    traj = m.run_batch(u, t, thetas)
    ok = ~traj.failed
    assert ok.sum() >= 30 and np.all(np.isfinite(traj.y[ok]))
    assert np.all(np.isnan(traj.y[traj.failed]))
    for j in np.flatnonzero(ok)[:4]:
        single = m.run_batch(u, t, {k: v[j:j + 1] for k, v in thetas.items()})
        np.testing.assert_array_equal(single.y[0], traj.y[j])


@pytest.mark.parametrize("name", [*MODELS, "bouc_wen_fractional"])
def test_serial_and_parallel_kernels_agree_bit_for_bit(name):
    from bayeshyst.models import kernel_parallelism

    t, u = _irregular()
    m = get(name)
    space = m.param_space(Record(t=t, u=u, y=0.4 * u, name="r"))
    thetas = space.unpack(space.sample_prior(np.random.default_rng(2), 12))
    with kernel_parallelism(0):
        par = m.run_batch(u, t, thetas)
    with kernel_parallelism(None):
        ser = m.run_batch(u, t, thetas)
    np.testing.assert_array_equal(par.y, ser.y)
    np.testing.assert_array_equal(par.failed, ser.failed)


@pytest.mark.parametrize("name", list(MODELS))
def test_linear_design_reproduces_the_output(name):
    t, u = _irregular()
    m = get(name)
    theta = {k: np.array([v]) for k, v in MODELS[name].items()}
    lin = m.linear_params[0]
    design = m.linear_design(u, t, theta)
    y = m.run_batch(u, t, theta).y
    pred = design.predict(theta[lin][:, None])
    np.testing.assert_allclose(pred, y, rtol=0, atol=1e-10 * np.ptp(y))


def test_delta_prior_scales_with_the_input_rate():
    t = np.arange(1000) / 1000.0
    slow = Record(t=t, u=50 + 40 * np.sin(2 * np.pi * t), y=np.sin(2 * np.pi * t), name="s")
    fast = Record(t=t, u=50 + 40 * np.sin(2 * np.pi * 10 * t), y=np.sin(2 * np.pi * t),
                  name="f")
    assert input_rate(fast) == pytest.approx(10 * input_rate(slow), rel=1e-3)
    sd = [AsymmetricBoucWenSgn().param_space(r)["delta"].prior.sigma for r in (slow, fast)]
    assert sd[1] == pytest.approx(10 * sd[0], rel=1e-3)


@pytest.mark.parametrize("name", list(MODELS))
def test_bad_settings_and_times_are_refused(name):
    with pytest.raises(ModelError, match="sign"):
        get(name, sign=2)
    with pytest.raises(ModelError, match="step_scale"):
        get(name, step_scale=0.9)
    t, u = _irregular(30)
    with pytest.raises(ParameterError, match="strictly increasing"):
        get(name).simulate(u, t[::-1], MODELS[name])


# ------------------------------------------------------------------ posterior recovery

SGN_TRUTH = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3, "delta": -0.15}


def sgn_record(seed, n=1200, sigma=0.05):
    """Two drive rates (2 Hz, then 6 Hz), so that δ's 1/|u̇| scaling is seen."""
    t = np.arange(n) * 1e-3
    f = np.where(t < 0.5 * t[-1], 2.0, 6.0)
    phase = 2 * np.pi * np.cumsum(f) * 1e-3
    u = 75.0 - 75.0 * np.cos(phase)
    y = AsymmetricBoucWenSgn().simulate(u, t, SGN_TRUTH)
    y = y + np.random.default_rng(seed).normal(0.0, sigma, n)
    return Record(t=t, u=u, y=y, name=f"sgn{seed}", warmup=150)


def _sgn_stats(seeds):
    from bayeshyst.inference.posterior import Posterior
    from tests.test_recovery import _fit_stats

    out = []
    for seed in seeds:
        post = Posterior(sgn_record(seed), "bouc_wen_asym_sgn")
        out.append(_fit_stats(post, {**SGN_TRUTH, "obs.offset": 0.0, "noise.sigma": 0.05},
                              seed))
    return out, post.ndim


def test_asym_sgn_posterior_is_calibrated():
    # oracle: the truth's squared Mahalanobis distances over independent fits ~ chi2
    from tests.test_recovery import _check_calibration

    fits, ndim = _sgn_stats(range(1))  # one fit (~6 s alone); the slow test runs 20
    _check_calibration(fits, ndim)


@pytest.mark.slow
def test_asym_sgn_90_percent_intervals_cover_at_the_nominal_rate():
    from tests.test_recovery import _check_calibration, _check_coverage

    fits, ndim = _sgn_stats(range(2, 22))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


FREQ_TRUTH = {"f_n": 120.0, "zeta": 0.3, "gain": 0.3, "alpha": 0.12, "beta": 0.004,
              "gamma": 0.001, "n": 1.3, "delta": -0.15, "tau": 1.5e-3}


def freq_record(seed, n=1600, sigma=0.05):
    """Three drive frequencies (4, 20, 60 Hz at 2 kHz) around the stage's 120 Hz."""
    t = np.arange(n) * 5e-4
    f = np.select([t < 0.25, t < 0.5], [4.0, 20.0], 60.0)
    u = 75.0 - 75.0 * np.cos(2 * np.pi * np.cumsum(f) * 5e-4)
    y = FrequencyFactorBoucWen().simulate(u, t, FREQ_TRUTH)
    y = y + np.random.default_rng(seed).normal(0.0, sigma, n)
    return Record(t=t, u=u, y=y, name=f"freq{seed}", warmup=150)


@pytest.mark.slow
def test_frequency_factor_posterior_is_calibrated():
    # ~1-2 min per fit on two busy cores: slow-marked, chi2 calibration over 5 fits
    from bayeshyst.inference.posterior import Posterior
    from tests.test_recovery import _check_calibration, _fit_stats

    fits = []
    for seed in range(5):
        post = Posterior(freq_record(seed), "bouc_wen_freq")
        fits.append(_fit_stats(post, {**FREQ_TRUTH, "obs.offset": 0.0, "noise.sigma": 0.05},
                               seed))
    _check_calibration(fits, post.ndim)
