"""Preisach models: slow relay-by-relay and analytic oracles, and the memory properties."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bayeshyst.models.preisach as P
from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models import registry
from bayeshyst.models.base import DataScales

SCALES = DataScales(0.0, 100.0, -2.0, 18.0)
FAST = settings(max_examples=25, deadline=None)


# ------------------------------------------------------------------ slow oracles
def relay_oracle(u, levels, mu, offset, relay):
    """Every relay with its own memory, every sample (review Eq. 1-3), pure Python.

    Starts from negative saturation (all relays off); relay up when ``u >= alpha``,
    down when ``u < beta``.
    """
    n = len(levels)
    cells = [(levels[i], levels[j]) for i in range(n) for j in range(i + 1)]
    on = [False] * len(cells)
    out = []
    for x in u:
        total = offset
        for c, (alpha, beta) in enumerate(cells):
            if x >= alpha:
                on[c] = True
            elif x < beta:
                on[c] = False
            value = (1.0 if on[c] else 0.0) if relay == "01" else (1.0 if on[c] else -1.0)
            total += mu[c] * value
        out.append(total)
    return np.array(out)


def dominant_extrema(history):
    """Staircase ``[(A_1, B_1), (A_2, B_2), ...]`` of a history, by its definition.

    ``A_1`` is the largest value (last occurrence), ``B_1`` the smallest after it, ``A_2``
    the largest after that, ...; a final ``A`` with nothing after it gets ``B = +inf``.
    """
    h = list(history)
    pairs, start = [], 0
    while start < len(h):
        seg = h[start:]
        ia = start + len(seg) - 1 - int(np.argmax(seg[::-1]))
        if ia == len(h) - 1:
            pairs.append((h[ia], math.inf))
            break
        seg = h[ia + 1:]
        ib = ia + 1 + len(seg) - 1 - int(np.argmin(seg[::-1]))
        pairs.append((h[ia], h[ib]))
        start = ib + 1
    return pairs


def everett_sum(pairs, everett):
    """Eq. 7-8: ``sum_k Y(A_k, B_{k-1}) - Y(A_k, B_k)`` with ``B_0 = -inf``."""
    total, b_prev = 0.0, -math.inf
    for a, b in pairs:
        total += everett(a, b_prev) - (everett(a, b) if b < math.inf else 0.0)
        b_prev = b
    return total


def random_weights(rng, model):
    return {"offset": rng.normal(), "mu": rng.normal(size=model.n_cells),
            "levels": model.param_space(SCALES).fixed["levels"]}


def signal(rng, kind, n=300):
    t = np.linspace(0.0, 1.0, n)
    if kind == "walk":
        return np.clip(50 + np.cumsum(rng.normal(0.0, 6.0, n)), -10, 110), t
    if kind == "sine":
        return 50 + 55 * np.sin(2 * np.pi * 5 * t) * np.exp(-2.5 * t), t
    # multiples of 6.25 V: the levels of Preisach(8) and the values halfway between them,
    # so that inputs hit thresholds exactly (ties)
    return rng.integers(0, 17, n) * 6.25, t


def density_theta(model, **over):
    theta = {"offset": 0.0, "k_rev": 0.0, "scale": 1.0, "centre": 45.0, "sd_centre": 20.0,
             "halfwidth": 12.0, model._spread: 0.6 if model.shape == "lognormal" else 8.0,
             "rho": 0.3, "bounds": np.array([0.0, 100.0])}
    theta.update(over)
    return theta


# ------------------------------------------------------------------ relay oracle
@pytest.mark.parametrize("relay", ["01", "pm1"])
@pytest.mark.parametrize("kind", ["walk", "sine", "lattice"])
def test_kernel_matches_relay_by_relay_oracle(relay, kind):
    rng = np.random.default_rng(["walk", "sine", "lattice"].index(kind) + 10 * len(relay))
    model = P.Preisach(8, relay=relay)
    for _ in range(3):
        theta = random_weights(rng, model)
        u, t = signal(rng, kind)
        y = model.simulate(u, t, theta)
        ref = relay_oracle(u, theta["levels"], theta["mu"], theta["offset"], relay)
        np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12)


def test_oracle_with_uneven_levels_and_one_level():
    rng = np.random.default_rng(3)
    u, t = signal(rng, "walk", 400)
    for n in (1, 5):
        model = P.Preisach(n)
        levels = np.sort(rng.uniform(0, 100, n))
        theta = {"offset": 0.3, "mu": rng.normal(size=model.n_cells), "levels": levels}
        ref = relay_oracle(u, levels, theta["mu"], 0.3, "01")
        np.testing.assert_allclose(model.simulate(u, t, theta), ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("relay", ["01", "pm1"])
def test_regressors_reproduce_output(relay):
    rng = np.random.default_rng(4)
    model = P.Preisach(6, relay=relay)
    theta = random_weights(rng, model)
    u, t = signal(rng, "sine", 200)
    phi = model.regressors(u, np.arange(u.size, dtype=float), theta)
    assert phi.shape == (200, 1 + model.n_cells)
    assert set(np.unique(phi[:, 1:])) <= ({0.0, 1.0} if relay == "01" else {-1.0, 1.0})
    coef = np.concatenate([[theta["offset"]], theta["mu"]])
    np.testing.assert_allclose(phi @ coef, model.simulate(u, t, theta), atol=1e-12)
    # from a given state: the regressors of the second half of the record
    mid = model.run(u[:100], t[:100], theta)
    phi2 = model.regressors(u[100:], np.arange(u.size - 100, dtype=float), theta,
                            state0=mid.state)
    np.testing.assert_allclose(phi2 @ coef, model.simulate(u, t, theta)[100:], atol=1e-12)


def test_everett_table_of_relays():
    rng = np.random.default_rng(5)
    model = P.Preisach(5)
    theta = random_weights(rng, model)
    table = model.everett_table(theta)
    assert table.values.shape == (6, 6) and not table.bilinear
    assert table.total == pytest.approx(theta["mu"].sum(), abs=1e-12)
    alpha, beta = model.cell_thresholds(theta)
    # Y(a, b) is the mass of the relays with b < beta <= alpha <= a
    for a, b in [(50.0, 20.0), (100.0, -1.0), (30.0, 30.0), (10.0, 70.0)]:
        want = theta["mu"][(alpha <= a) & (beta > b)].sum()
        assert table.evaluate(a, b) == pytest.approx(want, abs=1e-12)


# ------------------------------------------------------------------ memory properties
def _models():
    return [P.Preisach(7), P.PreisachDensity(n_grid=16)]


def _theta_for(model, rng):
    if isinstance(model, P.Preisach):
        return random_weights(rng, model)
    return density_theta(model, rho=rng.uniform(-0.8, 0.8), centre=rng.uniform(30, 70))


@FAST
@given(seed=st.integers(0, 2**31 - 1),
       prefix=st.lists(st.floats(0, 100), min_size=1, max_size=15),
       inner=st.lists(st.floats(0, 1), min_size=1, max_size=15),
       jump=st.floats(0, 60), suffix=st.lists(st.floats(0, 100), max_size=15),
       falling=st.booleans(), which=st.integers(0, 1))
def test_wiping_out(seed, prefix, inner, jump, suffix, falling, which):
    # extrema inside [p, s0] after the last prefix value p are wiped out once the input
    # reaches s0: the two histories give identical outputs and states from there on
    model = _models()[which]
    theta = _theta_for(model, np.random.default_rng(seed))
    p = prefix[-1]
    s0 = p - jump if falling else p + jump
    # clipped: p + f (s0 - p) may round one ulp beyond s0
    wiped = np.clip([p + f * (s0 - p) for f in inner], min(p, s0), max(p, s0))
    tail = np.array([s0, *suffix])
    u1 = np.array([*prefix, *wiped, *tail])
    u2 = np.array([*prefix, *tail])
    r1 = model.run(u1, np.arange(u1.size), theta)
    r2 = model.run(u2, np.arange(u2.size), theta)
    np.testing.assert_array_equal(r1.y[-tail.size:], r2.y[-tail.size:])
    np.testing.assert_array_equal(r1.state, r2.state)


def _loop(u1, u2, n=40):
    up = np.linspace(u1, u2, n)
    return np.concatenate([up, up[::-1][1:]])


@pytest.mark.parametrize("which", [0, 1])
def test_congruent_minor_loops(which):
    model = _models()[which]
    rng = np.random.default_rng(6 + which)
    theta = _theta_for(model, rng)
    u1, u2 = 35.0, 60.0
    # two different histories, both ending at u1 on a descent from a maximum above u2
    hist_a = np.concatenate([np.linspace(0, 95, 30), np.linspace(95, 10, 30),
                             np.linspace(10, 80, 30), np.linspace(80, u1, 30)])
    hist_b = np.concatenate([np.linspace(0, 70, 30), np.linspace(70, 25, 30),
                             np.linspace(25, 65, 30), np.linspace(65, u1, 30)])
    loop = _loop(u1, u2)
    ya = model.simulate(np.concatenate([hist_a, loop]), np.arange(hist_a.size + loop.size),
                        theta)[hist_a.size:]
    yb = model.simulate(np.concatenate([hist_b, loop]), np.arange(hist_b.size + loop.size),
                        theta)[hist_b.size:]
    shift = ya - yb
    assert abs(shift[0]) > 1e-6  # the histories do leave different states
    np.testing.assert_allclose(shift, shift[0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("which", [0, 1])
def test_return_point_memory(which):
    model = _models()[which]
    rng = np.random.default_rng(8 + which)
    theta = _theta_for(model, rng)
    u1, u2 = 30.0, 70.0
    hist = np.concatenate([np.linspace(0, 90, 20), np.linspace(90, u1, 20)])
    # up to u2 and back to u1, with smaller excursions inside [u1, u2] on the way
    path = np.array([u1, 50, 40, 62, 55, u2, 45, 52, 38, 44, u1, 48, 41, u2, 33, u1])
    u = np.concatenate([hist, path])
    y = model.simulate(u, np.arange(u.size), theta)[hist.size:]
    at_u1 = y[path == u1]
    at_u2 = y[path == u2]
    np.testing.assert_allclose(at_u1, at_u1[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(at_u2, at_u2[0], rtol=0, atol=1e-12)


# ------------------------------------------------------------------ state and batches
@FAST
@given(seed=st.integers(0, 2**31 - 1), cuts=st.lists(st.integers(1, 8), max_size=12),
       n=st.integers(1, 60), which=st.integers(0, 1))
def test_continuation_in_pieces(seed, cuts, n, which):
    model = _models()[which]
    rng = np.random.default_rng(seed)
    theta = _theta_for(model, rng)
    u = np.clip(50 + np.cumsum(rng.normal(0, 15, n)), -5, 105)
    t = np.arange(n, dtype=float)
    whole = model.run(u, t, theta)
    parts, state, start = [], None, 0
    for c in [*cuts, n]:
        stop = min(start + c, n)
        if stop > start:
            tr = model.run(u[start:stop], t[start:stop], theta, state0=state)
            parts.append(tr.y)
            state = tr.state
        start = stop
    np.testing.assert_allclose(np.concatenate(parts), whole.y, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(state, whole.state)


def test_length_one_pieces():
    model = P.PreisachDensity(n_grid=20)
    theta = density_theta(model)
    u, t = signal(np.random.default_rng(9), "sine", 120)
    state, ys = None, []
    for k in range(u.size):
        tr = model.run(u[k:k + 1], t[k:k + 1], theta, state0=state)
        ys.append(tr.y[0])
        state = tr.state
    np.testing.assert_allclose(ys, model.simulate(u, t, theta), rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", [P.Preisach(6, relay="pm1"), P.PreisachDensity(n_grid=24),
                                   P.PreisachDensity(n_grid=24, shape="gaussian")])
def test_batched_equals_one_by_one(model):
    space = model.param_space(SCALES)
    z = space.sample_prior(np.random.default_rng(10), 5)
    thetas = space.unpack(z)
    u, t = signal(np.random.default_rng(11), "walk", 250)
    yb = model.simulate_batch(u, t, thetas)
    for w in range(5):
        np.testing.assert_array_equal(yb[w], model.simulate(u, t, space.unpack(z[w])))


@pytest.mark.parametrize("model", [P.Preisach(), P.Preisach(relay="pm1"), P.PreisachDensity(),
                                   P.PreisachDensity(shape="gaussian")])
def test_prior_draws_never_nan(model):
    space = model.param_space(SCALES)
    z = space.sample_prior(np.random.default_rng(12), 200)
    u, t = signal(np.random.default_rng(13), "sine", 300)
    for row in z:
        assert np.all(np.isfinite(model.simulate(u, t, space.unpack(row))))


@pytest.mark.parametrize("which", [0, 1])
def test_rate_independent(which):
    model = _models()[which]
    theta = _theta_for(model, np.random.default_rng(14))
    u, t = signal(np.random.default_rng(15), "sine", 200)
    warped = 3.0 * t**3 + 0.1 * t  # monotone time warp
    np.testing.assert_array_equal(model.simulate(u, t, theta), model.simulate(u, warped, theta))


# ------------------------------------------------------------------ memory overflow
def test_overflow_forgets_innermost_pair():
    model = P.Preisach(9, max_memory=4)
    big = P.Preisach(9)
    theta = random_weights(np.random.default_rng(16), model)
    extrema = [0, 100, 2, 90, 10, 80, 20, 70, 30, 60]
    u = np.concatenate([np.linspace(a, b, 15)[1:] for a, b in itertools.pairwise(extrema)])
    u = np.concatenate([[0.0], u, [45.0]])
    tr = model.run(u, np.arange(u.size), theta)
    # stored: 100, 2, 90, 10 (full); pushing 80 drops (90, 10); pushing 70 drops (80, 20);
    # pushing 60 drops (70, 30): the memory is that of the history 0, 100, 2, 60, 45
    assert P.memory_merges(tr.state) == 3
    surgery = np.concatenate([np.linspace(0, 100, 15), np.linspace(100, 2, 15),
                              np.linspace(2, 60, 15), [45.0]])
    ref = big.run(surgery, np.arange(surgery.size), theta)
    assert tr.y[-1] == pytest.approx(ref.y[-1], abs=1e-12)
    keep = [0, 2, 3, 4, 5]  # count, tip, the three stored extrema (not the merge count)
    np.testing.assert_array_equal(tr.state[keep], ref.state[keep])
    assert P.memory_merges(ref.state) == 0
    # before the first overflow both memories agree; afterwards the output is approximate
    full = big.simulate(u, np.arange(u.size), theta)
    first = 5 * 14 + 1  # the reversal at 80 is the first with a full memory
    np.testing.assert_array_equal(tr.y[:first], full[:first])
    assert np.max(np.abs(tr.y - full)) > 1e-9
    assert np.all(np.isfinite(tr.y))


@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 80), depth=st.integers(2, 5))
def test_overflow_matches_spec_and_continues(seed, n, depth):
    # spec: on a reversal with a full memory the two most recent stored extrema are
    # forgotten; the output is then the Everett sum of the remaining staircase
    rng = np.random.default_rng(seed)
    model = P.Preisach(6, max_memory=depth)
    theta = random_weights(rng, model)
    u = rng.uniform(-5, 105, n)
    stack, tip, ref = [], u[0], []
    alpha, beta = model.cell_thresholds(theta)
    for x in u:
        rising = len(stack) % 2 == 0
        if (rising and x < tip) or (not rising and x > tip):
            if len(stack) == depth:
                del stack[-2:]
            stack.append(tip)
            rising = not rising
        tip = x
        while len(stack) >= 2 and (x >= stack[-2] if rising else x <= stack[-2]):
            del stack[-2:]
        ext = [*stack, tip]
        on = np.zeros(alpha.size, dtype=bool)
        for k in range(0, len(ext), 2):
            b = ext[k + 1] if k + 1 < len(ext) else math.inf
            on |= (alpha <= ext[k]) & (beta <= b)
        ref.append(theta["offset"] + theta["mu"][on].sum())
    whole = model.run(u, np.arange(n), theta)
    np.testing.assert_allclose(whole.y, ref, rtol=0, atol=1e-12)
    half = model.run(u[: n // 2], np.arange(n // 2), theta)
    rest = model.run(u[n // 2:], np.arange(n - n // 2), theta, state0=half.state)
    np.testing.assert_allclose(np.concatenate([half.y, rest.y]), whole.y, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ density model
def _cell_weights(table, edges, scale):
    """Mass of the density over each relay cell, from the Everett function."""
    ev = table.evaluate
    mu = []
    for i in range(edges.size - 1):
        for j in range(i + 1):
            if i == j:
                mu.append(ev(edges[i + 1], edges[i]))
            else:
                mu.append(ev(edges[i + 1], edges[j]) - ev(edges[i], edges[j])
                          - ev(edges[i + 1], edges[j + 1]) + ev(edges[i], edges[j + 1]))
    return scale * np.array(mu, dtype=float)


def _grid_pair(n_levels, n_grid, theta):
    dens = P.PreisachDensity(n_grid=n_grid)
    table = dens.everett_table(theta)
    edges = np.linspace(0.0, 100.0, n_levels + 1)
    relay = P.Preisach(n_levels)
    rtheta = {"offset": theta["offset"], "mu": _cell_weights(table, edges, theta["scale"]),
              "levels": 0.5 * (edges[1:] + edges[:-1])}
    return dens, relay, rtheta


def test_density_equals_relay_grid_on_cell_edges():
    theta = density_theta(P.PreisachDensity(), offset=1.5, scale=7.0)
    dens, relay, rtheta = _grid_pair(10, 60, theta)
    rng = np.random.default_rng(17)
    u = rng.integers(0, 11, 300) * 10.0  # every sample on a cell edge
    t = np.arange(u.size)
    np.testing.assert_allclose(relay.simulate(u, t, rtheta), dens.simulate(u, t, theta),
                               rtol=0, atol=1e-12)


def test_relay_grid_converges_to_density():
    theta = density_theta(P.PreisachDensity(), scale=1.0)
    u, t = signal(np.random.default_rng(18), "sine", 400)
    u = np.clip(u, 0, 100)
    errors = []
    for n_levels in (4, 8, 16, 32):
        dens, relay, rtheta = _grid_pair(n_levels, 128, theta)
        errors.append(np.max(np.abs(relay.simulate(u, t, rtheta) - dens.simulate(u, t, theta))))
    assert all(b < 0.75 * a for a, b in itertools.pairwise(errors)), errors


def test_density_grid_convergence():
    theta = density_theta(P.PreisachDensity())
    u, t = signal(np.random.default_rng(19), "walk", 400)
    fine = P.PreisachDensity(n_grid=512).simulate(u, t, theta)
    errors = [np.max(np.abs(P.PreisachDensity(n_grid=g).simulate(u, t, theta) - fine))
              for g in (16, 32, 64)]
    assert all(b < 0.5 * a for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < 1e-3


def test_uniform_density_matches_analytic_everett():
    lo, hi = 0.0, 100.0

    def exact(a, b):  # uniform density on the triangle, normalised: area ratio
        a, b = min(max(a, lo), hi), min(max(b, lo), hi)
        return (a - b) ** 2 / (hi - lo) ** 2 if a > b else 0.0

    # a bivariate Gaussian of (c, r) far wider than the plane is uniform on it
    model = P.PreisachDensity(n_grid=8, shape="gaussian")
    theta = density_theta(model, sd_centre=1e9, halfwidth=1.0, sd_halfwidth=1e9, rho=0.0,
                          bounds=np.array([lo, hi]))
    table = model.everett_table(theta)
    want = np.array([[exact(a, b) for b in table.nodes] for a in table.nodes])
    np.testing.assert_allclose(table.values, want, rtol=0, atol=1e-12)
    # the staircase with the analytic table, against the continuous closed form
    u = np.clip(signal(np.random.default_rng(20), "walk", 150)[0], lo, hi)
    ref = np.array([everett_sum(dominant_extrema(u[: k + 1]), exact) for k in range(u.size)])
    errors = []
    for g in (8, 16, 32, 64):
        nodes = np.linspace(lo, hi, g + 1)
        tab = P.EverettTable(nodes, [[exact(a, b) for b in nodes] for a in nodes], True)
        errors.append(np.max(np.abs(P.everett_response(u, tab)[0] - ref)))
    assert all(b < 0.3 * a for a, b in itertools.pairwise(errors)), errors  # O(h^2)
    on_nodes = np.linspace(lo, hi, 9)[np.random.default_rng(21).integers(0, 9, 100)]
    ref_nodes = [everett_sum(dominant_extrema(on_nodes[: k + 1]), exact) for k in range(100)]
    np.testing.assert_allclose(P.everett_response(on_nodes, table)[0], ref_nodes, atol=1e-12)


def test_symmetric_density_gives_point_symmetric_loop_and_rho_breaks_it():
    model = P.PreisachDensity(n_grid=64)
    x = np.linspace(0, 50, 26)
    u = np.concatenate([50 - x[::-1], 50 + x[1:], 50 + x[::-1][1:], 50 - x[1:]])
    up, down = slice(0, 51), slice(50, 101)

    def asymmetry(rho):
        y = model.simulate(u, np.arange(u.size), density_theta(model, centre=50.0, rho=rho))
        # point symmetry about (50, 1/2): up(50 + x) + down(50 - x) = 1
        return np.max(np.abs(y[up] + y[down] - 1.0))

    assert asymmetry(0.0) < 1e-8
    assert asymmetry(0.7) > 1e-2


def test_density_everett_table_is_normalised_and_monotone():
    model = P.PreisachDensity(n_grid=32)
    table = model.everett_table(density_theta(model))
    assert table.total == pytest.approx(1.0, abs=1e-12)
    vals = table.values
    assert np.all(np.diff(vals, axis=0) >= -1e-15)  # grows with alpha
    assert np.all(np.diff(vals, axis=1) <= 1e-15)  # shrinks with beta


# ------------------------------------------------------------------ contract and errors
def test_registry_and_settings():
    assert isinstance(registry.get("preisach", n_levels=5, relay="pm1"), P.Preisach)
    assert isinstance(registry.get("preisach_density", n_grid=10), P.PreisachDensity)
    assert P.Preisach(5).param_space()["mu"].shape == (15,)
    for bad in (dict(n_levels=0), dict(relay="+-1"), dict(max_memory=1)):
        with pytest.raises(ModelError):
            P.Preisach(**bad)
    for bad in (dict(n_grid=1), dict(shape="cauchy"), dict(max_memory=0)):
        with pytest.raises(ModelError):
            P.PreisachDensity(**bad)


def test_initial_state_is_rise_from_negative_saturation():
    model = P.Preisach(4)
    theta = random_weights(np.random.default_rng(22), model)
    state = model.initial_state(theta, 60.0)
    assert state.shape == (3 + 256,) and state[0] == 0 and state[2] == 60.0
    alpha, _ = model.cell_thresholds(theta)
    y = model.simulate([60.0], [0.0], theta)
    assert y[0] == pytest.approx(theta["offset"] + theta["mu"][alpha <= 60.0].sum())


def test_invalid_states_and_parameters():
    model = P.Preisach(4)
    theta = random_weights(np.random.default_rng(23), model)
    u, t = np.array([10.0, 20.0]), np.array([0.0, 1.0])
    good = model.run(u, t, theta).state
    for corrupt in ({0: 2.5}, {0: 300.0}, {0: 2.0, 3: 10.0, 4: 50.0}, {2: np.nan}):
        bad = good.copy()
        for k, v in corrupt.items():
            bad[k] = v
        with pytest.raises(ParameterError):
            model.run(u, t, theta, state0=bad)
    with pytest.raises(ParameterError):
        model.run(u, t, theta, state0=good[:-1])
    broken = dict(theta, levels=theta["levels"][::-1].copy())
    with pytest.raises(SimulationError):
        model.simulate(u, t, broken)
    batch = {k: np.stack([v, broken[k]]) for k, v in theta.items()}
    tr = model.run_batch(u, t, batch)
    assert tr.failed.tolist() == [False, True] and np.all(np.isnan(tr.y[1]))
    dens = P.PreisachDensity(n_grid=8)
    with pytest.raises(SimulationError):
        dens.simulate(u, t, density_theta(dens, rho=1.0))
    with pytest.raises(ParameterError):
        P.EverettTable([0.0, 0.0], np.zeros((2, 2)), True)
