"""The smooth term for structure no physical block explains (``unexplained``).

Oracles: the block's equation written out here with explicit sums; the squared-
exponential kernel its reduced-rank prior approximates; one call against the same record
applied in pieces; a slow change in time recovered by the MAP of a posterior.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayeshyst.data.record import Record
from bayeshyst.errors import ModelError
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get as get_model
from bayeshyst.models.blocks import Unexplained
from bayeshyst.models.blocks.smooth import log_se_spectrum, sine_basis

L = 2.5


def _slow_output(w, x, ref, half, a, b, span, m, length):
    """``(1 + g) w + h`` with every sum written out (the block's docstring)."""
    out = np.empty_like(w)
    for n in range(w.size):
        z = (x[n] - ref) / half
        g = h = 0.0
        for j in range(1, m + 1):
            wj = math.pi * j / (2 * L)
            s = math.sqrt(math.sqrt(2 * math.pi) * length * math.exp(-0.5 * (length * wj) ** 2))
            phi = math.sin(wj * (z + L)) / math.sqrt(L)
            g += 0.05 * s * phi * a[j - 1]
            h += 0.05 * span * s * phi * b[j - 1]
        out[n] = (1 + g) * w[n] + h
    return out


def _theta(block, rng, ref, half, span):
    m = block.n_basis
    return {"a": rng.standard_normal(m), "b": rng.standard_normal(m), "x_ref": ref,
            "x_half": half, "y_span": span}


@pytest.mark.parametrize("n_basis", [6, 9])
def test_time_feature_matches_the_written_out_equation(n_basis):
    rng = np.random.default_rng(n_basis)
    blk = Unexplained(feature="time", n_basis=n_basis)
    t = 10.0 + np.arange(400) / 100.0  # the record starts at 10 s: time counts from there
    w = np.sin(t) * 3 + 1
    th = _theta(blk, rng, 2.0, 2.0, 5.0)
    got = blk.apply(w, t, th).y
    want = _slow_output(w, t - t[0], 2.0, 2.0, th["a"], th["b"], 5.0, n_basis, blk.length)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shared", [True, False])
def test_a_batch_of_walkers_matches_the_written_out_equation_row_by_row(shared):
    # walkers that share the feature's scaling take the one-basis path, walkers with
    # their own scaling the per-walker path: both against the explicit sums
    rng = np.random.default_rng(7)
    blk = Unexplained(feature="time")
    t = 1.0 + np.arange(300) / 50.0
    w = rng.standard_normal((4, 300)).cumsum(axis=1)
    refs = np.full(4, 3.0) if shared else np.array([3.0, 2.0, 4.0, 3.5])
    halfs = np.full(4, 3.0) if shared else np.array([3.0, 2.5, 4.0, 1.5])
    th = {"a": rng.standard_normal((4, 6)), "b": rng.standard_normal((4, 6)),
          "x_ref": refs, "x_half": halfs, "y_span": np.full(4, 2.0)}
    got = blk.apply_batch(w, t, th).y
    for i in range(4):
        want = _slow_output(w[i], t - t[0], refs[i], halfs[i], th["a"][i], th["b"][i], 2.0,
                            6, blk.length)
        np.testing.assert_allclose(got[i], want, rtol=1e-12, atol=1e-12)


def test_a_column_feature_reads_the_column_and_is_the_identity_without_it():
    rng = np.random.default_rng(1)
    blk = Unexplained(feature="load_n")
    t = np.arange(300) / 100.0
    load = 10 + rng.standard_normal(300)
    w = np.cos(t)
    th = _theta(blk, rng, 10.0, 3.0, 2.0)
    got = blk.apply(w, t, th, covariates={"load_n": load}).y
    want = _slow_output(w, load, 10.0, 3.0, th["a"], th["b"], 2.0, 6, blk.length)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(blk.apply(w, t, th).y, w)
    assert blk.covariates == ("load_n",) and Unexplained().covariates == ()


@pytest.mark.parametrize("case", ["time", "column", "nominal", "own_scaling"])
def test_the_closed_form_design_is_the_written_out_equation_in_a_and_b(case):
    # the block's output is affine in (a, b): column j of the design is the written-out
    # output with a unit coefficient j minus the output with none, the constant the
    # latter (the composite's generic path applies the block that way, P + 1 times)
    rng = np.random.default_rng(11)
    feature = "time" if case in ("time", "own_scaling") else "load_n"
    blk = Unexplained(feature=feature, n_basis=7)
    n, width, m = 250, 3, 7
    t = 2.0 + np.arange(n) / 80.0
    load = 5 + rng.standard_normal(n)
    w = rng.standard_normal((width, n)).cumsum(axis=1)
    refs = np.array([1.5, 1.0, 2.0]) if case == "own_scaling" else np.full(width, 1.5)
    halfs = np.array([1.5, 0.7, 2.5]) if case == "own_scaling" else np.full(width, 1.5)
    spans = np.array([2.0, 3.0, 0.5])
    rest = {"x_ref": refs, "x_half": halfs, "y_span": spans}
    cov = None if case == "nominal" else {"load_n": load}
    phi, const, failed = blk._linear_columns(w, t, rest, ("b", "a"), cov)
    assert phi.shape == (width, n, 2 * m) and not failed.any()
    x = t - t[0] if feature == "time" else load
    zero = np.zeros(m)
    for i in range(width):
        def out(a, b, i=i):
            if case == "nominal":  # no column: the identity
                return w[i].copy()
            return _slow_output(w[i], x, refs[i], halfs[i], a, b, spans[i], m, blk.length)
        base = out(zero, zero)
        np.testing.assert_allclose(const[i], base, rtol=0, atol=1e-12)
        for j in range(m):
            e = np.eye(m)[j]
            # the order asked for: b's columns first, then a's
            np.testing.assert_allclose(phi[i, :, j], out(zero, e) - base, atol=1e-12)
            np.testing.assert_allclose(phi[i, :, m + j], out(e, zero) - base, atol=1e-12)
    # one of the two held fixed: the generic path (None)
    assert blk._linear_columns(w, t, rest, ("a",), cov) is None


def test_pieces_give_the_same_output_as_one_call():
    rng = np.random.default_rng(2)
    blk = Unexplained()
    t = 3.0 + np.arange(500) / 200.0
    w = rng.standard_normal(500)
    th = _theta(blk, rng, 1.25, 1.25, 4.0)
    whole = blk.apply(w, t, th)
    first = blk.apply(w[:123], t[:123], th)
    rest = blk.apply(w[123:], t[123:], th, state0=first.state)
    np.testing.assert_allclose(np.concatenate([first.y, rest.y]), whole.y, rtol=0, atol=0)


@pytest.mark.parametrize("n_basis", [6, 12, 20])
def test_the_reduced_rank_prior_is_the_squared_exponential_kernel(n_basis):
    # Riutort-Mayol et al. 2023: with length >= 1.75 L / m and L >= 3.2 length (so
    # m >= 6 at L = 2.5, the block's minimum) the approximation holds to about 1 % of
    # the variance over the data's [-1, 1]
    blk = Unexplained(n_basis=n_basis)
    z = np.linspace(-1, 1, 41)
    phi, w = sine_basis(z, n_basis)
    k = (phi * np.exp(log_se_spectrum(w, blk.length))[0]) @ phi.T
    exact = np.exp(-0.5 * (z[:, None] - z[None, :]) ** 2 / blk.length ** 2)
    assert np.abs(k - exact).max() < 0.02


def test_bad_settings_are_refused_by_name():
    with pytest.raises(ModelError, match="feature"):
        Unexplained(feature="a=b")
    with pytest.raises(ModelError, match="n_basis"):
        Unexplained(n_basis=5)  # its length would be too long for the basis domain


def test_a_slow_change_in_time_is_recovered():
    # a 3-operator PI whose offset wanders as a half sine over the record (0.2 um, 0.7 %
    # of the stroke) and whose gain falls by 2 %: the MAP's term follows both
    base = get_model("pi_play(n_operators=3)")
    t = np.arange(4000) / 1000.0
    u = 75.0 + 75.0 * np.sin(2 * np.pi * 2.0 * t - np.pi / 2)
    proto = Record(t, u, u.copy())
    theta = {**base.param_space(proto).fixed, "p0": 0.1, "w": np.array([0.03, 0.02, 0.01])}
    w = base.simulate(u, t, theta)
    wander = 0.2 * np.sin(np.pi * t / t[-1])
    gain = -0.02 * t / t[-1]
    y = w * (1 + gain) + wander + 0.003 * np.random.default_rng(0).standard_normal(t.size)
    post = Posterior(Record(t, u, y), "pi_play(n_operators=3)+unexplained")
    theta = post.space.unpack(find_map(post, seed=0).z)
    pred = post.model.simulate(u, t, {k: v for k, v in theta.items()
                                      if k.startswith(("static.", "unexplained."))})
    # what is left is the noise: the term took the wander and the gain change
    assert np.std(y - pred) < 1.5 * 0.003


def test_the_sampler_draws_the_coefficients_from_their_conjugate_posterior():
    # Bouc-Wen held at its true values and the noise known: the coefficients and the
    # offset are a Bayesian linear regression on the block's written-out columns, whose
    # Gaussian posterior is computed here densely; the sampler draws them as the
    # composite's linear group (exact Gibbs), so its moments must match
    rng = np.random.default_rng(3)
    t = np.arange(2000) / 1000.0
    u = 75.0 + 75.0 * np.sin(2 * np.pi * 2.0 * t - np.pi / 2)
    truth = {"k": 0.2, "alpha": 0.5, "beta": 0.01, "gamma": 0.005, "n": 1.0}
    w = get_model("bouc_wen").simulate(u, t, truth)
    sigma = 0.05
    y = w * (1 - 0.02 * t / t[-1]) + 0.3 * np.sin(np.pi * t / t[-1]) + 0.4 \
        + sigma * rng.standard_normal(t.size)
    post = Posterior(Record(t, u, y), "bouc_wen+unexplained").fix("noise.sigma", sigma)
    for name, value in truth.items():
        post = post.fix(f"static.{name}", value)
    assert post.model.linear_params == ("unexplained.a", "unexplained.b")
    fixed = post.space.fixed
    ref, half, span = (fixed[f"unexplained.{k}"] for k in ("x_ref", "x_half", "y_span"))
    m, length = 6, Unexplained().length
    cols = []
    for j in range(m):  # the columns of a_j, then b_j, then the offset: the slow equation
        e = np.zeros(m)
        e[j] = 1.0
        cols.append(_slow_output(w, t - t[0], ref, half, e, np.zeros(m), span, m, length)
                    - w)
    for j in range(m):
        e = np.zeros(m)
        e[j] = 1.0
        cols.append(_slow_output(w, t - t[0], ref, half, np.zeros(m), e, span, m, length)
                    - w)
    x = np.column_stack([*cols, np.ones(t.size)])
    off = post.space["obs.offset"].prior
    m0 = np.r_[np.zeros(2 * m), off.mu]
    s0 = np.r_[np.ones(2 * m), off.sigma]
    prec = np.diag(s0 ** -2.0) + x.T @ x / sigma ** 2
    cov = np.linalg.inv(prec)
    mean = cov @ (m0 / s0 ** 2 + x.T @ (y - w) / sigma ** 2)
    res = sample_posterior(post, SamplerSettings(seed=5, max_steps=3000))
    draws = res.draws(2000, seed=1)
    sd = np.sqrt(np.diag(cov))
    # exact Gibbs draws of a Gaussian are nearly independent: 2 000 draws, 5 se
    np.testing.assert_array_less(np.abs(draws.mean(axis=0) - mean), 5 * sd / math.sqrt(500))
    np.testing.assert_allclose(draws.std(axis=0, ddof=1), sd, rtol=0.15)
