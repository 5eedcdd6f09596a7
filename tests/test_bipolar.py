"""Butterfly models (bipolar drive, MODELS.md §9): kernel, properties, inverse, recovery.

Oracles: a slow pure-Python play + tanh written here; a brute-force ensemble of ±1
relays (the Preisach reading of the model); the analytic butterfly (P = 0, the strain's
minimum, exactly at E = ±E_c on the major loop); the mirror symmetry of a symmetric
drive from the symmetric (virgin) state; the existing bouc_wen_asym model for the Bouc–Wen
part of butterfly_bw; forward simulation of the designed command for the inverse.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from bayeshyst.data import Record
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.numerical import invert
from bayeshyst.models import get
from bayeshyst.models.base import DataScales

THETA = {"e_c": 0.9, "width": 0.25, "q": 1.2, "d_lin": 0.06}
BIPOLAR = DataScales(-2.0, 2.0, -0.2, 1.4, "kV/mm", "um")


def slow_butterfly(u, e_c, width, q, d, v0, polar=False, eta=0.0, w_rev=1.0):
    """Play of half-width e_c, P = (1 - eta) tanh(v / w) + eta tanh(u / w_rev),
    S = q P^2 + d u, one sample at a time."""
    v = float(v0)
    out = []
    for x in u:
        if x - e_c > v:
            v = x - e_c
        elif x + e_c < v:
            v = x + e_c
        p = (1.0 - eta) * math.tanh(v / width) + eta * math.tanh(x / w_rev)
        out.append(p if polar else q * p * p + d * x)
    return np.array(out), v


def irregular_bipolar(n=700, seed=0):
    """A bipolar field with reversals of every size (a random walk folded into +-2.3)."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.08, n) + 0.03 * np.sign(np.sin(np.arange(n) / 37.0))
    u = np.cumsum(steps)
    u = 2.3 * np.sin(u)  # bounded, with reversals wherever the walk turns or folds
    return np.arange(n) * 1e-3, u


def cycle(amplitude=2.0, n_per=400, cycles=3, phase=0.0):
    t = np.arange(n_per * cycles) / (n_per * 10.0)
    return t, amplitude * np.sin(2 * np.pi * 10.0 * t + phase)


def batch(theta, w=1):
    return {k: np.full(w, float(v)) for k, v in theta.items()}


# ----------------------------------------------------------------------- oracles


@pytest.mark.parametrize("start", ["poled", "virgin"])
def test_kernel_matches_slow_oracle(start):
    model = get(f"butterfly(start='{start}')")
    t, u = irregular_bipolar()
    v0 = u[0] + THETA["e_c"] if start == "poled" else np.clip(0.0, u[0] - 0.9, u[0] + 0.9)
    want, v_end = slow_butterfly(u, *THETA.values(), v0)
    traj = model.run(u, t, THETA)
    np.testing.assert_allclose(traj.y, want, rtol=0, atol=1e-13)
    assert traj.state[0] == pytest.approx(v_end, abs=1e-15)
    # from a non-default state (negatively switched) too, strain and polarisation
    s0 = np.array([-1.3])
    np.testing.assert_allclose(model.simulate(u, t, THETA, state0=s0),
                               slow_butterfly(u, *THETA.values(), -1.3)[0], atol=1e-13)
    np.testing.assert_allclose(model.polarisation(u, THETA, state0=s0),
                               slow_butterfly(u, *THETA.values(), -1.3, polar=True)[0],
                               atol=1e-15)


def test_reversible_part_matches_the_oracle_and_vanishes_at_eta_zero():
    model = get("butterfly(reversible=True)")
    t, u = irregular_bipolar(seed=4)
    th = {**THETA, "eta": 0.3, "w_rev": 1.7}
    want, _ = slow_butterfly(u, *THETA.values(), u[0] + 0.9, eta=0.3, w_rev=1.7)
    np.testing.assert_allclose(model.simulate(u, t, th), want, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(model.simulate(u, t, {**th, "eta": 0.0}),
                                  get("butterfly").simulate(u, t, THETA))
    p = model.polarisation(u, th)
    assert np.max(np.abs(p)) < 1.0  # still in units of saturation
    # the wings rise outward on both sides: just after either reversal the play is still,
    # and the strain falls away from +E_max and from -E_max alike (flat without it)
    tc, uc = cycle(n_per=400, cycles=2)
    top, bottom = 400 + 100, 400 + 300  # the sine's maximum and minimum of cycle 2
    for eta, sign in ((0.3, 1.0), (0.0, 0.0)):
        sc = model.simulate(uc, tc, {**th, "eta": eta, "d_lin": 0.0})
        after_top = np.diff(sc[top:top + 20])
        after_bottom = np.diff(sc[bottom:bottom + 20])
        assert np.all(np.sign(after_top) == -sign) and np.all(np.sign(after_bottom) == -sign)
    assert model.param_space(BIPOLAR).names == ("e_c", "width", "eta", "w_rev", "q", "d_lin")


def test_polarisation_is_a_preisach_ensemble_of_symmetric_relays():
    # P = tanh(v / w) is the mean of +-1 relays (c + E_c, c - E_c) with logistic centres
    # c of scale w / 2; the ensemble below is simulated relay by relay, with quantile
    # centres, so it differs from P by at most 1/m (the quantile step)
    model = get("butterfly(start='virgin')")
    _, u = irregular_bipolar(n=400, seed=3)
    e_c, w = THETA["e_c"], THETA["width"]
    m = 20000
    p = (np.arange(m) + 0.5) / m
    c = 0.5 * w * np.log(p / (1.0 - p))
    v0 = float(np.clip(0.0, u[0] - e_c, u[0] + e_c))
    s = np.where(v0 > c, 1.0, -1.0)
    ens = []
    for x in u:
        s = np.where(x >= c + e_c, 1.0, np.where(x <= c - e_c, -1.0, s))
        ens.append(s.mean())
    np.testing.assert_allclose(model.polarisation(u, THETA), ens, rtol=0, atol=1.5 / m)


def test_butterfly_bw_is_the_sum_of_its_parts():
    # oracle: the registered bouc_wen_asym and butterfly models, run separately
    bw = get("bouc_wen_asym")
    hyb = get("butterfly_bw")
    t, u = irregular_bipolar(n=500, seed=1)
    bw_theta = {"k": 0.05, "alpha": 0.3, "beta": 1.5, "gamma": 0.4, "n": 1.4, "delta": 0.02}
    full = {"e_c": 0.9, "width": 0.25, "q": 1.2, **bw_theta}
    want = (bw.simulate(u, t, bw_theta)
            + get("butterfly").simulate(u, t, {"e_c": 0.9, "width": 0.25, "q": 1.2,
                                               "d_lin": 0.0}))
    np.testing.assert_allclose(hyb.simulate(u, t, full), want, rtol=0, atol=1e-12)
    # q = 0 is bouc_wen_asym exactly
    np.testing.assert_array_equal(hyb.simulate(u, t, {**full, "q": 0.0}),
                                  bw.simulate(u, t, bw_theta))


# -------------------------------------------------------------------- properties


def test_bipolar_cycle_draws_a_butterfly_with_minima_at_plus_minus_ec():
    model = get("butterfly")
    t, u = cycle(n_per=4000)
    theta = {**THETA, "d_lin": 0.0}
    s = model.simulate(u, t, theta)
    last = slice(2 * 4000, 3 * 4000)
    ul, sl = u[last], s[last]
    du = np.gradient(ul)
    rising, falling = du > 0, du < 0
    # non-monotone along a rising stretch: it dips and comes back up
    i_min = np.flatnonzero(rising)[np.argmin(sl[rising])]
    i_max = np.flatnonzero(rising)[np.argmax(ul[rising])]
    assert sl[i_min] < 1e-3 * theta["q"] < sl[i_max]
    # with d_lin = 0 the minimum is where P = 0, i.e. exactly E = +E_c (rising) and
    # -E_c (falling), to the sampling of the field
    h = np.max(np.abs(np.diff(ul)))
    assert abs(ul[i_min] - theta["e_c"]) <= h
    j_min = np.flatnonzero(falling)[np.argmin(sl[falling])]
    assert abs(ul[j_min] + theta["e_c"]) <= h
    # both field extremes give positive strain, far above the minima
    assert sl[np.argmax(ul)] > 0.9 * theta["q"] and sl[np.argmin(ul)] > 0.9 * theta["q"]
    # with the linear term the minima stay within the switching width of +-E_c
    s2 = model.simulate(u, t, THETA)[last]
    assert abs(ul[np.flatnonzero(rising)[np.argmin(s2[rising])]] - THETA["e_c"]) < 0.5 * 0.25


@pytest.mark.parametrize("extra", [{}, {"eta": 0.3, "w_rev": 1.7}])
def test_polarisation_loop_is_point_symmetric_from_the_virgin_state(extra):
    model = get(f"butterfly(start='virgin', reversible={bool(extra)})")
    theta = {**THETA, **extra}
    t, u = irregular_bipolar(n=600, seed=5)
    u = u - u[0]  # starts at zero field: the virgin state is then symmetric
    p_plus = model.polarisation(u, theta)
    p_minus = model.polarisation(-u, theta)
    np.testing.assert_allclose(p_minus, -p_plus, rtol=0, atol=1e-15)
    assert np.ptp(p_plus) > 1.5  # the drive does switch the polarisation
    th0 = {**theta, "d_lin": 0.0}
    np.testing.assert_allclose(model.simulate(-u, t, th0), model.simulate(u, t, th0),
                               atol=1e-15)


def test_rate_independent_under_time_warp_and_refinement():
    model = get("butterfly")
    t, u = irregular_bipolar(n=300, seed=2)
    y = model.simulate(u, t, THETA)
    warped = np.cumsum(np.random.default_rng(0).uniform(0.1, 5.0, t.size))
    np.testing.assert_array_equal(model.simulate(u, warped, THETA), y)
    # inserting points along each monotone sample interval changes nothing at the old
    # samples (the play only sees the sequence of values)
    fine = np.concatenate([np.linspace(a, b, 4, endpoint=False)
                           for a, b in itertools.pairwise(u)] + [u[-1:]])
    yf = model.simulate(fine, np.arange(fine.size) * 1e-4, THETA)
    np.testing.assert_allclose(yf[::4], y, rtol=0, atol=1e-15)


def test_unipolar_drive_after_poling_is_monotone_and_counter_clockwise():
    from bayeshyst.data.virtual import loop_width

    model = get("butterfly")
    n = 2000
    t = np.arange(n) * 1e-3
    for e_max, opens in ((2.5, True), (1.6, False)):  # a loop opens only for E_max > 2 E_c
        u = 0.5 * e_max * (1 - np.cos(2 * np.pi * t * 2.0))
        s = model.simulate(u, t, THETA)
        du, ds = np.diff(u), np.diff(s)
        assert np.all(ds * np.sign(du) >= -1e-12)
        width, stroke = loop_width(u[n // 2:], s[n // 2:])
        # analytic branches from the poled state (v = E_c at E = 0): rising
        # v = max(E - E_c, E_c), falling v = min(E + E_c, max(E_max - E_c, E_c)); width
        # Q (P_fall^2 - P_rise^2), positive (counter-clockwise) where they differ
        grid = np.linspace(0.0, e_max, 20001)
        e_c, w, q = THETA["e_c"], THETA["width"], THETA["q"]
        p_r = np.tanh(np.maximum(grid - e_c, e_c) / w)
        p_f = np.tanh(np.minimum(grid + e_c, max(e_max - e_c, e_c)) / w)
        want = float(np.max(q * (p_f**2 - p_r**2)))
        assert width == pytest.approx(want, abs=2e-4 * stroke)
        assert (want > 1e-3 * stroke) == opens


def test_batched_equals_one_by_one_and_pieces_equal_one_run():
    for spec in ("butterfly", "butterfly(reversible=True)", "butterfly_bw"):
        model = get(spec)
        space = model.param_space(BIPOLAR)
        thetas = space.unpack(space.sample_prior(np.random.default_rng(4), 6))
        t, u = irregular_bipolar(n=400, seed=7)
        traj = model.run_batch(u, t, thetas)
        for j in range(6):
            one = {k: v[j] for k, v in thetas.items()}
            if traj.failed[j]:
                continue
            np.testing.assert_array_equal(model.simulate(u, t, one), traj.y[j])
            a = model.run(u[:150], t[:150], one)
            b = model.run(u[150:], t[150:], one, state0=a.state)
            # the play is exact; a cut restarts Bouc–Wen's adaptive steps (a different
            # partition of the input), so the pieces agree to its integration error,
            # documented <= 1e-7 of the stroke (measured here <= 2e-11), not bitwise
            tol = 0.0 if spec == "butterfly" else 1e-9 * np.ptp(traj.y[j])
            np.testing.assert_allclose(np.r_[a.y, b.y], traj.y[j], rtol=0, atol=tol)
        assert (~traj.failed).sum() >= 3


def test_prior_keeps_ec_in_the_drive_and_draws_never_give_nan():
    model = get("butterfly(reversible=True)")
    t, u = irregular_bipolar()
    for sc in (BIPOLAR, DataScales(0.0, 150.0, 0.0, 40.0)):
        space = model.param_space(sc)
        thetas = space.unpack(space.sample_prior(np.random.default_rng(0), 400))
        assert np.all((thetas["e_c"] >= 0) & (thetas["e_c"] <= max(-sc.u_min, sc.u_max)))
        traj = model.run_batch(u, t, thetas)
        assert not traj.failed.any() and np.all(np.isfinite(traj.y))
    # invalid vectors are flagged and their rows NaN, never silently simulated
    bad = batch({**THETA, "eta": 0.3, "w_rev": 1.7}, 5)
    bad["width"][1] = 0.0
    bad["e_c"][2] = -0.1
    bad["eta"][3] = 1.0
    bad["w_rev"][4] = 0.0
    traj = model.run_batch(u, t, bad)
    assert traj.failed.tolist() == [False, True, True, True, True]
    assert np.isnan(traj.y[1:]).all() and np.isfinite(traj.y[0]).all()


@pytest.mark.parametrize("spec", ["butterfly(reversible=True)", "butterfly_bw"])
def test_log_prob_of_prior_draws_is_finite_or_minus_inf(spec):
    # prior draws outside a model's support (Bouc–Wen's stable region) fail the
    # simulation: flagged, so the log-probability is -inf, never NaN
    post = Posterior(butterfly_record(0), spec)
    z = post.space.sample_prior(np.random.default_rng(0), 64)
    lp = post.log_prob_batch(z)
    assert not np.isnan(lp).any() and np.isfinite(lp).sum() >= 32


def test_output_is_linear_in_q_and_d():
    model = get("butterfly")
    t, u = irregular_bipolar(n=300)
    phi = model.regressors(u, t, {"e_c": 0.9, "width": 0.25})
    np.testing.assert_allclose(phi @ np.array([1.2, 0.06]), model.simulate(u, t, THETA),
                               atol=1e-13)
    np.testing.assert_allclose(phi[:, 1], u)


def test_bad_settings_and_states_are_refused():
    with pytest.raises(ModelError, match="start"):
        get("butterfly(start='negative')")
    with pytest.raises(ModelError, match="start"):
        get("butterfly_bw(start=1)")
    with pytest.raises(ModelError, match="reversible"):
        get("butterfly(reversible=1)")
    model = get("butterfly")
    t, u = irregular_bipolar(n=20)
    with pytest.raises(ParameterError, match="state"):
        model.run(u, t, THETA, state0=np.zeros(2))
    with pytest.raises(ParameterError, match="width"):
        model.polarisation(u, {**THETA, "width": -1.0})


def test_butterfly_bw_is_rate_independent_and_still_a_butterfly():
    model = get("butterfly_bw")
    theta = {"e_c": 0.9, "width": 0.25, "q": 1.2, "k": 0.05, "alpha": 0.1, "beta": 0.5,
             "gamma": 0.1, "n": 1.0, "delta": 0.01}
    t, u = cycle(n_per=800)
    y = model.simulate(u, t, theta)
    warped = np.cumsum(np.random.default_rng(1).uniform(0.1, 5.0, t.size))
    np.testing.assert_array_equal(model.simulate(u, warped, theta), y)
    last = slice(1600, 2400)
    rising = np.gradient(u[last]) > 0
    ys, us = y[last][rising], u[last][rising]
    i = np.argmin(ys)
    # the dip near +E_c on the rising branch, and the strain back up at +E_max
    assert abs(us[i] - 0.9) < 0.25 and ys[i] < 0.2 * ys[np.argmax(us)]


def test_settings_survive_the_model_spec():
    from bayeshyst.models import model_spec

    for spec in ("butterfly(start='virgin', reversible=True)", "butterfly_bw(start='virgin')"):
        model = get(spec)
        assert get(model_spec(model)) == model


# ----------------------------------------------------------------------- inverse


@pytest.mark.parametrize("spec", ["butterfly", "butterfly_bw"])
def test_inverse_on_one_wing_after_poling(spec):
    # oracle: forward simulation of the designed command meets the reference, which is
    # the model's own response to a unipolar command (so an exact inverse exists)
    model = get(spec)
    theta = batch({**THETA, **({"k": 0.05, "alpha": 0.03, "beta": 0.5, "gamma": 0.1,
                                "n": 1.0, "delta": 0.0} if spec == "butterfly_bw" else {})})
    if spec == "butterfly_bw":
        theta.pop("d_lin")
    n = 1200
    t = np.arange(n) * 1e-3
    u_true = 1.3 - 1.1 * np.cos(2 * np.pi * 2.0 * t) + 0.15 * np.sin(2 * np.pi * 7.0 * t)
    y_d = model.run_batch(u_true, t, theta).y[0]
    inv = invert(model, y_d, t, theta, u_limits=(0.0, 3.0))
    y = model.run_batch(inv.u, t, theta).y[0]
    assert np.max(np.abs(y - y_d)) <= 1e-6 * np.ptp(y_d)
    assert inv.n_saturated == 0 and inv.n_nonmonotone == 0


def test_inverse_over_a_bipolar_range_is_refused_with_the_reason():
    model = get("butterfly")
    t, u = cycle()
    theta = batch(THETA)
    y_d = model.run_batch(u, t, theta).y[0]
    with pytest.raises(ModelError, match=r"-E_c = -0\.9.*one wing"):
        invert(model, y_d, t, theta, u_limits=(-2.5, 2.5))
    with pytest.raises(ModelError, match="not monotone"):
        invert(model, y_d, t, theta)  # unlimited commands reach below -E_c too
    with pytest.raises(ModelError, match="d_lin < 0"):
        invert(model, y_d, t, {**theta, "d_lin": np.array([-0.01])}, u_limits=(0.0, 2.5))
    # with a reversible part P >= 0 needs E >= 0: -0.5 (inside -E_c) is refused too
    rev = get("butterfly(reversible=True)")
    th_rev = {**theta, "eta": np.array([0.3]), "w_rev": np.array([1.7])}
    with pytest.raises(ModelError, match="below 0"):
        invert(rev, y_d, t, th_rev, u_limits=(-0.5, 2.5))
    invert(model, y_d[:5], t[:5], theta, u_limits=(-0.5, 2.5))  # the plain model takes it
    # the composite is checked through its base model
    comp = get("butterfly+creep")
    space = comp.param_space(BIPOLAR)
    full = space.unpack(space.sample_prior(np.random.default_rng(0), 1))
    full.update({f"static.{k}": v for k, v in theta.items()})
    with pytest.raises(ModelError, match="butterfly"):
        invert(comp, y_d, t, full, u_limits=(-2.5, 2.5))


# ---------------------------------------------------------------------- recovery

TRUTH = {"e_c": 0.9, "width": 0.25, "q": 1.2, "d_lin": 0.06}
BW_TRUTH = {"e_c": 0.9, "width": 0.25, "q": 1.2, "k": 0.05, "alpha": 0.1, "beta": 0.5,
            "gamma": 0.1, "n": 1.0, "delta": 0.01}
#: the Bouc–Wen shape: held at the truth in the butterfly_bw fits (below)
BW_SHAPE = ("beta", "gamma", "n")
SIGMA = 0.01


def butterfly_record(seed, spec="butterfly", truth=None, n_per=200):
    """Two bipolar amplitudes (above the coercive field), poled start, white noise."""
    t1, u1 = cycle(amplitude=2.0, n_per=n_per, cycles=2)
    u2 = 1.5 * np.sin(2 * np.pi * 10.0 * t1)
    u = np.r_[u1, u2]
    t = np.arange(u.size) * 5e-4
    y = get(spec).simulate(u, t, TRUTH if truth is None else truth) + 0.05
    y = y + np.random.default_rng(seed).normal(0.0, SIGMA, u.size)
    return Record(t=t, u=u, y=y, name=f"butterfly{seed}", warmup=n_per // 4,
                  units={"t": "s", "u": "kV/mm", "y": "um"})


def _fit_stats(seed, spec="butterfly"):
    """(squared Mahalanobis distance of the truth, 90 % HDI hits, dimension) of one fit.

    butterfly_bw is fitted with the Bouc–Wen shape (beta, gamma, n) held at the truth:
    free, those three trade off along the ridge documented in bayeshyst.models.bouc_wen,
    and one fit took 5 min without converging (R-hat 1.21 after 8000 steps, every truth
    inside its band): too slow for a test, and a property of Bouc–Wen, tested there.
    """
    truth = TRUTH if spec == "butterfly" else BW_TRUTH
    rec = butterfly_record(seed, spec, truth)
    model = get(spec)
    space = model.param_space(rec)
    if spec == "butterfly_bw":
        for name in BW_SHAPE:
            space = space.fix(name, truth[name])
    post = Posterior(rec, model, space=space)
    res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=6000, n_walkers=16))
    assert res.converged, res.convergence
    free = {k: v for k, v in truth.items() if k in space.names}
    full = {**free, "obs.offset": 0.05, "noise.sigma": SIGMA}
    zt = post.space.pack(full)
    z = res.flat_z
    d = zt - z.mean(axis=0)
    d2 = float(d @ np.linalg.solve(np.cov(z.T), d))
    summ = {s.label: s for s in res.summary(0.9)}
    hits = {k: summ[k].hdi_lo <= v <= summ[k].hdi_hi for k, v in full.items()}
    return d2, hits, post.ndim


@pytest.mark.parametrize("spec", ["butterfly", "butterfly_bw"])
def test_posterior_recovers_the_truth(spec):
    # one fit: the truth's squared Mahalanobis distance is ~ chi2(d) for a calibrated
    # posterior; a two-sided 0.1 % test
    d2, _, ndim = _fit_stats(0, spec)
    p = stats.chi2.sf(d2, ndim)
    assert 5e-4 < p < 1 - 5e-4, (d2, p)


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["butterfly", "butterfly_bw"])
def test_90_percent_intervals_cover_at_the_nominal_rate(spec):
    fits = [_fit_stats(seed, spec) for seed in range(1, 13)]
    d2 = np.array([f[0] for f in fits])
    ndim = fits[0][2]
    p = stats.chi2.sf(d2.sum(), ndim * len(d2))
    assert 5e-4 < p < 1 - 5e-4, (d2, p)
    labels = list(fits[0][1])
    for label in labels:
        k = sum(f[1][label] for f in fits)
        # binomial test per parameter, Bonferroni over the parameters
        assert stats.binomtest(k, len(fits), 0.9).pvalue > 1e-3 / len(labels), (label, k)
