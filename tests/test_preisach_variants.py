"""Preisach variants (rate-weighted relays, diagonally weighted grid) against oracles.

Oracles: slow pure-Python implementations written from the equations (relay by relay
with the rate weight; the exact Everett function of weights spread along the cell
diagonals, summed over the dominant extrema by review Eq. 7–8), the parent models at
the special parameters where the variants reduce to them, an analytic loop-width ratio,
and the Preisach properties (wiping-out, congruent minor loops, rate independence or
its absence, state continuation, batched == one-by-one, serial == parallel); and
posterior recovery on data from each model.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayeshyst.data import Dataset, Record
from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get, kernel_parallelism
from bayeshyst.models.base import DataScales
from bayeshyst.models.pi import PrandtlIshlinskii
from bayeshyst.models.preisach import Preisach, PreisachDensity
from bayeshyst.models.preisach_variants import (
    DiagonalPreisach,
    PreisachDensityRate,
    PreisachRate,
)
from tests.test_preisach import dominant_extrema, everett_sum
from tests.test_recovery import _check_calibration, _check_coverage, _labels_and_truth

SCALES = DataScales(0.0, 100.0, -2.0, 18.0)
FAST = settings(max_examples=25, deadline=None)
RATE_MODELS = {"grid01": PreisachRate(5), "gridpm1": PreisachRate(5, relay="pm1"),
               "density": PreisachDensityRate(n_grid=20)}


def _theta(model, seed, data=SCALES, **over):
    space = model.param_space(data)
    theta = space.unpack(space.sample_prior(np.random.default_rng(seed), 1)[0])
    theta.update(over)
    return theta


def _parent(model):
    if isinstance(model, PreisachRate):
        return Preisach(model.n_levels, relay=model.relay, max_memory=model.max_memory)
    return PreisachDensity(n_grid=model.n_grid, shape=model.shape, max_memory=model.max_memory)


def _parent_theta(model, theta):
    return {k: v for k, v in theta.items() if k not in ("c", "udot0")}


def _irregular(seed, n=260):
    """An irregular input with reversals and minor loops, on uneven time steps."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5e-3, 2e-3, n))
    u = 50 + 45 * np.sin(2 * np.pi * 7 * t) * np.cos(2 * np.pi * 3 * t) + rng.normal(0, 4, n)
    return np.clip(u, -5, 105), t


# ------------------------------------------------------------------ slow oracles
def rate_relay_oracle(u, t, levels, mu, offset, relay, c, udot0, history=()):
    """Relay by relay, every sample: ``offset + F_k sum mu gamma`` (pure Python).

    ``history`` (inputs, times) runs first from negative saturation; outputs are those of
    ``u``. ``F_k = 1 + c ln(1 + |u_k - u_{k-1}| / (t_k - t_{k-1}) / udot0)``, 0 rate first.
    """
    hu, ht = (list(history[0]), list(history[1])) if history else ([], [])
    cells = [(levels[i], levels[j]) for i in range(len(levels)) for j in range(i + 1)]
    on = [False] * len(cells)
    out, prev = [], None
    for x, tk in zip([*hu, *u], [*ht, *t], strict=True):
        rate = 0.0 if prev is None else abs(x - prev[0]) / (tk - prev[1])
        f = 1.0 + c * math.log1p(rate / udot0)
        total = 0.0
        for k, (alpha, beta) in enumerate(cells):
            if x >= alpha:
                on[k] = True
            elif x < beta:
                on[k] = False
            total += mu[k] * ((1.0 if on[k] else 0.0) if relay == "01"
                              else (1.0 if on[k] else -1.0))
        out.append(offset + f * total)
        prev = (x, tk)
    return np.array(out[len(hu):])


def diagonal_everett(a, b, lo, hi, mu, n_lev):
    """Mass of the weights spread along the cell diagonals inside ``{b < beta <= alpha <= a}``.

    Cell ``(i, j)``: segment ``(e_i + h s, e_j + h s)``, ``s`` in [0, 1] uniform; the part
    with ``alpha <= a`` and ``beta > b`` is ``s in ((b - e_j)/h, (a - e_i)/h]``.
    """
    h = (hi - lo) / n_lev
    total, k = 0.0, 0
    for i in range(n_lev):
        for j in range(i + 1):
            s_hi = min(1.0, max(0.0, (a - (lo + i * h)) / h))
            s_lo = min(1.0, max(0.0, (b - (lo + j * h)) / h))
            total += mu[k] * max(0.0, s_hi - s_lo)
            k += 1
    return total


def diagonal_oracle(u, theta, n_lev):
    """Review Eq. 7–8 on the dominant extrema of each prefix of ``u`` (O(N^2), pure Python)."""
    lo, hi = theta["bounds"]
    mu = np.ravel(theta["mu"])

    def everett(a, b):
        return diagonal_everett(a, b, lo, hi, mu, n_lev)

    return np.array([float(np.ravel(theta["offset"])[0])
                     + everett_sum(dominant_extrema(u[:k + 1]), everett)
                     for k in range(len(u))])


# ------------------------------------------------------------------ rate-weighted
@pytest.mark.parametrize("relay", ["01", "pm1"])
def test_rate_grid_matches_relay_by_relay_oracle_from_a_continued_state(relay):
    model = PreisachRate(4, relay=relay)
    theta = _theta(model, 1, c=0.8, udot0=3e3)
    hist_u, hist_t = _irregular(2, 90)
    u, t = _irregular(3, 200)
    t = t + hist_t[-1]
    first = model.run(hist_u, hist_t, theta)
    got = model.run(u, t, theta, state0=first.state).y
    want = rate_relay_oracle(u, t, theta["levels"], theta["mu"], float(theta["offset"]),
                             relay, 0.8, 3e3, history=(hist_u, hist_t))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11)
    # and from the default initial state
    np.testing.assert_allclose(
        model.simulate(u, t, theta),
        rate_relay_oracle(u, t, theta["levels"], theta["mu"], float(theta["offset"]), relay,
                          0.8, 3e3), rtol=0, atol=1e-11)


def test_rate_density_is_the_parent_hysteresis_part_times_the_rate_weight():
    model = RATE_MODELS["density"]
    theta = _theta(model, 4, c=0.6, udot0=2e3)
    u, t = _irregular(5)
    parent = _parent(model)
    pth = _parent_theta(model, theta)
    reversible = theta["offset"] + theta["k_rev"] * u
    hyst = parent.simulate(u, t, pth) - reversible
    rate = np.concatenate([[0.0], np.abs(np.diff(u)) / np.diff(t)])
    want = reversible + (1.0 + 0.6 * np.log1p(rate / 2e3)) * hyst
    np.testing.assert_allclose(model.simulate(u, t, theta), want, rtol=0, atol=1e-11)


@pytest.mark.parametrize("name", list(RATE_MODELS))
def test_rate_with_zero_sensitivity_is_the_parent_exactly(name):
    model = RATE_MODELS[name]
    theta = _theta(model, 6, c=0.0)
    u, t = _irregular(7)
    np.testing.assert_array_equal(model.simulate(u, t, theta),
                                  _parent(model).simulate(u, t, _parent_theta(model, theta)))


def _mid_width_and_weight(model, theta, u, n, f_hz, amp):
    """Falling minus rising output at the second cycle's crossings of the sine's middle,
    and the rate weight ``F`` there (both crossings have the same ``|u̇|``)."""
    dt = 1.0 / (n * f_hz)
    y = model.simulate(u, np.arange(u.size) * dt, theta)
    rate = amp * math.sin(2 * math.pi / n) / dt
    return y[n + n // 2] - y[n], 1.0 + theta["c"] * math.log1p(rate / theta["udot0"])


@pytest.mark.parametrize("name", list(RATE_MODELS))
def test_rate_loop_widens_with_frequency_by_the_weight_ratio(name):
    # the same input samples at two frequencies: relay states are identical, so every
    # hysteretic deviation scales by F(rate_2) / F(rate_1), where at a mid crossing of
    # a sine the backward-difference rate is A sin(2 pi / n) / dt on both branches
    model = RATE_MODELS[name]
    c, ud0, amp, n = 0.7, 2e3, 45.0, 200
    theta = _theta(model, 8, c=c, udot0=ud0)
    k = np.arange(2 * n + 1)
    u = 50.0 + amp * np.sin(2 * np.pi * k / n)
    (w1, f1), (w2, f2) = (_mid_width_and_weight(model, theta, u, n, f_hz, amp)
                          for f_hz in (1.0, 20.0))
    static = _parent(model).simulate(u, k * 1.0, _parent_theta(model, theta))
    assert abs(static[n + n // 2] - static[n]) > 1e-3  # a loop there to widen
    assert f2 > f1 > 1.0
    np.testing.assert_allclose(w2 / w1, f2 / f1, rtol=1e-10)


def test_rate_model_changes_under_a_time_warp():
    model = RATE_MODELS["grid01"]
    theta = _theta(model, 9, c=0.5, udot0=1e3)
    u, t = _irregular(10)
    warped = t[0] + 3.0 * (t - t[0]) ** 2 + 0.2 * (t - t[0])
    assert np.max(np.abs(model.simulate(u, t, theta) - model.simulate(u, warped, theta))) > 1e-3


@FAST
@given(seed=st.integers(0, 2**31 - 1), prefix=st.lists(st.integers(0, 40), min_size=1,
                                                       max_size=12),
       inner=st.lists(st.integers(0, 40), min_size=1, max_size=12), jump=st.integers(1, 20),
       suffix=st.lists(st.integers(0, 40), max_size=12), which=st.sampled_from(list(RATE_MODELS)))
def test_rate_wiping_out_holds_at_constant_rate(seed, prefix, inner, jump, suffix, which):
    # lattice inputs moving one step of 2.5 V per sample, 0.25 s apart (both exact in
    # binary): |u̇| = 10 V/s after the first sample, so the rate weight is one constant
    # and inner extrema are wiped out once the input passes them
    model = RATE_MODELS[which]
    theta = _theta(model, seed % 1000, c=0.9, udot0=7.0)
    p = prefix[-1]
    top = p + jump
    inner = [p + x % (jump + 1) for x in inner]  # extrema inside [p, top]
    legs1 = [0, *prefix, *inner, top, *suffix]
    legs2 = [0, *prefix, top, *suffix]

    def walk(points):
        path = [points[0]]
        for q in points[1:]:
            step = 1 if q > path[-1] else -1
            path.extend(range(path[-1] + step, q + step, step) if q != path[-1] else [])
        return np.array(path, dtype=float) * 2.5, len(path)

    u1, _ = walk(legs1)
    u2, _ = walk(legs2)
    tail = len(walk([top, *suffix])[0])
    r1 = model.run(u1, np.arange(u1.size) * 0.25, theta)
    r2 = model.run(u2, np.arange(u2.size) * 0.25, theta)
    np.testing.assert_array_equal(r1.y[-tail:], r2.y[-tail:])
    mem = 3 + model.max_memory
    np.testing.assert_array_equal(r1.state[:mem], r2.state[:mem])


# ------------------------------------------------------------------ diagonal
def test_diagonal_matches_the_exact_everett_oracle_from_a_continued_state():
    model = DiagonalPreisach(5)
    theta = _theta(model, 11)
    theta["bounds"] = np.array([-3.0, 104.0])  # edges off the round numbers of the input
    hist, _ = _irregular(12, 60)
    u, t = _irregular(13, 160)
    first = model.run(hist, np.arange(hist.size), theta)
    got = model.run(u, t, theta, state0=first.state).y
    want = diagonal_oracle(np.concatenate([hist, u]), theta, 5)[hist.size:]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11)
    np.testing.assert_allclose(model.simulate(u, t, theta), diagonal_oracle(u, theta, 5),
                               rtol=0, atol=1e-11)


def _edge_path(turns, h, per_edge=1):
    pts = [turns[0] * h]
    for a, b in itertools.pairwise(turns):
        m = abs(b - a) * per_edge
        pts.extend(np.linspace(a * h, b * h, m + 1)[1:])
    return np.array(pts)


def test_diagonal_is_preisach_on_cell_edges_and_linear_in_between():
    n_lev = 6
    model, grid = DiagonalPreisach(n_lev), Preisach(n_lev)
    theta = _theta(model, 14)
    h = SCALES.u_span / n_lev
    grid_theta = {"offset": theta["offset"], "mu": theta["mu"],
                  "levels": grid.param_space(SCALES).fixed["levels"]}
    turns = [0, 5, 2, 4, 1, 6, 3, 5, 0, 2]
    on_edges = _edge_path(turns, h)
    ye = model.simulate(on_edges, np.arange(on_edges.size), theta)
    np.testing.assert_allclose(ye, grid.simulate(on_edges, np.arange(on_edges.size),
                                                 grid_theta), rtol=0, atol=1e-11)
    # 8 samples per cell between the edges: linear interpolation of the edge values
    fine = _edge_path(turns, h, per_edge=8)
    yf = model.simulate(fine, np.arange(fine.size), theta)
    np.testing.assert_allclose(yf[::8], ye, rtol=0, atol=1e-11)
    frac = np.arange(1, 8) / 8.0
    for k in range(ye.size - 1):
        np.testing.assert_allclose(yf[8 * k + 1:8 * k + 8], ye[k] + frac * (ye[k + 1] - ye[k]),
                                   rtol=0, atol=1e-11)


def test_diagonal_output_is_continuous_where_the_relay_grid_steps():
    model, grid = DiagonalPreisach(4), Preisach(4)
    theta = _theta(model, 15, mu=np.full(10, 1.0))
    u = np.linspace(0.0, 100.0, 4001)
    y = model.simulate(u, np.arange(u.size), theta)
    gth = {"offset": theta["offset"], "mu": theta["mu"],
           "levels": grid.param_space(SCALES).fixed["levels"]}
    yg = grid.simulate(u, np.arange(u.size), gth)
    # the largest jump of the grid is a whole row of cells; the diagonal model's step
    # is at most the total weight times the input step over the cell size
    assert np.max(np.diff(yg)) >= 4.0 - 1e-12
    assert np.max(np.abs(np.diff(y))) <= 10.0 * (100.0 / 4000) / 25.0 + 1e-12
    # outside the plane the output saturates at offset and offset + sum(mu)
    out = model.simulate(np.array([-50.0, 150.0, 400.0]), np.arange(3.0), theta)
    np.testing.assert_allclose(out - theta["offset"], [0.0, 10.0, 10.0], rtol=0, atol=1e-12)


def test_diagonal_with_one_weight_per_line_is_the_cell_model_with_tied_weights():
    tied, cells = DiagonalPreisach(5, weights="diagonal"), DiagonalPreisach(5)
    theta = _theta(tied, 30)
    i, j = np.tril_indices(5)
    u, t = _irregular(31)
    np.testing.assert_array_equal(
        tied.simulate(u, t, theta), cells.simulate(u, t, {**theta, "mu": theta["mu"][i - j]}))
    assert tied.param_space(SCALES)["mu"].shape == (5,)


def test_diagonal_with_one_weight_per_line_is_a_play_pi_model_inside_the_plane():
    # oracle: pi_play (review Eq. 11-12), thresholds d h / 2 and weights w_d / h, started
    # from the same plays (u0 - d h / 2); the identity holds once every play is inside
    # its line's centre range, i.e. after the input has reached the top of the plane
    n_lev = 5
    tied = DiagonalPreisach(n_lev, weights="diagonal")
    theta = _theta(tied, 32)
    lo, hi = theta["bounds"]
    h = (hi - lo) / n_lev
    u, t = _irregular(33)
    u = np.clip(np.concatenate([[lo, hi], u]), lo, hi)
    t = np.arange(u.size, dtype=float)
    w = theta["mu"] / h
    half = 0.5 * h * np.arange(1, n_lev)
    play = PrandtlIshlinskii(n_lev - 1)
    y_pi = play.run(u, t, {"p0": w[0], "w": w[1:], "r": half},
                    state0=u[0] - half).y
    const = theta["offset"] - np.sum(w * (lo + 0.5 * h * np.arange(n_lev)))
    np.testing.assert_allclose(tied.simulate(u, t, theta)[1:], (y_pi + const)[1:], rtol=0,
                               atol=1e-10)


@FAST
@given(seed=st.integers(0, 2**31 - 1),
       prefix=st.lists(st.floats(0, 100), min_size=1, max_size=15),
       inner=st.lists(st.floats(0, 1), min_size=1, max_size=15),
       jump=st.floats(0, 60), suffix=st.lists(st.floats(0, 100), max_size=15),
       falling=st.booleans())
def test_diagonal_wiping_out(seed, prefix, inner, jump, suffix, falling):
    model = DiagonalPreisach(5)
    theta = _theta(model, seed % 1000)
    p = prefix[-1]
    s0 = p - jump if falling else p + jump
    wiped = np.clip([p + f * (s0 - p) for f in inner], min(p, s0), max(p, s0))
    tail = np.array([s0, *suffix])
    u1 = np.array([*prefix, *wiped, *tail])
    u2 = np.array([*prefix, *tail])
    r1 = model.run(u1, np.arange(u1.size), theta)
    r2 = model.run(u2, np.arange(u2.size), theta)
    np.testing.assert_array_equal(r1.y[-tail.size:], r2.y[-tail.size:])
    np.testing.assert_array_equal(r1.state, r2.state)


def test_diagonal_minor_loops_are_congruent():
    model = DiagonalPreisach(6)
    theta = _theta(model, 16)
    u1, u2 = 35.0, 60.0
    hist_a = np.concatenate([np.linspace(0, 95, 30), np.linspace(95, 10, 30),
                             np.linspace(10, 80, 30), np.linspace(80, u1, 30)])
    hist_b = np.concatenate([np.linspace(0, 70, 30), np.linspace(70, 25, 30),
                             np.linspace(25, 65, 30), np.linspace(65, u1, 30)])
    up = np.linspace(u1, u2, 40)
    loop = np.concatenate([up, up[::-1][1:]])
    ys = [model.simulate(np.concatenate([h, loop]), np.arange(h.size + loop.size),
                         theta)[h.size:] for h in (hist_a, hist_b)]
    shift = ys[0] - ys[1]
    assert abs(shift[0]) > 1e-6  # the histories do leave different states
    np.testing.assert_allclose(shift, shift[0], rtol=0, atol=1e-12)


def test_diagonal_is_rate_independent():
    model = DiagonalPreisach(6)
    theta = _theta(model, 17)
    u, t = _irregular(18)
    warped = 3.0 * t**3 + 0.1 * t
    np.testing.assert_array_equal(model.simulate(u, t, theta), model.simulate(u, warped, theta))


@pytest.mark.parametrize("name", ["grid01", "density", "diagonal"])
def test_positive_weights_give_counter_clockwise_loops(name):
    # a relay only switches up on a rise and down on a fall, so with positive weights the
    # falling branch lies above the rising one at every input level (counter-clockwise)
    model = {**RATE_MODELS, "diagonal": DiagonalPreisach(6)}[name]
    theta = _theta(model, 29, **({"c": 0.5, "udot0": 1e3} if name != "diagonal" else {}))
    if "mu" in theta:
        theta["mu"] = np.abs(theta["mu"]) + 0.01
    n = 400
    k = np.arange(2 * n + 1)
    u = 50.0 - 45.0 * np.cos(2 * np.pi * k / n)
    y = model.simulate(u, k * 1e-3, theta)
    rise, fall = slice(n, n + n // 2 + 1), slice(n + n // 2, 2 * n + 1)
    level = np.linspace(10.0, 90.0, 33)
    y_rise = np.interp(level, u[rise], y[rise])
    y_fall = np.interp(level, u[fall][::-1], y[fall][::-1])
    assert np.all(y_fall - y_rise > 0.0)


# ------------------------------------------------------------------ shared properties
ALL = {**RATE_MODELS, "diagonal": DiagonalPreisach(5),
       "diagonal_tied": DiagonalPreisach(5, weights="diagonal")}


@pytest.mark.parametrize("name", list(ALL))
def test_two_pieces_and_single_samples_equal_one_run(name):
    model = ALL[name]
    theta = _theta(model, 19, **({"c": 0.4, "udot0": 2e3} if name in RATE_MODELS else {}))
    u, t = _irregular(20, 120)
    whole = model.run(u, t, theta)
    a = model.run(u[:47], t[:47], theta)
    b = model.run(u[47:], t[47:], theta, state0=a.state)
    np.testing.assert_allclose(np.concatenate([a.y, b.y]), whole.y, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(b.state, whole.state)
    state, ys = None, []
    for k in range(u.size):
        tr = model.run(u[k:k + 1], t[k:k + 1], theta, state0=state)
        ys.append(tr.y[0])
        state = tr.state
    np.testing.assert_allclose(ys, whole.y, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", list(ALL))
def test_batched_equals_one_by_one_and_serial_equals_parallel(name):
    model = ALL[name]
    space = model.param_space(SCALES)
    z = space.sample_prior(np.random.default_rng(21), 6)
    u, t = _irregular(22, 400)
    with kernel_parallelism(None):
        serial = model.simulate_batch(u, t, space.unpack(z))
    with kernel_parallelism(0):
        parallel = model.simulate_batch(u, t, space.unpack(z))
    np.testing.assert_array_equal(serial, parallel)
    for w in range(z.shape[0]):
        np.testing.assert_array_equal(serial[w], model.simulate(u, t, space.unpack(z[w])))


@pytest.mark.parametrize("name", [*ALL, "grid_default"])
def test_prior_draws_never_give_nan(name):
    model = ALL.get(name, PreisachRate())
    space = model.param_space(SCALES)
    z = space.sample_prior(np.random.default_rng(23), 200)
    u, t = _irregular(24, 300)
    traj = model.run_batch(u, t, space.unpack(z))
    assert not traj.failed.any()
    assert np.all(np.isfinite(traj.y))


@pytest.mark.parametrize("name", ["grid01", "diagonal", "diagonal_tied"])
def test_linear_design_reproduces_the_output(name):
    model = ALL[name]
    space = model.param_space(SCALES)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(25), 3))
    u, t = _irregular(26, 150)
    design = model.linear_design(u, t, thetas)
    beta = np.column_stack([thetas["offset"], thetas["mu"]])
    np.testing.assert_allclose(design.predict(beta), model.simulate_batch(u, t, thetas),
                               rtol=0, atol=1e-10)


def test_rate_prior_is_scaled_from_the_data_rate():
    from types import SimpleNamespace

    t = np.arange(500) * 1e-4
    rec = SimpleNamespace(t=t, u=50 + 40 * np.sin(2 * np.pi * 50 * t), y=np.sin(t))
    median = float(np.median(np.abs(np.diff(rec.u)) / 1e-4))
    prior = PreisachRate(3).param_space(rec)["udot0"].prior
    assert math.isclose(float(np.exp(prior.mu)), median, rel_tol=1e-9)


def test_bad_settings_states_and_inputs_are_refused():
    with pytest.raises(ModelError, match="n_levels"):
        DiagonalPreisach(0)
    with pytest.raises(ModelError, match="weights must be"):
        DiagonalPreisach(3, weights="row")
    with pytest.raises(ModelError, match="relay"):
        PreisachRate(3, relay="x")
    with pytest.raises(ModelError, match="max_memory"):
        PreisachDensityRate(max_memory=1)
    rate = PreisachRate(3)
    theta = _theta(rate, 27)
    u = np.array([10.0, 20.0, 30.0])
    with pytest.raises(ParameterError, match="strictly increasing"):
        rate.run(u, np.array([0.0, 1.0, 1.0]), theta)
    state = rate.run(u, np.arange(3.0), theta).state
    with pytest.raises(ParameterError, match="after the time"):
        rate.run(u, np.arange(3.0), theta, state0=state)
    with pytest.raises(ParameterError, match="shape"):
        rate.run(u, np.arange(3.0), theta, state0=state[:-1])
    bad = state.copy()
    bad[0] = 2.5  # not an integer count of extrema
    with pytest.raises(ParameterError, match="not a valid memory"):
        rate.run(u, np.arange(3.0) + 10, theta, state0=bad)
    for key, value in (("c", -0.1), ("udot0", 0.0)):
        with pytest.raises(SimulationError):
            rate.simulate(u, np.arange(3.0), {**theta, key: value})
    diag = DiagonalPreisach(3)
    dth = _theta(diag, 28)
    with pytest.raises(SimulationError):
        diag.simulate(u, np.arange(3.0), {**dth, "bounds": np.array([50.0, 50.0])})
    with pytest.raises(ParameterError, match="shape"):
        diag.run(u, np.arange(3.0), dth, state0=np.zeros(4))
    with pytest.raises(ParameterError, match="lo < hi"):
        diag.cell_segments({**dth, "bounds": np.array([1.0, 0.0])})


def test_registry_names_and_descriptions():
    for name, cls in (("preisach_rate", PreisachRate), ("preisach_diagonal", DiagonalPreisach),
                      ("preisach_density_rate", PreisachDensityRate)):
        model = get(name)
        assert isinstance(model, cls)
        assert model.equation.startswith("review Eq.")
        assert "The form, and why" in cls.__doc__
    assert get("preisach_rate").rate_dependent and get("preisach_density_rate").rate_dependent
    assert not get("preisach_diagonal").rate_dependent
    alpha, beta = DiagonalPreisach(3).cell_segments({"bounds": np.array([0.0, 30.0])})
    np.testing.assert_array_equal(alpha, [0, 10, 10, 20, 20, 20])
    np.testing.assert_array_equal(beta, [0, 0, 10, 0, 10, 20])


# ------------------------------------------------------------------ posterior recovery
# Data simulated from each model with Gaussian noise, refitted with the default priors;
# the checks of tests/test_recovery.py (helpers reused): the sum over independent fits
# of the truth's squared Mahalanobis distance is ~ chi2(S d) (two-sided 0.1 % test) and,
# slow, each parameter's 90 % HDI covers the truth at the nominal rate over 20 seeds
# (binomial test, Bonferroni over parameters).
SIGMA = 0.05
# 3 levels over 0-150 V: six cells, positive weights (a counter-clockwise loop)
MU = np.array([1.2, 0.8, 0.6, 0.5, 0.4, 1.0])
DIAGONAL_TRUTH = {"offset": 0.5, "mu": MU}
RATE_TRUTH = {"offset": 0.5, "mu": MU, "c": 0.6, "udot0": 800.0}
DENSITY_RATE_TRUTH = {"offset": 0.5, "k_rev": 0.02, "scale": 4.0, "centre": 70.0,
                      "sd_centre": 30.0, "halfwidth": 15.0, "sd_log_halfwidth": 0.5,
                      "rho": 0.2, "c": 0.6, "udot0": 800.0}


def _drive(f_hz, n_per=300, periods=3):
    """A decaying sine over 0–150 V (minor loops inside the major one)."""
    k = np.arange(n_per * periods)
    t = k / (n_per * f_hz)
    envelope = 1.0 - 0.5 * k / k.size
    return t, 75.0 - 74.0 * envelope * np.cos(2 * np.pi * f_hz * t)


def _records(model, truth, seed, freqs):
    """Noisy records from the model at ``freqs``, with the fixed values the fit will use."""
    rng = np.random.default_rng(seed)
    drives = [(f_hz, *_drive(f_hz)) for f_hz in freqs]
    # the fit places the fixed levels / bounds from the data's input range: so does the truth
    inputs = Dataset(tuple(Record(t=t, u=u, y=u, name=f"f{f_hz:g}")
                           for f_hz, t, u in drives))
    theta = {**truth, **model.param_space(inputs).fixed}
    recs = []
    for f_hz, t, u in drives:
        y = model.simulate(u, t, theta) + rng.normal(0.0, SIGMA, u.size)
        recs.append(Record(t=t, u=u, y=y, name=f"f{f_hz:g}", warmup=50,
                           metadata={"frequency_hz": f_hz}))
    return Dataset(tuple(recs), name=f"seed{seed}")


def _fit(model, truth, seed, freqs):
    """(squared Mahalanobis distance of the truth in z, label -> covered by the 90 % HDI)."""
    data = _records(model, truth, seed, freqs)
    post = Posterior(data, model)
    res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=8000,
                                                 n_walkers=2 * post.ndim + 2))
    assert res.converged, res.convergence
    full = {**truth, "noise.sigma": SIGMA}
    zt = post.space.pack(full)
    z = res.flat_z
    d = zt - z.mean(axis=0)
    d2 = float(d @ np.linalg.solve(np.cov(z.T), d))
    summ = {s.label: s for s in res.summary(0.9)}
    hits = {lab: summ[lab].hdi_lo <= v <= summ[lab].hdi_hi
            for lab, v in _labels_and_truth(post.space, full).items()}
    return d2, hits, post.ndim


def _stats(model, truth, seeds, freqs):
    out = [_fit(model, truth, seed, freqs) for seed in seeds]
    return [(d2, hits) for d2, hits, _ in out], out[0][2]


def test_diagonal_posterior_is_calibrated():
    fits, ndim = _stats(DiagonalPreisach(3), DIAGONAL_TRUTH, range(3), (2.0,))
    _check_calibration(fits, ndim)


@pytest.mark.slow
def test_diagonal_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _stats(DiagonalPreisach(3), DIAGONAL_TRUTH, range(3, 23), (2.0,))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_rate_posterior_is_calibrated():
    # two drive frequencies (peak rates ~0.7 and ~14 kV/s around udot0 = 0.8 kV/s), so
    # that c and udot0 are both identified
    fits, ndim = _stats(PreisachRate(3), RATE_TRUTH, range(3), (1.0, 20.0))
    _check_calibration(fits, ndim)


@pytest.mark.slow
def test_rate_90_percent_intervals_cover_at_the_nominal_rate():
    fits, ndim = _stats(PreisachRate(3), RATE_TRUTH, range(3, 23), (1.0, 20.0))
    _check_calibration(fits, ndim)
    _check_coverage(fits)


@pytest.mark.slow
def test_rate_density_posterior_is_calibrated_and_covers():
    fits, ndim = _stats(PreisachDensityRate(n_grid=16), DENSITY_RATE_TRUTH, range(3, 23),
                        (1.0, 20.0))
    _check_calibration(fits, ndim)
    _check_coverage(fits)
