"""The linear algebra of the residual score tests (bayeshyst.diagnosis.stats).

Oracles: an independent OLS implementation of the nested-model F test (explicit design
matrices, ``np.linalg.lstsq``, Frisch–Waugh and the partitioned inverse for the
coefficients and their covariance); the exact F null distribution (uniform p-values
for a linear model with Gaussian errors) and binomial bounds on rejection rates; the
known parameters of simulated AR processes (asymptotic standard errors); a direct
per-segment filter loop; a brute-force Holm step-down procedure; and the geometry of
orthogonal projections.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal, stats

from bayeshyst.diagnosis.stats import (
    f_test,
    fit_ar,
    holm,
    lag_test,
    orthonormal_basis,
    project_out,
    whiten,
)


# ----------------------------------------------------------------------- helpers
def _ols_rss(d: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    beta = np.linalg.lstsq(d, y, rcond=None)[0]
    res = y - d @ beta
    return beta, float(res @ res)


def _reference_f(y: np.ndarray, z: np.ndarray, x: np.ndarray):
    """Full vs restricted OLS on explicit designs (full rank assumed)."""
    n, q = z.shape
    k = x.shape[1]
    d = np.column_stack([z, x])
    _, rss0 = _ols_rss(z, y)
    beta, rss1 = _ols_rss(d, y)
    df2 = n - q - k
    stat = ((rss0 - rss1) / k) / (rss1 / df2)
    s2 = rss1 / df2
    cov_full = s2 * np.linalg.inv(d.T @ d)
    return {"stat": stat, "df1": k, "df2": df2, "p": stats.f.sf(stat, k, df2),
            "coef": beta[q:], "cov": cov_full[q:, q:], "rss0": rss0, "rss1": rss1}


def _binomial_band(p: float, reps: int, n_sd: float = 3.0) -> tuple[float, float]:
    sd = math.sqrt(p * (1 - p) / reps)
    return p - n_sd * sd, p + n_sd * sd


def _design(rng: np.random.Generator, n: int) -> np.ndarray:
    """Nuisance columns: a constant, a trend and a slow sine (like a fit's sensitivities)."""
    s = np.linspace(0.0, 1.0, n)
    return np.column_stack([np.ones(n), s, np.sin(2 * np.pi * 1.7 * s + rng.uniform(0, 1))])


def _ar1(rng: np.random.Generator, n: int, phi: float, burn: int = 500) -> np.ndarray:
    a = rng.standard_normal(n + burn)
    return signal.lfilter([1.0], [1.0, -phi], a)[burn:]


# ------------------------------------------------------------------------ f_test
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_f_test_equals_nested_ols_reference(seed):
    rng = np.random.default_rng(seed)
    n = 200
    z = _design(rng, n)
    # columns on very different scales: orthonormal_basis rescales, the answer must not
    x = rng.standard_normal((n, 3)) * np.array([1e-3, 1.0, 1e3]) + 0.3 * z[:, [1]]
    y = z @ np.array([1.0, -2.0, 0.5]) + x @ np.array([40.0, 0.1, 1e-5]) \
        + rng.standard_normal(n)
    t = f_test(y, z, x)
    ref = _reference_f(y, z, x)
    assert (t.df1, t.df2, t.n) == (ref["df1"], ref["df2"], n)
    np.testing.assert_allclose(t.statistic, ref["stat"], rtol=1e-9)
    np.testing.assert_allclose(t.p_value, ref["p"], rtol=1e-7, atol=1e-300)
    # Frisch–Waugh: the X coefficients of the full regression
    np.testing.assert_allclose(t.coef, ref["coef"], rtol=1e-8)
    # partitioned inverse: the X block of s^2 (D'D)^-1
    np.testing.assert_allclose(t.cov, ref["cov"], rtol=1e-7)
    np.testing.assert_allclose(t.partial_r2, 1 - ref["rss1"] / ref["rss0"], rtol=1e-9)
    lbf = 0.5 * (n * math.log(ref["rss0"] / ref["rss1"]) - ref["df1"] * math.log(n))
    np.testing.assert_allclose(t.log_bayes_factor, lbf, rtol=1e-9)


def test_f_test_counts_a_duplicated_column_of_x_once():
    rng = np.random.default_rng(7)
    n = 150
    z = _design(rng, n)
    x_new = rng.standard_normal(n)
    x = np.column_stack([x_new, -3.0 * x_new])
    y = z @ np.array([0.5, 1.0, 2.0]) + 0.7 * x_new + rng.standard_normal(n)
    t = f_test(y, z, x)
    ref = _reference_f(y, z, x_new[:, None])
    assert t.df1 == 1 and t.df2 == n - 3 - 1
    np.testing.assert_allclose(t.statistic, ref["stat"], rtol=1e-9)
    np.testing.assert_allclose(t.p_value, ref["p"], rtol=1e-7)
    # minimum-norm coefficients: ref = c0 - 3 c1 with c proportional to (1, -3)
    np.testing.assert_allclose(t.coef, ref["coef"][0] * np.array([1.0, -3.0]) / 10.0,
                               rtol=1e-8)


def test_f_test_ignores_a_column_of_x_inside_the_span_of_z():
    rng = np.random.default_rng(7)
    n = 150
    z = _design(rng, n)
    y = z @ np.array([0.5, 1.0, 2.0]) + rng.standard_normal(n)
    # X adds nothing beyond Z: no rank, no statistic (FTest's documented df1 = rank
    # added beyond Z)
    t = f_test(y, z, (z @ np.array([1.0, 2.0, -1.0]))[:, None])
    assert t.df1 == 0 and t.p_value == 1.0
    # and next to a genuinely new column it changes nothing
    x_new = rng.standard_normal(n)
    both = f_test(y, z, np.column_stack([x_new, z @ np.array([1.0, 2.0, -1.0])]))
    np.testing.assert_allclose(both.statistic, f_test(y, z, x_new[:, None]).statistic,
                               rtol=1e-9)


def test_f_test_p_values_are_uniform_under_the_null():
    # exact F(k, n-q-k) null: p ~ U(0, 1). 400 reps: sd of the rejection fraction at
    # 0.05 is sqrt(0.05 * 0.95 / 400) = 0.0109, so the 3-sd band is [0.0173, 0.0827].
    rng = np.random.default_rng(2024)
    n, reps = 120, 400
    p = np.empty(reps)
    for i in range(reps):
        z = _design(rng, n)
        x = rng.standard_normal((n, 2))
        y = z @ rng.standard_normal(3) + rng.standard_normal(n)
        p[i] = f_test(y, z, x).p_value
    assert stats.kstest(p, "uniform").pvalue > 1e-3
    lo, hi = _binomial_band(0.05, reps)
    assert lo <= np.mean(p < 0.05) <= hi


def _ar_null_pvalues(seed: int, reps: int, n: int, whitened: bool) -> np.ndarray:
    """y = Z g + AR(1, 0.8) noise, X two independent random walks (smooth): no effect."""
    rng = np.random.default_rng(seed)
    half = n // 2
    segs = [(0, half), (half, n)]
    out = np.empty(reps)
    for i in range(reps):
        z = _design(rng, n)
        x = np.cumsum(rng.standard_normal((n, 2)), axis=0)
        e = np.concatenate([_ar1(rng, half, 0.8), _ar1(rng, n - half, 0.8)])
        y = z @ rng.standard_normal(3) + e
        if not whitened:
            out[i] = f_test(y, z, x).p_value
            continue
        # as analyse_residual: AR(p) of the widest regression's residual, then filter
        wide = np.column_stack([z, x])
        resid = y - wide @ np.linalg.lstsq(wide, y, rcond=None)[0]
        ar = fit_ar(resid, segs, max_order=4)
        out[i] = f_test(whiten(y, segs, ar.phi), whiten(z, segs, ar.phi),
                        whiten(x, segs, ar.phi)).p_value
    return out


def test_serial_correlation_breaks_the_plain_test_and_whitening_restores_it():
    # n = 2000: feasible GLS is only asymptotically exact; at n = 600 its size with
    # random-walk regressors is about 0.068 (2000 simulated replications), at n = 2000
    # about 0.047, indistinguishable from 0.05
    reps, n = 400, 2000
    raw = _ar_null_pvalues(11, reps, n, whitened=False)
    # spurious regression: smooth X and AR(1, 0.8) errors inflate F by roughly
    # (1 + 0.8) / (1 - 0.8) = 9, far beyond the nominal 5 %
    assert np.mean(raw < 0.05) > 0.20
    white = _ar_null_pvalues(11, reps, n, whitened=True)
    lo, hi = _binomial_band(0.05, reps)  # [0.0173, 0.0827], see the uniform test
    assert lo <= np.mean(white < 0.05) <= hi


def test_f_test_detects_a_real_effect_and_estimates_it():
    rng = np.random.default_rng(5)
    n = 800
    z = _design(rng, n)
    x = rng.standard_normal((n, 2))
    beta = np.array([1.0, -0.6])
    y = z @ np.array([2.0, -1.0, 0.5]) + 0.3 * x @ beta + rng.standard_normal(n)
    t = f_test(y, z, x)
    assert t.p_value < 1e-6 and t.log_bayes_factor > 0
    se = np.sqrt(np.diag(t.cov))
    # true coefficients 0.3 beta; |z| > 4 has probability 6e-5 per coefficient
    assert np.all(np.abs(t.coef - 0.3 * beta) < 4 * se)


# ------------------------------------------------------------------------ fit_ar
def test_fit_ar_recovers_an_ar2():
    phi = np.array([0.6, -0.3])
    n = 20000
    rng = np.random.default_rng(3)
    e = signal.lfilter([1.0], [1.0, -phi[0], -phi[1]], rng.standard_normal(n + 1000))[1000:]
    fit = fit_ar(e, [(0, n)], max_order=6)
    assert fit.order == 2 and fit.bic.shape == (7,)
    assert int(np.argmin(fit.bic)) == 2
    # asymptotic sd of each AR(2) coefficient: sqrt((1 - phi2^2) / n) = 0.0067
    se = math.sqrt((1 - phi[1] ** 2) / n)
    assert np.all(np.abs(fit.phi - phi) < 3 * se)
    # innovation sd 1; its sampling sd is about 1 / sqrt(2 n) = 0.005
    assert abs(fit.sigma - 1.0) < 3 / math.sqrt(2 * n)


def test_fit_ar_picks_order_zero_for_white_noise():
    # BIC penalises an extra lag by log(n) = 8.5 against chi2_1 gains: each spurious
    # order wins with probability < P(chi2_1 > 8.5) = 0.0035, so with 5 orders the
    # chance of any is < 0.018 per series; P(more than 5 of 50 series wrong) < 1e-4.
    picks = []
    for seed in range(50):
        e = np.random.default_rng(seed).standard_normal(5000)
        picks.append(fit_ar(e, [(0, 2500), (2500, 5000)], max_order=5).order)
    assert np.mean(np.array(picks) == 0) >= 0.9


def test_fit_ar_uses_only_lags_inside_each_segment():
    rng = np.random.default_rng(9)
    n1, n2, p = 700, 500, 3
    # two independent AR(1) records at very different levels: a lag across the seam
    # would see a jump of 100
    e = np.concatenate([_ar1(rng, n1, 0.5) + 50.0, _ar1(rng, n2, 0.5) - 50.0])
    segs = [(0, n1), (n1, n1 + n2)]
    fit = fit_ar(e, segs, max_order=p)
    # reference: OLS on rows that have p predecessors in their own segment
    ys, xs = [], []
    for a, b in segs:
        for t in range(a + p, b):
            ys.append(e[t])
            xs.append([e[t - i] for i in range(1, p + 1)])
    ys, xs = np.array(ys), np.array(xs)
    m = ys.size
    bic = []
    for k in range(p + 1):
        rss = (_ols_rss(xs[:, :k], ys)[1] if k else float(ys @ ys))
        bic.append(m * math.log(rss / m) + k * math.log(m))
    np.testing.assert_allclose(fit.bic, bic, rtol=1e-10)
    k = int(np.argmin(bic))
    assert fit.order == k
    if k:
        np.testing.assert_allclose(fit.phi, _ols_rss(xs[:, :k], ys)[0], rtol=1e-10)
    # the same data treated as one segment gives a different fit (the seam enters)
    assert not np.allclose(fit_ar(e, [(0, n1 + n2)], max_order=p).bic, bic)


def test_fit_ar_refuses_too_few_samples():
    with pytest.raises(ValueError, match="AR\\(5\\)"):
        fit_ar(np.ones(40), [(0, 40)], max_order=5)


def test_whiten_filters_each_segment_separately():
    rng = np.random.default_rng(4)
    n1, n2 = 37, 51
    a = rng.standard_normal((n1 + n2, 2))
    phi = np.array([0.7, -0.2, 0.1])
    p = phi.size
    segs = [(0, n1), (n1, n1 + n2)]
    out = whiten(a, segs, phi)
    assert out.shape == (n1 + n2 - p * 2, 2)
    rows = []
    for s0, s1 in segs:
        for t in range(s0 + p, s1):
            rows.append(a[t] - sum(phi[i] * a[t - 1 - i] for i in range(p)))
    np.testing.assert_allclose(out, np.array(rows), rtol=1e-13, atol=1e-14)
    # 1-D input follows the same rows; empty phi leaves everything in place
    np.testing.assert_allclose(whiten(a[:, 0], segs, phi), np.array(rows)[:, 0], atol=1e-14)
    np.testing.assert_array_equal(whiten(a, segs, np.zeros(0)), a)
    # a segment no longer than p has no row with a past and is dropped entirely
    short = [(0, 3), (3, n1 + n2)]
    assert whiten(a, short, phi).shape[0] == n1 + n2 - 3 - p


# ----------------------------------------------------------------------- lag_test
def test_lag_test_is_calibrated_on_white_noise():
    # 300 reps: sd of the rejection fraction at 0.05 is sqrt(0.05 * 0.95 / 300) = 0.0126,
    # 3-sd band [0.0123, 0.0877]
    rng = np.random.default_rng(21)
    n, reps = 400, 300
    segs = [(0, 150), (150, n)]
    p = np.empty(reps)
    for i in range(reps):
        z = _design(rng, n)
        y = z @ rng.standard_normal(3) + rng.standard_normal(n)
        e = y - z @ np.linalg.lstsq(z, y, rcond=None)[0]
        p[i] = lag_test(e, z, segs)[0].p_value
    lo, hi = _binomial_band(0.05, reps)
    assert lo <= np.mean(p < 0.05) <= hi


def test_lag_test_measures_lag_one_autocorrelation():
    rng = np.random.default_rng(8)
    n1, n2 = 3000, 2000
    e = np.concatenate([_ar1(rng, n1, 0.5), _ar1(rng, n2, 0.5)])
    segs = [(0, n1), (n1, n1 + n2)]
    z = np.ones((n1 + n2, 1))
    test, rho = lag_test(e, z, segs)
    # sample lag-1 autocorrelation with pairs inside segments only
    num = sum(float(np.dot(e[a + 1:b], e[a:b - 1])) for a, b in segs)
    np.testing.assert_allclose(rho, num / float(e @ e), rtol=1e-12)
    # its sampling sd is about sqrt((1 - 0.5^2) / n) = 0.012
    assert abs(rho - 0.5) < 3 * math.sqrt(0.75 / e.size)
    assert test.df1 == 1 and test.p_value < 1e-12
    # the lag coefficient is the AR(1) estimate, equally close to phi
    assert abs(test.coef[0] - 0.5) < 3 * math.sqrt(0.75 / e.size)


# --------------------------------------------------------------------------- holm
def _holm_brute(p: np.ndarray) -> np.ndarray:
    m = p.size
    order = np.argsort(p, kind="stable")
    adj_sorted = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out = np.empty(m)
    out[order] = adj_sorted
    return out


def _holm_stepdown(p: np.ndarray, alpha: float) -> set[int]:
    m = p.size
    rejected = set()
    for k, i in enumerate(np.argsort(p, kind="stable")):
        if p[i] <= alpha / (m - k):
            rejected.add(int(i))
        else:
            break
    return rejected


@pytest.mark.parametrize("seed", range(20))
def test_holm_matches_the_step_down_procedure(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 12))
    # a mix of tiny, moderate and large p-values, rounded so that ties occur
    p = np.round(np.concatenate([rng.uniform(0, 0.02, m // 2),
                                 rng.uniform(0, 1, m - m // 2)]), 3)
    rng.shuffle(p)
    adj = holm(p)
    np.testing.assert_allclose(adj, _holm_brute(p), rtol=0, atol=1e-15)
    assert np.all((adj >= p) & (adj <= 1.0))
    assert set(np.flatnonzero(adj <= 0.05)) == _holm_stepdown(p, 0.05)


def test_holm_known_values():
    p = np.array([0.01, 0.04, 0.03, 0.005, 0.03])
    # sorted 0.005 0.01 0.03 0.03 0.04 -> x5 x4 x3 x2 x1 = .025 .04 .09 .06 .04 -> cummax
    np.testing.assert_allclose(holm(p), [0.04, 0.09, 0.09, 0.025, 0.09])
    assert holm([]).shape == (0,)
    np.testing.assert_allclose(holm([0.6, 0.9]), [1.0, 1.0])


# ---------------------------------------------------- orthonormal_basis / project_out
def test_orthonormal_basis_detects_rank_and_spans_the_columns():
    rng = np.random.default_rng(12)
    n = 60
    b = rng.standard_normal((n, 3))
    # a scaled duplicate, a combination on a very different scale, a zero column
    a = np.column_stack([b, -250.0 * b[:, 1], 1e-6 * (b[:, 0] - 2 * b[:, 2]), np.zeros(n)])
    q = orthonormal_basis(a)
    assert q.shape == (n, 3)
    np.testing.assert_allclose(q.T @ q, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(project_out(q, a), 0.0, atol=1e-9 * np.abs(a).max())
    assert orthonormal_basis(np.zeros((n, 2))).shape == (n, 0)
    assert orthonormal_basis(np.zeros((n, 0))).shape == (n, 0)


def test_project_out_leaves_only_the_orthogonal_part():
    rng = np.random.default_rng(13)
    n = 80
    a = rng.standard_normal((n, 4))
    q = orthonormal_basis(a)
    b = rng.standard_normal((n, 2)) + a @ rng.standard_normal((4, 2))
    r = project_out(q, b)
    np.testing.assert_allclose(a.T @ r, 0.0, atol=1e-10)
    # reference: the least-squares residual of b on a
    np.testing.assert_allclose(r, b - a @ np.linalg.lstsq(a, b, rcond=None)[0], atol=1e-10)
    np.testing.assert_array_equal(project_out(np.zeros((n, 0)), b), b)
