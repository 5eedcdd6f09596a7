"""Bouc–Wen in the ``saturation`` parametrisation (``h_sat``, ``kappa``).

Oracles: the classical model at the mapped ``beta, gamma`` (the same equations, so the
same output to the last bit of the mapping), the saturation level reached on a long
monotone input (``h -> (α/(β+γ))^(1/n)``, the definition of ``h_sat``), and the
forward model for the inverse.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayeshyst.data.record import Record
from bayeshyst.errors import ModelError
from bayeshyst.models.bouc_wen import AsymmetricBoucWen, BoucWen
from bayeshyst.models.bouc_wen_variants import AsymmetricBoucWenSgn
from bayeshyst.models.registry import get

SAT = {"k": 0.8, "alpha": 3.0, "h_sat": 2.0, "kappa": 4.0, "n": 2.5}


def _mapped(theta: dict) -> dict:
    """beta, gamma from h_sat, kappa by hand: beta + gamma = alpha / h_sat^n and
    (beta - gamma) / (beta + gamma) = kappa."""
    b_rise = theta["alpha"] / theta["h_sat"] ** theta["n"]
    return {"k": theta["k"], "alpha": theta["alpha"], "n": theta["n"],
            "beta": b_rise * (1 + theta["kappa"]) / 2, "gamma": b_rise * (1 - theta["kappa"]) / 2}


def _sine(amp: float = 10.0, spp: int = 200, periods: float = 2.5) -> np.ndarray:
    k = np.arange(int(spp * periods) + 1)
    return amp * np.sin(2 * np.pi * k / spp)


@pytest.mark.parametrize("sign", [-1, 1])
@pytest.mark.parametrize("theta", [SAT, {**SAT, "kappa": 0.05, "n": 1.0},
                                   {**SAT, "kappa": 2000.0, "n": 4.3, "h_sat": 6.0}])
def test_same_output_as_the_classical_model_at_the_mapped_parameters(sign, theta):
    u = _sine()
    t = np.arange(u.size) / 1000.0
    y = BoucWen(sign=sign, parametrisation="saturation").simulate(u, t, theta)
    ref = BoucWen(sign=sign).simulate(u, t, _mapped(theta))
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.ptp(ref))


def test_h_sat_is_the_level_h_saturates_at():
    model = BoucWen(parametrisation="saturation")
    u = np.linspace(0.0, 200.0, 4001)  # a long monotone stroke: h relaxes to its bound
    theta = {**SAT, "k": 0.0}
    h = -model.simulate(u, np.arange(u.size), theta)  # y = k u - h with k = 0
    assert h[-1] == pytest.approx(SAT["h_sat"], rel=1e-9)
    assert model.h_bound(theta) == SAT["h_sat"]
    assert BoucWen().h_bound(_mapped(SAT)) == pytest.approx(SAT["h_sat"], rel=1e-12)


def test_every_prior_draw_is_in_the_stable_region():
    # the classical priors put ~7 % of their mass at |gamma| > beta (flagged failed); in
    # the saturation coordinates the stable region is the whole space
    rng = np.random.default_rng(0)
    u = _sine()
    rec = Record(t=np.arange(u.size) / 1000.0, u=u, y=0.3 * u)
    thetas = {}
    for parametrisation, expect_failures in (("saturation", False), ("classical", True)):
        model = BoucWen(parametrisation=parametrisation)
        space = model.param_space(rec)
        thetas[parametrisation] = space.unpack(space.sample_prior(rng, 400))
        traj = model.run_batch(rec.u, rec.t, thetas[parametrisation])
        assert bool(traj.failed.any()) is expect_failures, parametrisation
    bw = BoucWen(parametrisation="saturation").classical(thetas["saturation"])
    assert np.all(bw["beta"] + bw["gamma"] > 0) and np.all(bw["beta"] - bw["gamma"] > 0)


def test_priors_are_in_output_units_whatever_n():
    rec = Record(t=np.arange(11.0), u=np.linspace(0, 100, 11), y=np.linspace(0, 40, 11),
                 units={"t": "s", "u": "V", "y": "um"})
    space = BoucWen(parametrisation="saturation").param_space(rec)
    assert space.names == ("k", "alpha", "h_sat", "kappa", "n")
    assert space["h_sat"].unit == "um"
    assert math.exp(space["h_sat"].prior.mu) == pytest.approx(0.15 * 40)  # the median
    assert math.exp(space["kappa"].prior.mu) == pytest.approx(1.0)


@pytest.mark.parametrize("sign", [-1, 1])
def test_inverse_drives_the_forward_model_to_the_target(sign):
    model = BoucWen(sign=sign, parametrisation="saturation")
    # k u - h is invertible where k exceeds dh/du (<= alpha + (beta - gamma) h_sat^n)
    theta = {**SAT, "k": 1.2 if sign == 1 else 20.0}
    u = _sine(amp=3.0)
    t = np.arange(u.size) / 1000.0
    y_d = model.simulate(u, t, theta)
    u_ff = model.inverse(y_d, t, theta)
    np.testing.assert_allclose(model.simulate(u_ff, t, theta), y_d, atol=1e-7 * np.ptp(y_d))


def test_asymmetric_model_takes_the_parametrisation_too():
    theta = {**SAT, "delta": 0.02}
    u = _sine(amp=5.0)
    t = np.arange(u.size) / 1000.0
    y = AsymmetricBoucWen(parametrisation="saturation").simulate(u, t, theta)
    ref = AsymmetricBoucWen().simulate(u, t, {**_mapped(SAT), "delta": 0.02})
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12 * np.ptp(ref))
    assert "delta" in AsymmetricBoucWen(parametrisation="saturation").param_space().names


def test_spec_string_and_bad_settings():
    model = get("bouc_wen(sign=1, parametrisation='saturation')")
    assert model == BoucWen(sign=1, parametrisation="saturation")
    with pytest.raises(ModelError, match="parametrisation: expected one of classical, "
                                         "saturation, got 'branches'"):
        BoucWen(parametrisation="branches")
    with pytest.raises(ModelError, match="only the classical parametrisation"):
        AsymmetricBoucWenSgn(parametrisation="saturation")


def test_overflowing_saturation_power_is_a_failed_walker_not_nan_parameters():
    model = BoucWen(parametrisation="saturation")
    u = _sine()
    theta = {k: np.array([v, v]) for k, v in SAT.items()}
    theta["h_sat"] = np.array([2.0, 1e300])  # h_sat^n overflows: beta + gamma = 0
    traj = model.run_batch(u, np.arange(u.size) / 1000.0, theta)
    assert traj.failed.tolist() == [False, True]
    assert np.all(np.isfinite(traj.y[0])) and math.isnan(traj.y[1, 0])


@pytest.mark.parametrize("theta", [
    # the MR damper's posterior at 0 A (N, mm): a return ~1000 times steeper than the
    # rise, n near 1 -- and a sharper, higher-n variant of it
    {"k": 0.12, "alpha": 540.0, "h_sat": 146.5, "kappa": 1000.0, "n": 1.1},
    {"k": 0.12, "alpha": 385.0, "h_sat": 95.0, "kappa": 2000.0, "n": 4.3}])
def test_sharp_force_loop_matches_solve_ivp(theta):
    from tests.test_bouc_wen import TOL, ivp_bw

    u = _sine(amp=25.0, spp=50, periods=2.0)  # 3 mm of stroke per sample at the sine's centre
    y = BoucWen(sign=1, parametrisation="saturation").simulate(u, np.arange(u.size), theta)
    bw = _mapped(theta)
    y_ref = theta["k"] * u + ivp_bw(u, bw["alpha"], bw["beta"], bw["gamma"], bw["n"])
    assert np.max(np.abs(y - y_ref)) <= TOL * np.ptp(y_ref)
