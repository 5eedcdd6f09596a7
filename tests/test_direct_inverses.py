"""Direct and closed-form inverses (issue 22): clockwise-relay Preisach, Bouc–Wen, Duhem.

Oracles:

* ``preisach_clockwise`` (review Eq. 9–10, ref. [60]): a relay-by-relay pure-Python loop
  written from Eq. 1–2 and 10; the identities ``theta = u/u_s - gamma`` summed (ramp
  minus the counter-clockwise ``preisach``) and ``theta_{a,b}[u] = u + gamma_{-b,-a}[-u]``
  (the clockwise relay is the ordinary one with input and thresholds mirrored); loop
  orientation (signed area); wiping-out; and, identified on swapped data from a
  Preisach plant, the tracking error it achieves on that known plant against the
  numerical inverse of a forward Preisach grid of the same size identified on the same
  data;
* Bouc–Wen and Duhem closed-form inverses (refs. [93], [84]): the command driven through
  the forward kernel (an independent integrator) reproduces the desired output to
  integration tolerance, and agrees with the numerical inverse.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from bayeshyst.data.record import Record
from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.analytic import analytic_inverse, swap_input_output
from bayeshyst.inverse.numerical import invert
from bayeshyst.models import get, registry
from bayeshyst.models.base import DataScales
from bayeshyst.models.preisach_clockwise import PreisachClockwise

SCALES = DataScales(0.0, 150.0, 0.0, 40.0)
FS = 2000.0


def irregular_input(n: int = 400, seed: int = 0, lo: float = -1.0, hi: float = 1.0):
    """A random walk of uneven steps with many reversals, inside ``[lo, hi]``."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.12, n) * rng.exponential(1.0, n)
    x = np.cumsum(steps)
    x = lo + (hi - lo) * (0.5 + 0.5 * np.sin(x))
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) * 1e-3
    return t, x


def cw_oracle(u, levels, mu, offset, u_scale, relay, history=()):
    """Clockwise relay grid, one relay at a time (review Eq. 1–2 and 10).

    Relays start as after negative saturation and a rise to the first input (or, with a
    ``history``, to that history's first value, then driven through it).
    """
    q = np.asarray(levels, float)
    cells = [(q[i], q[j]) for i in range(q.size) for j in range(i + 1)]
    first = history[0] if len(history) else u[0]
    on = [a <= first for a, _ in cells]
    out = []
    for k, uk in enumerate(list(history) + list(u)):
        for c, (a, b) in enumerate(cells):
            if uk >= a:
                on[c] = True
            elif uk < b:
                on[c] = False
        if k < len(history):
            continue
        total = offset
        for c, m in enumerate(mu):
            g = float(on[c]) if relay == "01" else (1.0 if on[c] else -1.0)
            total += m * (uk / u_scale - g)
        out.append(total)
    return np.array(out)


def cw_theta(model, seed, levels=None):
    rng = np.random.default_rng(seed)
    q = np.sort(rng.uniform(-0.9, 0.9, model.n_levels)) if levels is None else levels
    return {"offset": rng.normal(), "mu": rng.uniform(0.0, 1.0, model.n_cells),
            "u_scale": rng.uniform(0.3, 3.0), "levels": q}


def signed_area(x, y):
    """Shoelace area of the closed path (x, y): > 0 counter-clockwise, < 0 clockwise."""
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


# ------------------------------------------------------------ clockwise Preisach


@pytest.mark.parametrize("relay", ["01", "pm1"])
def test_clockwise_kernel_matches_relay_by_relay_oracle(relay):
    model = PreisachClockwise(n_levels=5, relay=relay)
    t, u = irregular_input()
    for seed in range(3):
        th = cw_theta(model, seed)
        y = model.simulate(u, t, th)
        want = cw_oracle(u, th["levels"], th["mu"], th["offset"], th["u_scale"], relay)
        np.testing.assert_allclose(y, want, rtol=0, atol=1e-12 * model.n_cells * 10)


@pytest.mark.parametrize("relay", ["01", "pm1"])
def test_from_a_remembered_state_matches_the_oracle_after_that_history(relay):
    model = PreisachClockwise(n_levels=5, relay=relay, max_memory=8)
    th = cw_theta(model, 4)
    # memory of: negative saturation, a rise to 0.85, a fall to -0.6, a rise to 0.2
    state = np.zeros(3 + 8)
    state[:3] = (2, 0, 0.2)
    state[3:5] = (0.85, -0.6)
    t, u = irregular_input(300, seed=5, lo=-0.95, hi=0.95)
    y = model.simulate(u, t, th, state0=state)
    want = cw_oracle(u, th["levels"], th["mu"], th["offset"], th["u_scale"], relay,
                     history=(-2.0, 0.85, -0.6, 0.2))
    np.testing.assert_allclose(y, want, atol=1e-11)


def test_one_relay_is_review_eq_10_literally():
    # u_scale = 1 in the input's unit, ±1 relay, weight 1: u - 1 above alpha, u + 1 below
    # beta, u - eps in between (eps the relay's last value)
    model = PreisachClockwise(n_levels=1, relay="pm1")
    th = {"offset": 0.0, "mu": np.array([1.0]), "u_scale": 1.0, "levels": np.array([0.0])}
    # one level: alpha = beta = 0, a step; two levels give a relay with alpha > beta
    u = np.array([-0.5, 0.3, 0.7, -0.2, -0.9])
    np.testing.assert_allclose(model.simulate(u, np.arange(5.0), th), u - np.sign(u))
    model = PreisachClockwise(n_levels=2, relay="pm1")
    # cells (q0, q0), (q1, q0), (q1, q1): weight only on the hysteretic relay (0.5, -0.5)
    th = {"offset": 0.0, "mu": np.array([0.0, 1.0, 0.0]), "u_scale": 1.0,
          "levels": np.array([-0.5, 0.5])}
    u = np.array([-0.8, 0.0, 0.6, 0.1, -0.3, -0.7, 0.2])
    eps = np.array([-1, -1, 1, 1, 1, -1, -1])
    np.testing.assert_allclose(model.simulate(u, np.arange(u.size * 1.0), th), u - eps)


@pytest.mark.parametrize("relay", ["01", "pm1"])
def test_clockwise_is_the_ramp_minus_the_counterclockwise_preisach(relay):
    # review Eq. 9 summed over the relays: sum mu theta = sum(mu) u / u_s - sum mu gamma
    cw = PreisachClockwise(n_levels=6, relay=relay)
    ccw = get(f"preisach(n_levels=6, relay={relay!r})")
    t, u = irregular_input(500, seed=2)
    th = cw_theta(cw, 7)
    y_ccw = ccw.simulate(u, t, {"offset": 0.0, "mu": th["mu"], "levels": th["levels"]})
    want = th["offset"] + th["mu"].sum() * u / th["u_scale"] - y_ccw
    np.testing.assert_allclose(cw.simulate(u, t, th), want, atol=1e-12)


def test_clockwise_relay_is_the_relay_with_input_and_thresholds_mirrored():
    # theta_{a,b}[u] = u + gamma_{-b,-a}[-u] (±1 relays, u_s = 1): summed with mirrored
    # weights, the clockwise grid equals the ramp plus a ±1 Preisach grid on levels -q
    # (reversed) driven by -u. Both start saturated (u_0 above every level) so that
    # their initial states agree; the input avoids the levels (tie conventions differ).
    n_lev = 5
    cw = PreisachClockwise(n_levels=n_lev, relay="pm1")
    ccw = get(f"preisach(n_levels={n_lev}, relay='pm1')")
    th = cw_theta(cw, 3)
    th["u_scale"] = 1.0
    q, mu = th["levels"], th["mu"]
    mirrored = np.empty_like(mu)
    for i in range(n_lev):
        for j in range(i + 1):
            i2, j2 = n_lev - 1 - j, n_lev - 1 - i  # (alpha, beta) = (q_i, q_j) -> (-q_j, -q_i)
            mirrored[i2 * (i2 + 1) // 2 + j2] = mu[i * (i + 1) // 2 + j]
    t, u = irregular_input(400, seed=9)
    u = np.r_[1.5, u]
    t = np.r_[0.0, t + 1.0]
    y_mirror = ccw.simulate(-u, t, {"offset": mu.sum(), "mu": mirrored, "levels": -q[::-1]})
    # pm1 preisach: offset c sits mid-stroke, output c - sum(mu) + 2 P = sum mu gamma
    want = th["offset"] + mu.sum() * u + (y_mirror - mu.sum())
    np.testing.assert_allclose(cw.simulate(u, t, th), want, atol=1e-12)


def test_loops_run_clockwise_where_the_preisach_loops_run_counterclockwise():
    cw = PreisachClockwise(n_levels=8)
    ccw = get("preisach(n_levels=8)")
    s = np.linspace(0.0, 1.0, 801)
    u = -np.cos(2 * np.pi * s)  # one closed cycle, -1 -> 1 -> -1
    t = s.copy()
    levels = np.linspace(-0.9, 0.9, 8)
    rng = np.random.default_rng(1)
    for _ in range(5):
        mu = rng.uniform(0.0, 1.0, cw.n_cells)
        y_cw = cw.simulate(u, t, {"offset": 0.0, "mu": mu, "u_scale": 0.5, "levels": levels})
        y_ccw = ccw.simulate(u, t, {"offset": 0.0, "mu": mu, "levels": levels})
        assert signed_area(u, y_ccw) > 0.0
        assert signed_area(u, y_cw) < 0.0
        # same loop, mirrored: the areas are equal and opposite (the ramp encloses none)
        assert signed_area(u, y_cw) == pytest.approx(-signed_area(u, y_ccw), rel=1e-9)


def test_wiping_out_and_return_point_memory():
    cw = PreisachClockwise(n_levels=7)
    th = cw_theta(cw, 11)
    plain = np.array([-1.0, 0.8, -0.5, 0.6])
    with_minor = np.array([-1.0, 0.8, -0.5, 0.3, -0.1, 0.45, 0.0, 0.6])
    a = cw.simulate(plain, np.arange(plain.size * 1.0), th)
    b = cw.simulate(with_minor, np.arange(with_minor.size * 1.0), th)
    assert b[-1] == pytest.approx(a[-1], abs=1e-12)  # the minor loops are wiped out
    # and a closed minor loop returns to its starting point
    loop = np.array([-1.0, 0.7, -0.2, 0.35, -0.2])
    y = cw.simulate(loop, np.arange(loop.size * 1.0), th)
    assert y[-1] == pytest.approx(y[2], abs=1e-12)


def test_rate_independent_two_pieces_and_batched():
    cw = PreisachClockwise(n_levels=6)
    t, u = irregular_input(300, seed=4)
    th = cw_theta(cw, 5)
    y = cw.simulate(u, t, th)
    warped = np.cumsum(np.exp(np.random.default_rng(0).normal(0, 1, t.size)))
    np.testing.assert_array_equal(cw.simulate(u, warped, th), y)
    first = cw.run(u[:137], t[:137], th)
    second = cw.run(u[137:], t[137:], th, state0=first.state)
    np.testing.assert_array_equal(np.r_[first.y, second.y], y)
    thetas = [cw_theta(cw, s, levels=th["levels"]) for s in range(4)]
    batch = {k: np.stack([np.asarray(x[k]) for x in thetas]) for k in thetas[0]}
    yb = cw.run_batch(u, t, batch).y
    for j, x in enumerate(thetas):
        np.testing.assert_array_equal(yb[j], cw.simulate(u, t, x))


def test_prior_draws_never_give_nan_and_bad_scales_fail():
    cw = PreisachClockwise()
    rec = Record(t=np.arange(400) / 1e3, u=20 + 18 * np.sin(np.arange(400) / 30.0),
                 y=75 + 70 * np.sin(np.arange(400) / 30.0 + 0.3), name="swapped")
    space = cw.param_space(rec)
    z = space.sample_prior(np.random.default_rng(0), 100)
    traj = cw.run_batch(rec.u, rec.t, space.unpack(z))
    assert not traj.failed.any() and np.all(np.isfinite(traj.y))
    theta = space.unpack(z)
    theta["u_scale"][:3] = (0.0, -1.0, np.nan)
    traj = cw.run_batch(rec.u, rec.t, theta)
    np.testing.assert_array_equal(np.flatnonzero(traj.failed), [0, 1, 2])
    one = space.unpack(z[0])
    one["u_scale"] = -1.0
    with pytest.raises(SimulationError):
        cw.simulate(rec.u, rec.t, one)


def test_bad_settings_are_refused():
    with pytest.raises(ModelError, match="relay"):
        PreisachClockwise(relay="10")
    with pytest.raises(ModelError):
        PreisachClockwise(n_levels=0)
    with pytest.raises(ModelError, match="max_memory"):
        PreisachClockwise(max_memory=1)


def test_numerical_inversion_of_the_compensator_model_reports_its_sawtooth():
    # the model of a compensator steps down where a relay switches: not monotone in its
    # input, declared so, and a numerical inversion says so instead of hiding it
    assert not PreisachClockwise.monotone_in_input
    assert registry.model_class("preisach").monotone_in_input
    cw = PreisachClockwise(n_levels=6)
    th = cw_theta(cw, 2)
    s = np.linspace(0, 1, 400)
    y_d = 2.0 * np.sin(2 * np.pi * s)
    inv = invert(cw, y_d, s, {k: np.asarray(v)[None] for k, v in th.items()},
                 u_limits=(-10.0, 10.0))
    assert inv.n_nonmonotone > 0


def test_regressors_give_the_output_linear_in_offset_and_weights():
    cw = PreisachClockwise(n_levels=4)
    t, u = irregular_input(200, seed=8)
    th = cw_theta(cw, 1)
    phi = cw.regressors(u, t, {"u_scale": th["u_scale"], "levels": th["levels"]})
    np.testing.assert_allclose(phi @ np.r_[th["offset"], th["mu"]], cw.simulate(u, t, th),
                               atol=1e-12)


# -------------------------------------------------- the direct inverse on a plant

PLANT_TRUTH = {"offset": 0.0, "k_rev": 0.08, "scale": 28.0, "centre": 75.0,
               "sd_centre": 40.0, "halfwidth": 15.0, "sd_log_halfwidth": 0.6, "rho": 0.2,
               "bounds": np.array([-7.5, 157.5])}


def _plant_data():
    plant = get("preisach_density(n_grid=48)")
    t = np.arange(3000) / 1000.0
    envelope = np.linspace(1.0, 0.3, t.size)
    u = 75 - 70 * envelope * np.cos(2 * np.pi * 2 * t) + 6 * np.sin(2 * np.pi * 13 * t)
    return plant, Record(t=t, u=u, y=plant.simulate(u, t, PLANT_TRUTH), name="plant")


def _least_squares(model, rec, theta):
    return _solve(model.regressors(rec.u, rec.t, theta), rec.y)


def _solve(phi, y):
    """Least squares by the normal equations (an SVD of 3000 x 79 takes a second when
    the BLAS threads compete with other processes; the Gram matrix takes milliseconds)."""
    beta = np.linalg.solve(phi.T @ phi, phi.T @ y)
    r = y - phi @ beta
    return float(r @ r), beta


def test_direct_inverse_identified_on_swapped_data_tracks_the_preisach_plant():
    # a Preisach plant (continuous density, so that a reference can be tracked at all);
    # its loop data swapped, a clockwise grid fitted by least squares (linear in offset
    # and weights; u_scale by a 1-D search) is the compensator. Against the same plant:
    # the numerical inverse of a forward Preisach grid of the same size, identified on
    # the same data, and no compensation (the fitted straight line inverted)
    plant, rec = _plant_data()
    swapped = swap_input_output(rec)[0]
    n_lev = 12
    cw = PreisachClockwise(n_levels=n_lev)
    levels = cw.param_space(swapped).fixed["levels"]

    # the columns u/u_s - gamma are affine in 1/u_s: two designs give every u_s
    phi1 = cw.regressors(swapped.u, swapped.t, {"u_scale": 1.0, "levels": levels})
    phi2 = cw.regressors(swapped.u, swapped.t, {"u_scale": 2.0, "levels": levels})

    def sse(log_scale):
        return _solve(phi1 + 2.0 * (np.exp(-log_scale) - 1.0) * (phi1 - phi2), swapped.y)

    best = minimize_scalar(lambda x: sse(x)[0], bounds=(np.log(0.1), np.log(400.0)),
                           method="bounded")
    beta = sse(best.x)[1]
    compensator = {"offset": beta[0], "mu": beta[1:], "u_scale": np.exp(best.x),
                   "levels": levels}
    fs, f = 500.0, 1.5
    t = np.arange(1000) / fs
    y_d = 20 - 14 * np.cos(2 * np.pi * f * t) + 2.0 * np.sin(2 * np.pi * 7 * t)
    scored = slice(int(fs / f), None)  # after the first cycle

    def nrmse(u):
        y = plant.simulate(u, t, PLANT_TRUTH)
        return 100 * np.sqrt(np.mean((y - y_d)[scored] ** 2)) / np.ptp(y_d)

    u_direct = cw.simulate(y_d, t, compensator)
    forward = get(f"preisach(n_levels={n_lev})")
    f_levels = forward.param_space(rec).fixed["levels"]
    fb = _least_squares(forward, rec, {"levels": f_levels})[1]
    u_numerical = invert(forward, y_d, t, {"offset": fb[:1], "mu": fb[None, 1:],
                                          "levels": f_levels[None]},
                         u_limits=(-40.0, 190.0)).u
    slope, icpt = np.polyfit(rec.u, rec.y, 1)
    errors = {"direct": nrmse(u_direct), "numerical": nrmse(u_numerical),
              "none": nrmse((y_d - icpt) / slope)}
    print(errors)
    assert errors["direct"] < 0.5 * errors["none"], errors
    assert errors["direct"] < errors["numerical"], errors
    # the identified compensator runs clockwise over a full cycle of its input
    cycle = slice(t.size - int(fs / f), None)
    assert signed_area(y_d[cycle], u_direct[cycle]) < 0.0


# ------------------------------------------------------------------ recovery


def _cw_case(seed, n=900, sigma=0.3):
    cw = PreisachClockwise(n_levels=3)
    t = np.arange(n) * 1e-3
    u = 20 - 18 * np.cos(2 * np.pi * 3 * t) * np.linspace(1, 0.4, n)
    rec0 = Record(t=t, u=u, y=np.zeros(n), name="shape")
    space = cw.param_space(Record(t=t, u=u, y=75 - 70 * np.cos(2 * np.pi * 3 * t), name="s"))
    truth = {"offset": 5.0, "mu": np.array([3.0, 8.0, 2.0, 6.0, 9.0, 4.0]), "u_scale": 6.0}
    y = cw.simulate(u, t, {**truth, "levels": space.fixed["levels"]})
    y = y + np.random.default_rng(seed).normal(0.0, sigma, n)
    return cw, space, rec0.with_(y=y), truth


def _cw_stats(seed):
    cw, space, rec, truth = _cw_case(seed)
    post = Posterior(rec, cw, space=space)
    res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000, n_walkers=24))
    assert res.converged, res.convergence
    truth_full = {**truth, "noise.sigma": 0.3}
    zt = post.space.pack(truth_full)
    d = zt - res.flat_z.mean(axis=0)
    return float(d @ np.linalg.solve(np.cov(res.flat_z.T), d)), post.ndim


def test_clockwise_posterior_recovers_the_truth():
    # one fit: the truth's squared Mahalanobis distance is ~ chi2(d) for a calibrated
    # posterior; the 0.1 % upper quantile bounds it (fails with probability 1e-3)
    from scipy import stats

    d2, ndim = _cw_stats(0)
    assert d2 < stats.chi2.ppf(0.999, ndim), (d2, ndim)


@pytest.mark.slow
def test_clockwise_posteriors_are_calibrated_over_seeds():
    from scipy import stats

    out = [_cw_stats(seed) for seed in range(1, 9)]
    total, dof = sum(d for d, _ in out), sum(n for _, n in out)
    p = stats.chi2.sf(total, dof)
    assert 1e-3 / 2 < p < 1 - 1e-3 / 2, (out, p)


# ---------------------------------------------- Bouc–Wen and Duhem closed forms


def smooth_input(n_cycles: float = 2.5, f: float = 10.0, lead: int = 40, fs: float = FS):
    """At rest, then a sine with a C2 envelope and minor loops (as tests/test_inverse.py)."""
    n = lead + int(n_cycles * fs / f)
    t = np.arange(n) / fs
    s = np.clip((t - lead / FS) * f, 0.0, None)
    envelope = np.where(s < 1.0, np.sin(0.5 * np.pi * np.clip(s, 0, 1)) ** 4, 1.0)
    u = 75.0 - 60.0 * envelope * np.cos(2 * np.pi * s) + 8.0 * envelope * np.sin(6 * np.pi * s)
    return t, u


def monotone_draw(model, t, u, seeds=range(300), refine=20):
    """A prior draw whose output rises with the input on every branch, and that output.

    Monotonicity is checked on the input refined ``refine`` times by linear interpolation
    (the path the rate-independent models take between samples): a closed-form inverse
    follows that path, and exists only where the loop does not fold back inside it.
    """
    space = model.param_space(SCALES)
    fine = np.arange((t.size - 1) * refine + 1) / refine
    u_fine = np.interp(fine, np.arange(t.size), u)
    t_fine = np.interp(fine, np.arange(t.size), t)
    for seed in seeds:
        theta = space.unpack(space.sample_prior(np.random.default_rng(seed), 1))
        traj = model.run_batch(u_fine, t_fine, theta)
        if traj.failed[0]:
            continue
        y = traj.y[0]
        du, dy = np.diff(u_fine), np.diff(y)
        moving = np.abs(du) > 1e-9
        if np.ptp(y) > 0.04 and np.all(dy[moving] * np.sign(du[moving]) > 0.0):
            return {k: np.asarray(v)[0] for k, v in theta.items()}, y[::refine]
    pytest.fail(f"no monotone prior draw of {model.name}")


CLOSED_FORMS = ["bouc_wen", "bouc_wen_asym", "bouc_wen(sign=1)", "duhem",
                "duhem(f_order=1, g_order=2)"]


@pytest.mark.parametrize("spec", CLOSED_FORMS)
def test_closed_form_inverse_reproduces_the_output_through_the_forward_kernel(spec):
    model = get(spec)
    assert model.has_inverse
    t, u_true = smooth_input()
    for seeds in (range(0, 300), range(300, 600)):
        theta, y_d = monotone_draw(model, t, u_true, seeds)
        u = analytic_inverse(model, y_d, t, theta)
        stroke = np.ptp(y_d)
        # forward(inverse(y_d)) == y_d: an independent integrator (order-5 Taylor for
        # Bouc–Wen, the exact linear ODE for Duhem) checks the inverse's RK4
        assert np.max(np.abs(model.simulate(u, t, theta) - y_d)) <= 1e-7 * stroke
        np.testing.assert_allclose(u, u_true, atol=1e-6 * 150)
        numerical = invert(model, y_d, t, {k: np.asarray(v)[None] for k, v in theta.items()},
                           u_limits=(-100.0, 250.0)).u
        np.testing.assert_allclose(u, numerical, atol=1e-6 * 150)


@pytest.mark.parametrize("spec", CLOSED_FORMS)
def test_closed_form_inverse_on_coarse_samples(spec):
    # 12 samples per cycle: each sample interval spans a large part of the loop (several
    # relaxation lengths of the state), so the inverse's step control, not the sampling,
    # sets its accuracy
    model = get(spec)
    t, u_true = smooth_input(n_cycles=3.0, lead=2, fs=120.0)
    theta, y_d = monotone_draw(model, t, u_true)
    u = model.inverse(y_d, t, theta)
    assert np.max(np.abs(model.simulate(u, t, theta) - y_d)) <= 1e-7 * np.ptp(y_d)
    np.testing.assert_allclose(u, u_true, atol=1e-6 * 150)


@pytest.mark.parametrize("spec", ["bouc_wen", "duhem"])
def test_closed_form_inverse_from_a_remembered_state(spec):
    model = get(spec)
    t, u_true = smooth_input()
    theta, y_d = monotone_draw(model, t, u_true)
    cut = 137  # mid-loop: the state is far from relaxed
    head = model.run(u_true[:cut], t[:cut], theta)
    u = model.inverse(y_d[cut:], t[cut:], theta, state0=head.state)
    tail = model.run(u, t[cut:], theta, state0=head.state).y
    assert np.max(np.abs(tail - y_d[cut:])) <= 1e-7 * np.ptp(y_d)
    np.testing.assert_allclose(u, u_true[cut:], atol=1e-6 * 150)


def test_bouc_wen_delayed_multiplicative_structure_errs_where_output_driven_does_not():
    # review §9: u = (y_d + H(u)) / k is an algebraic loop; [93]'s one-sample delay,
    # u_k = (y_d,k + h_{k-1}) / k, breaks it at the cost of an error that the
    # output-driven state (no delay) does not have
    model = get("bouc_wen")
    t, u_true = smooth_input()
    theta, y_d = monotone_draw(model, t, u_true)
    k = theta["k"]
    state = model.run(u_true[:1], t[:1], theta).state
    u_delay = np.empty_like(y_d)
    u_delay[0] = u_true[0]
    for i in range(1, y_d.size):
        u_delay[i] = (y_d[i] + state[0]) / k
        state = model.run(u_delay[i:i + 1], t[i:i + 1], theta, state0=state).state
    stroke = np.ptp(y_d)
    delayed = np.max(np.abs(model.simulate(u_delay, t, theta) - y_d)) / stroke
    exact = np.max(np.abs(model.simulate(model.inverse(y_d, t, theta), t, theta) - y_d)) / stroke
    assert exact < 1e-7 < 1e-3 < delayed, (exact, delayed)


def test_duhem_without_hysteresis_inverts_a_straight_line_exactly():
    # alpha = 0, F = f0, G = g0: w = f0 + g0 (s - s0) with s0 = 0 (F(s0) = y_d[0] = f0)
    model = get("duhem(f_order=1, g_order=0)")
    theta = {"alpha": 0.0, "f": np.array([3.0, 1e-3]), "g": np.array([12.0]),
             "u_centre": 75.0, "u_half": 75.0}
    y_d = 3.0 + np.array([0.0, 2.0, 5.5, 1.0, -4.0, 0.5])
    u = model.inverse(y_d, np.arange(6.0), theta)
    np.testing.assert_allclose(u, 75.0 + 75.0 * (y_d - 3.0) / 12.0, atol=1e-9)


def test_inverses_refuse_a_loop_that_folds_back_and_bad_parameters():
    t = np.arange(5.0)
    y_d = np.array([0.0, 5.0, 10.0, 20.0, 30.0])
    bw = get("bouc_wen")
    # dy/du = k - f with f up to alpha: k < alpha folds the loop back
    folded = {"k": 0.05, "alpha": 0.3, "beta": 0.01, "gamma": 0.0, "n": 1.0}
    with pytest.raises(ParameterError, match="folds back"):
        bw.inverse(y_d, t, folded)
    with pytest.raises(ParameterError, match="stable region"):
        bw.inverse(y_d, t, {"k": 0.3, "alpha": 0.1, "beta": 0.001, "gamma": 0.01, "n": 1.0})
    duhem = get("duhem(f_order=1, g_order=0)")
    flat = {"alpha": 1.0, "f": np.array([0.0, 10.0]), "g": np.array([-1.0]),
            "u_centre": 0.0, "u_half": 1.0}
    with pytest.raises(ParameterError, match="folds back"):
        duhem.inverse(y_d, t, flat)
    with pytest.raises(ParameterError, match="state0"):
        duhem.inverse(y_d, t, {**flat, "f": np.array([1.0, 0.0])})
    with pytest.raises(ParameterError, match="finite"):
        bw.inverse(np.array([0.0, np.nan]), t[:2], folded)


def test_models_with_an_analytic_inverse_are_listed():
    have = {n for n in registry.names() if registry.model_class(n).has_inverse}
    assert {"pi_play", "mbw", "bouc_wen", "bouc_wen_asym", "duhem"} <= have
    assert "preisach_clockwise" not in have  # a direct inverse: it *is* a compensator


# ------------------------------------------------------- compensate, when chosen


def test_compensate_uses_the_closed_form_when_chosen():
    # one fit, the nominal command both ways: the closed form of the Bouc–Wen MAP and the
    # numerical inverse of the same MAP are the same command (to the root finder's
    # tolerance), and so track the virtual plant equally
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inverse.compensate import compensate
    from tests.test_compensate import HYSTERESIS_ONLY, loops

    data = loops(HYSTERESIS_ONLY, [1.0], cycles=3)
    # a short run: the nominal command is the MAP's either way, converged or not
    sampler = SamplerSettings(max_steps=200, n_walkers=16, seed=3)
    fit = fit_model(data, "bouc_wen", "gaussian", sampler=sampler)
    common = {"fit": fit, "sampler": sampler, "n_design_draws": 4, "n_predict_draws": 20}
    numerical = compensate(data, "bouc_wen", **common).rows[0]
    closed = compensate(data, "bouc_wen", nominal_inverse="closed_form", **common).rows[0]
    span = np.ptp(numerical.curves["u_nominal"])
    np.testing.assert_allclose(closed.curves["u_nominal"], numerical.curves["u_nominal"],
                               atol=1e-5 * span)
    assert closed.nominal_nrmse_percent == pytest.approx(numerical.nominal_nrmse_percent,
                                                         abs=1e-3)
    assert closed.nominal_nrmse_percent < closed.uncompensated_nrmse_percent
    with pytest.raises(ParameterError, match="no closed-form inverse"):
        compensate(data, "preisach", nominal_inverse="closed_form", fit=fit)
    with pytest.raises(ParameterError, match="nominal_inverse"):
        compensate(data, "bouc_wen", nominal_inverse="exact", fit=fit)


def test_cli_refuses_a_closed_form_nominal_for_a_model_without_one_before_fitting(
        tmp_path, capsys):
    from bayeshyst.cli import main
    from bayeshyst.data import write_csv
    from tests.test_compensate_cli import _virtual_data

    path = tmp_path / "virtual.csv"
    write_csv(_virtual_data(), path)
    out = tmp_path / "out"
    assert main(["compensate", str(path), "--model", "maxwell_slip", "--nominal-inverse",
                 "closed_form", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no closed-form inverse" in err and "bouc_wen" in err and "Traceback" not in err
    assert not out.exists()


def test_closed_form_feedforward_counts_saturation_and_checks_itself():
    from bayeshyst.inverse.closed_form import closed_form_feedforward
    from bayeshyst.inverse.feedforward import Draws

    model = get("bouc_wen")
    t, u_true = smooth_input()
    theta, y_d = monotone_draw(model, t, u_true)
    one = Draws({k: np.asarray(v)[None] for k, v in theta.items()}, np.array([0.5]))
    ff = closed_form_feedforward(model, y_d + 0.5, t, one, one, label="nominal")
    assert ff.inversion.n_saturated == 0 and ff.inversion.max_error <= 1e-7 * np.ptp(y_d)
    np.testing.assert_allclose(ff.u, u_true, atol=1e-6 * 150)  # the offset taken off first
    capped = closed_form_feedforward(model, y_d + 0.5, t, one, one, label="nominal",
                                     u_limits=(0.0, 120.0))
    assert capped.inversion.n_saturated == int(np.sum(u_true > 120.0)) > 0
    assert capped.u.max() == 120.0
    assert capped.inversion.max_error > 1e-3 * np.ptp(y_d)  # measured, not hidden
    with pytest.raises(ParameterError, match="one parameter vector"):
        two = Draws({k: np.repeat(np.asarray(v)[None], 2, axis=0) for k, v in theta.items()},
                    np.zeros(2))
        closed_form_feedforward(model, y_d, t, two, two, label="nominal")
