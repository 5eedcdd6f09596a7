"""MRC electromechanical model (review Eq. 38–44) against oracles.

Oracles: ``scipy.signal.lsim`` of the closed-loop transfer function when ``H`` is linear
(built from the *physical* parameters, so the documented mapping is tested too); the
exact play-PI inverse (Kuhnen, :func:`play_pi_inverse`) of the static stop-type relation
when the mechanics is quasi-static; ``brentq`` for the algebraic loop. Then properties.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal
from scipy.optimize import brentq

from bayeshyst.errors import ModelError, ParameterError, SimulationError
from bayeshyst.models import get
from bayeshyst.models._kernels.mrc import loop_solve
from bayeshyst.models.mrc import MRCElectromechanical
from bayeshyst.models.pi import PrandtlIshlinskii, play_pi_inverse
from tests.contracts import (
    assert_batch_equals_single,
    assert_pieces_match,
    assert_prior_draws_simulate,
)

FS = 5000.0
T = np.arange(1500) / FS
U = 40.0 + 30.0 * np.sin(2 * np.pi * 40 * T) + 8.0 * np.sin(2 * np.pi * 310 * T + 1.0)
DATA = SimpleNamespace(t=np.arange(1001) / FS, u=np.linspace(0.0, 80.0, 1001),
                       y=np.linspace(0.0, 9.0, 1001))


def _theta(**kw):
    th = {"f_n": 400.0, "zeta": 0.15, "gain": 0.15, "coupling": 0.8,
          "rho": np.array([0.3, 0.2, 0.5]), "delta": np.array([2.0, 6.0, 15.0])}
    th.update(kw)
    return th


def _lsim_physical(model, theta, u, t):
    """x from m x'' + c x' + k x = T_F u_p with H linear (q_b fixed at the start)."""
    p = model.physical_parameters(theta, C=2e-6, k=3e6)
    inv_ch = np.sum(1.0 / p["C_i"])  # series capacitors of the sticking elements
    if inv_ch == 0.0:  # no hysteresis at all: u_p = u
        num, stiff = p["T_F"], p["k"]
    else:
        ch = 1.0 / inv_ch
        num = p["T_F"] * ch / (ch + p["C"])
        stiff = p["k"] + p["T_F"] * p["T_q"] / (ch + p["C"])
    sys = signal.lti([num], [p["m"], p["c"], stiff])
    return signal.lsim(sys, u, t)[1]


@pytest.mark.parametrize("case", ["sticking elements", "no elements"])
def test_linear_case_matches_lsim(case):
    model = MRCElectromechanical(3)
    # slip deflections far beyond any charge swing: H is the linear series capacitance;
    # rho = 0: H vanishes. Start at u = 0 so the relaxed state is the zero state of lsim.
    theta = (_theta(delta=np.full(3, 1e9)) if case == "sticking elements"
             else _theta(rho=np.zeros(3)))
    u = U - U[0]
    y = model.simulate(u, T, theta)
    ref = _lsim_physical(model, theta, u, T)
    assert np.max(np.abs(y - ref)) <= 1e-6 * np.ptp(ref)


def _quasi_static_error(f_n):
    model = MRCElectromechanical(3)
    rho, delta, c, gain = np.array([0.3, 0.2, 0.5]), np.array([1.0, 3.0, 6.0]), 0.5, 2.0
    t = np.arange(4001) / 2000.0
    u = 20.0 * np.sin(2 * np.pi * t) * np.minimum(1.0, t)  # starts at 0 with u' = 0
    y = model.simulate(u, t, _theta(f_n=f_n, zeta=0.5, gain=gain, coupling=c, rho=rho,
                                    delta=delta))
    # statically x = gain u_p, Q = (1 + c) u_p and u = sum rho E_delta[Q] + Q / (1 + c):
    # a stop-PI in Q, i.e. the play-PI (1/(1+c) + sum rho) Q - sum rho F_delta[Q],
    # whose exact inverse gives Q(u) in closed form
    inv = play_pi_inverse(1.0 / (1.0 + c) + rho.sum(), -rho, delta)
    q = PrandtlIshlinskii(3).simulate(u, t, inv.play_theta)
    ref = gain * q / (1.0 + c)
    return np.max(np.abs(y - ref)) / np.ptp(ref)


def test_quasi_static_limit_is_the_static_maxwell_slip_inverse():
    # the residual is the first-order lag 2 zeta f / f_n of the mechanics (1e-4 here):
    # it must be that small and shrink tenfold per decade of f_n
    e3, e4 = _quasi_static_error(1e3), _quasi_static_error(1e4)
    assert e4 < 1e-4
    assert 7.0 < e3 / e4 < 13.0


def test_loop_residual_below_1e10_at_every_step():
    model = MRCElectromechanical(4)
    rng = np.random.default_rng(5)
    u = 40.0 + np.cumsum(rng.normal(0, 3.0, 1500))
    theta = _theta(rho=np.array([0.4, 0.3, 0.2, 0.6]), delta=np.array([1.0, 3.0, 7.0, 12.0]),
                   coupling=1.3)
    d = model.diagnose(u, T, theta)
    assert np.max(np.abs(d["residual"])) <= 1e-10
    np.testing.assert_allclose(d["u_h"] + d["u_p"], u, atol=1e-12)
    np.testing.assert_allclose(d["Q"], d["u_p"] + theta["coupling"] / theta["gain"] * d["y"],
                               atol=1e-10)
    np.testing.assert_array_equal(d["y"], model.simulate(u, T, theta))
    # the hysteresis is active: elements slip, so u_h saturates and reverses
    assert np.ptp(d["u_h"]) > 5.0


def test_loop_solve_matches_brentq():
    rng = np.random.default_rng(9)
    for _ in range(200):
        n = int(rng.integers(1, 6))
        rho, delta = rng.uniform(0, 2, n), rng.uniform(0, 5, n)
        qb = rng.normal(0, 4, n)
        r = rng.normal(0, 10)

        def g(q, rho=rho, delta=delta, qb=qb, r=r):
            return q + np.sum(rho * np.clip(q - qb, -delta, delta)) - r

        hmax = float(np.sum(rho * delta))
        q, ok = loop_solve(r, rho, delta, qb, rng.normal(0, 10), hmax)
        assert ok
        ref = brentq(g, r - hmax - 1, r + hmax + 1, xtol=1e-14, rtol=1e-15)
        assert abs(q - ref) <= 1e-12 * (1 + abs(ref))
        assert abs(g(q)) <= 1e-12


def _loop_area(model, theta, freq, n=400):
    t = np.arange(3 * n + 1) / (n * freq)
    u = 40.0 + 35.0 * np.sin(2 * np.pi * freq * t)
    y = model.simulate(u, t, theta)
    return np.sum(y[2 * n + 1:] * np.diff(u[2 * n:]))  # third period: settled


def test_loop_widens_with_frequency():
    model = MRCElectromechanical(3)
    theta = _theta()
    areas = [_loop_area(model, theta, theta["f_n"] / r) for r in (200.0, 30.0, 8.0)]
    # counter-clockwise (negative signed area in sum y du) and wider with frequency
    assert areas[0] < 0
    assert abs(areas[0]) < abs(areas[1]) < abs(areas[2])


# --------------------------------------------------------------------- properties
@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(1, 119), min_size=1, max_size=6, unique=True))
def test_state_continuation(cuts):
    assert_pieces_match(MRCElectromechanical(3), U[:120], T[:120], _theta(),
                        [0, *sorted(cuts), 120])


def test_length_one_pieces():
    assert_pieces_match(MRCElectromechanical(3), U[:300], T[:300], _theta(), range(301))


def test_batched_equals_one_by_one():
    model = MRCElectromechanical(4)
    assert_batch_equals_single(model, U, T, model.param_space(DATA), seed=3)


def test_prior_draws_never_nan():
    model = MRCElectromechanical(5)
    assert_prior_draws_simulate(model, U[:500], T[:500], model.param_space(DATA), seed=17)


def test_failures_are_flagged_not_returned():
    model = MRCElectromechanical(3, max_substeps=50)
    thetas = {k: np.stack([np.asarray(v, float)] * 3) for k, v in _theta().items()}
    thetas["f_n"][1] = 1e6  # needs ~ 8000 sub-steps per sample > max_substeps
    thetas["rho"][2, 0] = -1.0  # a negative capacitance: G is not monotone
    traj = model.run_batch(U, T, thetas)
    np.testing.assert_array_equal(traj.failed, [False, True, True])
    assert np.all(np.isnan(traj.y[1:])) and np.all(np.isnan(traj.state[1:]))
    thetas["f_n"][1] = 400.0  # a failed walker's NaN state stays failed when continued
    more = model.run_batch(U, T + T[-1] + 1.0 / FS, thetas, state0=traj.state)
    np.testing.assert_array_equal(more.failed, [False, True, True])
    with pytest.raises(SimulationError):
        model.simulate(U, T, _theta(f_n=1e6))
    with pytest.raises(SimulationError):
        model.diagnose(U, T, _theta(zeta=-0.1))


def test_settings_and_inputs_are_validated():
    with pytest.raises(ModelError):
        MRCElectromechanical(0)
    with pytest.raises(ModelError):
        get("mrc", step=2.0)
    with pytest.raises(ParameterError):
        MRCElectromechanical(3).simulate(U, T[::-1], _theta())
    traj = MRCElectromechanical(3).run(U[:10], T[:10], _theta())
    with pytest.raises(ParameterError):  # continuing must move forward in time
        MRCElectromechanical(3).run(U[:10], T[:10], _theta(), state0=traj.state)


def test_relaxed_state_is_static_equilibrium():
    model = MRCElectromechanical(3)
    theta = _theta()
    u = np.full(200, 25.0)
    y = model.simulate(u, T[:200], theta)
    np.testing.assert_allclose(y, theta["gain"] * 25.0, rtol=1e-14)
    assert isinstance(get("mrc"), MRCElectromechanical)
    p = model.physical_parameters(theta, C=1.0, k=1.0)
    np.testing.assert_allclose(p["v_i"] / (1.0 / p["C_i"]), theta["delta"])
    assert p["T_F"] * p["T_q"] / (p["k"] * p["C"]) == pytest.approx(theta["coupling"])
