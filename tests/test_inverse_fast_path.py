"""The prepared one-step path of numerical inversion gives the bits of the general one.

Oracles: the forward simulation of the whole model (``run_batch``), which a chain of
one-sample steps must reproduce exactly; the output map's own block ``_apply`` (with its
per-call monotonicity proof), which the prepared kernel must match bit for bit; and a
slow, straightforward posterior-mean inverse written here -- every candidate command
simulated through ``run_batch`` from the committed state -- which the fast inverter must
match to round-off.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayeshyst.inverse.numerical import FTOL_REL, XTOL_REL, invert
from bayeshyst.inverse.rootfind import solve_increasing, solve_scalar
from bayeshyst.models import get
from bayeshyst.models.base import DataScales
from bayeshyst.models.blocks import AsymmetricOutput
from bayeshyst.models.onestep import StepChain, asym_output_prepared, asym_output_valid

SCALES = DataScales(0.0, 150.0, 0.0, 40.0)
FS = 2000.0


def signal(n: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A smooth input with minor loops, starting at rest (V), and its times (s)."""
    t = np.arange(n) / FS
    s = np.clip((np.arange(n) - 20) / 200.0, 0.0, None)
    u = 75.0 - 60.0 * np.sin(0.5 * np.pi * np.clip(s, 0, 1)) ** 2 * np.cos(2 * np.pi * 3 * s)
    return t, u + 4.0 * np.sin(2 * np.pi * 11 * s)


def draws(model, n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """``n`` prior draws of ``model`` with positive operator weights (invertible)."""
    space = model.param_space(SCALES)
    theta = space.unpack(space.sample_prior(np.random.default_rng(seed), n))
    for k in theta:
        if k.split(".")[-1] == "w":
            theta[k] = np.abs(theta[k])
        if k.split(".")[-1] == "p0":
            theta[k] = np.abs(theta[k]) + 0.1
    return theta


SPECS = [
    "pi_play(n_operators=5)+asym_output(order=3)+creep",  # every part on a fast kernel
    "bouc_wen+drift+asym_output(order=2)",                # general parts between them
    "pi_play(n_operators=3)",                             # a bare model
]


@pytest.mark.parametrize("spec", SPECS)
def test_steps_reproduce_the_general_path_bit_for_bit(spec):
    # the oracle: the model's own batched simulation, one sample at a time from the
    # state it returned (what the inverter did before the chain)
    model = get(spec)
    t, u = signal()
    theta, width = model._batch_theta(draws(model, 6), batched=True)
    chain = StepChain.of_model(model, theta, width)
    states = chain.rest(float(u[0]))
    ref_state = np.concatenate(states, axis=1)
    for k in range(u.size):
        y, states, failed = chain.advance(float(u[k]), t[k:k + 1], states, k)
        ref = model.run_batch(u[k:k + 1], t[k:k + 1], theta, state0=ref_state)
        ref_state = ref.state
        np.testing.assert_array_equal(failed, ref.failed)
        np.testing.assert_array_equal(np.where(failed, np.nan, y), ref.y[:, 0])
        np.testing.assert_array_equal(np.concatenate(states, axis=1)[~failed],
                                      ref.state[~failed])


@pytest.mark.parametrize("spec", [SPECS[0], SPECS[2]])
def test_steps_of_kernels_exact_in_pieces_reproduce_a_whole_run(spec):
    model = get(spec)
    t, u = signal()
    theta, width = model._batch_theta(draws(model, 6), batched=True)
    full = model.run_batch(u, t, theta)
    chain = StepChain.of_model(model, theta, width)
    states = chain.rest(float(u[0]))
    ys, failed = [], np.zeros(width, dtype=bool)
    for k in range(u.size):
        y, states, f = chain.advance(float(u[k]), t[k:k + 1], states, k)
        ys.append(y)
        failed |= f
    y = np.column_stack(ys)
    y[failed] = np.nan
    np.testing.assert_array_equal(failed, full.failed)
    np.testing.assert_array_equal(y, full.y)


def test_a_step_leaves_the_state_it_was_given_alone():
    model = get(SPECS[0])
    t, u = signal(40)
    theta, width = model._batch_theta(draws(model, 3), batched=True)
    chain = StepChain.of_model(model, theta, width)
    states = chain.rest(float(u[0]))
    before = [s.copy() for s in states]
    for x in (10.0, 90.0, 140.0):
        chain.step(x, t[:1], states, 0)
    for a, b in zip(states, before, strict=True):
        np.testing.assert_array_equal(a, b)


def test_prepared_output_map_matches_the_block_with_its_checks():
    block = AsymmetricOutput(order=4)
    rng = np.random.default_rng(1)
    width = 200
    # wide coefficients: many draws are not monotone and must fail as in the block
    theta = {"a2": rng.normal(0, 0.4, width), "a3": rng.normal(0, 0.3, width),
             "a4": rng.normal(0, 0.2, width), "centre": np.full(width, 20.0),
             "half_span": np.full(width, 20.0)}
    theta["a2"][:3] = [np.nan, 1e300, 0.0]
    theta["half_span"][3] = 0.0
    tb, _ = block._batch_theta(theta, batched=True)
    w = rng.uniform(-10.0, 50.0, (width, 7))
    out_ref, _, failed_ref = block._apply(w, np.zeros(7), tb, np.empty((width, 0)))
    a = np.column_stack([tb["a2"], tb["a3"], tb["a4"]])
    ok = np.empty(width, dtype=bool)
    asym_output_valid(a, tb["centre"], tb["half_span"], ok)
    out, failed = np.empty((width, 7)), np.empty(width, dtype=bool)
    asym_output_prepared(w, a, tb["centre"], tb["half_span"], ok, out, failed)
    assert 0 < failed_ref.sum() < width
    np.testing.assert_array_equal(failed, failed_ref)
    np.testing.assert_array_equal(out, out_ref)


def test_scalar_solver_takes_the_steps_of_the_batched_one():
    def g(x):
        return x + 3.0 * np.maximum(x - 0.3, 0.0) + 0.5 * np.maximum(x - 0.7, 0.0) - 1.234

    batched = solve_increasing(lambda x: g(x), np.array([0.1]), np.array([0.05]), lo=-2.0,
                               hi=5.0, ftol=1e-13, xtol=1e-15)
    scalar = solve_scalar(lambda z: float(g(np.array([z]))[0]), 0.1, 0.05, lo=-2.0, hi=5.0,
                          ftol=1e-13, xtol=1e-15)
    assert scalar.x[0] == batched.x[0] and scalar.n_evaluations == batched.n_evaluations


def slow_mean_inverse(model, y_d, t, thetas, offset, lo, hi):
    """The posterior-mean command, every candidate simulated through ``run_batch``.

    The algorithm of :func:`~bayeshyst.inverse.numerical.invert` for a model without
    preview blocks and draws that never fail: per sample, the bracketed root of the mean
    residual over draws from the committed state (the relaxed state at the candidate for
    the first sample), then the state advanced with the root.
    """
    n = y_d.size
    span = float(np.ptp(y_d))
    ftol, xtol = FTOL_REL * span, XTOL_REL * max(hi - lo, 1.0)
    u_scale = hi - lo
    x, step, state = 0.5 * (lo + hi), 0.05 * u_scale, None
    u = np.empty(n)
    for k in range(n):
        def mean_residual(z, k=k, state=state):
            traj = model.run_batch(np.array([z]), t[k:k + 1], thetas, state0=state)
            return float(np.mean(traj.y[:, 0] + offset - y_d[k]))

        res = solve_increasing(lambda z: np.array([mean_residual(float(z[0]))]),
                               np.array([x]), np.array([step]), lo=lo, hi=hi, ftol=ftol,
                               xtol=xtol)
        xk = float(res.x[0])
        state = model.run_batch(np.array([xk]), t[k:k + 1], thetas, state0=state).state
        step = max(abs(xk - x), 1e-3 * u_scale)
        x = xk
        u[k] = xk
    return u


def test_fast_posterior_mean_inverse_matches_a_slow_one():
    model = get("pi_play(n_operators=4)+asym_output(order=2)+creep")
    t, u_true = signal(160)
    thetas = draws(model, 5, seed=4)
    thetas["asym_output.a2"] = np.linspace(-0.1, 0.1, 5)
    offset = np.linspace(-0.3, 0.3, 5)
    y_d = model.run_batch(u_true, t, thetas).y.mean(axis=0) + offset.mean()
    lo, hi = -50.0, 250.0
    inv = invert(model, y_d, t, thetas, offset=offset, u_limits=(lo, hi))
    slow = slow_mean_inverse(model, y_d, t, thetas, offset, lo, hi)
    np.testing.assert_allclose(inv.u, slow, rtol=0, atol=1e-12 * (hi - lo))
    # and the property itself: the posterior-mean output meets the reference
    y = model.run_batch(inv.u, t, thetas).y + offset[:, None]
    assert np.max(np.abs(y.mean(axis=0) - y_d)) <= 1e-8 * np.ptp(y_d)


def test_blocks_after_a_delay_are_inverted_per_draw():
    # creep after a delay is a later stage, inverted per draw through its own chain
    model = get("pi_play(n_operators=4)+delay(max_delay_samples=4)+creep")
    t, u_true = signal(200)
    thetas = draws(model, 1, seed=2)
    thetas["delay.d"] = np.array([1.25 / FS])
    y_d = model.run_batch(u_true, t, thetas).y[0]
    inv = invert(model, y_d, t, thetas, u_limits=(-50.0, 250.0))
    y = model.run_batch(inv.u, t, thetas).y[0]
    assert inv.stages[1:] == ("delay: deconvolution", "creep: per sample")
    assert math.isfinite(inv.max_error)
    assert np.max(np.abs(y - y_d)) <= 1e-6 * np.ptp(y_d)
