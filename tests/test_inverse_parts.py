"""The parts of numerical inversion: bracketed root finding and stable deconvolution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from bayeshyst.errors import ParameterError
from bayeshyst.inverse.lti import deconvolve, impulse_responses
from bayeshyst.inverse.rootfind import solve_increasing
from bayeshyst.models.blocks import ARX, Delay, SecondOrder

# ------------------------------------------------------------------------ root finding


def test_roots_of_piecewise_linear_maps():
    # kinked increasing maps with known roots (a PI one-step map is such a map)
    roots = np.array([-0.5, 0.31, 0.9, 1.7, 5.0])

    def ramp(x):
        return x + 3.0 * np.maximum(x - 0.3, 0.0) + 0.5 * np.maximum(x - 0.7, 0.0)

    def fun(x):
        return ramp(x) - ramp(roots)

    res = solve_increasing(fun, np.zeros(5), np.full(5, 0.1), ftol=1e-12, xtol=1e-14)
    np.testing.assert_allclose(res.x, roots, atol=1e-11)
    assert not res.saturated.any() and not res.nonmonotone.any()
    assert res.n_evaluations < 60  # bisection alone would need ~45 per root after bracketing


def test_unreachable_target_saturates_and_says_so():
    res = solve_increasing(lambda x: np.tanh(x) - np.array([0.5, 2.0]), np.zeros(2),
                           np.ones(2), lo=-10.0, hi=10.0, ftol=1e-12, xtol=1e-14)
    assert res.x[0] == pytest.approx(np.arctanh(0.5), abs=1e-10)
    assert list(res.saturated) == [False, True] and res.x[1] == 10.0


def test_staircase_keeps_the_closer_side_of_the_jump():
    # a relay model's output is a staircase: no exact root; the closer plateau is chosen
    def fun(x):
        return np.floor(x) - np.array([2.3, 2.8])

    res = solve_increasing(fun, np.zeros(2), np.ones(2), ftol=1e-12, xtol=1e-12)
    np.testing.assert_allclose(res.residual, [-0.3, 0.2], atol=1e-12)


def test_decreasing_map_is_flagged():
    # from 1.2 the expansion walks right into the falling part of the sine
    res = solve_increasing(lambda x: np.sin(3 * x) + 0.2 * x - 0.1, np.array([1.2]),
                           np.array([0.5]), ftol=1e-12, xtol=1e-14)
    assert res.nonmonotone[0]


# ------------------------------------------------------------------ deconvolution


FS = 20_000.0


def rest_then_move(n=3000, lead=400):
    t = np.arange(n) / FS
    s = np.clip((np.arange(n) - lead) / 800.0, 0.0, 1.0)
    return t, np.sin(0.5 * np.pi * s) ** 4 * (1.0 + 0.3 * np.sin(2 * np.pi * 120 * t))


BLOCKS = [
    (SecondOrder(), {"f_n": [1500.0, 900.0], "zeta": [0.07, 0.3]}),
    (SecondOrder(hold="zoh"), {"f_n": [1500.0], "zeta": [0.05]}),
    (Delay(), {"d": [0.7 / FS, 2.3 / FS]}),  # fractions > 1/2: zeros outside the circle
    (ARX(2, 3, 1), {"kappa": [[-0.9, 0.8]], "beta": [[0.6, -0.3]]}),
]


@pytest.mark.parametrize(("block", "theta"), BLOCKS, ids=lambda b: getattr(b, "name", ""))
def test_deconvolution_inverts_the_block_kernel(block, theta):
    theta = {k: np.asarray(v, float) for k, v in theta.items()}
    t, v = rest_then_move()
    inv = deconvolve(block, theta, v, t)
    y = block.apply_batch(inv.w, t, theta).y
    np.testing.assert_allclose(y, np.broadcast_to(v, y.shape), atol=1e-9)


@pytest.mark.parametrize(("block", "theta"), BLOCKS, ids=lambda b: getattr(b, "name", ""))
def test_periodic_deconvolution_is_the_steady_state(block, theta):
    theta = {k: np.asarray(v, float) for k, v in theta.items()}
    n = 400
    t = np.arange(n) / FS
    v = np.sin(2 * np.pi * np.arange(n) / n) + 0.2 * np.cos(6 * np.pi * np.arange(n) / n)
    w = deconvolve(block, theta, v, t, periodic=True).w
    reps = 12
    y = block.apply_batch(np.tile(w, (1, reps)), np.arange(reps * n) / FS, theta).y
    np.testing.assert_allclose(y[:, -n:], np.broadcast_to(v, (w.shape[0], n)), atol=1e-9)


def test_impulse_response_matches_scipy_foh():
    # oracle: scipy's first-order-hold discretisation of the same continuous system
    fn, zeta = 1200.0, 0.2
    wn = 2 * np.pi * fn
    g = impulse_responses(SecondOrder(), {"f_n": np.array([fn]), "zeta": np.array([zeta])},
                          1 / FS, 1)[0]
    num, den, _ = signal.cont2discrete(([wn ** 2], [1, 2 * zeta * wn, wn ** 2]), 1 / FS,
                                       method="foh")
    ref = signal.dlsim((np.ravel(num), den, 1 / FS), np.r_[1.0, np.zeros(g.size - 1)])[1]
    np.testing.assert_allclose(g, ref.ravel(), atol=1e-12)


def test_deconvolution_needs_uniform_sampling():
    t = np.cumsum(np.r_[0.0, np.full(99, 1 / FS)])
    t[50:] += 0.3 / FS
    with pytest.raises(ParameterError, match="uniform"):
        deconvolve(Delay(), {"d": np.array([1 / FS])}, np.ones(100), t)


def test_single_problem_path_equals_the_batched_path():
    # the scalar fast path must take exactly the batched solver's steps
    rng = np.random.default_rng(4)
    for _ in range(20):
        c = rng.uniform(-3, 3)
        k1, k2 = rng.uniform(0.1, 3, 2)

        def fun(x, c=c, k1=k1, k2=k2):
            return k1 * x + k2 * np.maximum(x - 0.4, 0.0) + 0.3 * np.floor(2 * x) - c

        one = solve_increasing(fun, np.array([0.2]), np.array([0.3]), lo=-2.0, hi=2.0,
                               ftol=1e-12, xtol=1e-13)
        both = solve_increasing(fun, np.array([0.2, 0.2]), np.array([0.3, 0.3]), lo=-2.0,
                                hi=2.0, ftol=1e-12, xtol=1e-13)
        assert one.x[0] == both.x[0] and one.residual[0] == both.residual[0]
        assert one.saturated[0] == both.saturated[0]
        assert one.nonmonotone[0] == both.nonmonotone[0]


def test_small_array_quantile_equals_numpy() -> None:
    from bayeshyst.inverse.numerical import _quantile

    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 8, 24, 101):
        a = rng.normal(size=n)
        for q in (0.0, 0.1, 0.5, 0.9, 0.999, 1.0):
            assert _quantile(a, q) == pytest.approx(float(np.quantile(a, q)), abs=1e-12)
