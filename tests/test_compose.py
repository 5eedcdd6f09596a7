"""Composed models: spec strings, namespacing, Hammerstein reductions and properties.

Oracles: a Hammerstein model with unit-gain dynamics is its static model exactly; a
composite equals its base run followed by its blocks applied by hand; state
continuation (two pieces, and one sample at a time, equal one run); batched equals
one-by-one; prior draws never give NaN; loops widen and tilt towards resonance.
"""

from __future__ import annotations

import itertools
import re
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models import get
from bayeshyst.models.blocks import ARX, Creep, Delay, Drift, SecondOrder
from bayeshyst.models.compose import Composite, Hammerstein, WithCreep, block_names, parse_spec
from bayeshyst.models.maxwell import MaxwellSlip
from bayeshyst.models.pi import PrandtlIshlinskii

SPECS = [
    "pi_play+arx",
    "pi_play+second_order+creep",
    "pi_stop+delay+drift",
    "maxwell_slip+asym_output",
    "pi_play+creep_fractional+arx+arx",
]


def _record(n: int = 2000, fs: float = 1e4, f: float = 20.0, jitter: float = 0.0,
            seed: int = 0) -> SimpleNamespace:
    """A unipolar piezo-like drive (0–150 V) with a loop-shaped output (0–20 µm)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.full(n, 1.0 / fs) * (1 + jitter * rng.uniform(-1, 1, n)))
    u = 75.0 + 70.0 * np.sin(2 * np.pi * f * t) * (0.7 + 0.3 * np.sin(2 * np.pi * 1.3 * t))
    return SimpleNamespace(t=t, u=u, y=0.12 * u + 0.8 * np.cos(2 * np.pi * f * t) + 1.0)


REC = _record()


def _thetas(model, width: int, seed: int, data=REC):
    space = model.param_space(data)
    return space.unpack(space.sample_prior(np.random.default_rng(seed), width))


def test_spec_strings_build_composites_with_namespaced_parameters():
    model = get("pi_play+second_order+creep")
    assert isinstance(model, Composite) and model.name == "pi_play+second_order+creep"
    names = model.param_space(REC).all_names
    assert "static.w" in names and "static.p0" in names and "static.r" in names
    assert "creep.c" in names and "creep.tau" in names and "second_order.f_n" in names
    assert model.rate_dependent and not get("maxwell_slip+asym_output").rate_dependent
    twice = parse_spec("pi_play + arx + arx")
    assert twice.namespaces == ("arx", "arx_2")
    assert "arx_2.kappa" in twice.param_space().names
    assert parse_spec("pi_stop") == get("pi_stop")
    assert "creep" in block_names() and "arx" in block_names()
    assert "static" in model.describe()


def test_bad_specs_name_the_valid_choices():
    with pytest.raises(ModelError, match="valid blocks: arx, asym_output"):
        get("pi_play+creeep")
    with pytest.raises(ModelError, match="must start with a hysteresis model"):
        get("creep+pi_play")
    with pytest.raises(ModelError, match="empty part"):
        get("pi_play++arx")
    with pytest.raises(ModelError, match="unknown model"):
        get("no_such_model+arx")
    with pytest.raises(ModelError):
        Composite(PrandtlIshlinskii(4), ("arx",))
    with pytest.raises(ModelError):
        Composite(ARX(), (ARX(),))


def test_constructors_flatten_and_match_spec_strings():
    pi = PrandtlIshlinskii(10)
    ham = Hammerstein(pi, ARX(2, 2))
    assert ham == parse_spec("pi_play+arx")
    nested = WithCreep(ham, n_terms=3)
    assert nested.base == pi and nested.blocks == (ARX(2, 2), Creep(3))
    assert nested.name == "pi_play+arx+creep"
    assert WithCreep(MaxwellSlip(), 5).param_space()["creep.c"].shape == (5,)


@pytest.mark.parametrize("base", [PrandtlIshlinskii(8), get("pi_stop"), MaxwellSlip(6)])
def test_hammerstein_with_unit_gain_dynamics_is_the_static_model_exactly(base):
    model = Hammerstein(base, ARX(0, 1))
    assert model.param_space(REC).names == tuple(f"static.{n}" for n in
                                                  base.param_space(REC).names)
    static = _thetas(base, 1, 3)
    theta = {f"static.{k}": v[0] for k, v in static.items()}
    y = model.simulate(REC.u, REC.t, theta)
    np.testing.assert_array_equal(y, base.simulate(REC.u, REC.t,
                                                   {k: v[0] for k, v in static.items()}))


def test_composite_is_its_base_followed_by_its_blocks():
    model = get("pi_play+second_order+creep")
    theta = {k: v[0] for k, v in _thetas(model, 1, 4).items()}
    sub = {ns: {k.split(".", 1)[1]: v for k, v in theta.items() if k.startswith(ns + ".")}
           for ns in ("static", "second_order", "creep")}
    w = model.base.simulate(REC.u, REC.t, sub["static"])
    w = SecondOrder().apply(w, REC.t, sub["second_order"]).y
    w = Creep().apply(w, REC.t, sub["creep"]).y
    np.testing.assert_array_equal(model.simulate(REC.u, REC.t, theta), w)


@settings(max_examples=40, deadline=None)
@given(spec=st.sampled_from(SPECS), seed=st.integers(0, 10_000),
       cuts=st.lists(st.integers(1, 59), max_size=6))
def test_two_pieces_equal_one_run(spec, seed, cuts):
    model = get(spec)
    rec = _record(n=60, jitter=0.04, seed=seed)
    theta = {k: v[0] for k, v in _thetas(model, 1, seed).items()}
    whole = model.run(rec.u, rec.t, theta)
    bounds = [0, *sorted(set(cuts)), 60]
    state, parts = None, []
    for a, b in itertools.pairwise(bounds):
        traj = model.run(rec.u[a:b], rec.t[a:b], theta,
                         state0=model.initial_state(theta, rec.u[0]) if state is None else state)
        parts.append(traj.y)
        state = traj.state
    np.testing.assert_array_equal(np.concatenate(parts), whole.y)
    np.testing.assert_array_equal(state, whole.state)


@pytest.mark.parametrize("spec", SPECS)
def test_one_sample_at_a_time_equals_one_run(spec):
    model = get(spec)
    theta = {k: v[0] for k, v in _thetas(model, 1, 8).items()}
    u, t = REC.u[:120], REC.t[:120]
    whole = model.simulate(u, t, theta)
    state = model.initial_state(theta, u[0])
    steps = []
    for k in range(u.size):
        traj = model.run(u[k:k + 1], t[k:k + 1], theta, state0=state)
        steps.append(traj.y[0])
        state = traj.state
    np.testing.assert_array_equal(steps, whole)


@pytest.mark.parametrize("spec", SPECS)
def test_batched_equals_one_by_one(spec):
    model = get(spec)
    thetas = _thetas(model, 5, 9)
    rec = _record(n=4100)  # W N above the kernels' threshold: the blocks run in parallel
    traj = model.run_batch(rec.u, rec.t, thetas)
    assert traj.n_failed == 0
    for i in range(5):
        one = model.run(rec.u, rec.t, {k: v[i] for k, v in thetas.items()})
        np.testing.assert_array_equal(traj.y[i], one.y)
        np.testing.assert_array_equal(traj.state[i], one.state)


@pytest.mark.parametrize("data", [REC, None], ids=["data-scaled", "no-data"])
@pytest.mark.parametrize("spec", ["pi_play+arx", "pi_play+second_order+creep",
                                  "pi_stop+delay+drift", "maxwell_slip+asym_output"])
def test_prior_draws_never_give_nan(spec, data):
    model = get(spec)
    traj = model.run_batch(REC.u, REC.t, _thetas(model, 200, 10, data=data))
    assert traj.n_failed == 0 and np.all(np.isfinite(traj.y))


@pytest.mark.parametrize("spec", ["pi_play+arx", "pi_play+second_order+creep+delay",
                                  "maxwell_slip+asym_output+creep_fractional"])
def test_a_record_starts_at_rest(spec):
    model = get(spec)
    theta = {k: v[0] for k, v in _thetas(model, 1, 12).items()}
    y = model.simulate(np.full(300, 60.0), REC.t[:300], theta)
    np.testing.assert_allclose(y, y[0], rtol=1e-12)


def test_loops_widen_and_tilt_as_the_drive_approaches_resonance():
    model = Hammerstein(PrandtlIshlinskii(6), SecondOrder())
    space = model.param_space(REC)
    theta = {"static.p0": 0.08, "static.w": np.full(6, 0.01), "static.r": space.fixed["static.r"],
             "second_order.f_n": 100.0, "second_order.zeta": 0.2}
    areas, slopes = [], []
    for f in (2.0, 40.0, 70.0):
        t = np.arange(int(4 * 20_000 / f)) / 20_000.0
        u = 75.0 + 70.0 * np.sin(2 * np.pi * f * t)
        y = model.simulate(u, t, theta)
        last = t >= 3.0 / f  # the fourth period, after the transient
        uu, yy = u[last], y[last]
        areas.append(abs(np.sum(0.5 * (yy[1:] + yy[:-1]) * np.diff(uu))))
        slopes.append(np.polyfit(uu, yy, 1)[0])
    assert areas[0] < areas[1] < areas[2] and areas[2] > 3 * areas[0]
    assert slopes[0] < slopes[1] < slopes[2] and slopes[2] > 1.3 * slopes[0]


def test_state_of_the_wrong_size_is_refused():
    model = Composite(PrandtlIshlinskii(4), (Delay(5), Drift()))
    theta = {k: v[0] for k, v in _thetas(model, 1, 1).items()}
    with pytest.raises(ParameterError, match="blocks alone need"):
        model.run(REC.u[:5], REC.t[:5], theta, state0=np.zeros(3))


def test_spec_strings_carry_settings():
    m = get("pi_play(n_operators=4)+second_order")
    assert m.base == get("pi_play", n_operators=4)
    assert get("preisach(n_levels=6, relay='01')") == get("preisach", n_levels=6, relay="01")
    assert get(" pi_play ( n_operators = 3 ) ") == get("pi_play", n_operators=3)


@pytest.mark.parametrize("spec, message", [
    ("pi_play(4)", "given by name"),
    ("pi_play(n=4)", "no setting(s) ['n']"),
    ("pi_play(n_operators=x)", "must be a literal"),
    ("pi_play(n_operators=4", "cannot read"),
    ("pi_play+second_order(fn=3)", "block 'second_order' has no setting(s) ['fn']"),
    ("pi_play(**{'a': 1})", "'**' is not allowed"),
])
def test_bad_spec_settings_are_named(spec, message):
    with pytest.raises(ModelError, match=re.escape(message)):
        get(spec)
