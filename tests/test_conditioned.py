"""``conditioned``: any static model's slope and width following a measured column.

Oracles: ``pi_covariate`` (the same slope and width law written into the PI kernel:
equal on a constant column and whenever ``b = 0``); a slow pure-Python PI written in
``pi_covariate``'s physical form with the wrapper's one documented difference (held
memory dilates about the centre); the base models themselves at ``a = b = 0`` and
without the column; Maxwell-slip with scaled stiffnesses and slip deflections on a
constant column (analytic); properties (pieces, batches, prior draws, failures, linear
design); the spec grammar and its errors; recovery of ``a``, ``b`` from Bouc–Wen data.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bayeshyst.data import Record
from bayeshyst.errors import DataError, ModelError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inverse.numerical import invert
from bayeshyst.models import get, model_spec
from bayeshyst.models.base import DataScales
from bayeshyst.models.conditioned import Conditioned
from bayeshyst.models.pi_weighted import CovariatePI

COL = "temperature_c"
N_OP = 5
SCALES = DataScales(0.0, 150.0, 0.0, 40.0)
BASES = ("bouc_wen", "preisach", "maxwell_slip", "duhem", "pi_play")


def _irregular(n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Irregular times, an input with reversals of every size, and a wandering column."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(2e-4, 3e-3, n))
    u = 75.0 + 60.0 * np.sin(2 * np.pi * 3.0 * t) * np.cos(2 * np.pi * 0.7 * t) \
        + rng.normal(0.0, 4.0, n)
    c = 30.0 + np.cumsum(rng.normal(0.0, 0.4, n))
    return t, u, c


def _record(t, u, c) -> Record:
    return Record(t=t, u=u, y=0.2 * u + np.sin(t), name="r", covariates={COL: c})


def _theta(model, seed: int, data=None) -> dict:
    space = model.param_space(SCALES if data is None else data)
    return space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])


def _batched(theta: dict) -> dict:
    return {k: np.asarray(v, dtype=float)[None, ...] for k, v in theta.items()}


def _pi_pair(seed: int, a: float, b: float, c0: float = 30.0):
    """``pi_covariate`` and ``conditioned(pi_play)`` with the same operators, a, b, c0."""
    cov_pi = CovariatePI(N_OP, column=COL)
    wrapped = get(f"conditioned(pi_play(n_operators={N_OP}), column='{COL}')")
    th = _theta(cov_pi, seed) | {"a": a, "b": b, "c0": c0}
    th_w = {k: v for k, v in th.items() if k not in ("a", "b", "c0")}
    th_w |= {"cond.a": a, "cond.b": b, "cond.c0": c0, "cond.u_c": 75.0}
    return cov_pi, th, wrapped, th_w


# ------------------------------------------------------------------ exact oracles


@pytest.mark.parametrize(("a", "b", "level"), [(0.012, -0.02, 37.5), (-0.01, 0.03, 21.0),
                                               (0.0, 0.05, 45.0)])
def test_wrapped_pi_play_is_pi_covariate_on_a_constant_column(a, b, level):
    # the conjugation of a play by a scaling about u_c is a play of scaled threshold
    t, u, _ = _irregular()
    cov_pi, th, wrapped, th_w = _pi_pair(1, a, b)
    col = {COL: np.full(u.size, level)}
    y_ref = cov_pi.simulate(u, t, th, covariates=col)
    y = wrapped.simulate(u, t, th_w, covariates=col)
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-12 * np.abs(y_ref).max())


def test_wrapped_pi_play_is_pi_covariate_when_only_the_slope_varies():
    t, u, c = _irregular()
    cov_pi, th, wrapped, th_w = _pi_pair(2, 0.015, 0.0)
    y_ref = cov_pi.simulate(u, t, th, covariates={COL: c})
    y = wrapped.simulate(u, t, th_w, covariates={COL: c})
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-12 * np.abs(y_ref).max())


def _slow_dilating_pi(u, c, p0, w, r, a, b, c0, u_c):
    """pi_covariate's recurrence in physical units, with the memory dilating about u_c.

    The one line marked differs from ``pi_covariate``: a held play follows the
    change of the width factor (the wrapper keeps the base's state in its own scaled
    coordinates), where pi_covariate leaves it in place.
    """
    z = np.full(len(r), float(u[0]))
    s_prev = 1.0 + b * (c[0] - c0)
    out = []
    for uk, ck in zip(u, c, strict=True):
        f, s = 1.0 + a * (ck - c0), 1.0 + b * (ck - c0)
        z = u_c + (s / s_prev) * (z - u_c)  # <- the wrapper's memory
        z = np.minimum(np.maximum(z, uk - s * r), uk + s * r)
        out.append(f * (p0 * uk + float(np.dot(w, z))))
        s_prev = s
    return np.array(out)


def test_wrapped_pi_play_on_a_varying_column_is_the_dilating_memory_oracle():
    t, u, c = _irregular()
    cov_pi, th, wrapped, th_w = _pi_pair(3, 0.01, 0.04)
    y = wrapped.simulate(u, t, th_w, covariates={COL: c})
    y_slow = _slow_dilating_pi(u, c, float(th["p0"]), th["w"], th["r"], 0.01, 0.04, 30.0, 75.0)
    np.testing.assert_allclose(y, y_slow, rtol=0, atol=1e-11 * np.abs(y_slow).max())
    # and that is a real difference from pi_covariate (held plays stay put there)
    y_cov = cov_pi.simulate(u, t, th, covariates={COL: c})
    assert np.abs(y - y_cov).max() > 1e-3 * np.ptp(y_cov)


@pytest.mark.parametrize("base", BASES)
def test_without_sensitivity_or_without_the_column_it_is_the_base_exactly(base):
    t, u, c = _irregular(200)
    model = get(f"conditioned({base}, column='{COL}')")
    theta = _theta(model, 4, _record(t, u, c))
    plain = {k: v for k, v in theta.items() if not k.startswith("cond.")}
    y_base = get(base).simulate(u, t, plain)
    flat = theta | {"cond.a": 0.0, "cond.b": 0.0}
    np.testing.assert_array_equal(model.simulate(u, t, flat, covariates={COL: c}), y_base)
    # no column: nominal conditions c = c0, whatever a and b
    hot = theta | {"cond.a": 0.02, "cond.b": 0.05}
    np.testing.assert_array_equal(model.simulate(u, t, hot), y_base)


def test_constant_column_on_maxwell_slip_scales_stiffness_and_slip_deflection():
    # analytic: springs x f (slope), slip deflections x s about u_c (width)
    t, u, _ = _irregular()
    model = get(f"conditioned(maxwell_slip(n_elements=4), column='{COL}')")
    theta = _theta(model, 5, SCALES) | {"cond.a": 0.01, "cond.b": -0.015, "cond.c0": 20.0}
    dc = 12.0
    f, s = 1 + 0.01 * dc, 1 - 0.015 * dc
    y = model.simulate(u, t, theta, covariates={COL: np.full(u.size, 20.0 + dc)})
    ref = get("maxwell_slip(n_elements=4)").simulate(
        u, t, {"k0": f * theta["k0"], "k": f * theta["k"], "delta": s * theta["delta"]})
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("base", ["bouc_wen", "duhem"])
def test_constant_column_is_the_base_loop_magnified_about_its_centre(base):
    # non-homogeneous families: the base driven through (u - u_c) / s, its excursion
    # from y_c magnified by s, then scaled by f -- computed from the base's public API
    t, u, _ = _irregular()
    model = get(f"conditioned({base}, column='{COL}')")
    theta = _theta(model, 6, SCALES) | {"cond.a": -0.008, "cond.b": 0.02, "cond.c0": 25.0}
    dc, u_c = 10.0, float(theta["cond.u_c"])
    f, s = 1 - 0.008 * dc, 1 + 0.02 * dc
    bm = get(base)
    plain = {k: v for k, v in theta.items() if not k.startswith("cond.")}
    y_c = bm.run(np.array([u_c]), np.zeros(1), plain).y[0]
    ref = f * (y_c + s * (bm.simulate(u_c + (u - u_c) / s, t, plain) - y_c))
    y = model.simulate(u, t, theta, covariates={COL: np.full(u.size, 25.0 + dc)})
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_constant_column_on_preisach_is_a_threshold_scaling_about_the_centre():
    # analytic: a relay of thresholds L driven by u_c + (u - u_c)/s is the relay of
    # thresholds u_c + s (L - u_c) driven by u, so the wrapper is preisach with scaled
    # levels, weights x f s and offset f (s offset + (1 - s) y_c)
    t, u, _ = _irregular()
    model = get(f"conditioned(preisach(n_levels=6), column='{COL}')")
    theta = _theta(model, 16, SCALES) | {"cond.a": 0.01, "cond.b": 0.03, "cond.c0": 20.0}
    dc, u_c = 8.0, float(theta["cond.u_c"])
    f, s = 1 + 0.01 * dc, 1 + 0.03 * dc
    plain = {k: v for k, v in theta.items() if not k.startswith("cond.")}
    base = get("preisach(n_levels=6)")
    y_c = float(base.run(np.array([u_c]), np.zeros(1), plain).y[0])
    ref = base.simulate(u, t, {"levels": u_c + s * (theta["levels"] - u_c),
                               "mu": f * s * theta["mu"],
                               "offset": f * (s * theta["offset"] + (1 - s) * y_c)})
    y = model.simulate(u, t, theta, covariates={COL: np.full(u.size, 20.0 + dc)})
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_constant_column_on_bouc_wen_rescales_its_saturation():
    # analytic: with h_phys = s h(v), dh_phys/du = alpha - (beta .. + gamma) s^-n |h_phys|^n,
    # and f y = f k u - f h: Bouc-Wen with k, alpha x f and beta, gamma x f^(1-n) s^-n --
    # the saturated loop's width (alpha / (beta + gamma))^(1/n) scales by s exactly
    t, u, _ = _irregular()
    model = get(f"conditioned(bouc_wen, column='{COL}')")
    theta = _theta(model, 6, SCALES) | {"cond.a": -0.008, "cond.b": 0.02, "cond.c0": 25.0}
    dc, n = 10.0, float(theta["n"])
    f, s = 1 - 0.008 * dc, 1 + 0.02 * dc
    y = model.simulate(u, t, theta, covariates={COL: np.full(u.size, 25.0 + dc)})
    scale = f ** (1 - n) * s ** -n
    ref = get("bouc_wen").simulate(u, t, {"k": f * theta["k"], "alpha": f * theta["alpha"],
                                          "beta": scale * theta["beta"],
                                          "gamma": scale * theta["gamma"], "n": n})
    # two adaptive integrations (steps follow the relaxation length): each within
    # ~3e-8 of the stroke of the exact solution (bouc_wen's docstring)
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-6 * np.ptp(ref))


# ------------------------------------------------------------------ state, batches, failures


@pytest.mark.parametrize("base", BASES)
def test_pieces_and_single_samples_equal_one_run(base):
    model = get(f"conditioned({base}, column='{COL}')")
    t, u, c = _irregular(90)
    theta = _theta(model, 7, _record(t, u, c)) | {"cond.a": 0.01, "cond.b": 0.03}
    whole = model.run(u, t, theta, covariates={COL: c})
    for bounds in ([0, 37, 38, 70, u.size], list(range(u.size + 1))):
        s, ys = None, []
        for lo, hi in itertools.pairwise(bounds):
            tr = model.run(u[lo:hi], t[lo:hi], theta, state0=s, covariates={COL: c[lo:hi]})
            ys.append(tr.y)
            s = tr.state
        # Bouc-Wen re-derives a cached |h|^n at a boundary: equal to rounding there
        np.testing.assert_allclose(np.concatenate(ys), whole.y, rtol=1e-12, atol=0)
        np.testing.assert_allclose(s, whole.state, rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("base", ["bouc_wen", "preisach"])
def test_batched_equals_one_by_one(base):
    model = get(f"conditioned({base}, column='{COL}')")
    t, u, c = _irregular(150)
    data = _record(t, u, c)
    space = model.param_space(data)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(8), 6))
    # walkers 1 and 3 share a width law (one kernel call), and walker 1 fails by its
    # slope factor: walker 3 must still see its own width factor
    thetas["cond.b"][3] = thetas["cond.b"][1]
    thetas["cond.a"][1] = -1.0
    batch = model.run_batch(u, t, thetas, covariates={COL: c})
    assert batch.failed[1] and not batch.failed[3]
    for j in range(6):
        one = {k: v[j] for k, v in thetas.items()}
        if batch.failed[j]:
            continue
        np.testing.assert_array_equal(model.simulate(u, t, one, covariates={COL: c}),
                                      batch.y[j])


def test_prior_draws_never_give_nan_and_bad_factors_are_flagged():
    model = get(f"conditioned(bouc_wen, column='{COL}')")
    t, u, c = _irregular(200)
    data = _record(t, u, c)
    space = model.param_space(data)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(9), 200))
    traj = model.run_batch(u, t, thetas, covariates={COL: c})
    assert np.all(np.isfinite(traj.y[~traj.failed]))
    dc = c[None, :] - thetas["cond.c0"][:, None]
    bad = (np.any(1 + thetas["cond.a"][:, None] * dc <= 0, axis=1)
           | np.any(1 + thetas["cond.b"][:, None] * dc <= 0, axis=1))
    assert np.all(traj.failed[bad])
    # a slope factor and a width factor that reach 0 exactly, and one below: failed, no
    # division by zero (numpy would warn; warnings are errors here)
    c0 = float(thetas["cond.c0"][0])
    col = np.full(u.size, c0 + 10.0)
    one = {k: v[:1] for k, v in thetas.items()}
    with np.errstate(all="raise"):
        for key, value in (("cond.a", -0.1), ("cond.b", -0.1), ("cond.b", -0.3)):
            tr = model.run_batch(u, t, one | {key: np.array([value]),
                                              "cond.c0": np.array([c0])},
                                 covariates={COL: col})
            assert tr.failed[0], (key, value)


# ------------------------------------------------------------------ linear design, inverse


@pytest.mark.parametrize("spec", ["conditioned(pi_play)", "conditioned(bouc_wen)",
                                  "conditioned(preisach)", "conditioned(pi_play)+creep"])
def test_the_base_linear_group_stays_linear_under_the_column(spec):
    # oracle: the model's own simulation at the parameters' values
    model = get(spec)
    base = model.base.base if "+" in spec else model.base
    prefix = "static." if "+" in spec else ""
    assert model.linear_params == tuple(prefix + n for n in base.linear_params)
    t, u, c = _irregular(150)
    data = _record(t, u, c)
    space = model.param_space(data)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(10), 3))
    thetas[f"{prefix}cond.b"] = np.abs(thetas[f"{prefix}cond.b"])  # keep s > 0 here
    design = model.linear_design(u, t, thetas, covariates={COL: c})
    beta = np.concatenate([thetas[n].reshape(3, -1) for n in model.linear_params], axis=1)
    y = model.run_batch(u, t, thetas, covariates={COL: c}).y
    ok = ~design.failed
    np.testing.assert_allclose(design.predict(beta)[ok], y[ok], rtol=0,
                               atol=1e-9 * np.abs(y[ok]).max())


def test_inverse_designs_for_nominal_conditions():
    model = get(f"conditioned(pi_play(n_operators={N_OP}), column='{COL}')")
    t = np.arange(300) / 2000.0
    u = 75.0 - 60.0 * np.cos(2 * np.pi * 10.0 * t)
    theta = _batched(_theta(model, 11, SCALES) | {"p0": 0.2, "w": np.full(N_OP, 0.05),
                                                  "cond.a": 0.01, "cond.b": 0.03,
                                                  "cond.c0": 25.0})
    y_d = model.run_batch(u, t, theta).y[0]
    inv = invert(model, y_d, t, theta, u_limits=(-100.0, 250.0))
    np.testing.assert_allclose(inv.u, u, atol=1e-6 * 150)
    hot = model.run_batch(inv.u, t, theta, covariates={COL: np.full(u.size, 35.0)}).y[0]
    assert np.abs(hot - y_d).max() > 0.05 * np.ptp(y_d)  # off-nominal: the command misses


# ------------------------------------------------------------------ spec, names, errors


@pytest.mark.parametrize("spec", [
    "conditioned(bouc_wen)",
    "conditioned(bouc_wen, column='load_n')",
    "conditioned(preisach(n_levels=6), column='temperature_c')+creep",
    "conditioned(duhem, column='t_k')+second_order+creep",
    "conditioned('maxwell_slip(n_elements=3)', column='x')",
])
def test_spec_round_trip(spec):
    model = get(spec)
    assert get(model_spec(model)) == model
    assert model_spec(get(model_spec(model))) == model_spec(model)


def test_spec_forms_name_the_same_model():
    a = get("conditioned(preisach(n_levels=6), column='load_n')")
    assert a == get("conditioned", base="preisach(n_levels=6)", column="load_n")
    assert a == get("conditioned(base='preisach(n_levels=6)', column='load_n')")
    assert a == Conditioned(get("preisach", n_levels=6), column="load_n")
    assert a.name == "conditioned(preisach, column='load_n')"
    assert a.covariates == ("load_n",)
    comp = get("conditioned(bouc_wen, column='load_n')+creep")
    assert comp.name == "conditioned(bouc_wen, column='load_n')+creep"
    assert comp.covariates == ("load_n",)
    names = comp.param_space().all_names
    assert "static.cond.a" in names and "static.k" in names and "creep.c" in names


@pytest.mark.parametrize(("spec", "match"), [
    ("conditioned(bouc_wen+creep, column='t')", r"composite.*conditioned\(bouc_wen, col"),
    ("conditioned(bouc_wen, column='t'", "cannot read"),
    ("conditioned(bouc_wen, preisach)", "one base model"),
    ("conditioned(bouc_wen, base='preisach')", "one base model"),
    ("conditioned(3, column='t')", "only a wrapper's base model"),
    ("conditioned(no_such_model)", "unknown model 'no_such_model'"),
    ("pi_play(bouc_wen)", "only a wrapper such as 'conditioned'"),
    ("bouc_wen+creep(bouc_wen)", "block 'creep' must be given by name"),
    ("conditioned(pi_covariate)", "already reads the measured column"),
    ("conditioned(bouc_wen_freq)", "rate-dependent"),
    ("conditioned(bouc_wen, column='a=b')", "column must name a data column"),
    ("conditioned(bouc_wen, colum='t')", "no setting"),
])
def test_bad_specs_are_refused_in_words(spec, match):
    with pytest.raises(ModelError, match=match):
        get(spec)


def test_a_composite_base_is_refused_with_the_spec_to_write():
    with pytest.raises(ModelError, match=r"conditioned\(bouc_wen, column=...\)\+"):
        Conditioned(get("bouc_wen+creep"))


def test_the_column_is_named_when_missing():
    model = get("conditioned(bouc_wen, column='load_n')")
    t, u, c = _irregular(100)
    with pytest.raises(ModelError, match="load_n"):
        model.run(u, t, _theta(model, 12), covariates={COL: c})
    with pytest.raises(DataError, match="load_n"):
        Posterior(_record(t, u, c), model)


def test_a_composite_starts_at_rest_under_the_column():
    # constant input, constant column away from c0: the composite's creep block rests
    # at the conditioned base's output at the first sample, so nothing moves
    model = get(f"conditioned(bouc_wen, column='{COL}')+creep")
    t = np.arange(100) * 1e-3
    u = np.full(100, 120.0)
    theta = _theta(model, 13, SCALES) | {"static.cond.a": 0.01, "static.cond.b": 0.05,
                                         "static.cond.c0": 20.0}
    y = model.simulate(u, t, theta, covariates={COL: np.full(100, 30.0)})
    np.testing.assert_allclose(y, y[0], rtol=0, atol=1e-12 * abs(y[0]))


def test_posterior_evaluates_through_the_spec():
    t, u, c = _irregular(200)
    post = Posterior(_record(t, u, c), f"conditioned(bouc_wen, column='{COL}')+creep")
    z = post.space.sample_prior(np.random.default_rng(14), 64)
    lp = post.log_prob_batch(z)
    assert not np.any(np.isnan(lp)) and np.any(np.isfinite(lp))


def test_cli_fit_with_a_conditioned_spec_saves_a_fit_that_reloads(tmp_path):
    # the CLI's --model, the file's extra column, and the saved fit's model_spec round trip
    from bayeshyst.cli import main
    from bayeshyst.inference.saved import load_fit

    t, u, c = _irregular(400, seed=3)
    spec = f"conditioned(pi_play(n_operators=2), column='{COL}')+creep"
    truth_model = get(spec)
    theta = _theta(truth_model, 15, _record(t, u, c)) | {"static.cond.a": 0.01,
                                                         "static.cond.b": 0.02}
    y = truth_model.simulate(u, t, theta, covariates={COL: c})
    y = y + np.random.default_rng(0).normal(0.0, 0.01 * np.ptp(y), u.size)
    csv = tmp_path / "d.csv"
    np.savetxt(csv, np.column_stack([t, u, y, c]), delimiter=",",
               header=f"t,u,y,{COL}", comments="")
    out = tmp_path / "fit"
    assert main(["fit", str(csv), "--model", spec, "--steps", "300", "--no-figures",
                 "--no-calibration", "--quiet", "--out", str(out)]) == 0
    fit = load_fit(out)
    assert fit.model == truth_model
    assert fit.to_dict()["model"] == model_spec(truth_model)
    (rec,) = fit.data
    np.testing.assert_array_equal(rec.covariates[COL], c)
    z = fit.draws(10, seed=1)
    fresh = Posterior(rec, spec)
    np.testing.assert_allclose(fit.posterior.log_prob_batch(z), fresh.log_prob_batch(z),
                               rtol=0, atol=1e-9)


# ------------------------------------------------------------------ recovery

BW_TRUTH = {"k": 0.3, "alpha": 0.12, "beta": 0.004, "gamma": 0.001, "n": 1.3}
SPEC = f"conditioned(bouc_wen, column='{COL}')"


def _bw_ramp_record(seed: int, n: int = 1200, sigma: float = 0.05) -> tuple[Record, dict]:
    """Bouc-Wen data over a temperature ramp 20 -> 40 °C, with the fitted space's truth."""
    t = np.arange(n) * 1e-3
    u = 75.0 - 75.0 * np.cos(2 * np.pi * t / 0.5)
    temp = np.linspace(20.0, 40.0, n)
    model = get(SPEC)
    truth = BW_TRUTH | {"cond.a": 0.004, "cond.b": 0.008, "cond.c0": float(np.mean(temp)),
                        "cond.u_c": 75.0}
    y = model.simulate(u, t, truth, covariates={COL: temp})
    y = y + np.random.default_rng(seed).normal(0.0, sigma, n)
    rec = Record(t=t, u=u, y=y, name=f"bw{seed}", warmup=250, covariates={COL: temp})
    free = {k: v for k, v in truth.items() if k not in ("cond.c0", "cond.u_c")}
    return rec, free | {"obs.offset": 0.0, "noise.sigma": sigma}


def _ramp_fits(seeds) -> tuple[list[float], dict[str, list[bool]], int]:
    """Per fit: the truth's squared Mahalanobis distance in the sampler's coordinates
    and whether each parameter's 90 % HDI covers it; and the dimension."""
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings

    d2, hits, ndim = [], {}, 0
    for seed in seeds:
        rec, truth = _bw_ramp_record(seed)
        post = Posterior(rec, SPEC)
        ndim = post.ndim
        res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000, n_walkers=20))
        assert res.converged, res.convergence
        z = res.flat_z
        d = post.space.pack(truth) - z.mean(axis=0)
        d2.append(float(d @ np.linalg.solve(np.cov(z.T), d)))
        summ = {s.label: s for s in res.summary(0.9)}
        for k, v in truth.items():
            hits.setdefault(k, []).append(bool(summ[k].hdi_lo <= v <= summ[k].hdi_hi))
    return d2, hits, ndim


def test_bouc_wen_on_a_temperature_ramp_one_fit_is_calibrated():
    # one fit: the truth's squared Mahalanobis distance ~ chi2(d), two-sided 0.1 %
    from scipy import stats

    (d2,), _, ndim = _ramp_fits([0])
    p = stats.chi2.sf(d2, ndim)
    assert 1e-3 / 2 < p < 1 - 1e-3 / 2, (d2, ndim, p)


@pytest.mark.slow
def test_bouc_wen_on_a_temperature_ramp_recovers_slope_and_width_laws():
    # oracle: the truth that simulated the data. Over 20 independent noise draws: the
    # sum of the Mahalanobis distances against chi2(S d) at a two-sided 0.1 % level
    # (fails over- and underconfident posteriors), and every parameter's 90 % HDI --
    # cond.a and cond.b included -- covers the truth at the nominal rate (binomial,
    # Bonferroni over the parameters at 0.1 %)
    from scipy import stats

    seeds = range(1, 21)
    d2, hits, ndim = _ramp_fits(seeds)
    p = stats.chi2.sf(sum(d2), ndim * len(seeds))
    print(f"Mahalanobis^2 {np.round(d2, 1)} on {ndim} dof each: p = {p:.3f}; covered: "
          + ", ".join(f"{k} {sum(v)}/{len(v)}" for k, v in hits.items()))
    assert 1e-3 / 2 < p < 1 - 1e-3 / 2, (d2, p)
    for k, v in hits.items():
        assert stats.binomtest(sum(v), len(v), 0.9).pvalue > 1e-3 / len(hits), (k, v)


def test_bad_settings_are_refused_in_words():
    with pytest.raises(ModelError, match="base must be a hysteresis model"):
        Conditioned(base=3)
    with pytest.raises(ModelError, match="column must name a data column"):
        Conditioned(column=5)
    with pytest.raises(ModelError, match=r"already reads the measured column.*load_n"):
        Conditioned(CovariatePI(3, column="load_n"))
    with pytest.raises(ModelError, match="already reads"):
        Conditioned(Conditioned())  # one column per wrapper: its names are cond.*


def test_flags_follow_the_base_and_the_class_reads_as_registered():
    assert Conditioned.name == "conditioned" and isinstance(Conditioned.equation, str)
    assert Conditioned.monotone_in_input is True
    relay = Conditioned(get("preisach_clockwise"))
    assert relay.monotone_in_input is False  # a compensator's relay grid stays one
    assert Conditioned(get("preisach")).has_output_offset is True
    assert Conditioned(get("bouc_wen")).has_output_offset is False
    assert get("conditioned").equation == "review Eq. 47-48 (the base's), slope and width " \
                                          "of a measured column (§3)"
